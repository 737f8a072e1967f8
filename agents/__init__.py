"""Controllers and learners for OPS: SPGD-PID, PPO and SAC (brax.training), TD3, DroQ, and a
physics-informed controller, behind one ``train`` / ``evaluate`` / ``save`` / ``load`` API, each
configured by its config type (declared beside its code, on the base ``agents.config.AlgoConfig``:
presets "paper", "fast", ... overridable per field); ``agents.controllers.trim``: an
extremum-seeking trim around any of their policies."""

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
from agents.controllers.physics_informed import PhysicsConfig
from agents.controllers.spgd import SPGDConfig
from agents.controllers.trim import TrimConfig
from agents.learners.brax.ppo import PPOConfig
from agents.learners.brax.sac import SACConfig
from agents.learners.offpolicy.droq import DroQConfig
from agents.learners.offpolicy.td3 import TD3Config

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
