"""Controllers and learners for OPS: SPGD-PID, PPO and SAC (brax.training), TD3, and a
physics-informed controller, behind one ``train`` / ``evaluate`` / ``save`` / ``load`` API."""

from agents.base import ALGOS, EvalResult, Policy, TrainResult, evaluate, load, save, summarize, train, train_seeds

__all__ = ["ALGOS", "EvalResult", "Policy", "TrainResult", "evaluate", "load", "save", "summarize", "train", "train_seeds"]
