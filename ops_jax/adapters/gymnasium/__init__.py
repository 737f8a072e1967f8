"""The Gymnasium adapters (``OPSGymEnv``, ``OPSVectorEnv``) and their jitted programs."""
