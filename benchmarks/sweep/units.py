"""The sweep's work: the cells of the plan's sections (benchmarks/sweep/plan.py) as work units
(records of benchmarks/sweep/records.py), their computation into the cell store, the report pass;
compilation-cache setup of a worker process. The command line is benchmarks/sweep/command.py; the
Ray executor benchmarks/sweep/executor.py (docs/sweep.md).
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from benchmarks import costs
from benchmarks.sweep import plan as sweep_plan
from benchmarks.cells import CellStore
from benchmarks.sweep.records import Cell, Controller, EvalUnit, Evaluation, TrainUnit, Unit
from benchmarks.sweep.section import IMPERFECT_COST, TEST_SEED_OFFSET


def algo_entry(name: str):
    """The ``agents.registry.Algo`` of ``name`` (imported here: jax loads after the sweep's
    settings)."""
    from agents import registry

    return registry.get(name)


def is_learner(algo: str) -> bool:
    return algo_entry(algo).learner


class Sweep:
    """The sweep of ``preset`` into the folder ``out``: the store of its cells (``store``), the
    plan's units, their computation and the report pass."""

    def __init__(self, preset: dict, out: Path, log, meta: dict | None = None):
        """``meta``: keys stored in each cell computed here (``CellStore``)."""
        self.preset = preset
        self.out = out
        self.log = log
        self.algos = list(preset["algos"])
        self.store = CellStore(out / "cells", log, meta)
        self.timing = {}
        self.memo = {}  # results read once and shared by sections (the table-1 runs)
        self.aux_seeds = min(
            preset.get("aux_seeds", preset["seeds"]), preset["seeds"]
        )  # transfer, feedback

    # -- trained controllers --------------------------------------------------------------------
    def train_cell(self, controller: Controller, seed: int) -> Cell:
        """The training cell of ``controller``'s seed ``seed``: its configuration holds the
        environment in the dict form of ``ops_jax.EnvSpec``, the preset's hyperparameters under the
        controller's and every setting they resolve to (a changed preset is another cell)."""
        algo = controller.algo
        hyper = {"config": self.preset["algo_config"]} if is_learner(algo) else {}
        hyper.update(self.preset.get("hyper", {}).get(algo, {}))
        hyper.update(controller.hyper)
        steps = self.preset["budgets"][algo] if controller.steps is None else controller.steps
        return Cell(
            label=controller.label(seed),
            config=dict(
                kind="train",
                algo=algo,
                env=controller.env.as_dict(),
                seed=seed,
                steps=steps,
                hyper=hyper,
                episodes=self.preset["episodes"],
                settings=algo_entry(algo).settings(hyper),
            ),
        )

    @staticmethod
    def checkpoint(cell: Cell) -> str:
        """The folder of training cell ``cell``'s checkpoint, relative to the output folder."""
        return f"checkpoints/{cell.label}-{cell.key}"

    def _finished(self, cell: Cell, quiet: bool = True) -> bool:
        """Whether the training cell is stored and its checkpoint loads (what is not is reported
        unless ``quiet``)."""
        record = self.store.load(cell.label, cell.config, quiet=quiet)
        return record is not None and self._loads(record, quiet=quiet)

    def _loads(self, record: dict, quiet: bool = False) -> bool:
        """Whether a cell's checkpoint is there and loads (not truncated, corrupt or of an older
        format)."""
        import agents

        try:
            agents.load(self.out / record["checkpoint"])
            return True
        except (FileNotFoundError, ValueError) as exc:
            if not quiet:
                self.log(f"checkpoint {record['checkpoint']} unusable ({exc}): training again")
            return False

    def trained(self, controller: Controller, seed: int, result=None) -> dict:
        """Train (or reuse) ``controller`` on seed ``seed``, evaluate it in its training and testing
        environment. ``result``: an already trained ``TrainResult`` for this cell (from a multi-seed
        call)."""
        import agents

        cell, env = self.train_cell(controller, seed), controller.env
        config, checkpoint = cell.config, self.checkpoint(cell)

        # A controller with nothing to train records an evaluation as its curve: the same draws as
        # the training-environment evaluation below (which computes them again, with the compiled
        # program kept).
        curve = {} if is_learner(controller.algo) else {"curve_episodes": config["episodes"]}

        def compute():
            trained = (
                result
                if result is not None
                else agents.train(
                    controller.algo,
                    env,
                    seed=seed,
                    total_steps=config["steps"],
                    progress=False,
                    **config["hyper"],
                    **curve,
                )
            )
            agents.save(self.out / checkpoint, trained)
            ev_train = agents.evaluate(trained, env, episodes=config["episodes"], seed=seed)
            ev_test = agents.evaluate(
                trained, env, episodes=config["episodes"], seed=seed + TEST_SEED_OFFSET
            )
            return dict(
                checkpoint=checkpoint,
                curve={k: np.asarray(v).tolist() for k, v in trained.curve.items()},
                wall_time=trained.wall_time,
                train_env=_eval_record(ev_train),
                test_env=_eval_record(ev_test),
            )

        computed = self.store.computed
        record = self.store.get(cell.label, config, compute)
        if self.store.computed == computed and not self._loads(
            record
        ):  # stored cell, checkpoint lost or unusable
            self.store.path(cell.label, config).unlink()
            record = self.store.get(cell.label, config, compute)
        return record

    def trained_seeds(self, controller: Controller, seeds) -> dict:
        """{seed: ``trained`` record} of ``controller``; the unfinished seeds of an algorithm that
        vmaps seeds
        (TD3) train in one call first, then each seed's cell is written as it is evaluated."""
        import agents

        results = {}
        if algo_entry(controller.algo).vmaps_seeds:
            todo = [s for s in seeds if not self._finished(self.train_cell(controller, s))]
            if len(todo) > 1:
                config = self.train_cell(controller, todo[0]).config
                results = dict(
                    zip(
                        todo,
                        agents.train_seeds(
                            controller.algo,
                            controller.env,
                            seeds=todo,
                            total_steps=config["steps"],
                            progress=False,
                            **config["hyper"],
                        ),
                    )
                )
        return {seed: self.trained(controller, seed, results.get(seed)) for seed in seeds}

    def policy(self, record: dict):
        import agents

        return agents.load(self.out / record["checkpoint"])

    def eval_cell(self, checkpoint: str, evaluation: Evaluation) -> Cell:
        """The cell of ``evaluation`` of the controller stored at ``checkpoint`` (relative to the
        output folder)."""
        return Cell(
            label=evaluation.label,
            config=dict(
                kind="eval",
                checkpoint=checkpoint,
                env=evaluation.env.as_dict(),
                seed=evaluation.seed,
                episodes=self.preset["episodes"],
            ),
        )

    def evaluated(self, evaluation: Evaluation, record: dict) -> dict:
        """The cell of ``evaluation`` of the controller of training ``record`` (computed unless
        stored)."""
        import agents

        cell = self.eval_cell(record["checkpoint"], evaluation)
        return self.store.get(
            cell.label,
            cell.config,
            lambda: _eval_record(
                agents.evaluate(
                    self.policy(record),
                    evaluation.env,
                    episodes=cell.config["episodes"],
                    seed=evaluation.seed,
                )
            ),
        )

    # -- the plan's work units ---------------------------------------------------------------------
    def train_units(self, controller: Controller, seeds) -> list:
        """Training units of ``controller``: one unit of all ``seeds`` for an algorithm that vmaps
        seeds, else one per seed."""
        entry = algo_entry(controller.algo)
        groups = [list(seeds)] if entry.vmaps_seeds else [[s] for s in seeds]
        factor = IMPERFECT_COST if controller.env.imperfections is not None else 1.0
        units = []
        for group in groups:
            cells = [self.train_cell(controller, s) for s in group]
            config = cells[0].config
            cost = (
                len(group)
                * costs.train_s(
                    controller.algo, config["hyper"], config["steps"], controller.env.stages
                )
                * factor
            )
            units.append(
                TrainUnit(
                    key=controller.prefix if len(groups) == 1 else cells[0].label,
                    algo=controller.algo,
                    controller=controller,
                    cells=cells,
                    cost=round(cost, 1),
                )
            )
        return units

    def eval_unit(self, key: str, controller: Controller, seed: int, evals: list) -> EvalUnit:
        """The unit of ``evals`` (``Evaluation``s) of ``controller``'s seed ``seed``; it needs that
        training cell's unit (``deps``, resolved by ``units``)."""
        train = self.train_cell(controller, seed)
        cells = [self.eval_cell(self.checkpoint(train), e) for e in evals]
        factor = IMPERFECT_COST if any(e.env.imperfections is not None for e in evals) else 1.0
        return EvalUnit(
            key=key,
            algo=controller.algo,
            train=train,
            evals=evals,
            cells=cells,
            cost=len(cells) * costs.cost_model(controller.algo).eval_s * factor,
        )

    def units(self, sections) -> list:
        """The work units of ``sections`` (names of ``sweep_plan.PLAN``), in plan order, each once,
        an ``EvalUnit``'s ``deps`` naming the unit of its training cell
        (benchmarks/sweep/records.py)."""
        units, producer = {}, {}
        for name, section in sweep_plan.PLAN.items():
            for unit in section.units(self) if name in sections else ():
                if unit.key not in units:
                    units[unit.key] = unit
                    producer.update({cell.label: unit.key for cell in unit.cells})
        return [
            dataclasses.replace(u, deps=(producer[u.train.label],))
            if isinstance(u, EvalUnit)
            else u
            for u in units.values()
        ]

    def todo(self, unit: Unit):
        """``unit`` reduced to its cells not stored yet (a train unit's seeds), or None when all
        are."""
        if not isinstance(unit, TrainUnit):
            return (
                unit
                if any(self.store.load(c.label, c.config) is None for c in unit.cells)
                else None
            )
        left = [cell for cell in unit.cells if not self._finished(cell, quiet=False)]
        if not left:
            return None
        per_seed = unit.cost / len(unit.cells)
        return dataclasses.replace(unit, cells=left, cost=round(per_seed * len(left), 1))

    def compute_unit(self, unit: Unit, record: dict | None = None) -> None:
        """Compute ``unit``'s cells into this sweep's folder; an eval unit needs its controller's
        training ``record`` (and checkpoint in this folder)."""
        if isinstance(unit, TrainUnit):
            self.trained_seeds(unit.controller, unit.seeds)
        elif isinstance(unit, EvalUnit):
            for evaluation in unit.evals:
                self.evaluated(evaluation, record)
        else:
            section = sweep_plan.PLAN[unit.section]
            for cell in unit.cells:
                self.store.get(cell.label, cell.config, lambda c=cell.config: section.compute(c))

    def run(self, sections, workers=(), computed=0, started=float("nan")):
        """Load every cell of ``sections`` (computing any not stored), then write each section's
        report and the summary; returns (cells computed, cells reused). ``workers``: a record
        (algos, timing) per worker that computed ``computed`` cells for this run before;
        ``started``: the command's start (time.time()), if known."""
        from benchmarks.sweep import report as sweep_report

        t0 = time.perf_counter()
        chosen = [s for name, s in sweep_plan.PLAN.items() if name in sections]
        results = {}
        for section in chosen:
            t = time.perf_counter()
            results[section.name] = section.results(self)
            self.timing[section.name] = time.perf_counter() - t
        t = time.perf_counter()
        for section in chosen:
            section.report(self, results[section.name])
        self.timing["tables and figures"] = time.perf_counter() - t
        self.timing["total"] = time.perf_counter() - t0
        counts = (self.store.computed + computed, self.store.reused - computed)
        sweep_report.summary(
            self.out, self.preset, sections, self.timing, counts, workers, time.time() - started
        )
        return counts


def _eval_record(ev) -> dict:
    npow = np.asarray(ev.normalized_power)
    return dict(
        summary=ev.summary,
        final=npow[:, -1].tolist(),
        mean_curve=npow.mean(0).tolist(),
        std_curve=npow.std(0).tolist(),
    )


def enable_compilation_cache():
    """Persist XLA compilations (``OPS_JAX_CACHE`` or ~/.cache/ops-jax/xla): the many trainings of a
    sweep share programs that differ only in their seed, so later cells and re-runs skip
    compiling."""
    import jax

    folder = Path(os.environ.get("OPS_JAX_CACHE", Path.home() / ".cache" / "ops-jax" / "xla"))
    folder.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


QUICK_XLA_FLAG = "--xla_backend_optimization_level=0"


def quick_compilation():
    """``--quick`` compiles with XLA's backend optimisation level 0 (added to XLA_FLAGS unless that
    sets the level already; before jax's backend starts): compilation, not execution, is most of
    its wall time (docs/sweep.md). Results differ from an
    optimised build by rounding, which training amplifies; the disk cache keys include XLA_FLAGS,
    so the two builds are never mixed."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_optimization_level" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {QUICK_XLA_FLAG}".strip()
