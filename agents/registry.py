"""The algorithms of ``agents``: one ``Algo`` entry each (name, module, config type, display name,
whether its seeds train in one vmapped call, its sweep presets). ``agents.ALGOS``, the command
line's ``--algo`` choices, the sweep's learners, cost table and table names all read this registry.

A new algorithm is its module (meeting ``AlgoModule``) plus one ``register`` line::

    register(Algo("mine", "agents.mine", MineConfig, "Mine", sweep=SweepPresets(...)))
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Mapping
from typing import Callable, Protocol

from agents.config import DroQConfig, PhysicsConfig, PPOConfig, SACConfig, SPGDConfig, TD3Config


class AlgoModule(Protocol):
    """What an algorithm's module provides (see ``agents.base``)."""

    def train(self, env_config: dict, *, seed: int, total_steps: int | None, progress_fn: Callable | None,
              **hyper): ...  # -> TrainResult

    def make_policy(self, env_config: dict, hyper: dict): ...  # -> Policy

    def params_template(self, env_config: dict, hyper: dict): ...  # pytree of the parameters' structure


@dataclasses.dataclass(frozen=True)
class SweepPresets:
    """An algorithm's part of the sweep's presets ("quick", "default", "paper"): training budget (env
    steps) and hyperparameter overrides per preset, the reality section's own budgets, and the cost
    model on one worker of a 2-core CPU: a training cell (``fixed_s`` + ``s_per_step`` x budget) x
    ``stage_growth`` ** (N - 5) on N > 5 stages; an evaluation cell of 32 episodes, ``eval_s``."""

    budgets: dict
    hyper: dict = dataclasses.field(default_factory=dict)
    reality_budgets: dict = dataclasses.field(default_factory=dict)
    fixed_s: float = 5.0
    s_per_step: float = 0.0
    stage_growth: float = 1.0
    eval_s: float = 1.0

    def cell_seconds(self, steps: int, stages: int = 5) -> float:
        """Estimated seconds of one training cell with a budget of ``steps`` env steps on ``stages`` stages."""
        return (self.fixed_s + self.s_per_step * steps) * self.stage_growth ** max(0, stages - 5)


@dataclasses.dataclass(frozen=True)
class Algo:
    """One algorithm: ``name`` (``agents.train``'s ``algo``), ``module`` (an ``AlgoModule``), ``config``
    (its type of ``agents.config``), ``display`` (tables, figures), ``vmaps_seeds`` (the module's
    ``train_seeds`` trains several seeds in one call), ``sweep`` (its presets of benchmarks.sweep)."""

    name: str
    module: str
    config: type
    display: str
    vmaps_seeds: bool = False
    sweep: SweepPresets | None = None

    @property
    def learner(self) -> bool:
        """Whether it trains (its config has named hyperparameter sets, "paper" / "fast")."""
        return "config" in {f.name for f in dataclasses.fields(self.config)}

    def settings(self, hyper: dict) -> dict:
        """Every field of the config that ``hyper`` (a preset name under "config" and overrides) resolves to, in its
        stored form: what a run with ``hyper`` trains with under the presets of this version."""
        return self.config.from_hyper(hyper).to_hyper()

    def load(self) -> AlgoModule:
        return importlib.import_module(self.module)


class Registry(dict):
    """Entries by their ``name``, in the order registered; ``what`` names an entry in messages."""

    def __init__(self, what: str):
        super().__init__()
        self.what = what

    def register(self, entry):
        """Add ``entry`` (its name must be new); returns it."""
        if entry.name in self:
            raise ValueError(f"{self.what} {entry.name!r} is registered already")
        self[entry.name] = entry
        return entry

    def unregister(self, name: str) -> None:
        self.pop(name)

    def entry(self, name: str):
        """The entry ``name`` (ValueError listing the registered names otherwise)."""
        if name not in self:
            raise ValueError(f"{self.what} must be one of {sorted(self)}, got {name!r}")
        return self[name]


REGISTRY = Registry("algo")  # name -> Algo
register, unregister, get = REGISTRY.register, REGISTRY.unregister, REGISTRY.entry


class _Column(Mapping):
    """A live read-only view name -> one attribute of each registered ``Algo``."""

    def __init__(self, attr: str):
        self.attr = attr

    def __getitem__(self, name):
        return getattr(REGISTRY[name], self.attr)

    def __iter__(self):
        return iter(REGISTRY)

    def __len__(self):
        return len(REGISTRY)


CONFIG_TYPES = _Column("config")  # name -> config type
NAMES = _Column("display")  # name -> display name

# Sweep cost constants fitted to the default preset's measured run (docs/results.md): medians of its
# table-1 cells (PPO 94.7 s for 1,916,928 env steps, SAC 69.3 s for 99,968, TD3 38.5 s per seed for
# 59,776, physics-informed 5.5 s), its stage scan (physics-informed at N = 6 and 7: 14-107 s) and its
# evaluations (physics-informed 5.4-6.1 s, the others 0.1-0.2 s of rollout).
register(Algo("spgd", "agents.spgd", SPGDConfig, "SPGD",
              sweep=SweepPresets(budgets={"quick": 0, "default": 0, "paper": 0}, fixed_s=2.0)))
register(Algo("physics", "agents.physics_informed", PhysicsConfig, "Physics",
              sweep=SweepPresets(budgets={"quick": 0, "default": 0, "paper": 0}, fixed_s=6.0, stage_growth=3.5, eval_s=6.0,
                                 hyper={"quick": {"starts": 4, "iters": 4},
                                        "default": {"starts": 8, "iters": 6}})))  # half the fit cost of 16 x 8
register(Algo("ppo", "agents.ppo", PPOConfig, "PPO",
              sweep=SweepPresets(budgets={"quick": 32_768, "default": 2_000_000, "paper": 200_000},
                                 hyper={"quick": {"num_evals": 2, "num_eval_envs": 16, "hidden": [64, 64],
                                                  "num_updates_per_batch": 2}},
                                 s_per_step=4.7e-5)))
register(Algo("sac", "agents.sac", SACConfig, "SAC",
              sweep=SweepPresets(budgets={"quick": 3_000, "default": 100_000, "paper": 200_000},
                                 hyper={"quick": {"min_replay_size": 1024, "num_evals": 2, "num_eval_envs": 16,
                                                  "hidden": [64, 64], "grad_updates_per_step": 4, "batch_size": 256},
                                        "default": {"min_replay_size": 2048}},
                                 # randomised training is far from done at 100k (docs/imperfections.md)
                                 reality_budgets={"default": 300_000},
                                 s_per_step=6.4e-4)))
register(Algo("td3", "agents.td3", TD3Config, "TD3", vmaps_seeds=True,
              sweep=SweepPresets(budgets={"quick": 3_000, "default": 60_000, "paper": 250_000},
                                 hyper={"quick": {"learning_starts": 1024, "eval_every": 1000, "eval_episodes": 4},
                                        "default": {"eval_every": 5000}},
                                 fixed_s=3.0, s_per_step=5.9e-4)))
register(Algo("droq", "agents.droq", DroQConfig, "DroQ", vmaps_seeds=True))  # in the sweep's budget section only
