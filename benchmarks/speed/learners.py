"""Training speed of the learners: env steps per second of ``agents.train`` for PPO, SAC and TD3 at
the sweep's default settings (5-stage hard), with the XLA compile time and count inside each call.

    python -m benchmarks.speed.learners [--algos ppo sac td3] [--repeats 3] [--steps ppo=262144 ...]
                                        [--python /other/venv/bin/python ...]
                                        [--out results/learners_speed.json]

Each measurement is one fresh process (``agents.train`` from a cold start, compilation included, as
a sweep cell pays it). ``--python`` adds interpreters (other JAX versions, say) measured side by
side: the runs alternate between interpreters, repeat after repeat, and the table gives each one's
median and its ratio to the first interpreter (this one).
"""

from __future__ import annotations

import json
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

from agents.io import write_json_atomic
from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import keep_ctrl_c

ENV = {"stages": 5, "mode": "hard"}
# Budgets per algorithm (env steps): enough for the steady state to dominate a cold call.
STEPS = {"ppo": 262_144, "sac": 30_000, "td3": 30_000}


def _sweep_hyper(algo: str) -> dict:
    """The default sweep preset's hyperparameters of ``algo`` (its config name and overrides)."""
    from benchmarks.sweep.plan import preset

    default = preset("default")
    return {"config": default["algo_config"], **default.get("hyper", {}).get(algo, {})}


def measure_one(algo: str, steps: int) -> dict:
    """Train ``algo`` once in this process: env steps trained, wall and CPU seconds (all threads),
    XLA compile seconds and count."""
    import jax

    from benchmarks.common import count_compiles

    compile_s = count_compiles()
    import agents

    t0, c0 = time.perf_counter(), time.process_time()
    result = agents.train(
        algo, ENV, seed=0, total_steps=steps, progress=False, **_sweep_hyper(algo)
    )
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    trained = result.env_steps
    return dict(
        algo=algo,
        jax=jax.__version__,
        steps=trained,
        wall_s=wall,
        cpu_s=cpu,
        steps_per_s=trained / wall,
        compile_s=compile_s[0],
        compiles=compile_s[1],
    )


def _run(python: str, algo: str, steps: int) -> dict:
    """One measurement in a fresh process of interpreter ``python``."""
    code = (
        "import json, sys; from benchmarks.speed.learners import measure_one; "
        f"print('RESULT ' + json.dumps(measure_one({algo!r}, {steps})))"
    )
    out = subprocess.run(
        [python, "-c", code],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("RESULT ")]
    if out.returncode != 0 or not lines:
        tail = "\n".join(out.stderr.strip().splitlines()[-3:])
        raise SystemExit(
            f"learners_speed: {python} failed on {algo} (exit {out.returncode}):\n{tail}"
        )
    return json.loads(lines[-1][len("RESULT ") :])


def _table(rows: list[dict], pythons: list[str], algos: list[str]) -> str:
    lines = [
        "| algo | JAX | env steps | wall s (median) | CPU s | env-steps/s | compile s | "
        "compiles | vs first |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for algo in algos:
        base = None
        for py in pythons:
            rs = [r for r in rows if r["algo"] == algo and r["python"] == py]
            rate = statistics.median(r["steps_per_s"] for r in rs)
            base = rate if base is None else base
            med = {k: statistics.median(r[k] for r in rs) for k in ("wall_s", "cpu_s", "compile_s")}
            lines.append(
                f"| {algo} | {rs[0]['jax']} | {rs[0]['steps']:,} | {med['wall_s']:.1f} | "
                f"{med['cpu_s']:.1f} | {rate:,.0f} | {med['compile_s']:.1f} | "
                f"{rs[0]['compiles']} | {rate / base:.2f}x |"
            )
    return "\n".join(lines)


def main(argv=None) -> None:
    keep_ctrl_c()
    ap = ArgumentParser(
        prog="python -m benchmarks.speed.learners", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("--algos", nargs="+", default=list(STEPS), choices=list(STEPS))
    ap.add_argument(
        "--steps", nargs="*", default=[], metavar="ALGO=N", help="budgets other than the defaults"
    )
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--python", nargs="*", default=[], help="other interpreters measured side by side"
    )
    ap.add_argument("--out", type=Path, default=Path("results/learners_speed.json"))
    args = ap.parse_args(argv)
    steps = dict(STEPS)
    for item in args.steps:
        algo, _, n = item.partition("=")
        if algo not in STEPS or not n.isdigit() or int(n) < 1:
            ap.error(f"--steps takes ALGO=N with ALGO in {list(STEPS)} and N >= 1, got {item!r}")
        steps[algo] = int(n)
    ap.check_least(args, repeats=1)
    pythons = [sys.executable] + args.python
    rows = []
    total = args.repeats * len(args.algos) * len(pythons)
    for rep in range(args.repeats):
        for algo in args.algos:
            for py in pythons:
                r = _run(py, algo, steps[algo])
                r.update(python=py, repeat=rep)
                rows.append(r)
                print(
                    f"[{len(rows)}/{total}] {algo} jax {r['jax']}: {r['steps']:,} steps in "
                    f"{r['wall_s']:.1f} s ({r['steps_per_s']:,.0f}/s, compile "
                    f"{r['compile_s']:.1f} s x{r['compiles']})",
                    flush=True,
                )
    table = _table(rows, pythons, args.algos)
    print(table)
    write_json_atomic(
        args.out,
        dict(
            host=platform.node(),
            cpu_count=__import__("os").cpu_count(),
            date=time.strftime("%Y-%m-%d"),
            env=ENV,
            steps=steps,
            rows=rows,
            table=table,
        ),
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
