"""The sweep's typed records, from the plan (benchmarks/sweep/plan.py) through the Ray workers
(benchmarks/sweep/executor.py) to the report: a stored ``Cell``, a ``Controller`` a section trains,
an ``Evaluation`` of one, and the work units ``TrainUnit``, ``EvalUnit`` and ``SectionUnit``.

Frozen dataclasses built by keyword (an unknown field is a TypeError), picklable (Ray ships the
units). A cell's stored form is its ``config`` dict, keyed by ``Cell.key``
(``benchmarks.cells.config_hash``): the records carry it as it is, so the cells stored before these
records existed keep their keys.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from benchmarks.cells import config_hash
from ops_jax import EnvSpec


def seed_label(prefix: str, seed: int) -> str:
    """The label of seed ``seed``'s cell among cells ``prefix`` (one controller or one of its
    tests)."""
    return f"{prefix}-s{seed}"


@dataclasses.dataclass(frozen=True, kw_only=True)
class Cell:
    """One stored cell: its readable ``label`` and its configuration ``config`` (the stored form,
    JSON-able)."""

    label: str
    config: dict

    @property
    def key(self) -> str:
        """The hash of ``config`` (16 hex digits): with the label, the cell's file name in the
        store."""
        return config_hash(self.config)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Controller:
    """A controller a section trains: ``algo`` on ``env`` (an ``EnvSpec``; a dict of
    ``ops_jax.make`` options is converted), ``hyper`` overriding the preset's hyperparameters,
    ``steps`` its budget in env steps (None: the preset's); its training cells are labelled
    ``<prefix>-s<seed>``."""

    prefix: str
    algo: str
    env: EnvSpec
    hyper: dict = dataclasses.field(default_factory=dict)
    steps: int | None = None

    def __post_init__(self):
        object.__setattr__(self, "env", EnvSpec.from_options(self.env))

    def label(self, seed: int) -> str:
        """The label of seed ``seed``'s training cell."""
        return seed_label(self.prefix, seed)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Evaluation:
    """A test of a trained controller: cell ``label``, environment ``env`` (an ``EnvSpec``; a dict
    is converted) and episode seed ``seed``."""

    label: str
    env: EnvSpec
    seed: int

    def __post_init__(self):
        object.__setattr__(self, "env", EnvSpec.from_options(self.env))


@dataclasses.dataclass(frozen=True, kw_only=True)
class Unit:
    """The work one worker does in one call: ``key`` (unique in a plan), ``algo`` (what its compiled
    programs are for), its ``cells``, ``cost`` (estimated seconds) and ``deps`` (keys of the units
    whose checkpoints it needs)."""

    kind: ClassVar[str] = ""
    key: str
    algo: str
    cells: tuple[Cell, ...]
    cost: float
    deps: tuple[str, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "cells", tuple(self.cells))
        object.__setattr__(self, "deps", tuple(self.deps))


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrainUnit(Unit):
    """The training cells of ``controller``, one per seed, trained in one ``Sweep.trained_seeds``
    call."""

    kind: ClassVar[str] = "train"
    controller: Controller

    @property
    def seeds(self) -> tuple[int, ...]:
        """The seeds of its cells, in order."""
        return tuple(cell.config["seed"] for cell in self.cells)


@dataclasses.dataclass(frozen=True, kw_only=True)
class EvalUnit(Unit):
    """The ``evals`` of the controller of training cell ``train`` (one cell each)."""

    kind: ClassVar[str] = "eval"
    train: Cell
    evals: tuple[Evaluation, ...]

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "evals", tuple(self.evals))


@dataclasses.dataclass(frozen=True, kw_only=True)
class SectionUnit(Unit):
    """One cell of a ``CellSection``, computed by that section (``section``, its name)."""

    kind: ClassVar[str] = "cell"
    section: str
