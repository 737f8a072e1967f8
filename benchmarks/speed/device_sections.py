"""The sections of ``benchmarks.speed.device``, each run in a child process: step, rollout and
training rates, the sweep."""

from __future__ import annotations

import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.speed.batch_scan import batches, scan

ROOT = Path(__file__).resolve().parents[1]
ENV = {"stages": 5, "mode": "hard"}
# Training runs: env steps and hyperparameters (full size; --tiny below).
TRAIN = {
    "droq": (20_000, {"config": "budget"}),
    "td3": (30_000, {"config": "fast", "eval_every": 5000}),  # the default sweep's settings
    "sac": (30_000, {"config": "fast", "min_replay_size": 2048}),
}
TRAIN_TINY = {
    "droq": (
        300,
        {"config": "budget", "learning_starts": 128, "eval_every": 100, "eval_episodes": 2},
    ),
    "td3": (
        512,
        {
            "config": "fast",
            "num_envs": 8,
            "learning_starts": 256,
            "eval_every": 128,
            "eval_episodes": 2,
        },
    ),
    "sac": (
        1024,
        {
            "config": "fast",
            "num_envs": 8,
            "min_replay_size": 256,
            "num_evals": 2,
            "num_eval_envs": 4,
            "grad_updates_per_step": 2,
        },
    ),
}
# --------------------------------------------------------------------------------------------------
# The sections, each run in a child process: ``fn(args, deadline, record)``, record(dict) saving its
# results so far.


def device_info() -> dict:
    """The first JAX device's kind and platform, the device count, JAX's version and the host."""
    import jax
    import jaxlib

    d = jax.devices()[0]
    return dict(
        device=dict(
            kind=d.device_kind,
            platform=d.platform,
            count=jax.device_count(),
            devices=[str(x) for x in jax.devices()],
        ),
        jax=jax.__version__,
        jaxlib=jaxlib.__version__,
        host=platform.node(),
        cpu_count=os.cpu_count(),
        machine=platform.machine(),
        python=platform.python_version(),
    )


def step_dtypes(stages: int, model: str) -> list[str]:
    """The dtypes of every array that ``reset_batch`` and ``step_batch`` return (traced, not
    run)."""
    import jax
    import jax.numpy as jnp

    import ops_jax

    env, params = ops_jax.make(stages, "hard", model=model)
    keys = jax.random.split(jax.random.key(0), 2)
    obs, state = jax.eval_shape(env.reset_batch, keys, params)
    stepped = jax.eval_shape(env.step_batch, keys, state, jnp.zeros((2, stages)), params)
    return sorted({str(x.dtype) for x in jax.tree.leaves((obs, state, stepped))})


def _scan_section(args, measure_one, deadline: float, record, out: dict) -> dict:
    """``out`` with the scan of ``measure_one(model, stages, batch)`` over the command line's
    models, stages and batches until ``deadline`` (``batch_scan.scan``)."""
    configs = [(m, n) for n in args.stages for m in args.models]
    scan(measure_one, configs, batches(args.tiny, args.batch_exp), deadline, record, out)
    return out


def section_step_batch(args, deadline: float, record) -> dict:
    """env-steps/s of a jitted 200-step scan of ``env.step_batch``
    (``benchmarks.speed.throughput.measure``)."""
    import jax

    from benchmarks.speed.throughput import SCAN_STEPS, measure

    out = dict(
        scan_steps=SCAN_STEPS,
        repeats=args.repeats,
        x64=bool(getattr(jax.config, "jax_enable_x64", False)),
        dtypes={m: step_dtypes(args.stages[0], m) for m in args.models},
    )

    def one(model, n, b):
        (row,) = measure(n, model, b, args.repeats, paths=("step_batch",))
        return {
            k: row[k]
            for k in ("model", "stages", "batch", "compile_s", "median_scan_s", "steps_per_s")
        }

    return _scan_section(args, one, deadline, record, out)


def rollout_rate(stages: int, model: str, batch: int, repeats: int, steps: int = 200) -> dict:
    """env-steps/s of ``ops_jax.rollout`` (uniform random actions, the whole trajectory returned):
    the first call's time less the median of ``repeats`` later calls is its compilation."""
    import statistics

    import jax

    import ops_jax

    env, params = ops_jax.make(stages, "hard", model=model)

    def policy(key, obs):
        return jax.random.uniform(key, (obs.shape[0], stages), minval=-1.0, maxval=1.0)

    t0 = time.perf_counter()
    jax.block_until_ready(ops_jax.rollout(env, params, policy, jax.random.key(0), batch, steps))
    first = time.perf_counter() - t0
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(
            ops_jax.rollout(env, params, policy, jax.random.key(1 + i), batch, steps)
        )
        times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    return dict(
        model=model,
        stages=stages,
        batch=batch,
        compile_s=max(0.0, first - median),
        median_scan_s=median,
        steps_per_s=batch * steps / median,
    )


def section_rollout(args, deadline: float, record) -> dict:
    """env-steps/s of ``ops_jax.rollout`` over 200 steps, the trajectory kept on the device."""
    out = dict(scan_steps=200, repeats=args.repeats)
    return _scan_section(
        args, lambda m, n, b: rollout_rate(n, m, b, args.repeats), deadline, record, out
    )


class OutOfTime(Exception):
    """A training run stopped at its section's deadline."""


def train_rate(algo: str, steps: int, hyper: dict, deadline: float, record, out: dict) -> dict:
    """Train ``algo`` once from a cold start: env steps, wall seconds, XLA compile seconds and
    count, env-steps/s with and without compilation; stops at ``deadline`` (raising
    ``OutOfTime``)."""
    import agents
    from benchmarks.common import count_compiles

    compile_s = count_compiles()
    out.update(algo=algo, env=ENV, total_steps=steps, hyper=hyper, progress=[])
    t0 = time.perf_counter()

    def progress_fn(step, metrics):
        elapsed = time.perf_counter() - t0
        out["progress"].append(
            dict(
                step=int(step),
                elapsed_s=elapsed,
                compile_s=compile_s[0],
                normalized_power=metrics.get("normalized_power"),
            )
        )
        out["steps_per_s_so_far"] = int(step) / max(elapsed, 1e-9)
        record(out)
        if time.monotonic() > deadline:
            raise OutOfTime(f"stopped at its deadline after {int(step):,} of {steps:,} env steps")

    result = agents.train(
        algo, ENV, seed=0, total_steps=steps, progress_fn=progress_fn, progress=False, **hyper
    )
    wall = time.perf_counter() - t0
    trained = result.env_steps
    out.update(
        env_steps=trained,
        wall_s_train=wall,
        compile_s=compile_s[0],
        compiles=compile_s[1],
        steps_per_s=trained / wall,
        steps_per_s_excl_compile=trained / max(wall - compile_s[0], 1e-9),
        wall_time={k: v for k, v in result.wall_time.items() if isinstance(v, (int, float))},
    )
    return out


def _train_section(algo: str):
    def run(args, deadline: float, record) -> dict:
        steps, hyper = (TRAIN_TINY if args.tiny else TRAIN)[algo]
        steps = args.steps.get(algo, steps)
        return train_rate(algo, steps, dict(hyper), deadline, record, {})

    run.__doc__ = f"Training rate of {algo}."
    return run


def section_sweep(args, deadline: float, record) -> dict:
    """Wall time of ``python -m benchmarks.sweep --quick --only table1`` (fresh output folder and
    compilation cache), in a process stopped at ``deadline``."""
    work = Path(tempfile.mkdtemp(prefix="ops-jax-device-sweep-"))
    base = ["-m", "benchmarks.sweep", "--quick", "--only", "table1"] + (
        ["--algos", "spgd", "--seeds", "2"] if args.tiny else []
    )
    cmd = [sys.executable, *base, "--out", str(work / "out")]
    env = {**os.environ, "OPS_JAX_CACHE": str(work / "xla-cache"), "PYTHONPATH": _pythonpath()}
    out = dict(command=" ".join(["python", *base, "--out", "<tmp>"]))
    record(out)
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd,
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        log, _ = proc.communicate(timeout=max(1.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        _stop(proc, signal.SIGINT, 8.0)
        out["wall_s_sweep"] = time.perf_counter() - t0
        record(out)
        raise OutOfTime(
            f"the quick sweep ran past its deadline ({out['wall_s_sweep']:.0f} s)"
        ) from None
    finally:
        summary = work / "out" / "summary.md"
        out["cells"] = (
            len(list((work / "out" / "cells").glob("*.json")))
            if (work / "out" / "cells").exists()
            else 0
        )
        out["summary_written"] = summary.exists()
        shutil.rmtree(work, ignore_errors=True)
    out["wall_s_sweep"] = time.perf_counter() - t0
    out["exit_status"] = proc.returncode
    if proc.returncode != 0:
        raise RuntimeError(
            f"the quick sweep exited with {proc.returncode}: "
            + " | ".join(log.strip().splitlines()[-3:])
        )
    return out


SECTION_FNS = {
    "step_batch": section_step_batch,
    "rollout": section_rollout,
    "droq": _train_section("droq"),
    "td3": _train_section("td3"),
    "sac": _train_section("sac"),
    "sweep": section_sweep,
}


def _pythonpath() -> str:
    """PYTHONPATH with this checkout first (children import the same packages)."""
    return os.pathsep.join(
        [str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    )


def _stop(proc: subprocess.Popen, sig: int, wait_s: float) -> None:
    """Send ``sig`` to ``proc``'s process group, then SIGKILL it if it is still running after
    ``wait_s``."""
    try:
        os.killpg(proc.pid, sig)
        proc.wait(timeout=wait_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    except ProcessLookupError:
        pass
