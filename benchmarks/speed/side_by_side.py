"""This checkout's batched step beside another git commit's, timed in one run: the commit is
checked out into a temporary git worktree, and one worker process per tree (this one and the other)
compiles the parts of ``step_breakdown`` (the whole ``env.step_batch``, ``physics.measure``, the
step's random draws), each a jitted 200-step ``lax.scan``. The workers then take turns, one repeat
each, so a load change on a shared host hits both alike; medians of wall and CPU time (this
worker's threads), and the ratios other / this.

    python -m benchmarks.speed.step_breakdown --against main --stages 5 --model phasor \\
        --batch 8192 --repeats 5

The other commit must have the same package layout (``ops_jax``, ``benchmarks.speed``); its
``ops_jax`` is timed with this checkout's benchmark code.
"""

from __future__ import annotations

import contextlib
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import ops_jax
from benchmarks.speed.throughput import SCAN_STEPS
from ops_jax import noise

PARTS = ("step", "physics", "draws")
ROOT = Path(__file__).resolve().parents[2]
# The worker imports ops_jax from the tree it is given, everything else from this checkout.
_BOOT = (
    "import sys; tree = sys.argv[1]; sys.path.insert(0, tree); import ops_jax, ops_jax.env; "
    "sys.path.remove(tree); from benchmarks.speed.side_by_side import worker; worker(sys.argv[2:])"
)


@contextlib.contextmanager
def worktree(rev: str):
    """A temporary detached git worktree of ``rev``, removed on exit."""
    with tempfile.TemporaryDirectory(prefix="ops-against-") as tmp:
        path = Path(tmp) / "tree"
        git = ["git", "-C", str(ROOT)]
        subprocess.run(
            [*git, "worktree", "add", "--detach", str(path), rev], check=True, capture_output=True
        )
        try:
            yield path
        finally:
            subprocess.run([*git, "worktree", "remove", "--force", str(path)], capture_output=True)


def physics_scan(stages: int, model: str, batch: int):
    """(fn, args): SCAN_STEPS measurements of ``batch`` offsets that move every step."""

    def run(x):
        def body(acc, t):
            m = ops_jax.physics.measure(x + 1e-3 * t, stages=stages, model=model)
            return acc + m.power.sum() + m.samples.sum(), None

        return jax.lax.scan(body, jnp.float32(0), jnp.arange(SCAN_STEPS, dtype=jnp.float32))[0]

    return run, (jax.random.uniform(jax.random.key(0), (batch, stages), minval=-0.3, maxval=0.3),)


def draws_scan(env, batch: int):
    """(fn, args): SCAN_STEPS of the draws one step makes, one key per instance (as
    ``step_batch``)."""
    c = env.config
    shapes = dict(
        normal={"run": (c.feedback_k, c.stages), "obs": (env.frame_size,)},
        uniform={"knot": (c.stages,)},
    )

    def run(key):
        def body(acc, t):
            keys = jax.random.split(jax.random.fold_in(key, t), batch)
            d = jax.vmap(lambda k: noise.draws(k, **shapes))(keys)
            return acc + sum(v.sum() for v in d.values()), None

        return jax.lax.scan(body, jnp.float32(0), jnp.arange(SCAN_STEPS))[0]

    return run, (jax.random.key(1),)


def _compiled_parts(stages: int, model: str, batch: int) -> dict:
    """{part: (compiled fn, args, (compile wall s, compile CPU s))} of the three scans at one
    size."""
    from benchmarks.speed import throughput

    env, _ = ops_jax.make(stages, "hard", model=model)
    run, obs, state = throughput.build(stages, model, batch)
    specs = {
        "step": (run, (jax.random.key(1), obs, state)),
        "physics": physics_scan(stages, model, batch),
        "draws": draws_scan(env, batch),
    }
    out = {}
    for part, (fn, args) in specs.items():
        t0, c0 = time.perf_counter(), time.process_time()
        compiled = jax.jit(fn).lower(*args).compile()
        compile_s = (time.perf_counter() - t0, time.process_time() - c0)
        jax.block_until_ready(compiled(*args))  # warm-up
        out[part] = (compiled, args, compile_s)
    return out


def worker(argv) -> None:
    """Compile the parts for ``stages model batch``, print their compile times, then time one repeat
    of each part per line read from stdin and print (wall s, CPU s) per part, one JSON line each."""
    stages, model, batch = int(argv[0]), argv[1], int(argv[2])
    parts = _compiled_parts(stages, model, batch)
    print(json.dumps({p: c for p, (_, _, c) in parts.items()}), flush=True)
    for _ in sys.stdin:
        times = {}
        for part, (fn, args, _) in parts.items():
            t0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn(*args))
            times[part] = (time.perf_counter() - t0, time.process_time() - c0)
        print(json.dumps(times), flush=True)


def _start(tree: Path, stages: int, model: str, batch: int):
    proc = subprocess.Popen(
        [sys.executable, "-c", _BOOT, str(tree), str(stages), model, str(batch)],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    line = proc.stdout.readline()
    if not line:
        raise RuntimeError(f"the worker for {tree} ended before it compiled (exit {proc.wait()})")
    return proc, json.loads(line)


def compare(rev: str, stages: int, model: str, batch: int, repeats: int) -> dict:
    """One row: per part the medians (ns per instance-step, wall and CPU) of this checkout and of
    ``rev``, and their ratios (rev / this: how many times faster this checkout is)."""
    with worktree(rev) as other:
        trees = {"this": ROOT, rev: other}
        procs, compile_s = {}, {}
        try:
            for name, tree in trees.items():
                procs[name], compile_s[name] = _start(tree, stages, model, batch)
            samples = {name: [] for name in trees}
            for _ in range(repeats):
                for name, proc in procs.items():
                    proc.stdin.write("run\n")
                    proc.stdin.flush()
                    samples[name].append(json.loads(proc.stdout.readline()))
        finally:
            for proc in procs.values():
                proc.stdin.close()
                proc.wait()
    per = 1e9 / (batch * SCAN_STEPS)
    row = dict(
        model=model, stages=stages, batch=batch, against=rev, repeats=repeats, compile_s=compile_s
    )
    for part in PARTS:
        for name in trees:
            key = "this" if name == "this" else "other"
            for i, clock in enumerate(("wall", "cpu")):
                row[f"{part}_{key}_{clock}_ns"] = per * statistics.median(
                    s[part][i] for s in samples[name]
                )
        for clock in ("wall", "cpu"):
            row[f"{part}_speedup_{clock}"] = (
                row[f"{part}_other_{clock}_ns"] / row[f"{part}_this_{clock}_ns"]
            )
    return row


def print_row(r: dict) -> None:
    """One line per part: ns per instance-step of the other commit and of this checkout, and the
    ratios."""
    for part in PARTS:
        print(
            f"{r['model']:7} {r['stages']:>2} {r['batch']:>8} {part:8} "
            f"{r[f'{part}_other_wall_ns']:>10.1f} {r[f'{part}_this_wall_ns']:>10.1f} "
            f"{r[f'{part}_speedup_wall']:>6.2f}x {r[f'{part}_other_cpu_ns']:>10.1f} "
            f"{r[f'{part}_this_cpu_ns']:>10.1f} {r[f'{part}_speedup_cpu']:>6.2f}x",
            flush=True,
        )


HEADER = (
    f"{'model':7} {'N':>2} {'batch':>8} {'part':8} {'other ns':>10} {'this ns':>10} {'wall':>7} "
    f"{'other cpu':>10} {'this cpu':>10} {'cpu':>7}"
)
