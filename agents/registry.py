"""The registry of algorithms: one ``Algo`` entry each (name, module, config type, display name,
the optional protocol members its module provides, its sweep presets, its cost model). ``agents.ALGOS``, the
command line's ``--algo`` choices, the sweep's learners, the lab-budget section's controllers, both their cost
estimates and table names all read this registry.

The entries are registered by ``agents.algos`` (imported with the package), above the algorithms' modules:
this module names none of them, so the algorithms may use ``agents.api``, which looks them up here. A new
algorithm is its module (meeting ``AlgoModule``) plus one ``register`` line in ``agents.algos``::

    register(Algo("mine", "agents.mine", MineConfig, "Mine",
                  sweep=SweepPresets(...), cost=CostModel(...)))
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Mapping
from typing import Any, Callable, Protocol


class AlgoModule(Protocol):
    """What an algorithm's module provides (see ``agents.api``)."""

    def train(
        self,
        env_config: dict,
        *,
        seed: int,
        total_steps: int | None,
        progress_fn: Callable | None,
        **hyper,
    ): ...  # -> TrainResult

    def make_policy(self, env_config: dict, hyper: dict): ...  # -> Policy

    def params_template(
        self, env_config: dict, hyper: dict
    ): ...  # pytree of the parameters' structure


class SeedsModule(AlgoModule, Protocol):
    """An ``AlgoModule`` that trains several seeds in one vmapped call (``Algo.vmaps_seeds``)."""

    def train_seeds(
        self, env_config: dict, *, seeds, total_steps: int | None = None, progress_fn=None, **hyper
    ): ...  # -> list[TrainResult]


class OffPolicyModule(SeedsModule, Protocol):
    """A ``SeedsModule`` of ``agents.learners.offpolicy.driver`` (``Algo.off_policy``): its one run passes every checkpoint."""

    LEARNER: Any  # agents.learners.offpolicy.driver.Learner


@dataclasses.dataclass(frozen=True)
class CostModel:
    """Estimated seconds of an algorithm's cells on one worker of a 2-core CPU (the sweep's units, the lab-budget
    section's cells): a training run of ``steps`` env steps, ``updates`` gradient steps, on N stages costs
    (``fixed_s`` + ``s_per_step`` x steps + ``s_per_update`` x updates) x ``stage_growth`` ** (N - 5) for N > 5;
    an evaluation of 32 episodes ``eval_s``."""

    fixed_s: float = 5.0
    s_per_step: float = 0.0
    s_per_update: float = 0.0
    stage_growth: float = 1.0
    eval_s: float = 1.0

    def train_s(self, steps: int, updates: float = 0.0, stages: int = 5) -> float:
        """Seconds of one training run of ``steps`` env steps and ``updates`` gradient steps on ``stages`` stages."""
        return (
            self.fixed_s + self.s_per_step * steps + self.s_per_update * updates
        ) * self.stage_growth ** max(0, stages - 5)


@dataclasses.dataclass(frozen=True)
class SweepPresets:
    """An algorithm's part of the sweep's presets ("quick", "default", "paper"): training budget (env
    steps) and hyperparameter overrides per preset, the reality section's own budgets; ``lab_budget``: its
    hyperparameters in the lab-budget section (benchmarks.budget.plan) per preset of that section ("quick",
    "default", "full"), where it is trained if a learner, else evaluated as a reference."""

    budgets: dict
    hyper: dict = dataclasses.field(default_factory=dict)
    reality_budgets: dict = dataclasses.field(default_factory=dict)
    lab_budget: dict = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class Algo:
    """One algorithm: ``name`` (``agents.train``'s ``algo``), ``module`` (an ``AlgoModule``), ``config``
    (its type of ``agents.config``), ``display`` (tables, figures), ``vmaps_seeds`` (the module is a
    ``SeedsModule``), ``off_policy`` (an ``OffPolicyModule``), ``sweep`` (its presets of benchmarks.sweep.command),
    ``cost`` (its cells' seconds in the sweep and the lab-budget section)."""

    name: str
    module: str
    config: type
    display: str
    vmaps_seeds: bool = False
    sweep: SweepPresets | None = None
    cost: CostModel = CostModel()
    off_policy: bool = False

    @property
    def learner(self) -> bool:
        """Whether it trains (its config has named hyperparameter sets, "paper" / "fast")."""
        return "config" in {f.name for f in dataclasses.fields(self.config)}

    def settings(self, hyper: dict) -> dict:
        """Every field of the config that ``hyper`` (a preset name under "config" and overrides) resolves to, in its
        stored form: what a run with ``hyper`` trains with under the presets of this version."""
        return self.config.from_hyper(hyper).to_hyper()

    def train_s(self, hyper: dict, steps: int, stages: int = 5) -> float:
        """``cost.train_s`` of a run of ``steps`` env steps with ``hyper`` (its gradient steps from the config)."""
        return self.cost.train_s(
            steps, steps * self.config.from_hyper(hyper).updates_per_step(), stages
        )

    def members(self) -> tuple:
        """The names its module must provide: ``AlgoModule``'s, and ``SeedsModule``'s / ``OffPolicyModule``'s where
        declared."""
        return (
            "train",
            "make_policy",
            "params_template",
            *("train_seeds",) * (self.vmaps_seeds or self.off_policy),
            *("LEARNER",) * self.off_policy,
        )

    def load(self) -> AlgoModule:
        """Its module (TypeError naming what the module lacks of ``members``)."""
        module = importlib.import_module(self.module)
        missing = [m for m in self.members() if not hasattr(module, m)]
        if missing:
            raise TypeError(
                f"algo {self.name!r}: module {self.module} lacks {missing}, which its entry declares"
            )
        return module


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
