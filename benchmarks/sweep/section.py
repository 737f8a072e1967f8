"""A section of ``benchmarks.sweep``: a name, its cells as work units, and its report.

The plan (benchmarks/sweep/plan.py) is a list of sections; the unit list, the executor and the
report pass all iterate the same objects. A section's ``units(sweep)`` declares its work (units of
benchmarks/sweep/records.py: the one place its cells are declared), ``results(sweep)`` reads its
cells back from the store (computing any that are missing) and ``report(sweep, results)`` writes its
tables and figures. ``CellSection`` adapts a section of independent cells given as three functions.
"""

from __future__ import annotations

import abc
from typing import Callable

from benchmarks.sweep.records import Cell, SectionUnit

TEST_SEED_OFFSET = 10_000  # the testing environment's seed: the training seed + this
# seconds of a cell of a section that estimates none (algorithms: benchmarks.costs.CostModel)
EVAL_S = 1.0
# a cell's cost factor with lab imperfections (docs/imperfections.md: 3.5-6x the ideal step)
IMPERFECT_COST = 3.0


class Section(abc.ABC):
    """One part of the sweep. ``default``: part of a run without ``--only``."""

    name: str = ""
    default: bool = True

    @abc.abstractmethod
    def units(self, sweep) -> list:
        """The work units of this section's cells (``benchmarks.sweep.records.Unit``s, from
        ``Sweep.train_units`` and ``Sweep.eval_unit``; units shared with another section carry the
        same key and are computed once)."""

    @abc.abstractmethod
    def results(self, sweep):
        """This section's stored cells, in the form ``report`` takes."""

    @abc.abstractmethod
    def report(self, sweep, results) -> None:
        """Write this section's tables and figures into ``sweep.out``."""

    def compute(self, config: dict) -> dict:
        """The result of one cell of kind "cell" (``CellSection``)."""
        raise NotImplementedError(f"section {self.name} has no cells of its own kind")


class CellSection(Section):
    """A section of independent cells: ``cells(preset) -> [config dict]`` (each JSON-able; optional
    keys ``label`` and ``cost``, estimated seconds), ``compute(config) -> result dict`` (run by a
    worker) and ``report(records, out) -> str`` (records: [(config, result)]; returns the report's
    text); ``cost(config)`` (optional) estimates a cell's seconds without being part of its
    configuration."""

    def __init__(
        self,
        name: str,
        cells: Callable,
        compute: Callable,
        report: Callable,
        default: bool = False,
        cost: Callable | None = None,
    ):
        self.name, self.default = name, default
        self._cells, self._compute, self._report = cells, compute, report
        self._cost = cost or (lambda config: float(config.get("cost", EVAL_S)))

    def labelled(self, preset: dict) -> list:
        """The preset's cells (``Cell``: label and stored configuration)."""
        return [
            Cell(label=c.get("label", f"{self.name}-{i}"), config=dict(c, section=self.name))
            for i, c in enumerate(self._cells(preset))
        ]

    def units(self, sweep) -> list:
        return [
            SectionUnit(
                key=cell.label,
                algo=self.name,
                section=self.name,
                cells=(cell,),
                cost=float(self._cost(cell.config)),
            )
            for cell in self.labelled(sweep.preset)
        ]

    def compute(self, config: dict) -> dict:
        return self._compute({k: v for k, v in config.items() if k != "section"})

    def results(self, sweep) -> list:
        return [
            (
                {k: v for k, v in cell.config.items() if k != "section"},
                sweep.store.get(cell.label, cell.config, lambda c=cell.config: self.compute(c)),
            )
            for cell in self.labelled(sweep.preset)
        ]

    def report(self, sweep, results) -> None:
        self._report(results, sweep.out)
