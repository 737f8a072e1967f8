"""``python -m benchmarks.budget``'s command line: the lab-budget section's plan
(``benchmarks.budget.plan``) of a preset (``benchmarks.budget.presets``), computed cell by cell into
``<out>/cells``, then its report."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from agents import TrimConfig
from benchmarks.budget import plan
from ops_jax.cli.progress import keep_ctrl_c
from ops_jax.env import PROBES


def parser() -> argparse.ArgumentParser:
    """The command line's options."""
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.budget", description=plan.__doc__.split("\n")[0]
    )
    ap.add_argument(
        "--preset",
        choices=sorted(plan.PRESETS),
        default="default",
        help="quick: tiny (seconds); default: DroQ, the references, protocol (b); full: every "
        "learner; frames-residual-history: the frames only (benchmarks/budget/presets.py)",
    )
    ap.add_argument("--out", type=Path, required=True, help="output folder")
    ap.add_argument(
        "--only", nargs="+", default=None, help="controllers (default: all of the preset)"
    )
    ap.add_argument(
        "--seeds", nargs="+", type=int, default=None, help="training seeds (default: the preset's)"
    )
    ap.add_argument(
        "--envs", nargs="+", default=None, help="environments by name (default: all of the preset)"
    )
    ap.add_argument(
        "--bench-scale",
        type=float,
        default=None,
        metavar="X",
        help="protocol (b)'s unseen benches at X times the lab preset, X in (0, 10] (default: the "
        "preset's)",
    )
    ap.add_argument(
        "--bench-probe",
        choices=PROBES,
        default=None,
        help="how a probe is measured on protocol (b)'s benches: frame, a frame later as on a "
        "bench (ops_jax EnvConfig.probe; default: the simulator's, instant)",
    )
    ap.add_argument(
        "--bench-trim",
        choices=sorted(TrimConfig.PRESETS),
        default=None,
        help="the trim's preset (agents.TrimConfig) around protocol (b)'s adapted policies "
        "(default: the preset's)",
    )
    return ap


def main(argv=None) -> str:
    """Compute the cells of the chosen plan (reusing those stored in ``<out>/cells``) and write the
    report."""
    ap = parser()
    args = ap.parse_args(argv)
    keep_ctrl_c()
    from benchmarks.cells import CellStore

    try:
        chosen = plan.cells(
            args.preset,
            args.only,
            args.seeds,
            args.envs,
            args.bench_scale,
            args.bench_probe,
            args.bench_trim,
        )
    except ValueError as exc:
        ap.error(str(exc).replace("bench_scale", "--bench-scale"))
    store = CellStore(args.out / "cells")
    records = []
    for i, cell in enumerate(chosen):
        label = f"{cell.env}-{cell.algo}-s{cell.seed}"
        t0 = time.perf_counter()
        result = store.get(label, cell.to_dict(), lambda: plan.compute(cell))
        records.append({"cell": cell, "result": result})
        before = f"before {result['before']:.3f}, " if "before" in result else ""
        print(
            f"[{i + 1}/{len(chosen)}] {label}: "
            + before
            + ", ".join(f"{k} {v:.3f}" for k, v in result["scores"].items())
            + f" ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
    text = plan.report(records, args.out)
    print(text)
    return text
