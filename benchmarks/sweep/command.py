"""The paper's experiments on ops-jax, reproduced and extended, as one resumable command.

    python -m benchmarks.sweep                      # default preset (5 seeds, ~51 min on 2 cores)
    python -m benchmarks.sweep --quick              # a first look in a few minutes
    python -m benchmarks.sweep --preset paper --seeds 20
    python -m benchmarks.sweep --only table1 --out results/mine
    python -m benchmarks.sweep --preset paper --seeds 20 --ray auto  # a Ray cluster: docs/scale.md

Sections (benchmarks/sweep/plan.py): ``table1`` (5-stage x easy/medium/hard x algorithms x seeds:
final P/Pmax in the training and testing environments, Welch's t-test bolding), ``table2`` (timings
of the paper's Table 2, from the table1 runs), ``stages`` (stage scan N = 1..7), ``transfer`` (train
on one mode, test on each), ``feedback`` (train at k = 1, test at k = 1..100), ``budget`` (score
against env steps on a lab's budget, benchmarks/budget/plan.py); when named with ``--only``,
``reality`` (controllers under lab imperfections, benchmarks/sweep/reality.py). Everything lands in
``results/<name>/``: tables (.md, .csv), figures (.png), ``summary.md``. Finished work units are
stored in ``cells/`` the moment they finish (see benchmarks/cells.py): a re-run, or a run after a
crash, skips them. The work is cut into units (``Sweep.units``, from each section's declared cells)
that Ray actors compute, on a local Ray instance with ``--jobs`` workers by default or on a cluster
with ``--ray ADDRESS`` (benchmarks/sweep/executor.py); this process stores what they return and then
writes the reports (docs/sweep.md).

Evaluation as in the paper: P/Pmax at the end of 200-step test episodes. The training environment
uses the training seed's draws; the testing environment another seed, so in hard mode it has a
different drift realisation.
"""

from __future__ import annotations

import os

# Before jax loads (the imports below load it): XLA's C++ log lines, e.g. one per program loaded
# from the persistent compilation cache, would drown the progress output.
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
# A GPU shared with the workers: no process reserves most of its memory up front
# (benchmarks/sweep/executor.py).
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from benchmarks.sweep import plan as sweep_plan, presets  # noqa: E402
from benchmarks.sweep.units import enable_compilation_cache, quick_compilation  # noqa: E402
from ops_jax.cli.parser import ArgumentParser  # noqa: E402
from ops_jax.cli.progress import keep_ctrl_c  # noqa: E402

SECTIONS = sweep_plan.default_sections()  # a run without --only


def build_preset(args) -> dict:
    name = "quick" if args.quick else args.preset
    preset = json.loads(json.dumps(presets.preset(name)))  # deep copy
    if args.seeds is not None:
        preset["seeds"] = args.seeds
    if args.algos:
        preset["algos"] = list(args.algos)
        preset["stage_algos"] = [a for a in preset["stage_algos"] if a in args.algos] or list(
            args.algos
        )
    return preset


def parser() -> ArgumentParser:
    """The command line of ``python -m benchmarks.sweep``."""
    ap = ArgumentParser(
        prog="python -m benchmarks.sweep",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        "--preset",
        choices=("default", "paper"),
        default="default",
        help="seeds, budgets and episodes of every section (benchmarks/sweep/presets.py; default: "
        "default)",
    )
    ap.add_argument("--quick", action="store_true", help="a few-minute version (tests, first look)")
    ap.add_argument("--seeds", type=int, help="seeds per cell (the paper used 20)")
    ap.add_argument("--algos", nargs="+", choices=presets.preset("default")["algos"])
    ap.add_argument(
        "--only",
        nargs="+",
        choices=tuple(sweep_plan.PLAN),
        help=f"sections to run (default: {' '.join(SECTIONS)}; the others only when named, e.g. "
        "reality: benchmarks/sweep/reality.py)",
    )
    ap.add_argument("--out", type=Path, help="output folder (default results/<preset>)")
    ap.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="run the work on this Ray cluster ('auto' as in ray.init(address='auto'), or "
        "HOST:PORT); default: a local Ray instance with --jobs workers",
    )
    ap.add_argument(
        "--jobs",
        type=int,
        help="workers computing units at once (default: 2 locally, or 1 on a 1-CPU machine; with "
        "--ray, one per CPU of the cluster); times in table2 are then measured beside the other "
        "workers",
    )
    ap.add_argument(
        "--restarts",
        type=int,
        default=2,
        help="times Ray restarts a worker that died (crash signal, killed, node lost) and retries "
        "its unit (default 2); a later run resumes from the stored cells in any case",
    )
    ap.add_argument(
        "--worker-gpus",
        type=float,
        default=0.0,
        help="GPUs each worker claims on a Ray cluster with GPUs (e.g. 1, or 0.5 to share one by "
        "two)",
    )
    return ap


def main(argv=None):
    """Run the sweep's sections from the command line ``argv``; the output folder."""
    ap = parser()
    args = ap.parse_args(argv)
    keep_ctrl_c()
    if args.seeds is not None and args.seeds < 2:
        ap.error(
            "--seeds must be >= 2 (Welch's t-test needs two samples per algorithm), got "
            f"{args.seeds}"
        )
    ap.check_least(args, worker_gpus=0, restarts=0, jobs=1)
    preset = build_preset(args)
    preset["command"] = " ".join(
        ["python -m benchmarks.sweep", *(sys.argv[1:] if argv is None else argv)]
    )
    out = (args.out or Path("results") / preset["name"]).resolve()
    out.mkdir(parents=True, exist_ok=True)
    sections = args.only or list(sweep_plan.default_sections())
    if args.quick:
        quick_compilation()
    enable_compilation_cache()
    # imports jax: after the environment above is set
    from benchmarks.sweep import executor as sweep_ray

    jobs = args.jobs or (None if args.ray else min(2, os.cpu_count() or 1))
    try:
        computed, reused = sweep_ray.run(
            preset,
            out,
            sections,
            address=args.ray,
            jobs=jobs,
            restarts=args.restarts,
            worker_gpus=args.worker_gpus,
        )
    except KeyboardInterrupt:  # Ray's workers are stopped by then (sweep_ray.run shuts Ray down)
        stored = len(list((out / "cells").glob("*.json")))
        print(
            f"interrupted: {stored} finished cells are kept in {out}/cells; run the same command "
            "again to resume",
            file=sys.stderr,
            flush=True,
        )
        raise SystemExit(130) from None
    print(f"wrote {out}/summary.md ({computed} cells computed, {reused} reused)")
    return out
