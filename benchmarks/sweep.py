"""The paper's experiments on ops-jax, reproduced and extended, as one resumable command.

    python -m benchmarks.sweep                      # default preset (5 seeds, <= ~30 min on 2 cores)
    python -m benchmarks.sweep --quick              # a first look in a few minutes
    python -m benchmarks.sweep --preset paper --seeds 20
    python -m benchmarks.sweep --only table1 --out results/mine

Sections: ``table1`` (5-stage x easy/medium/hard x algorithms x seeds: final P/Pmax in the training
and testing environments, Welch's t-test bolding), ``table2`` (timings of the paper's Table 2, from
the table1 runs), ``stages`` (stage scan N = 1..7), ``transfer`` (train on one mode, test on each),
``feedback`` (train at k = 1, test at k = 1..100). Everything lands in ``results/<name>/``: tables
(.md, .csv), figures (.png), ``summary.md``. Finished work units are stored in ``cells/`` the
moment they finish (see benchmarks/cells.py): a re-run, or a run after a crash, skips them. The
command runs the work in ``--jobs`` worker processes (default 2), each computing the cells of its
own algorithms, then one more that writes the reports (``supervise``).

Evaluation as in the paper: P/Pmax at the end of 200-step test episodes. The training environment
uses the training seed's draws; the testing environment another seed, so in hard mode it has a
different drift realisation.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from benchmarks.cells import CellStore, config_hash
from benchmarks.common import write_json_atomic

MODES = ("easy", "medium", "hard")
SECTIONS = ("table1", "table2", "stages", "transfer", "feedback")
_PAPER_ALGOS = ("spgd", "ppo", "sac", "td3")
PAPER_TABLE1 = {  # (mode, env) -> {algo: (mean, std)}, from ../shared/docs/paper_results.md
    (mode, env): dict(zip(_PAPER_ALGOS, values))
    for (mode, env), values in {
        ("easy", "training"): ((0.9919, 0.0121), (0.8184, 0.0884), (0.9410, 0.0572), (0.9552, 0.0483)),
        ("easy", "testing"): ((0.9909, 0.0125), (0.8067, 0.0661), (0.9403, 0.0531), (0.9572, 0.0501)),
        ("medium", "training"): ((0.6155, 0.0271), (0.7591, 0.0728), (0.9145, 0.0727), (0.9353, 0.0451)),
        ("medium", "testing"): ((0.6178, 0.0263), (0.7519, 0.0623), (0.9098, 0.0838), (0.9285, 0.0437)),
        ("hard", "training"): ((0.5321, 0.0352), (0.6977, 0.0732), (0.8739, 0.0775), (0.8724, 0.0680)),
        ("hard", "testing"): ((0.5132, 0.0348), (0.6526, 0.0687), (0.8371, 0.0804), (0.8488, 0.0615)),
    }.items()
}
PAPER_TABLE2 = {  # algo -> (sim TPS, opt TPS, convergence step, training s, inference TPS, test conv step, control s)
    "ppo": (0.0086, 0.0274, "142666 ± 25390", "5141 ± 979", 0.0057, "78 ± 10", "1.13 ± 0.21"),
    "sac": (0.0086, 0.0199, "168844 ± 24889", "4833 ± 740", 0.0046, "67 ± 10", "0.89 ± 0.18"),
    "td3": (0.0086, 0.0175, "212018 ± 28484", "5456 ± 804", 0.0036, "58 ± 7", "0.71 ± 0.12"),
}

# Training budgets (environment steps) per preset and algorithm; hyper config per preset.
PRESETS = {
    "quick": dict(  # a first look: tiny budgets, a cheaper physics fit, few episodes
        seeds=2, algos=("spgd", "physics", "ppo", "sac", "td3"), config="fast", episodes=8,
        budgets={"spgd": 0, "physics": 0, "ppo": 32_768, "sac": 3_000, "td3": 3_000},
        hyper={"ppo": {"num_evals": 2, "num_eval_envs": 16, "hidden": [64, 64], "num_updates_per_batch": 2},
               "sac": {"min_replay_size": 1024, "num_evals": 2, "num_eval_envs": 16, "hidden": [64, 64],
                       "grad_updates_per_step": 4, "batch_size": 256},
               "td3": {"learning_starts": 1024, "eval_every": 1000, "eval_episodes": 4},
               "physics": {"starts": 4, "iters": 4}},
        stage_range=(2, 3), stage_modes=("easy",), stage_algos=("spgd",), stage_seeds=1,
        feedback_ks=(1, 100), aux_seeds=1,
    ),
    "default": dict(  # budgets for a run well under 30 min on 2 CPU cores (22.0 min measured, see README)
        seeds=5, algos=("spgd", "physics", "ppo", "sac", "td3"), config="fast", episodes=32,
        budgets={"spgd": 0, "physics": 0, "ppo": 2_000_000, "sac": 100_000, "td3": 60_000},
        hyper={"sac": {"min_replay_size": 2048}, "td3": {"eval_every": 5000},
               "physics": {"starts": 8, "iters": 6}},  # half the fit cost of 16 x 8 (hard 0.997 vs 0.9995)
        stage_range=(1, 7), stage_modes=("easy", "hard"), stage_algos=("spgd", "physics"), stage_seeds=1,
        feedback_ks=(1, 20, 40, 60, 80, 100), aux_seeds=2,
    ),
    "paper": dict(
        seeds=20, algos=("spgd", "physics", "ppo", "sac", "td3"), config="paper", episodes=100,
        budgets={"spgd": 0, "physics": 0, "ppo": 200_000, "sac": 200_000, "td3": 250_000},
        stage_range=(1, 7), stage_modes=MODES, stage_algos=("spgd", "physics", "td3", "sac"), stage_seeds=5,
        feedback_ks=(1, 20, 40, 60, 80, 100),
    ),
}
TEST_SEED_OFFSET = 10_000
LEARNERS = ("ppo", "sac", "td3")  # algorithms with a "paper" / "fast" hyperparameter config


# Relative wall time of one algorithm's cells: how ``partition`` balances workers. The resulting split
# (PPO + TD3 | SAC + physics + SPGD) measured 1,312 s against 1,038 s for the default preset (PPO 2M
# steps, 2 x 128 networks; 1,171 against 1,143 s with stop 14's 2 x 64) and 74 s against 82 s for the quick one
# (2026-11-24).
ALGO_COST = {"ppo": 3.0, "sac": 3.0, "td3": 2.0, "physics": 1.5, "spgd": 0.5}


def partition(algos, jobs: int) -> list:
    """``algos`` split over at most ``jobs`` workers: heaviest first (``ALGO_COST``) onto the least
    loaded. An algorithm's cells all go to one worker, since its transfer and feedback cells use the
    checkpoints its table-1 cells write."""
    parts = [[] for _ in range(max(1, min(jobs, len(algos))))]
    load = [0.0] * len(parts)
    for algo in sorted(algos, key=lambda a: -ALGO_COST.get(a, 1.0)):
        i = load.index(min(load))
        parts[i].append(algo)
        load[i] += ALGO_COST.get(algo, 1.0)
    return parts


class Sweep:
    def __init__(self, preset: dict, out: Path, log, algos=None, bar_position: int = 0):
        """``algos``: the algorithms this process computes (a worker's part; default all)."""
        self.p = preset
        self.out = out
        self.log = log
        self.algos = list(algos or preset["algos"])
        self.bar_position = bar_position
        self.cells = CellStore(out / "cells", log)
        self.ckpt_dir = out / "checkpoints"
        self.timing = {}
        self.aux_seeds = min(preset.get("aux_seeds", preset["seeds"]), preset["seeds"])  # transfer, feedback

    # -- trained controllers --------------------------------------------------------------------
    def _train_config(self, algo: str, env_config: dict, seed: int) -> dict:
        hyper = {"config": self.p["config"]} if algo in LEARNERS else {}
        hyper.update(self.p.get("hyper", {}).get(algo, {}))
        return dict(kind="train", algo=algo, env=env_config, seed=seed, steps=self.p["budgets"][algo],
                    hyper=hyper, episodes=self.p["episodes"])

    def _finished(self, label: str, config: dict) -> bool:
        record = self.cells.load(label, config, quiet=True)
        return record is not None and self._loads(record, quiet=True)

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

    def trained(self, algo: str, env_config: dict, seed: int, label: str, result=None) -> dict:
        """Train (or reuse) one controller, evaluate it in its training and testing environment.
        ``result``: an already trained ``TrainResult`` for this cell (from a multi-seed call)."""
        import agents

        config = self._train_config(algo, env_config, seed)
        ckpt = self.ckpt_dir / f"{label}-{config_hash(config)}"

        # A controller with nothing to train records an evaluation as its curve: the same one as
        # the training-environment evaluation below, which is then served from memory.
        curve = {} if algo in LEARNERS else {"curve_episodes": config["episodes"]}

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

    def trained_seeds(self, algo: str, env_config: dict, seeds, label: Callable[[int], str], bar) -> dict:
        """``trained`` for each seed; the unfinished seeds of an algorithm that vmaps seeds (TD3)
        train in one call first, then each seed's cell is written as it is evaluated."""
        import agents

        results = {}
        if hasattr(agents.base.algo_module(algo), "train_seeds"):
            todo = [s for s in seeds if not self._finished(label(s), self._train_config(algo, env_config, s))]
            if len(todo) > 1:
                bar.set_description(f"{label(todo[0]).rsplit('-s', 1)[0]} seeds {todo} (one vmapped call)")
                config = self._train_config(algo, env_config, todo[0])
                results = dict(zip(todo, agents.train_seeds(algo, env_config, seeds=todo, total_steps=config["steps"],
                                                            **config["hyper"])))
        records = {}
        for seed in seeds:
            bar.set_description(f"{label(seed)}")
            records[seed] = self.trained(algo, env_config, seed, label(seed), results.get(seed))
            bar.update()
        return records

    def policy(self, record: dict):
        import agents

        return agents.load(self.out / record["checkpoint"])

    def evaluated(self, label: str, record: dict, env_config: dict, seed: int) -> dict:
        import agents

        config = dict(kind="eval", checkpoint=record["checkpoint"], env=env_config, seed=seed,
                      episodes=self.p["episodes"])
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

    def count(self, sections) -> int:
        p = self.p
        n1 = len(MODES) * len(self.algos) * p["seeds"]
        n_stages = p["stage_range"][1] - p["stage_range"][0] + 1
        nst = n_stages * len(p["stage_modes"]) * len(self._stage_algos()) * p["stage_seeds"]
        total = 0
        if {"table1", "table2", "transfer", "feedback"} & set(sections):
            total += n1
        if "stages" in sections:
            total += nst
        if "transfer" in sections:
            total += len(self.algos) * self.aux_seeds * len(MODES) * len(MODES)
        if "feedback" in sections:
            total += len(self.algos) * self.aux_seeds * len(p["feedback_ks"])
        return total

    def compute(self, sections):
        """A worker's part: every cell of ``self.algos`` in ``sections``, no reports. Returns the
        wall time per section."""
        self._sections(sections, report=None)
        return self.timing

    def run(self, sections, workers=(), started=float("nan")):
        """Every cell (computing those not stored), then the tables, figures and summary; returns
        (cells computed, cells reused). ``workers``: the records (algos, timing, computed) of
        the part workers that computed cells for this run before this process; ``started``: the
        command's start (time.time()), if known."""
        from benchmarks import sweep_report as report

        self._sections(sections, report)
        # The part workers' cells were computed in this run; this process only loaded them.
        counts = (self.cells.computed + sum(w["computed"] for w in workers),
                  self.cells.reused - sum(w["computed"] for w in workers))
        report.summary(self.out, self.p, sections, self.timing, counts, workers, time.time() - started)
        return counts

    def _sections(self, sections, report):
        """Compute (or load) the cells of ``sections``, then write their reports unless ``report`` is None."""
        bar = tqdm(total=self.count(sections), unit="cell", dynamic_ncols=True, position=self.bar_position,
                   desc="sweep" if self.algos == list(self.p["algos"]) else f"sweep {'+'.join(self.algos)}")
        t0 = time.perf_counter()
        runs = self.table1_runs(bar) if {"table1", "table2", "transfer", "feedback"} & set(sections) else {}
        self.timing["table1 training + evaluation"] = time.perf_counter() - t0
        results = {}
        for name, compute in (("stages", lambda: self.stage_scan(bar)), ("transfer", lambda: self.transfer(runs, bar)),
                              ("feedback", lambda: self.feedback(runs, bar))):
            if name in sections:
                t = time.perf_counter()
                results[name] = compute()
                self.timing[name] = time.perf_counter() - t
        bar.close()
        if report is not None:
            t = time.perf_counter()
            if "table1" in sections:
                report.table1(self.out, runs, self.p)
                report.training_curves(self.out, runs, self.p)
                report.testing_curves(self.out, runs, self.p)
            if "table2" in sections:
                report.table2(self.out, runs, self.p)
            for name, res in results.items():
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


def _crash_injection(sweep: Sweep, out: Path):
    """Tests of ``supervise``: with OPS_SWEEP_CRASH_AFTER=K the process kills itself with SIGSEGV
    once it has computed K cells, once per output folder (marker file ``.crash-injected``)."""
    after = int(os.environ.get("OPS_SWEEP_CRASH_AFTER", "0"))
    marker = out / ".crash-injected"
    if after <= 0 or marker.exists():
        return
    get = sweep.cells.get

    def get_then_crash(*args, **kw):
        record = get(*args, **kw)
        if sweep.cells.computed >= after:
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
WORKER_ENV = "OPS_SWEEP_WORKER"  # set in the worker processes that supervise() starts
STARTED_ENV = "OPS_SWEEP_STARTED"  # the command's start (time.time()), for the summary's wall time
PARTS_ENV = "OPS_SWEEP_PARTS"  # in the report worker: how many part workers computed cells before it
PART_TIMING_DIR = ".parts"  # in the output folder: each part worker's algorithms, cells computed and timing
CRASH_SIGNALS = {signal.SIGSEGV, signal.SIGBUS, signal.SIGABRT, signal.SIGILL, signal.SIGFPE}


def _die_with_parent():  # Linux: the worker gets SIGKILL when the supervising process dies
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _supervised(cmd: list, env: dict, restarts: int, procs: list, name: str) -> int:
    """Run ``cmd`` and start it again, up to ``restarts`` times, when it dies of a crash signal;
    each process is appended to ``procs`` (for interruption). Returns the exit code."""
    for attempt in range(restarts + 1):
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, preexec_fn=_die_with_parent if sys.platform == "linux" else None)
        procs.append(proc)
        code = proc.wait()
        if code >= 0 or -code not in CRASH_SIGNALS:
            return code if code >= 0 else 128 - code
        then = (f"resuming from the stored cells (restart {attempt + 1} of {restarts})" if attempt < restarts
                else "no restarts left (re-run the command to resume from the stored cells)")
        print(f"{name} died with {signal.Signals(-code).name} after {time.perf_counter() - t0:.0f} s; {then}",
              file=sys.stderr)
    return 128 - code


def supervise(argv: list, restarts: int, parts: list, out: Path) -> int:
    """Run the sweep in worker processes (``python -X faulthandler``, so a crash prints the Python
    stack), each restarted up to ``restarts`` times when it dies of a crash signal (SIGSEGV, SIGBUS,
    SIGABRT, SIGILL, SIGFPE): finished cells are stored, so a restart resumes. With several
    ``parts`` (lists of algorithms), one worker per part computes its cells, all at once; then one
    more worker finds every cell stored and writes the tables, figures and summary. Returns the
    exit code (the first failing worker's)."""
    cmd = [sys.executable, "-X", "faulthandler", "-m", "benchmarks.sweep", *argv]
    env = {**os.environ, WORKER_ENV: "1", STARTED_ENV: str(time.time())}
    procs = []
    try:
        if len(parts) > 1:
            timing_dir = out / PART_TIMING_DIR
            for stale in timing_dir.glob("part*.json"):
                stale.unlink()
            # Workers sharing one accelerator must not each reserve most of its memory up front.
            part_env = {**env, "XLA_PYTHON_CLIENT_PREALLOCATE": os.environ.get("XLA_PYTHON_CLIENT_PREALLOCATE", "false")}
            codes = [1] * len(parts)  # a thread that raised (e.g. could not start its worker) counts as failed

            def work(i):
                codes[i] = _supervised([*cmd, "--part", f"{i}/{len(parts)}"], part_env, restarts, procs,
                                       f"sweep worker {i + 1} ({'+'.join(parts[i])})")

            threads = [threading.Thread(target=work, args=(i,), daemon=True) for i in range(len(parts))]
            for t in threads:
                t.start()
            for t in threads:
                while t.is_alive():
                    t.join(0.5)
            if any(codes):
                i = next(i for i, c in enumerate(codes) if c)
                print(f"sweep worker {i + 1} ({'+'.join(parts[i])}) exited with code {codes[i]}; the other workers' "
                      "cells are stored (re-run the command to resume)", file=sys.stderr)
                return codes[i]
            env[PARTS_ENV] = str(len(parts))
        return _supervised(cmd, env, restarts, procs, "sweep worker")
    except KeyboardInterrupt:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.wait()
        return 130


def quick_compilation():
    """``--quick`` compiles with XLA's backend optimisation level 0 (added to XLA_FLAGS unless that
    sets the level already; before jax's backend starts): compilation, not execution, is most of
    its wall time (measured: 214 s instead of 244 s for the whole preset). Results differ from an
    optimised build by rounding, which training amplifies; the disk cache keys include XLA_FLAGS,
    so the two builds are never mixed."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_optimization_level" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {QUICK_XLA_FLAG}".strip()


def build_preset(args) -> dict:
    name = "quick" if args.quick else args.preset
    preset = json.loads(json.dumps(PRESETS[name]))  # deep copy
    preset["name"] = name
    if args.seeds is not None:
        if args.seeds < 2:
            raise SystemExit("--seeds must be >= 2 (Welch's t-test needs two samples per algorithm)")
        preset["seeds"] = args.seeds
    if args.algos:
        preset["algos"] = list(args.algos)
        preset["stage_algos"] = [a for a in preset["stage_algos"] if a in args.algos] or list(args.algos)
    return preset


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", choices=("default", "paper"), default="default")
    ap.add_argument("--quick", action="store_true", help="a few-minute version (tests, first look)")
    ap.add_argument("--seeds", type=int, help="seeds per cell (the paper used 20)")
    ap.add_argument("--algos", nargs="+", choices=PRESETS["default"]["algos"])
    ap.add_argument("--only", nargs="+", choices=(*SECTIONS, "reality"),
                    help="sections to run (default: all but reality, which runs alone: benchmarks/reality.py)")
    ap.add_argument("--out", type=Path, help="output folder (default results/<preset>)")
    ap.add_argument("--restarts", type=int, default=2,
                    help="times to resume from the stored cells after a worker process crashes (default 2; 0 with "
                         "--jobs 1: run in this process)")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                    help="worker processes computing cells at once, each for its own algorithms (default: 2, or "
                         "1 on a 1-CPU machine); times in table2 are then measured beside the other workers")
    ap.add_argument("--part", help=argparse.SUPPRESS)  # I/J: this worker computes part I of J (see supervise)
    args = ap.parse_args(argv)
    if args.restarts < 0:
        raise SystemExit(f"--restarts must be >= 0, got {args.restarts}")
    if args.jobs < 1:
        raise SystemExit(f"--jobs must be >= 1, got {args.jobs}")
    preset = build_preset(args)
    out = args.out or Path("results") / preset["name"]
    out.mkdir(parents=True, exist_ok=True)
    if args.only and "reality" in args.only:
        from benchmarks import reality

        command = " ".join(["python -m benchmarks.sweep", *(sys.argv[1:] if argv is None else argv)])
        print(f"wrote {reality.run(preset, out, command)}")
        return out
    sections = args.only or list(SECTIONS)
    parts = partition(preset["algos"], args.jobs)
    if (args.restarts or len(parts) > 1) and os.environ.get(WORKER_ENV) != "1":
        raise SystemExit(supervise(sys.argv[1:] if argv is None else list(argv), args.restarts, parts, out))
    # Before jax is first imported (enable_compilation_cache): XLA's C++ log lines, e.g. one error
    # line per program loaded from the persistent cache, would drown the progress bar.
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    if args.quick:
        quick_compilation()
    enable_compilation_cache()
    log = lambda msg: tqdm.write(msg, file=sys.stderr)  # noqa: E731
    if args.part:
        i, n = (int(v) for v in args.part.split("/"))
        sweep = Sweep(preset, out, log, algos=partition(preset["algos"], n)[i], bar_position=i)
        _crash_injection(sweep, out)
        timing = sweep.compute(sections)
        write_json_atomic(out / PART_TIMING_DIR / f"part{i}.json",
                          dict(algos=sweep.algos, timing=timing, computed=sweep.cells.computed))
        return out
    sweep = Sweep(preset, out, log)
    _crash_injection(sweep, out)
    workers = [json.loads((out / PART_TIMING_DIR / f"part{i}.json").read_text())
               for i in range(int(os.environ.get(PARTS_ENV, "0")))]
    computed, reused = sweep.run(sections, workers, started=float(os.environ.get(STARTED_ENV, "nan")))
    print(f"wrote {out}/summary.md ({computed} cells computed, {reused} reused)")
    return out


if __name__ == "__main__":
    main()
