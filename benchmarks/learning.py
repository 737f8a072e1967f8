"""Learning benchmark: train each algorithm on N-stage easy / medium / hard with several seeds and
report the testing P/Pmax (mean +- std over seeds), wall time per run and test-time steps to 0.9.

    python -m benchmarks.learning [--algos td3 sac ...] [--modes easy medium hard] [--seeds 5]
                                  [--stages 5] [--steps N] [--config fast] [--episodes 50]
                                  [--out results/learning] [--fresh] [--checkpoint-every M]

Each run: ``agents.train(algo, {"stages", "mode"}, seed=s, total_steps=--steps, config=--config)``,
then ``agents.evaluate`` on the testing environment (seed 1000 + s, drift fully on in hard mode,
``--episodes`` episodes of 200 steps, the exact "field" model). Per run it records the final P/Pmax
(mean over episodes), the median test-time steps to reach 0.9 and the fraction of episodes that do,
and the wall time (total, simulation, optimisation). Results go to ``<out>/learning.json``
(rewritten atomically after every run; a stored run with the same hyperparameters, as resolved now
(so a changed default counts), and the same --episodes is reused, and said so, unless ``--fresh``;
one with others is rerun) and checkpoints to ``<out>/checkpoints/<algo>_<mode>_s<seed>``. TD3 and
DroQ write that checkpoint as they train too, every ``--checkpoint-every`` env steps
(``agents.learners.offpolicy.checkpoint``): a run stopped by Ctrl-C (one line, exit status 130, the
finished runs kept) or a kill continues from it when the command is run again with the same settings
(a checkpoint of other settings, or with ``--fresh``, is discarded, and said so). A run that fails
is recorded with its error and printed; nothing is skipped silently.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import traceback
from pathlib import Path

import numpy as np

from agents.io import read_json, write_json_atomic
from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import exit_interrupted, keep_ctrl_c


def run_key(algo: str, mode: str, seed: int) -> str:
    return f"{algo}/{mode}/{seed}"


def expected_hyper(algo: str, steps, config) -> dict:
    """The hyperparameters a run with these arguments trains with, in the stored (JSON) form."""
    from agents.registry import CONFIG_TYPES

    learner_config = CONFIG_TYPES[algo].make(config)
    if steps is not None and hasattr(learner_config, "total_steps"):
        learner_config = dataclasses.replace(learner_config, total_steps=int(steps))
    return json.loads(json.dumps(learner_config.to_hyper()))


def checkpointing(
    algo: str, env_config: dict, seed: int, steps, config, folder: Path, every, fresh
):
    """``(Checkpoints in folder, a note)`` of a TD3 or DroQ run (a checkpoint there of other
    settings, or with ``fresh``, removed; the note says so, or from which step the run continues),
    else ``(None, None)``."""
    import shutil

    from agents import api as base, registry
    from agents.learners.offpolicy import checkpoint

    if not registry.get(algo).off_policy:
        return None, None
    env_config = base.check_env_config(env_config)
    wanted = checkpoint.identity(algo, env_config, expected_hyper(algo, steps, config), [seed])
    try:
        meta = checkpoint.check_fits(folder, wanted)
        note = None if meta is None else f"continuing from its checkpoint at step {meta['step']:,}"
        if meta is not None and fresh:
            raise ValueError("--fresh")
    except ValueError as exc:
        note = f"discarding its checkpoint: {exc}"
        for stale in (folder, Path(f"{folder}.old")):
            shutil.rmtree(stale, ignore_errors=True)
    return checkpoint.Checkpoints(folder, every or checkpoint.EVERY), note


def run_one(
    algo: str,
    stages: int,
    mode: str,
    seed: int,
    steps,
    config,
    episodes: int,
    ckpt_dir: Path | None,
    checkpoints=None,
) -> dict:
    """Train and evaluate one (algo, mode, seed), ``checkpoints`` (TD3, DroQ) as it trains; the run
    record."""
    import agents
    from agents import api as base

    env_config = base.check_env_config({"stages": stages, "mode": mode})
    settings = {"config": config, "checkpoints": checkpoints}
    hyper = {k: v for k, v in settings.items() if v is not None}
    t0 = time.perf_counter()
    result = base.train(algo, env_config, seed=seed, total_steps=steps, progress=False, **hyper)
    train_s = time.perf_counter() - t0
    ev = agents.evaluate(result, env_config, episodes=episodes, seed=1000 + seed)
    if ckpt_dir is not None:
        agents.save(ckpt_dir / f"{algo}_{mode}_s{seed}", result)
    s = ev.summary
    return dict(
        algo=algo,
        mode=mode,
        seed=seed,
        stages=stages,
        status="ok",
        episodes=episodes,
        testing_p_pmax=s["final_mean"],
        testing_p_pmax_std_over_episodes=s["final_std"],
        mean_last10=s["mean_last10"],
        steps_to_0p9=s["steps_to_0p9_median"],
        fraction_reached_0p9=s["fraction_reached_0p9"],
        measurements_per_step=s["measurements_per_step"],
        train_steps=int(np.asarray(result.curve["step"])[-1]) if len(result.curve["step"]) else 0,
        wall_time=dict(result.wall_time),
        train_call_s=train_s,
        curve={k: np.asarray(v).tolist() for k, v in result.curve.items()},
        hyper=result.config.to_hyper(),
    )


def run_job(args, job: tuple, ckpt_dir: Path | None, write, kept: str) -> dict:
    """The run record of ``job`` (algo, mode, seed) with ``main``'s arguments, its checkpoints (TD3,
    DroQ), lines to ``write``; a Ctrl-C or SIGTERM is one line (``kept``: what the finished runs
    left) and exit status 130 (143)."""
    algo, mode, seed = job
    key, checkpoints = run_key(*job), None
    try:
        if ckpt_dir is not None:
            checkpoints, note = checkpointing(
                algo,
                {"stages": args.stages, "mode": mode},
                seed,
                args.steps,
                args.config,
                ckpt_dir / f"{algo}_{mode}_s{seed}",
                args.checkpoint_every,
                args.fresh,
            )
            if note:
                write(f"{key}: {note}")
        rec = run_one(
            algo,
            args.stages,
            mode,
            seed,
            args.steps,
            args.config,
            args.episodes,
            ckpt_dir,
            checkpoints,
        )
    except KeyboardInterrupt as stop:
        saved = checkpoints is not None and checkpoints.saved_step is not None
        exit_interrupted(
            f"stopped during {key}; {kept}"
            + (f", this run's checkpoint in {checkpoints.folder}" if saved else "")
            + "; run the same command again to go on from there",
            128 + getattr(stop, "signum", 2),
        )
    wall = rec["wall_time"].get("total", float("nan"))
    write(
        f"{key}: testing P/Pmax {rec['testing_p_pmax']:.4f}, steps to 0.9 {rec['steps_to_0p9']}, "
        f"{rec['fraction_reached_0p9']:.0%} reach it, wall {wall:.1f} s"
    )
    return rec


def aggregate(runs: list[dict]) -> dict:
    """Per (algo, mode): mean / std over seeds of the testing P/Pmax, wall time, steps to 0.9."""
    table = {}
    for r in runs:
        table.setdefault((r["algo"], r["mode"]), []).append(r)
    out = {}
    for (algo, mode), rs in sorted(table.items()):
        ok = [r for r in rs if r["status"] == "ok"]
        p = np.array([r["testing_p_pmax"] for r in ok])
        st = np.array([r["steps_to_0p9"] for r in ok], float)
        wt = np.array([r["wall_time"].get("total", np.nan) for r in ok], float)
        out[f"{algo}/{mode}"] = dict(
            algo=algo,
            mode=mode,
            seeds=len(ok),
            failed=len(rs) - len(ok),
            p_pmax_mean=float(p.mean()) if p.size else float("nan"),
            p_pmax_std=float(p.std()) if p.size else float("nan"),
            steps_to_0p9_mean=float(np.nanmean(st)) if np.isfinite(st).any() else float("nan"),
            wall_time_s_mean=float(wt.mean()) if wt.size else float("nan"),
            wall_time_s_max=float(wt.max()) if wt.size else float("nan"),
        )
    return out


def format_table(agg: dict) -> str:
    lines = [
        f"{'algo':8s} {'mode':7s} {'seeds':>5s} {'testing P/Pmax':>18s} {'steps to 0.9':>12s} "
        f"{'wall s/run':>10s}"
    ]
    for row in agg.values():
        fail = f"  ({row['failed']} failed)" if row["failed"] else ""
        lines.append(
            f"{row['algo']:8s} {row['mode']:7s} {row['seeds']:5d} {row['p_pmax_mean']:8.4f} +- "
            f"{row['p_pmax_std']:6.4f} {row['steps_to_0p9_mean']:12.1f} "
            f"{row['wall_time_s_mean']:10.1f}{fail}"
        )
    return "\n".join(lines)


def parser() -> ArgumentParser:
    """The command line of ``python -m benchmarks.learning``."""
    from agents.api import ALGOS
    from agents.learners.offpolicy.checkpoint import EVERY

    ap = ArgumentParser(
        prog="python -m benchmarks.learning",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--algos", nargs="+", default=[a for a in ALGOS], choices=sorted(ALGOS))
    ap.add_argument(
        "--modes", nargs="+", default=["easy", "medium", "hard"], choices=["easy", "medium", "hard"]
    )
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--seed0", type=int, default=0, help="first seed")
    ap.add_argument("--stages", type=int, default=5)
    ap.add_argument(
        "--steps", type=int, default=None, help="env steps per run (default: each algorithm's)"
    )
    ap.add_argument(
        "--config",
        default=None,
        help="hyperparameter set passed as config= (default: the algorithm's)",
    )
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--out", type=Path, default=Path("results/learning"))
    ap.add_argument(
        "--fresh", action="store_true", help="ignore runs already in <out>/learning.json"
    )
    ap.add_argument("--no-checkpoints", action="store_true")
    ap.add_argument(
        "--checkpoint-every",
        type=int,
        default=None,
        metavar="M",
        help=f"TD3, DroQ: env steps between two checkpoints of a run (default {EVERY})",
    )
    return ap


def stored_runs(path: Path, args) -> dict:
    """The finished runs in ``path`` (learning.json) at ``args.stages``, by run key; none with
    ``--fresh`` or without the file."""
    if not path.exists() or args.fresh:
        return {}
    return {
        run_key(r["algo"], r["mode"], r["seed"]): r
        for r in read_json(path)["runs"]
        if r["status"] == "ok" and r["stages"] == args.stages
    }


def job_record(args, job: tuple, stored, ckpt_dir: Path | None, write, kept: str):
    """The run record of ``job`` (algo, mode, seed), a failure recorded with its error; None where
    ``stored`` (its stored run, or None) has the same hyperparameters and --episodes and is kept."""
    algo, mode, seed = job
    key = run_key(*job)
    same = stored is not None and (stored.get("hyper"), stored.get("episodes")) == (
        expected_hyper(algo, args.steps, args.config),
        args.episodes,
    )
    if same:
        write(
            f"{key}: reusing the stored run (testing P/Pmax {stored['testing_p_pmax']:.4f}); "
            "--fresh reruns it"
        )
        return None
    if stored is not None:
        write(f"{key}: the stored run used other hyperparameters or --episodes: rerunning")
    try:
        return run_job(args, job, ckpt_dir, write, kept)
    except Exception as exc:  # recorded and printed, never silently skipped
        rec = dict(
            algo=algo,
            mode=mode,
            seed=seed,
            stages=args.stages,
            status="error",
            error=f"{type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(limit=5),
        )
        write(f"{key}: FAILED {rec['error']}")
        return rec


def save(path: Path, args, runs: dict) -> dict:
    """Write learning.json at ``path`` (the settings, ``runs``' records and their summary); the
    summary."""
    agg = aggregate(list(runs.values()))
    write_json_atomic(
        path,
        dict(
            stages=args.stages,
            steps=args.steps,
            config=args.config,
            episodes=args.episodes,
            runs=list(runs.values()),
            summary=agg,
        ),
    )
    return agg


def main(argv=None) -> dict:
    """Run (or reuse) every (algo, mode, seed) of the command line ``argv``; the summary."""
    from agents.api import algo_module

    ap = parser()
    args = ap.parse_args(argv)
    keep_ctrl_c()
    ap.check_least(
        args, seeds=1, stages=1, episodes=1, steps=0, checkpoint_every=1
    )  # before any run
    for algo in args.algos:  # a missing extra stops here, at once, naming its install command
        algo_module(algo)

    from ops_jax.cli.progress import progress

    path = args.out / "learning.json"
    done = stored_runs(path, args)
    ckpt_dir = None if args.no_checkpoints else args.out / "checkpoints"
    jobs = [
        (a, m, s)
        for a in args.algos
        for m in args.modes
        for s in range(args.seed0, args.seed0 + args.seeds)
    ]
    runs = dict(done)
    bar = progress(jobs, unit="run")
    for job in bar:
        key = run_key(*job)
        bar.set_description(key)
        kept = f"the {len(runs)} finished runs are in {path}"
        rec = job_record(args, job, done.get(key), ckpt_dir, bar.write, kept)
        if rec is not None:
            runs[key] = rec
            save(path, args, runs)
    agg = save(path, args, runs)
    print(format_table(agg))
    print(f"written to {path}")
    return agg


if __name__ == "__main__":
    failed = sum(row["failed"] for row in main().values())
    if failed:  # the table and the file hold the others
        sys.exit(
            f"python -m benchmarks.learning: {failed} run(s) failed; their errors are above and "
            "in learning.json"
        )
