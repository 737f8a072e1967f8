"""Learners: brax's PPO and SAC (``brax/``), and the off-policy family TD3 and DroQ
(``offpolicy/``)."""
