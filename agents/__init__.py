"""Controllers and learners for OPS: SPGD-PID, PPO and SAC (brax.training), TD3, DroQ, and a
physics-informed controller, behind one ``train`` / ``evaluate`` / ``save`` / ``load`` API, each
configured by its config type (``agents.config``: presets "paper", "fast", ... overridable per field);
``agents.controllers.trim``: an extremum-seeking trim around any of their policies."""

from agents import algos  # noqa: F401  (registers the algorithms)
from agents.api import (
    ALGOS,
    EvalResult,
    Policy,
    TrainResult,
    evaluate,
    load,
    save,
    summarize,
    train,
    train_seeds,
)
from agents.config import (
    DroQConfig,
    PhysicsConfig,
    PPOConfig,
    SACConfig,
    SPGDConfig,
    TD3Config,
    TrimConfig,
)

__all__ = [
    "ALGOS",
    "DroQConfig",
    "EvalResult",
    "PPOConfig",
    "PhysicsConfig",
    "Policy",
    "SACConfig",
    "SPGDConfig",
    "TD3Config",
    "TrainResult",
    "TrimConfig",
    "evaluate",
    "load",
    "save",
    "summarize",
    "train",
    "train_seeds",
]
