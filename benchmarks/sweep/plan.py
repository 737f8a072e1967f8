"""The sweep's plan: its sections, each declared once (benchmarks/sweep/section.py); its presets are
benchmarks/sweep/presets.py.

Sections: ``table1`` (5-stage x easy/medium/hard x algorithms x seeds, evaluated in the training and
testing environments), ``table2`` (timings, from the table1 runs), ``stages`` (stage scan),
``transfer`` (train on one mode, test on each), ``feedback`` (train at k = 1, test at k = 1..100),
``budget`` (benchmarks/budget/plan.py) and, when named, ``reality`` (benchmarks/sweep/reality.py).
``register(section)`` adds a section.
"""

from __future__ import annotations

import abc

from agents.registry import Registry
from benchmarks.budget import plan as budget
from benchmarks.sweep import lock_table, presets, reality
from benchmarks.sweep import report, report_scans, report_table1
from benchmarks.sweep.paper import MODES
from benchmarks.sweep.records import Controller, Evaluation, seed_label
from benchmarks.sweep.section import TEST_SEED_OFFSET, CellSection, Section
from ops_jax import EnvSpec


def table1_controller(mode: str, algo: str) -> Controller:
    """The table-1 controller of ``algo`` trained in ``mode`` (5 stages)."""
    return Controller(prefix=f"table1-{mode}-{algo}", algo=algo, env=table1_env(mode))


def table1_env(mode: str) -> EnvSpec:
    """The table-1 environment of ``mode``: 5 stages, the ideal system."""
    return EnvSpec(stages=5, mode=mode)


def table1_ceilings() -> dict:
    """{mode: ``ops_jax.imperfections.ceilings`` of the table-1 environment of ``mode``}."""
    from ops_jax.imperfections import ceilings

    return {mode: ceilings(table1_env(mode)) for mode in MODES}


def table1_units(sweep) -> list:
    """The table-1 trainings: every algorithm on the 5-stage system in each mode, each seed."""
    return [
        u
        for mode in MODES
        for algo in sweep.algos
        for u in sweep.train_units(table1_controller(mode, algo), range(sweep.preset["seeds"]))
    ]


def table1_runs(sweep) -> dict:
    """{(mode, algo, seed): cell record} of the table-1 trainings (read once per sweep)."""
    if "table1" not in sweep.memo:
        runs = {}
        for mode in MODES:
            for algo in sweep.algos:
                records = sweep.trained_seeds(
                    table1_controller(mode, algo), range(sweep.preset["seeds"])
                )
                runs.update({(mode, algo, seed): r for seed, r in records.items()})
        sweep.memo["table1"] = runs
    return sweep.memo["table1"]


class Table1(Section):
    """Final P/Pmax in the training and testing environments, Welch's t-test bolding; the curves;
    the lock figures."""

    name = "table1"

    def units(self, sweep):
        return table1_units(sweep)

    def results(self, sweep):
        return table1_runs(sweep)

    def report(self, sweep, runs):
        report_table1.table1(sweep.out, runs, sweep.preset)
        report.training_curves(sweep.out, runs, sweep.preset)
        report.testing_curves(sweep.out, runs, sweep.preset)
        lock_table.lock_table(sweep.out, runs, sweep.preset, table1_ceilings())


class Table2(Table1):
    """The paper's Table 2 (time usage), from the table-1 runs."""

    name = "table2"

    def report(self, sweep, runs):
        report.table2(sweep.out, runs, sweep.preset)


class Stages(Section):
    """Stage scan N = lo..hi: final testing P/Pmax and training convergence step."""

    name = "stages"

    @staticmethod
    def _controllers(sweep) -> list:
        """(N, mode, controller) of each trained controller."""
        lo, hi = sweep.preset["stage_range"]
        algos = [a for a in sweep.preset["stage_algos"] if a in sweep.algos]
        return [
            (
                n,
                mode,
                Controller(
                    prefix=f"stages-N{n}-{mode}-{algo}", algo=algo, env=EnvSpec(stages=n, mode=mode)
                ),
            )
            for n in range(lo, hi + 1)
            for mode in sweep.preset["stage_modes"]
            for algo in algos
        ]

    def units(self, sweep):
        return [
            u
            for _, _, controller in self._controllers(sweep)
            for u in sweep.train_units(controller, range(sweep.preset["stage_seeds"]))
        ]

    def results(self, sweep):
        res = {}
        for n, mode, controller in self._controllers(sweep):
            records = sweep.trained_seeds(controller, range(sweep.preset["stage_seeds"]))
            res.update({(n, mode, controller.algo, seed): r for seed, r in records.items()})
        return res

    def report(self, sweep, res):
        report_scans.stages(sweep.out, res, sweep.preset)


class TableOneEvaluations(Section):
    """Evaluations of the table-1 controllers (the first ``aux_seeds`` seeds) in other environments:
    ``evals(sweep, mode) -> [(key, label prefix, env options)]`` for the controllers trained in
    ``mode``."""

    @abc.abstractmethod
    def evals(self, sweep, mode: str) -> list:
        """(key, label prefix, env options) of each evaluation of the controllers of ``mode``."""

    def _tests(self, sweep) -> list:
        """(mode, controller, seed, [(result key, Evaluation)]) of each table-1 controller tested
        here."""
        out = []
        for mode in MODES:
            for algo in sweep.algos:
                for seed in range(sweep.aux_seeds):
                    tests = [
                        (
                            (*key, algo, seed),
                            Evaluation(
                                label=seed_label(f"{label}-{algo}", seed),
                                env=env,
                                seed=seed + TEST_SEED_OFFSET,
                            ),
                        )
                        for key, label, env in self.evals(sweep, mode)
                    ]
                    if tests:
                        out.append((mode, table1_controller(mode, algo), seed, tests))
        return out

    def units(self, sweep):
        return table1_units(sweep) + [
            sweep.eval_unit(
                f"{self.name}-evals-{mode}-{controller.algo}-s{seed}",
                controller,
                seed,
                [evaluation for _, evaluation in tests],
            )
            for mode, controller, seed, tests in self._tests(sweep)
        ]

    def results(self, sweep):
        runs = table1_runs(sweep)
        return {
            key: sweep.evaluated(evaluation, runs[mode, controller.algo, seed])
            for mode, controller, seed, tests in self._tests(sweep)
            for key, evaluation in tests
        }


class Transfer(TableOneEvaluations):
    """Trained on one mode, tested on each."""

    name = "transfer"

    def evals(self, sweep, mode):
        return [
            ((mode, test), f"transfer-{mode}-{test}", {"stages": 5, "mode": test}) for test in MODES
        ]

    def report(self, sweep, res):
        report_scans.transfer(sweep.out, res, sweep.preset)


class Feedback(TableOneEvaluations):
    """Trained at k = 1 (hard mode), tested at each feedback delay factor k."""

    name = "feedback"

    def evals(self, sweep, mode):
        return [
            ((k,), f"feedback-k{k}", {"stages": 5, "mode": "hard", "feedback_k": k})
            for k in sweep.preset["feedback_ks"]
            if mode == "hard"
        ]

    def report(self, sweep, res):
        report_scans.feedback(sweep.out, res, sweep.preset)


PLAN = Registry("sweep section")  # name -> Section, in the order the sweep runs and reports them
register, unregister = PLAN.register, PLAN.unregister


def default_sections() -> tuple:
    """The sections of a run without ``--only``."""
    return tuple(name for name, s in PLAN.items() if s.default)


def _budget_cell(config: dict) -> budget.Cell:
    """The lab-budget cell of its stored configuration (the sweep's ``section`` key left out)."""
    return budget.Cell.from_dict({k: v for k, v in config.items() if k != "section"})


def _budget_section() -> CellSection:
    """Score against env steps on a lab's budget (benchmarks/budget/plan.py), at the budget preset
    of ``presets.BUDGET_PRESETS``; part of a run without ``--only``. Its cells are stored as dicts
    (``benchmarks.budget.cell.Cell.to_dict``), read back into records here."""
    return CellSection(
        "budget",
        lambda p: [c.to_dict() for c in budget.cells(presets.BUDGET_PRESETS[p["name"]])],
        lambda config: budget.compute(_budget_cell(config)),
        lambda records, out: budget.report(
            [{"cell": _budget_cell(c), "result": r} for c, r in records], out / "budget"
        ),
        default=True,
        cost=lambda config: budget.cost(_budget_cell(config)),
    )


for _section in (
    Table1(),
    Table2(),
    Stages(),
    Transfer(),
    Feedback(),
    reality.Reality(),
    _budget_section(),
):
    register(_section)
