"""The registry of algorithms: one ``Algo`` entry each (name, module, config type, display name, the
optional protocol members its module provides). ``agents.ALGOS`` and the command line's ``--algo``
choices read this registry, and so do the benchmarks (their own presets, budgets and cost models, in
``benchmarks/``, name the algorithms by their entries' names).

Each algorithm is one unit: its module declares its config type and its entry, ``ALGO``, beside its
code (``agents.learners.offpolicy.td3``: ``TD3Config`` and
``ALGO = Algo("td3", __name__, TD3Config, "TD3", ...)``); ``agents.algos`` (imported with the
package) registers each with one line. This module names none of them, so the algorithms may use
``agents.api``, which looks them up here. A new algorithm is its module (meeting ``AlgoModule``,
with its ``ALGO``) plus one line in ``agents.algos``::

    register_module("agents.mine")
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Mapping
from typing import Any, Callable, Protocol

from ops_jax import EnvSpec


class AlgoModule(Protocol):
    """What an algorithm's module provides (see ``agents.api``): ``train`` of an ``EnvSpec`` (or a
    dict of its options) and a preset or config with overrides; ``make_policy`` and
    ``params_template`` of a ``TrainResult``'s ``env_spec`` and ``config``."""

    def train(
        self,
        env_config: EnvSpec | dict,
        *,
        seed: int,
        total_steps: int | None,
        progress_fn: Callable | None,
        **hyper,
    ): ...  # -> TrainResult

    def make_policy(self, env_spec: EnvSpec, config): ...  # -> Policy

    def params_template(self, env_spec: EnvSpec, config): ...  # pytree of the parameters' structure


class SeedsModule(AlgoModule, Protocol):
    """An ``AlgoModule`` that trains several seeds in one vmapped call (``Algo.vmaps_seeds``)."""

    def train_seeds(
        self,
        env_config: EnvSpec | dict,
        *,
        seeds,
        total_steps: int | None = None,
        progress_fn=None,
        **hyper,
    ): ...  # -> list[TrainResult]


class OffPolicyModule(SeedsModule, Protocol):
    """A ``SeedsModule`` of ``agents.learners.offpolicy.driver`` (``Algo.off_policy``): its one run
    passes every checkpoint."""

    LEARNER: Any  # agents.learners.offpolicy.learner.Learner


@dataclasses.dataclass(frozen=True)
class Algo:
    """One algorithm: ``name`` (``agents.train``'s ``algo``), ``module`` (an ``AlgoModule``),
    ``config`` (its ``agents.config.AlgoConfig`` type), ``display`` (tables, figures),
    ``vmaps_seeds`` (the module is a ``SeedsModule``), ``off_policy`` (an ``OffPolicyModule``),
    ``needs`` (a module its training imports, imported by ``load``: where an extra is missing, the
    program stops there, before any work)."""

    name: str
    module: str
    config: type
    display: str
    vmaps_seeds: bool = False
    off_policy: bool = False
    needs: str = ""

    @property
    def learner(self) -> bool:
        """Whether it trains (its config has named hyperparameter sets, "paper" / "fast")."""
        return "config" in {f.name for f in dataclasses.fields(self.config)}

    def settings(self, hyper: dict) -> dict:
        """Every field of the config that ``hyper`` (a preset name under "config" and overrides)
        resolves to, in its stored form: what a run with ``hyper`` trains with under the presets of
        this version."""
        return self.config.from_hyper(hyper).to_hyper()

    def members(self) -> tuple:
        """The names its module must provide: ``AlgoModule``'s, and ``SeedsModule``'s /
        ``OffPolicyModule``'s where declared."""
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
        if self.needs:
            importlib.import_module(self.needs)
        missing = [m for m in self.members() if not hasattr(module, m)]
        if missing:
            raise TypeError(
                f"algo {self.name!r}: module {self.module} lacks {missing}, which its entry "
                "declares"
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


def register_module(module: str) -> Algo:
    """Import ``module`` and register the ``Algo`` it declares as ``ALGO`` (whose ``module`` must be
    it)."""
    entry = getattr(importlib.import_module(module), "ALGO", None)
    if not isinstance(entry, Algo) or entry.module != module:
        raise TypeError(
            f"module {module} must declare ALGO, an agents.registry.Algo of module {module!r}"
        )
    return register(entry)


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
