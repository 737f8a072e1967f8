"""Where a batched env step's time goes: the whole ``env.step_batch``, its physics alone
(``physics.measure``) and its random draws alone (``noise.draws``, one key per instance), each a
jitted 200-step ``lax.scan`` at the same batch, median of the repeats (compilation apart).

    python -m benchmarks.speed.step_breakdown --stages 5 --model phasor --batch 65536 1048576 \\
        --out results/breakdown.json

Per row: ns per instance-step of each part, and each part's share of the whole step (the rest is the
environment's own bookkeeping: action, drift, reward, observation, auto-reset).

``--against REV`` times another git commit's code beside this checkout's in one run, the two taking
turns (``benchmarks.speed.side_by_side``): per part the medians of both (wall and CPU) and their
ratio.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import jax

import ops_jax
from agents.io import write_json_atomic
from benchmarks.speed import side_by_side
from benchmarks.speed.side_by_side import draws_scan, physics_scan
from benchmarks.speed.throughput import SCAN_STEPS, measure
from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import keep_ctrl_c


def _median_scan_s(fn, args, repeats: int) -> tuple[float, float]:
    """(compile s, median s) of a jitted ``fn(*args)``."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t0)
    return compile_s, statistics.median(times)


def breakdown(stages: int, model: str, batch: int, repeats: int) -> dict:
    """One row: ns per instance-step of the step, its physics and its draws, and their shares."""
    env, _ = ops_jax.make(stages, "hard", model=model)
    step = measure(stages, model, batch, repeats, paths=("step_batch",))[0]
    per = 1e9 / (batch * SCAN_STEPS)
    row = dict(
        model=model,
        stages=stages,
        batch=batch,
        step_ns=step["median_scan_s"] * per,
        step_compile_s=step["compile_s"],
    )
    for part, (fn, args) in (
        ("physics", physics_scan(stages, model, batch)),
        ("draws", draws_scan(env, batch)),
    ):
        compile_s, median = _median_scan_s(fn, args, repeats)
        row[f"{part}_ns"], row[f"{part}_compile_s"] = median * per, compile_s
        row[f"{part}_share"] = row[f"{part}_ns"] / row["step_ns"]
    return row


def main(argv=None) -> list[dict]:
    keep_ctrl_c()
    ap = ArgumentParser(
        prog="python -m benchmarks.speed.step_breakdown",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--stages", type=int, nargs="+", default=[5])
    ap.add_argument("--model", choices=("phasor", "field"), default="phasor")
    ap.add_argument("--batch", type=int, nargs="+", default=[1024, 65536])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path("results/breakdown.json"))
    ap.add_argument(
        "--against", metavar="REV", help="also time this git commit's code, side by side"
    )
    args = ap.parse_args(argv)
    for name, values in (
        ("--stages", args.stages),
        ("--batch", args.batch),
        ("--repeats", [args.repeats]),
    ):
        if min(values) < 1:
            ap.error(f"{name} must be >= 1, got {min(values)}")
    out = dict(
        jax=jax.__version__, device=jax.devices()[0].device_kind, scan_steps=SCAN_STEPS, rows=[]
    )
    if args.against:
        return _side_by_side(args, out)
    print(
        f"{'model':7} {'N':>2} {'batch':>8} {'step ns':>9} {'physics ns':>10} {'draws ns':>9} "
        f"{'physics':>8} {'draws':>6}"
    )
    for n in args.stages:
        for b in args.batch:
            r = breakdown(n, args.model, b, args.repeats)
            out["rows"].append(r)
            write_json_atomic(args.out, out)
            print(
                f"{r['model']:7} {n:>2} {b:>8} {r['step_ns']:>9.2f} {r['physics_ns']:>10.2f} "
                f"{r['draws_ns']:>9.2f} {r['physics_share']:>8.0%} {r['draws_share']:>6.0%}",
                flush=True,
            )
    print(f"wrote {args.out}")
    return out["rows"]


def _side_by_side(args, out: dict) -> list[dict]:
    """``main`` with ``--against``: one side-by-side row per stage count and batch."""
    print(side_by_side.HEADER)
    for n in args.stages:
        for b in args.batch:
            row = side_by_side.compare(args.against, n, args.model, b, args.repeats)
            out["rows"].append(row)
            write_json_atomic(args.out, out)
            side_by_side.print_row(row)
    print(f"wrote {args.out}")
    return out["rows"]


if __name__ == "__main__":
    main()
