"""The sweep's work: the cells of the plan's sections (benchmarks/sweep_plan.py) as work units, their
computation into the cell store, the report pass; compilation-cache setup of a worker process. The
command line is benchmarks/sweep.py; the Ray executor benchmarks/sweep_ray.py (docs/sweep.md).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable

import numpy as np

from benchmarks import sweep_plan
from ops_jax import EnvSpec
from benchmarks.cells import CellStore, config_hash
from benchmarks.sweep_section import IMPERFECT_COST, TEST_SEED_OFFSET, seed_label


def algo_entry(name: str):
    """The ``agents.registry.Algo`` of ``name`` (imported here: jax loads after the sweep's settings)."""
    from agents import registry

    return registry.get(name)


def is_learner(algo: str) -> bool:
    return algo_entry(algo).learner


class Sweep:
    def __init__(self, preset: dict, out: Path, log, meta: dict | None = None):
        """``meta``: keys stored in each cell computed here (``CellStore``)."""
        self.p = preset
        self.out = out
        self.log = log
        self.algos = list(preset["algos"])
        self.cells = CellStore(out / "cells", log, meta)
        self.ckpt_dir = out / "checkpoints"
        self.timing = {}
        self.memo = {}  # results read once and shared by sections (the table-1 runs)
        self.aux_seeds = min(preset.get("aux_seeds", preset["seeds"]), preset["seeds"])  # transfer, feedback

    # -- trained controllers --------------------------------------------------------------------
    def _train_config(self, algo: str, env_config: EnvSpec | dict, seed: int, extra: dict | None = None,
                      steps: int | None = None) -> dict:
        """A training cell's configuration (its environment in the dict form of ``ops_jax.EnvSpec``, so a spec and
        its dict are one cell); ``extra``: hyperparameters over the preset's (a section's variant);
        ``steps``: a budget other than the preset's (a section's own)."""
        hyper = {"config": self.p["config"]} if is_learner(algo) else {}
        hyper.update(self.p.get("hyper", {}).get(algo, {}))
        hyper.update(extra or {})
        return dict(kind="train", algo=algo, env=EnvSpec.from_options(env_config).as_dict(), seed=seed,
                    steps=self.p["budgets"][algo] if steps is None else steps, hyper=hyper, episodes=self.p["episodes"],
                    settings=algo_entry(algo).settings(hyper))  # a changed preset is another cell

    def _finished(self, label: str, config: dict, quiet: bool = True) -> bool:
        """Whether the training cell is stored and its checkpoint loads (what is not is reported unless ``quiet``)."""
        record = self.cells.load(label, config, quiet=quiet)
        return record is not None and self._loads(record, quiet=quiet)

    def _loads(self, record: dict, quiet: bool = False) -> bool:
        """Whether a cell's checkpoint is there and loads (not truncated, corrupt or of an older format)."""
        import agents

        try:
            agents.load(self.out / record["checkpoint"])
            return True
        except (FileNotFoundError, ValueError) as exc:
            if not quiet:
                self.log(f"checkpoint {record['checkpoint']} unusable ({exc}): training again")
            return False

    def trained(self, algo: str, env_config: dict, seed: int, label: str, result=None, extra=None,
                steps=None) -> dict:
        """Train (or reuse) one controller, evaluate it in its training and testing environment.
        ``result``: an already trained ``TrainResult`` for this cell (from a multi-seed call);
        ``extra``, ``steps``: hyperparameter overrides and budget (``_train_config``)."""
        import agents

        config = self._train_config(algo, env_config, seed, extra, steps)
        ckpt = self.ckpt_dir / f"{label}-{config_hash(config)}"

        # A controller with nothing to train records an evaluation as its curve: the same draws as
        # the training-environment evaluation below (which computes them again, with the compiled program kept).
        curve = {} if is_learner(algo) else {"curve_episodes": config["episodes"]}

        def compute():
            trained = result if result is not None else agents.train(
                algo, env_config, seed=seed, total_steps=config["steps"], **config["hyper"], **curve)
            agents.save(ckpt, trained)
            ev_train = agents.evaluate(trained, env_config, episodes=config["episodes"], seed=seed)
            ev_test = agents.evaluate(trained, env_config, episodes=config["episodes"], seed=seed + TEST_SEED_OFFSET)
            return dict(
                checkpoint=str(ckpt.relative_to(self.out)),
                curve={k: np.asarray(v).tolist() for k, v in trained.curve.items()},
                wall_time=trained.wall_time,
                train_env=_eval_record(ev_train),
                test_env=_eval_record(ev_test),
            )

        computed = self.cells.computed
        record = self.cells.get(label, config, compute)
        if self.cells.computed == computed and not self._loads(record):  # stored cell, checkpoint lost or unusable
            self.cells.path(label, config).unlink()
            record = self.cells.get(label, config, compute)
        return record

    def trained_seeds(self, algo: str, env_config: dict, seeds, label: Callable[[int], str], extra=None,
                      steps=None) -> dict:
        """``trained`` for each seed; the unfinished seeds of an algorithm that vmaps seeds (TD3)
        train in one call first, then each seed's cell is written as it is evaluated."""
        import agents

        results = {}
        if algo_entry(algo).vmaps_seeds:
            todo = [s for s in seeds if not self._finished(label(s), self._train_config(algo, env_config, s, extra, steps))]
            if len(todo) > 1:
                config = self._train_config(algo, env_config, todo[0], extra, steps)
                results = dict(zip(todo, agents.train_seeds(algo, env_config, seeds=todo, total_steps=config["steps"],
                                                            **config["hyper"])))
        records = {}
        for seed in seeds:
            records[seed] = self.trained(algo, env_config, seed, label(seed), results.get(seed), extra, steps)
        return records

    def policy(self, record: dict):
        import agents

        return agents.load(self.out / record["checkpoint"])

    def evaluated(self, label: str, record: dict, env_config: dict, seed: int) -> dict:
        import agents

        config = self._eval_config(record["checkpoint"], env_config, seed)
        return self.cells.get(label, config, lambda: _eval_record(
            agents.evaluate(self.policy(record), env_config, episodes=config["episodes"], seed=seed)))

    # -- the plan's work units ---------------------------------------------------------------------
    def train_cell(self, label: str, algo: str, env: dict, seed: int, extra=None, steps=None) -> tuple:
        """(label, configuration) of one training cell."""
        return label, self._train_config(algo, env, seed, extra, steps)

    def train_units(self, prefix: str, algo: str, env: dict, seeds, extra=None, steps=None) -> list:
        """Training units of ``algo`` on ``env``, cells ``prefix``-s<seed>: one unit of all ``seeds`` for an
        algorithm that vmaps seeds, else one per seed; ``extra``, ``steps``: as ``_train_config``."""
        groups = [list(seeds)] if algo_entry(algo).vmaps_seeds else [[s] for s in seeds]
        factor = IMPERFECT_COST if "imperfections" in env else 1.0
        units = []
        for group in groups:
            cells = [self.train_cell(seed_label(prefix, s), algo, env, s, extra, steps) for s in group]
            config = cells[0][1]
            cost = len(group) * algo_entry(algo).train_s(config["hyper"], config["steps"], env["stages"]) * factor
            units.append(dict(key=prefix if len(groups) == 1 else cells[0][0], algo=algo, kind="train", env=env,
                              seeds=group, prefix=prefix, cells=cells, deps=[], cost=round(cost, 1),
                              hyper=extra or {}, steps=steps))
        return units

    def eval_unit(self, key: str, algo: str, train: tuple, evals: list) -> dict:
        """The unit evaluating the controller of training cell ``train`` (label, config) in ``evals``
        [(label, env config, seed)]; it needs that cell's unit (``deps``, resolved by ``units``)."""
        ckpt = f"checkpoints/{train[0]}-{config_hash(train[1])}"
        cells = [(label, self._eval_config(ckpt, env, seed)) for label, env, seed in evals]
        factor = IMPERFECT_COST if any("imperfections" in env for _, env, _ in evals) else 1.0
        return dict(key=key, algo=algo, kind="eval", train=train, evals=evals, cells=cells, deps=[],
                    cost=len(cells) * algo_entry(algo).cost.eval_s * factor)

    def units(self, sections) -> list:
        """The work units of ``sections`` (names of ``sweep_plan.PLAN``), in plan order, each once:
        dicts with ``key``, ``algo``, ``kind`` ("train": one ``trained_seeds`` call of ``seeds``,
        labels ``prefix``-s<seed>; "eval": evaluations (``evals``: label, env, seed) of one trained
        controller ``train`` (label, config); "cell": a ``CellSection``'s cell), ``cells`` [(label,
        config)], ``deps`` (keys of the units whose checkpoints it needs) and ``cost`` (estimated seconds)."""
        units, producer = {}, {}
        for name, section in sweep_plan.PLAN.items():
            for unit in section.units(self) if name in sections else ():
                if unit["key"] not in units:
                    units[unit["key"]] = unit
                    producer.update({label: unit["key"] for label, _ in unit["cells"]})
        for unit in units.values():
            if unit["kind"] == "eval":
                unit["deps"] = [producer[unit["train"][0]]]
        return list(units.values())

    def todo(self, unit: dict):
        """``unit`` reduced to its cells not stored yet (a train unit's seeds), or None when all are."""
        if unit["kind"] != "train":
            return unit if any(self.cells.load(label, config) is None for label, config in unit["cells"]) else None
        left = [(label, config) for label, config in unit["cells"] if not self._finished(label, config, quiet=False)]
        if not left:
            return None
        seeds = [config["seed"] for _, config in left]
        per_seed = unit["cost"] / len(unit["seeds"])
        return {**unit, "cells": left, "seeds": seeds, "cost": round(per_seed * len(seeds), 1)}

    def compute_unit(self, unit: dict, record: dict | None = None) -> None:
        """Compute ``unit``'s cells into this sweep's folder; an eval unit needs its controller's
        training ``record`` (and checkpoint in this folder)."""
        if unit["kind"] == "train":
            self.trained_seeds(unit["algo"], unit["env"], unit["seeds"], lambda s: seed_label(unit["prefix"], s),
                               unit.get("hyper"), unit.get("steps"))
        elif unit["kind"] == "eval":
            for label, env, seed in unit["evals"]:
                self.evaluated(label, record, env, seed)
        else:
            section = sweep_plan.PLAN[unit["section"]]
            for label, config in unit["cells"]:
                self.cells.get(label, config, lambda c=config: section.compute(c))

    def run(self, sections, workers=(), computed=0, started=float("nan")):
        """Load every cell of ``sections`` (computing any not stored), then write each section's report
        and the summary; returns (cells computed, cells reused). ``workers``: a record (algos, timing)
        per worker that computed ``computed`` cells for this run before; ``started``: the command's
        start (time.time()), if known."""
        from benchmarks import sweep_report

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
        counts = (self.cells.computed + computed, self.cells.reused - computed)
        sweep_report.summary(self.out, self.p, sections, self.timing, counts, workers, time.time() - started)
        return counts

    def _eval_config(self, checkpoint: str, env_config: EnvSpec | dict, seed: int) -> dict:
        return dict(kind="eval", checkpoint=checkpoint, env=EnvSpec.from_options(env_config).as_dict(), seed=seed,
                    episodes=self.p["episodes"])


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
    sweep share programs that differ only in their seed, so later cells and re-runs skip compiling."""
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
