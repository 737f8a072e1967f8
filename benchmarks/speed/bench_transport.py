"""The bench's Channel Access transports side by side: one simulated bench, the same controller and
seed, each transport's runner in turn.

    python -m benchmarks.speed.bench_transport --seconds 15 --rounds 2 --out DIR

Starts one IOC (``ops_jax.ioc``, free-running at ``--ioc-rate`` Hz, ``--seed``) and, for every
round, runs ``python -m agents.bench --controller CONTROLLER --seconds S --seed SEED`` once per
transport (``agents.bench.transport``: ``OPS_BENCH_TRANSPORT``), the order turned round every other
round, the bench reset (its ``RESET`` PV) before each run. ``--tree NAME=DIR`` adds a row run from
another checkout of this project (its own default transport, ophyd on ``--tree-layer``): a
reference to compare with. Per row:
the median over the rounds of the runner's CPU time per control step (``time.process_time``, ms),
its latency (frame to setpoint write) p50 and p99 (ms), frames per step and steps per second,
and the host's load average around the runs. Prints a table, writes ``DIR/bench_transport.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from agents.bench.transport import TRANSPORTS
from benchmarks.lab.processes import ROOT, START_S, start_ioc
from ops_jax import pvs
from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import keep_ctrl_c

PREFIX = "TR:"
FIGURES = (  # summary.json keys in the table, with their headings
    ("cpu_ms_per_step", "CPU ms/step"),
    ("latency_ms_p50", "latency p50 ms"),
    ("latency_ms_p99", "latency p99 ms"),
    ("frames_per_step", "frames/step"),
    ("rate_hz", "steps/s"),
)


def parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(prog="python -m benchmarks.speed.bench_transport", description=__doc__)
    ap.add_argument("--transports", nargs="+", default=list(TRANSPORTS), choices=TRANSPORTS)
    ap.add_argument(
        "--tree", action="append", default=[], metavar="NAME=DIR", help="a checkout's row"
    )
    ap.add_argument(
        "--tree-layer",
        default="caproto",
        help="ophyd's control layer in the --tree rows (OPHYD_CONTROL_LAYER; default caproto)",
    )
    ap.add_argument("--controller", default="spgd")
    ap.add_argument("--seconds", type=float, default=15.0, help="each run's length (s)")
    ap.add_argument("--rounds", type=int, default=2, help="runs per row")
    ap.add_argument("--rate", type=float, default=100.0, help="the runner's step cap (Hz)")
    ap.add_argument("--ioc-rate", type=float, default=100.0, help="the bench's frame rate (Hz)")
    ap.add_argument(
        "--stale-s",
        type=float,
        default=5.0,
        help="the watchdog's stale_s (s; a shared host stalls)",
    )
    ap.add_argument("--stages", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    return ap


def rows(args) -> list:
    """(row name, checkout folder, transport or None: the checkout's default)."""
    out = [(name, ROOT, name) for name in args.transports]
    for spec in args.tree:
        name, sep, folder = spec.partition("=")
        if not (sep and name and Path(folder).is_dir()):
            raise SystemExit(f"--tree must be NAME=DIR with an existing DIR, got {spec!r}")
        out.append((name, Path(folder).resolve(), None))
    return out


def reset(env: dict) -> None:
    """Start the bench again (its ``RESET`` PV)."""
    code = f"from caproto.sync.client import write; write({PREFIX + pvs.RESET!r}, 1)"
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=60, cwd=ROOT)


def run_once(args, env: dict, row: tuple, out: Path) -> dict:
    """One runner's summary.json, with the load average (1 min) before and after its run."""
    name, folder, transport = row
    env = {**env, "PYTHONPATH": str(folder)}
    for key in ("OPS_BENCH_TRANSPORT", "OPHYD_CONTROL_LAYER"):
        env.pop(key, None)
    if transport is not None:
        env["OPS_BENCH_TRANSPORT"] = transport
    else:
        env["OPHYD_CONTROL_LAYER"] = args.tree_layer
    command = [
        sys.executable,
        "-m",
        "agents.bench",
        *("--prefix", PREFIX, "--controller", args.controller, "--stages", str(args.stages)),
        *("--seconds", str(args.seconds), "--rate", str(args.rate), "--seed", str(args.seed)),
        *("--stale-s", str(args.stale_s), "--out", str(out)),
    ]
    reset(env)
    load = os.getloadavg()[0]
    with open(out.parent / f"{out.name}.log", "w") as log:
        rc = subprocess.run(
            command, cwd=folder, env=env, stdout=log, stderr=subprocess.STDOUT, timeout=START_S
        ).returncode
    if rc not in (0, 3):  # 3: the watchdog stopped it (its reason in the summary)
        raise SystemExit(f"{name}: the runner exited with {rc}; see {out.parent / out.name}.log")
    summary = json.loads((out / "summary.json").read_text())
    return {**summary, "load_before": load, "load_after": os.getloadavg()[0]}


def measure(args) -> dict:
    """Every row's runs on one IOC: {row: [summary, ...]}."""
    args.out.mkdir(parents=True, exist_ok=True)
    ioc_args = ["--prefix", PREFIX, "--stages", str(args.stages), "--rate", str(args.ioc_rate)]
    ioc = start_ioc(args.out, *ioc_args, "--seed", str(args.seed))
    table = {name: [] for name, _, _ in rows(args)}
    try:
        for k in range(args.rounds):
            order = rows(args) if k % 2 == 0 else rows(args)[::-1]
            for row in order:
                summary = run_once(args, ioc.env, row, args.out / f"{row[0]}-{k}")
                table[row[0]].append(summary)
                print(f"round {k}: {row[0]}: {figures(summary)}", flush=True)
    finally:
        ioc.kill()
    return table


def figures(summary: dict) -> str:
    """One run's figures on a line, and how it ended."""
    shown = ", ".join(f"{head} {summary[key]:.2f}" for key, head in FIGURES)
    return f"{shown}, stopped by {summary['stopped_by']}"


def medians(runs: list) -> dict:
    """The median over ``runs`` of each figure, and the load average's range."""
    out = {key: float(np.median([r[key] for r in runs])) for key, _ in FIGURES}
    loads = [r[k] for r in runs for k in ("load_before", "load_after")]
    return {**out, "load_min": min(loads), "load_max": max(loads), "runs": len(runs)}


def render(table: dict) -> str:
    """The table of medians, one row per transport or checkout."""
    heads = ["row", *(h for _, h in FIGURES), "load 1 min"]
    lines = [" | ".join(heads), " | ".join("---" for _ in heads)]
    for name, runs in table.items():
        m = medians(runs)
        cells = [f"{m[key]:.2f}" for key, _ in FIGURES]
        lines.append(" | ".join([name, *cells, f"{m['load_min']:.1f}-{m['load_max']:.1f}"]))
    return "\n".join(lines)


def main(argv=None) -> None:
    keep_ctrl_c()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser().parse_args(argv)
    if args.seconds <= 0 or args.rounds < 1:
        raise SystemExit("--seconds must be > 0 and --rounds >= 1")
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    table = measure(args)
    print(render(table))
    record = {
        "started": started,
        "command": " ".join(["python -m benchmarks.speed.bench_transport", *map(str, argv)]),
        "host_cores": os.cpu_count(),
        "medians": {name: medians(runs) for name, runs in table.items()},
        "runs": table,
    }
    (args.out / "bench_transport.json").write_text(json.dumps(record, indent=1, default=str))


if __name__ == "__main__":
    main()
