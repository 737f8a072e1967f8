"""A section of ``benchmarks.sweep``: a name, its cells as work units, and its report.

The plan (benchmarks/sweep_plan.py) is a list of sections; the unit list, the executor and the
report pass all iterate the same objects. A section's ``units(sweep)`` declares its work (cell
labels and configurations: the one place they are written), ``results(sweep)`` reads its cells back
from the store (computing any that are missing) and ``report(sweep, results)`` writes its tables
and figures. ``CellSection`` adapts a section of independent cells given as three functions.
"""

from __future__ import annotations

from typing import Callable

TEST_SEED_OFFSET = 10_000  # the testing environment's seed: the training seed + this
EVAL_S = 1.0  # seconds of a cell of a section that estimates none (algorithms: agents.registry.CostModel)
IMPERFECT_COST = 3.0  # a cell's cost factor with lab imperfections (docs/imperfections.md: 3.5-6x the ideal step)


def seed_label(prefix: str, seed: int) -> str:
    """The label of the training cell of seed ``seed`` among a section's cells ``prefix`` (one controller)."""
    return f"{prefix}-s{seed}"


class Section:
    """One part of the sweep. ``default``: part of a run without ``--only``."""

    name: str = ""
    default: bool = True

    def units(self, sweep) -> list:
        """The work units of this section's cells (``Sweep.train_units`` / ``Sweep.eval_unit`` dicts;
        units shared with another section carry the same key and are computed once)."""
        raise NotImplementedError

    def results(self, sweep):
        """This section's stored cells, in the form ``report`` takes."""
        raise NotImplementedError

    def report(self, sweep, results) -> None:
        """Write this section's tables and figures into ``sweep.out``."""
        raise NotImplementedError

    def compute(self, config: dict) -> dict:
        """The result of one cell of kind "cell" (``CellSection``)."""
        raise NotImplementedError(f"section {self.name} has no cells of its own kind")


class CellSection(Section):
    """A section of independent cells: ``cells(preset) -> [config dict]`` (each JSON-able; optional keys
    ``label`` and ``cost``, estimated seconds), ``compute(config) -> result dict`` (run by a worker) and
    ``report(records, out) -> str`` (records: [(config, result)]; returns the report's text); ``cost(config)``
    (optional) estimates a cell's seconds without being part of its configuration."""

    def __init__(self, name: str, cells: Callable, compute: Callable, report: Callable, default: bool = False,
                 cost: Callable | None = None):
        self.name, self.default = name, default
        self._cells, self._compute, self._report = cells, compute, report
        self._cost = cost or (lambda config: float(config.get("cost", EVAL_S)))

    def labelled(self, preset: dict) -> list:
        """[(label, config)] of the preset's cells."""
        return [(c.get("label", f"{self.name}-{i}"), dict(c, section=self.name))
                for i, c in enumerate(self._cells(preset))]

    def units(self, sweep) -> list:
        return [dict(key=label, algo=self.name, kind="cell", section=self.name, cells=[(label, config)], deps=[],
                     cost=float(self._cost(config))) for label, config in self.labelled(sweep.p)]

    def compute(self, config: dict) -> dict:
        return self._compute({k: v for k, v in config.items() if k != "section"})

    def results(self, sweep) -> list:
        return [({k: v for k, v in config.items() if k != "section"},
                 sweep.cells.get(label, config, lambda c=config: self.compute(c)))
                for label, config in self.labelled(sweep.p)]

    def report(self, sweep, results) -> None:
        self._report(results, sweep.out)
