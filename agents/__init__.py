"""Controllers and learners for OPS: SPGD-PID, PPO and SAC (brax.training), TD3, DroQ, and a
physics-informed controller, behind one ``train`` / ``evaluate`` / ``save`` / ``load`` API, each
configured by its config type (``agents.config``: presets "paper", "fast", ... overridable per field)."""

from agents.base import ALGOS, EvalResult, Policy, TrainResult, evaluate, load, save, summarize, train, train_seeds
from agents.config import DroQConfig, PhysicsConfig, PPOConfig, SACConfig, SPGDConfig, TD3Config

__all__ = ["ALGOS", "DroQConfig", "EvalResult", "PPOConfig", "PhysicsConfig", "Policy", "SACConfig", "SPGDConfig",
           "TD3Config", "TrainResult", "evaluate", "load", "save", "summarize", "train", "train_seeds"]
