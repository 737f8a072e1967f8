"""Env-steps/s of each way to run ops-jax under Gymnasium, side by side: one env
(``gymnasium.make``), ``make_vec``'s "sync", "async" under each start method, and
"vector_entry_point" (same batch, and a large one). Each mode runs in a fresh Python process (so
"async" may fork before JAX starts, and each pays its own start-up: import, workers, compile).

    python -m benchmarks.speed.gym_modes [--models phasor] [--stages 5] [--num-envs 8] [--big 1024]
                                   [--out results/gym_modes.json]

Hard mode, zero actions (episodes truncate after 200 steps and restart), median of ``--repeats``
timed runs after a warm-up; "start s" is construction + reset + first step.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

ENV_ID = "ops_jax/OPS-v0"
ENV_STEPS = 2400  # env-steps per timed run (at least 2 steps per run)
WATCHDOG_S = 300


def modes(num_envs: int, big: int) -> list[tuple[str, str | None, int]]:
    """(vectorization mode, start method, num_envs) of each row."""
    return [
        ("single", None, 1),
        ("sync", None, num_envs),
        ("async", "fork", num_envs),
        ("async", "forkserver", num_envs),
        ("async", "spawn", num_envs),
        ("vector_entry_point", None, num_envs),
        ("vector_entry_point", None, big),
    ]


def measure_one(
    mode: str, context: str | None, num_envs: int, model: str, stages: int = 5, repeats: int = 3
) -> dict:
    """Env-steps/s (median of ``repeats``) and start-up seconds of one mode, in this process."""
    import gymnasium
    import numpy as np

    import ops_jax  # noqa: F401  (registers the id)

    t0 = time.perf_counter()
    kw = dict(stages=stages, mode="hard", model=model)
    if mode == "single":
        env = gymnasium.make(ENV_ID, **kw)
        action = np.zeros(stages, np.float32)
    else:
        vector_kwargs = {"context": context} if context else {}
        env = gymnasium.make_vec(
            ENV_ID, num_envs=num_envs, vectorization_mode=mode, vector_kwargs=vector_kwargs, **kw
        )
        action = np.zeros((num_envs, stages), np.float32)
    env.reset(seed=0)

    def run(n):
        for _ in range(n):
            _, _, term, trunc, _ = env.step(action)
            if mode == "single" and (term or trunc):
                env.reset()

    run(1)
    start_s = time.perf_counter() - t0
    steps = max(2, ENV_STEPS // num_envs)
    run(steps // 4)  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        run(steps)
        times.append(time.perf_counter() - t)
    env.close()
    median = statistics.median(times)
    return dict(
        mode=mode,
        context=context,
        num_envs=num_envs,
        model=model,
        stages=stages,
        start_s=start_s,
        env_steps_per_s=num_envs * steps / median,
    )


def run_in_subprocess(
    mode: str, context: str | None, num_envs: int, model: str, stages: int, repeats: int
) -> dict:
    """``measure_one`` in a fresh Python process under a watchdog; a failure becomes the row's
    ``error``."""
    row = dict(mode=mode, context=context, num_envs=num_envs, model=model, stages=stages)
    one = json.dumps({**row, "repeats": repeats})
    cmd = [sys.executable, "-m", "benchmarks.speed.gym_modes", "--one", one]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=WATCHDOG_S)
    except subprocess.TimeoutExpired:
        return dict(row, error=f"no result within {WATCHDOG_S} s")
    if out.returncode != 0:
        return dict(
            row, error=(out.stderr.strip().splitlines() or ["exit code %d" % out.returncode])[-1]
        )
    return json.loads(out.stdout.strip().splitlines()[-1])


def label(row: dict) -> str:
    """A row's mode as a reader would name it, e.g. "async (forkserver)"."""
    return row["mode"] + (f" ({row['context']})" if row.get("context") else "")


def measure_modes(
    models, stages: int = 5, num_envs: int = 8, big: int = 1024, repeats: int = 3, write=print
) -> list[dict]:
    """Every mode for every model, one fresh process each; ``write`` gets the header and each
    row."""
    from ops_jax.cli.progress import progress

    header = f"{'model':7} {'mode':30} {'envs':>5} {'env-steps/s':>12} {'start s':>8}"
    write(
        f"Gymnasium modes, N = {stages}, hard (one fresh process per row)\n{header}\n"
        + "-" * len(header)
    )
    rows = []
    combos = [(m, *spec) for m in models for spec in modes(num_envs, big)]
    for model, mode, context, n in progress(combos, desc="gymnasium modes", unit="mode"):
        row = run_in_subprocess(mode, context, n, model, stages, repeats)
        rows.append(row)
        if "error" in row:
            write(f"{model:7} {label(row):30} {n:>5} failed: {row['error']}")
        else:
            write(
                f"{model:7} {label(row):30} {n:>5} {row['env_steps_per_s']:>12,.0f} "
                f"{row['start_s']:>8.1f}"
            )
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.speed.gym_modes",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--models", nargs="+", default=["phasor"], choices=["field", "phasor"])
    ap.add_argument("--stages", type=int, default=5)
    ap.add_argument("--num-envs", type=int, default=8, help="instances of every vector mode")
    ap.add_argument(
        "--big", type=int, default=1024, help="instances of the second vector_entry_point row"
    )
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path("results/gym_modes.json"))
    ap.add_argument(
        "--one", help=argparse.SUPPRESS
    )  # internal: one row as JSON, run in a fresh process
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(measure_one(**json.loads(args.one))))
        return None
    import platform

    from agents.io import write_json_atomic

    rows = measure_modes(args.models, args.stages, args.num_envs, args.big, args.repeats)
    write_json_atomic(
        args.out,
        dict(
            meta=dict(
                host=platform.node(), platform=platform.platform(), python=platform.python_version()
            ),
            rows=rows,
        ),
    )
    print(f"wrote {args.out}")
    return rows


if __name__ == "__main__":
    main()
