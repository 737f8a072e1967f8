"""The sweep's plan and work: presets, sections, the work units (``Sweep.units``) and their
computation into the cell store, the reports; compilation-cache setup of a worker process. The
command line is benchmarks/sweep.py; the Ray executor benchmarks/sweep_ray.py (docs/sweep.md).
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Callable

import numpy as np

from benchmarks import reality
from benchmarks.cells import CellStore, config_hash
from benchmarks.paper import MODES

SECTIONS = ("table1", "table2", "stages", "transfer", "feedback")  # the default run
EXTRA_SECTIONS = ("reality",)  # run when asked for (--only): benchmarks/reality.py

# The sweep's presets: seeds, episodes and section settings; each algorithm's budgets, hyperparameters and
# cost come from its entry in agents.registry (``preset``).
PRESETS = {
    "quick": dict(  # a first look: tiny budgets, a cheaper physics fit, few episodes
        seeds=2, config="fast", episodes=8,
        stage_range=(2, 3), stage_modes=("easy",), stage_algos=("spgd",), stage_seeds=1,
        feedback_ks=(1, 100), aux_seeds=1, reality_seeds=2,
    ),
    "default": dict(  # ~45 min on 2 CPU cores (docs/results.md)
        seeds=5, config="fast", episodes=32,
        stage_range=(1, 7), stage_modes=("easy", "hard"), stage_algos=("spgd", "physics"), stage_seeds=1,
        feedback_ks=(1, 20, 40, 60, 80, 100), aux_seeds=2, reality_seeds=3,
    ),
    "paper": dict(
        seeds=20, config="paper", episodes=100,
        stage_range=(1, 7), stage_modes=MODES, stage_algos=("spgd", "physics", "td3", "sac"), stage_seeds=5,
        feedback_ks=(1, 20, 40, 60, 80, 100), reality_seeds=5,
    ),
}
TEST_SEED_OFFSET = 10_000
EVAL_S = 1.0  # seconds of one evaluation cell (the progress bar's weights; training cells: agents.registry)
IMPERFECT_COST = 3.0  # a cell's cost factor with lab imperfections (docs/imperfections.md: 3.5-6x the ideal step)


def preset(name: str) -> dict:
    """The preset ``name`` with the registered algorithms' parts: ``algos``, ``budgets``, ``hyper`` and
    (where any) ``reality_budgets``."""
    from agents.registry import REGISTRY

    algos = [a for a in REGISTRY.values() if a.sweep is not None and name in a.sweep.budgets]
    out = dict(PRESETS[name], name=name, algos=tuple(a.name for a in algos),
               budgets={a.name: a.sweep.budgets[name] for a in algos})
    hyper = {a.name: a.sweep.hyper[name] for a in algos if name in a.sweep.hyper}
    reality = {a.name: a.sweep.reality_budgets[name] for a in algos if name in a.sweep.reality_budgets}
    return {**out, **({"hyper": hyper} if hyper else {}), **({"reality_budgets": reality} if reality else {})}


def algo_entry(name: str):
    """The ``agents.registry.Algo`` of ``name`` (imported here: jax loads after the sweep's settings)."""
    from agents import registry

    return registry.get(name)


def cell_seconds(algo: str, steps: int) -> float:
    """Estimated seconds of one training cell of ``algo`` with a budget of ``steps`` env steps."""
    return algo_entry(algo).sweep.cell_seconds(steps)


def is_learner(algo: str) -> bool:
    return algo_entry(algo).learner


class _Silent:
    """A progress bar that shows nothing (for workers and the report pass)."""

    def set_description(self, desc: str = "") -> None:
        pass

    def update(self, n: float = 1) -> None:
        pass


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
        self.aux_seeds = min(preset.get("aux_seeds", preset["seeds"]), preset["seeds"])  # transfer, feedback

    # -- trained controllers --------------------------------------------------------------------
    def _train_config(self, algo: str, env_config: dict, seed: int, extra: dict | None = None,
                      steps: int | None = None) -> dict:
        """A training cell's configuration; ``extra``: hyperparameters over the preset's (a section's variant);
        ``steps``: a budget other than the preset's (a section's own)."""
        hyper = {"config": self.p["config"]} if is_learner(algo) else {}
        hyper.update(self.p.get("hyper", {}).get(algo, {}))
        hyper.update(extra or {})
        return dict(kind="train", algo=algo, env=env_config, seed=seed,
                    steps=self.p["budgets"][algo] if steps is None else steps, hyper=hyper, episodes=self.p["episodes"])

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

        # A controller with nothing to train records an evaluation as its curve: the same one as
        # the training-environment evaluation below, which is then served from memory.
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

    def trained_seeds(self, algo: str, env_config: dict, seeds, label: Callable[[int], str], bar=_Silent(),
                      extra=None, steps=None) -> dict:
        """``trained`` for each seed; the unfinished seeds of an algorithm that vmaps seeds (TD3)
        train in one call first, then each seed's cell is written as it is evaluated."""
        import agents

        results = {}
        if algo_entry(algo).vmaps_seeds:
            todo = [s for s in seeds if not self._finished(label(s), self._train_config(algo, env_config, s, extra, steps))]
            if len(todo) > 1:
                bar.set_description(f"{label(todo[0]).rsplit('-s', 1)[0]} seeds {todo} (one vmapped call)")
                config = self._train_config(algo, env_config, todo[0], extra, steps)
                results = dict(zip(todo, agents.train_seeds(algo, env_config, seeds=todo, total_steps=config["steps"],
                                                            **config["hyper"])))
        records = {}
        for seed in seeds:
            bar.set_description(f"{label(seed)}")
            records[seed] = self.trained(algo, env_config, seed, label(seed), results.get(seed), extra, steps)
            bar.update()
        return records

    def policy(self, record: dict):
        import agents

        return agents.load(self.out / record["checkpoint"])

    def evaluated(self, label: str, record: dict, env_config: dict, seed: int) -> dict:
        import agents

        config = self._eval_config(record["checkpoint"], env_config, seed)
        return self.cells.get(label, config, lambda: _eval_record(
            agents.evaluate(self.policy(record), env_config, episodes=config["episodes"], seed=seed)))

    def table1_runs(self, bar):
        runs = {}
        for mode in MODES:
            for algo in self.algos:
                records = self.trained_seeds(algo, {"stages": 5, "mode": mode}, range(self.p["seeds"]),
                                             lambda s: f"table1-{mode}-{algo}-s{s}", bar)
                runs.update({(mode, algo, seed): r for seed, r in records.items()})
        return runs

    # -- sections -----------------------------------------------------------------------------
    def _stage_algos(self) -> list:
        return [a for a in self.p["stage_algos"] if a in self.algos]

    def units(self, sections) -> list:
        """The cells of ``sections`` as work units, in order: dicts with ``key``, ``algo``, ``kind``
        ("train": one ``trained_seeds`` call of ``seeds``, labels ``prefix``-s<seed>; "eval": the
        transfer and feedback evaluations (``evals``: label, env, seed) of one table-1 controller
        ``train`` (label, config)), ``cells`` [(label, config)], ``deps`` (keys of the units whose
        checkpoints it needs) and ``cost`` (estimated seconds, ``cell_seconds``)."""
        import agents

        units, producer = [], {}

        def train(prefix, algo, env, seeds, extra=None, steps=None):
            groups = [list(seeds)] if algo_entry(algo).vmaps_seeds else [[s] for s in seeds]
            factor = IMPERFECT_COST if "imperfections" in env else 1.0
            for group in groups:
                cells = [(f"{prefix}-s{s}", self._train_config(algo, env, s, extra, steps)) for s in group]
                key = prefix if len(groups) == 1 else cells[0][0]
                cost = len(group) * cell_seconds(algo, cells[0][1]["steps"]) * factor
                units.append(dict(key=key, algo=algo, kind="train", env=env, seeds=group, prefix=prefix, cells=cells,
                                  deps=[], cost=round(cost, 1), hyper=extra or {}, steps=steps))
                producer.update({label: key for label, _ in cells})

        p = self.p
        table1 = {"table1", "table2", "transfer", "feedback"} & set(sections)
        for mode in MODES if table1 else ():
            for algo in self.algos:
                train(f"table1-{mode}-{algo}", algo, {"stages": 5, "mode": mode}, range(p["seeds"]))
        lo, hi = p["stage_range"]
        for n in range(lo, hi + 1) if "stages" in sections else ():
            for mode in p["stage_modes"]:
                for algo in self._stage_algos():
                    train(f"stages-N{n}-{mode}-{algo}", algo, {"stages": n, "mode": mode}, range(p["stage_seeds"]))
        for mode in MODES:
            for algo in self.algos:
                for seed in range(self.aux_seeds):
                    evals = [(f"transfer-{mode}-{test}-{algo}-s{seed}", {"stages": 5, "mode": test},
                              seed + TEST_SEED_OFFSET) for test in MODES if "transfer" in sections]
                    evals += [(f"feedback-k{k}-{algo}-s{seed}", {"stages": 5, "mode": "hard", "feedback_k": k},
                               seed + TEST_SEED_OFFSET)
                              for k in p["feedback_ks"] if "feedback" in sections and mode == "hard"]
                    if not evals:
                        continue
                    label = f"table1-{mode}-{algo}-s{seed}"
                    config = self._train_config(algo, {"stages": 5, "mode": mode}, seed)
                    ckpt = f"checkpoints/{label}-{config_hash(config)}"
                    cells = [(lab, self._eval_config(ckpt, env, s)) for lab, env, s in evals]
                    units.append(dict(key=f"evals-{mode}-{algo}-s{seed}", algo=algo, kind="eval", train=(label, config),
                                      evals=evals, cells=cells, deps=[producer[label]], cost=len(cells) * EVAL_S))
        if "reality" in sections:
            for algo, training, env, extra in reality.trainings(self.algos, [a for a in self.algos if is_learner(a)]):
                prefix = f"reality-{training}-{algo}"
                steps = self._reality_budget(algo)
                train(prefix, algo, env, range(self._reality_seeds()), extra, steps)
                for seed in range(self._reality_seeds()):
                    label, config = f"{prefix}-s{seed}", self._train_config(algo, env, seed, extra, steps)
                    ckpt = f"checkpoints/{label}-{config_hash(config)}"
                    evals = [(self._reality_label(prefix, level, seed), test_env, seed + TEST_SEED_OFFSET)
                             for level, test_env in self._reality_levels()]
                    cells = [(lab, self._eval_config(ckpt, e, s)) for lab, e, s in evals]
                    units.append(dict(key=f"evals-{prefix}-s{seed}", algo=algo, kind="eval", train=(label, config),
                                      evals=evals, cells=cells, deps=[producer[label]],
                                      cost=len(cells) * EVAL_S * IMPERFECT_COST))
        return units

    def _reality_seeds(self) -> int:
        return self.p.get("reality_seeds", self.p["seeds"])

    def _reality_budget(self, algo: str) -> int:
        """``algo``'s training budget (env steps) in the reality section: ``reality_budgets``, else the preset's."""
        return self.p.get("reality_budgets", {}).get(algo, self.p["budgets"][algo])

    @staticmethod
    def _reality_levels() -> list:
        """(level name, test env config) of the reality section."""
        return [(name, reality.env_config(scale)) for name, scale in reality.LEVELS]

    @staticmethod
    def _reality_label(prefix: str, level: str, seed: int) -> str:
        return f"{prefix}-{level.replace(' ', '')}-s{seed}"

    def todo(self, unit: dict):
        """``unit`` reduced to its cells not stored yet (a train unit's seeds), or None when all are."""
        if unit["kind"] == "eval":
            return unit if any(self.cells.load(label, config) is None for label, config in unit["cells"]) else None
        left = [(label, config) for label, config in unit["cells"] if not self._finished(label, config, quiet=False)]
        if not left:
            return None
        seeds = [config["seed"] for _, config in left]
        per_seed = unit["cost"] / len(unit["seeds"])
        return {**unit, "cells": left, "seeds": seeds, "cost": round(per_seed * len(seeds), 1)}

    def compute_unit(self, unit: dict, record: dict | None = None) -> None:
        """Compute ``unit``'s cells into this sweep's folder; an eval unit needs its controller's
        table-1 ``record`` (and checkpoint in this folder)."""
        if unit["kind"] == "train":
            self.trained_seeds(unit["algo"], unit["env"], unit["seeds"], lambda s: f"{unit['prefix']}-s{s}",
                               extra=unit.get("hyper"), steps=unit.get("steps"))
        else:
            for label, env, seed in unit["evals"]:
                self.evaluated(label, record, env, seed)

    def run(self, sections, workers=(), computed=0, started=float("nan")):
        """Load every cell (computing any not stored), then write the tables, figures and summary;
        returns (cells computed, cells reused). ``workers``: a record (algos, timing) per worker
        that computed ``computed`` cells for this run before; ``started``: the command's start
        (time.time()), if known."""
        from benchmarks import sweep_report as report

        self._sections(sections, report)
        counts = (self.cells.computed + computed, self.cells.reused - computed)
        report.summary(self.out, self.p, sections, self.timing, counts, workers, time.time() - started)
        return counts

    def _eval_config(self, checkpoint: str, env_config: dict, seed: int) -> dict:
        return dict(kind="eval", checkpoint=checkpoint, env=env_config, seed=seed, episodes=self.p["episodes"])

    def _sections(self, sections, report, bar=_Silent()):
        """Compute (or load) the cells of ``sections``, then write their reports unless ``report`` is None."""
        t0 = time.perf_counter()
        runs = self.table1_runs(bar) if {"table1", "table2", "transfer", "feedback"} & set(sections) else {}
        self.timing["table1 training + evaluation"] = time.perf_counter() - t0
        results = {}
        for name, compute in (("stages", lambda: self.stage_scan(bar)), ("transfer", lambda: self.transfer(runs, bar)),
                              ("feedback", lambda: self.feedback(runs, bar)), ("reality", lambda: self.reality(bar))):
            if name in sections:
                t = time.perf_counter()
                results[name] = compute()
                self.timing[name] = time.perf_counter() - t
        if report is not None:
            t = time.perf_counter()
            if "table1" in sections:
                report.table1(self.out, runs, self.p)
                report.training_curves(self.out, runs, self.p)
                report.testing_curves(self.out, runs, self.p)
            if "table2" in sections:
                report.table2(self.out, runs, self.p)
            for name, res in results.items():
                if name == "reality":
                    reality.report(self.out, res, self.p, self.p.get("command", "python -m benchmarks.sweep --only reality"))
                else:
                    getattr(report, name)(self.out, res, self.p)
            self.timing["tables and figures"] = time.perf_counter() - t
        self.timing["total"] = time.perf_counter() - t0

    def stage_scan(self, bar):
        res = {}
        lo, hi = self.p["stage_range"]
        for n in range(lo, hi + 1):
            for mode in self.p["stage_modes"]:
                for algo in self._stage_algos():
                    records = self.trained_seeds(algo, {"stages": n, "mode": mode}, range(self.p["stage_seeds"]),
                                                 lambda s: f"stages-N{n}-{mode}-{algo}-s{s}", bar)
                    res.update({(n, mode, algo, seed): r for seed, r in records.items()})
        return res

    def reality(self, bar) -> dict:
        """{"algo/training": {level: [final P / P_best per seed]}} (each seed: the mean over its test episodes)."""
        ratios = reality.best_ratios()
        res = {}
        for algo, training, env, extra in reality.trainings(self.algos, [a for a in self.algos if is_learner(a)]):
            prefix = f"reality-{training}-{algo}"
            records = self.trained_seeds(algo, env, range(self._reality_seeds()), lambda s: f"{prefix}-s{s}", bar, extra,
                                         self._reality_budget(algo))
            res[f"{algo}/{training}"] = {level: [] for level, _ in self._reality_levels()}
            for seed, record in records.items():
                for level, test_env in self._reality_levels():
                    ev = self.evaluated(self._reality_label(prefix, level, seed), record, test_env, seed + TEST_SEED_OFFSET)
                    res[f"{algo}/{training}"][level].append(float(np.mean(ev["final"]) * ratios[level]))
        return res

    def transfer(self, runs, bar):
        res = {}
        for (train_mode, algo, seed), record in runs.items():
            if seed >= self.aux_seeds:
                continue
            for test_mode in MODES:
                bar.set_description(f"transfer {algo} {train_mode}->{test_mode} seed {seed}")
                res[train_mode, test_mode, algo, seed] = self.evaluated(
                    f"transfer-{train_mode}-{test_mode}-{algo}-s{seed}", record,
                    {"stages": 5, "mode": test_mode}, seed + TEST_SEED_OFFSET)
                bar.update()
        return res

    def feedback(self, runs, bar):
        res = {}
        for (mode, algo, seed), record in runs.items():
            if mode != "hard" or seed >= self.aux_seeds:
                continue
            for k in self.p["feedback_ks"]:
                bar.set_description(f"feedback {algo} k={k} seed {seed}")
                res[k, algo, seed] = self.evaluated(f"feedback-k{k}-{algo}-s{seed}", record,
                                                    {"stages": 5, "mode": "hard", "feedback_k": k},
                                                    seed + TEST_SEED_OFFSET)
                bar.update()
        return res


def _eval_record(ev) -> dict:
    npow = np.asarray(ev.normalized_power)
    return dict(
        summary=ev.summary,
        final=npow[:, -1].tolist(),
        mean_curve=npow.mean(0).tolist(),
        std_curve=npow.std(0).tolist(),
    )


def crash_injection(sweep: Sweep, marker: Path):
    """Tests of crash recovery: with OPS_SWEEP_CRASH_AFTER=K the process kills itself with SIGSEGV
    once it has computed K cells, once per ``marker`` file (created first)."""
    after = int(os.environ.get("OPS_SWEEP_CRASH_AFTER", "0"))
    if after <= 0 or marker.exists():
        return
    get = sweep.cells.get

    def get_then_crash(*args, **kw):
        record = get(*args, **kw)
        if sweep.cells.computed >= after and not marker.exists():
            marker.touch()
            os.kill(os.getpid(), signal.SIGSEGV)
        return record

    sweep.cells.get = get_then_crash


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
    its wall time (measured: 214 s instead of 244 s for the whole preset). Results differ from an
    optimised build by rounding, which training amplifies; the disk cache keys include XLA_FLAGS,
    so the two builds are never mixed."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_optimization_level" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {QUICK_XLA_FLAG}".strip()
