"""Steady-state environment throughput: env-steps/s of a jitted 200-step ``lax.scan`` of
``OPSEnv.step_batch`` and of ``jax.vmap(OPSEnv.step)`` (hard mode, uniform random actions,
auto-reset included; the two timed alternately in one process, and whether their optimised programs
are identical), per physics model, stage count and batch size, against the reference's recorded
single-instance step time.

    python -m benchmarks.speed.throughput [--stages 3 5 7] [--batch 1 64 1024 8192] [--repeats 5]
                                    [--out results/throughput.json]
    python -m benchmarks.speed.throughput --gymnax --stages 5 --batch 4096 --models phasor \\
        --repeats 5

``--gymnax``: only ``jax.vmap`` of the gymnax adapter's step (``ops_jax.adapters.gymnax``, needs the
gymnax extra) against ``step_batch``, side by side, by wall time and by this process's CPU time
(less moved by other jobs on a shared machine); the other tables are left out.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import ops_jax
from agents.evaluation import split_over_devices
from agents.io import write_json_atomic
from benchmarks.common import load_reference_timing
from ops_jax import noise
from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import exit_interrupted, keep_ctrl_c, progress

SCAN_STEPS = 200
PATHS = ("step_batch", "vmap")  # env.step_batch(keys, ...) | jax.vmap(env.step)(keys, ...)
GYMNAX_PATHS = ("step_batch", "gymnax")  # ... | jax.vmap of the gymnax adapter's step


def build(stages: int, model: str, batch: int, path: str = "step_batch"):
    """A jitted function running SCAN_STEPS batched steps (``path`` in PATHS or GYMNAX_PATHS) from a
    given state. With several local devices that divide the batch, the batch is split across them
    (``agents.evaluation.split_over_devices``)."""
    env, params = ops_jax.make(stages, "hard", model=model)
    step = env.step_batch if path == "step_batch" else jax.vmap(env.step, in_axes=(0, 0, 0, None))
    if path == "gymnax":
        from ops_jax.adapters import gymnax as gymnax_env

        gymnax, gymnax_params = gymnax_env.make(stages, "hard", model=model)
        step = jax.vmap(
            lambda k, s, a, p: gymnax.step(k, s, a, gymnax_params), in_axes=(0, 0, 0, None)
        )
    sharding = split_over_devices(batch, "batch")
    shard = (
        (lambda x: x)
        if sharding is None
        else (lambda x: jax.lax.with_sharding_constraint(x, sharding))
    )

    @jax.jit
    def run(key, obs, state):
        def body(carry, t):
            obs, state = carry
            k = jax.random.fold_in(key, t)
            k_act, k_env = jax.random.split(k)
            # U[-1, 1) from the simulator's own unrolled hash (jax.random.uniform's loops over its
            # rounds through memory and would time the benchmark more than the step).
            action = shard(noise.draws(k_act, uniform={"a": (batch, stages)})["a"])
            keys = shard(jax.random.split(k_env, batch))
            obs, state, reward, *_ = step(keys, state, action, params)
            return (obs, state), reward.mean()

        (obs, state), r = jax.lax.scan(body, (obs, state), jnp.arange(SCAN_STEPS))
        return obs, state, r

    obs, state = jax.jit(env.reset_batch)(jax.random.split(jax.random.key(0), batch), params)
    if sharding is not None:
        obs, state = jax.device_put((obs, state), sharding)
    return run, obs, state


def program_text(compiled) -> str:
    """The optimised HLO of a compiled function without its source locations (for comparing
    programs)."""
    lines = compiled.as_text().splitlines()
    debug_info = r"^\s*(\d+ [{\"]|FileNames|FunctionNames|FileLocations|StackFrames)"
    text = "\n".join(l for l in lines if not re.match(debug_info, l))
    return re.sub(r"(, )?(metadata=\{[^}]*\}|stack_frame_id=\d+)", "", text)


def measure(stages: int, model: str, batch: int, repeats: int, paths=PATHS) -> list[dict]:
    """One row per step path; the paths' repeats alternate, so load changes hit them alike."""
    key = jax.random.key(1)
    compiled, compile_s, times, cpu = {}, {}, {p: [] for p in paths}, {p: [] for p in paths}
    for p in paths:
        run, obs, state = build(stages, model, batch, p)
        t0 = time.perf_counter()
        compiled[p] = (run.lower(key, obs, state).compile(), obs, state)
        compile_s[p] = time.perf_counter() - t0
        jax.block_until_ready(compiled[p][0](key, obs, state))  # warm-up
    for i in range(repeats):
        for p in paths:
            fn, obs, state = compiled[p]
            t0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn(jax.random.key(2 + i), obs, state))
            times[p].append(time.perf_counter() - t0)
            cpu[p].append(time.process_time() - c0)
    rows = []
    for p in paths:
        median = statistics.median(times[p])
        rows.append(
            dict(
                model=model,
                stages=stages,
                batch=batch,
                step=p,
                compile_s=compile_s[p],
                median_scan_s=median,
                median_scan_cpu_s=statistics.median(
                    cpu[p]
                ),  # this process's CPU seconds: less moved by other jobs
                steps_per_s=batch * SCAN_STEPS / median,
                us_per_step_per_instance=1e6 * median / (batch * SCAN_STEPS),
            )
        )
    base = rows[0]["steps_per_s"]
    for r in rows:
        r["vs_" + paths[0]] = r["steps_per_s"] / base
        r["cpu_vs_" + paths[0]] = rows[0]["median_scan_cpu_s"] / r["median_scan_cpu_s"]
        r["same_program_as_" + paths[0]] = program_text(compiled[r["step"]][0]) == program_text(
            compiled[paths[0]][0]
        )
    return rows


def measure_only(stages: int, model: str, batch: int, repeats: int) -> float:
    """Median seconds per instance of ``physics.measure`` alone (power and samples) on a batch."""
    x = jax.random.uniform(jax.random.key(0), (batch, stages), minval=-0.3, maxval=0.3)
    fn = jax.jit(lambda x: ops_jax.physics.measure(x, stages=stages, model=model)[:2])
    jax.block_until_ready(fn(x))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(x))
        times.append(time.perf_counter() - t0)
    return statistics.median(times) / batch


def step_cost(
    stages: int = 5,
    model: str = "phasor",
    num_envs: int | None = None,
    *,
    number: int = 1000,
    repeats: int = 5,
    **options,
) -> dict:
    """Steady-state cost of the Gymnasium adapters: ``num_envs=None`` times ``OPSGymEnv.step``
    (seconds per step, best of ``repeats`` runs of ``number`` steps, zero actions, truncation
    disabled); an integer times ``OPSVectorEnv.step`` (env-steps per second)."""
    import timeit

    from ops_jax.adapters.gymnasium.env import OPSGymEnv, OPSVectorEnv

    if num_envs is None:
        env = OPSGymEnv(stages=stages, mode="hard", model=model, max_steps=2**30, **options)
        action = np.zeros(stages, np.float32)
    else:
        env = OPSVectorEnv(num_envs=num_envs, stages=stages, mode="hard", model=model, **options)
        action = np.zeros((num_envs, stages), np.float32)
    env.reset(seed=0)
    for _ in range(10):
        env.step(action)  # compile and warm up
    per_call = min(timeit.repeat(lambda: env.step(action), number=number, repeat=repeats)) / number
    out = dict(stages=stages, model=model, num_envs=num_envs, seconds_per_call=per_call)
    if num_envs is not None:
        out["env_steps_per_second"] = num_envs / per_call
    return out


def main(argv=None):
    ap = ArgumentParser(
        prog="python -m benchmarks.speed.throughput",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--stages", type=int, nargs="+", default=[3, 5, 7])
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 64, 1024, 8192])
    ap.add_argument("--models", nargs="+", default=["field", "phasor"], choices=["field", "phasor"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--host-devices",
        type=int,
        default=1,
        help="CPU only: split the CPU into this many JAX devices (one thread each) and the batch "
        "across them; sets XLA_FLAGS=--xla_force_host_platform_device_count (default 1)",
    )
    ap.add_argument(
        "--gymnax",
        action="store_true",
        help="only vmap(gymnax adapter step) against step_batch (needs the gymnax extra)",
    )
    ap.add_argument("--out", type=Path, default=Path("results/throughput.json"))
    args = ap.parse_args(argv)
    keep_ctrl_c()
    ap.check_least(args, host_devices=1)
    if args.host_devices > 1:  # read when jax's backend starts, i.e. before the first computation
        os.environ["XLA_FLAGS"] = (
            f"{os.environ.get('XLA_FLAGS', '')} "
            f"--xla_force_host_platform_device_count={args.host_devices}"
        ).strip()

    results = dict(
        meta=_meta(args), rows=[], physics_measure=[], gymnasium=[], gymnasium_modes=None
    )
    try:
        (measure_gymnax if args.gymnax else measure_all)(args, results)
    except KeyboardInterrupt:
        results["meta"]["interrupted"] = True
        write_json_atomic(args.out, results)
        combos = len(args.models) * len(args.stages) * len(args.batch)
        exit_interrupted(
            f"{len(results['rows']) // len(PATHS)} of {combos} configurations measured, kept in "
            f"{args.out} (meta.interrupted: true); run the command again to measure them all"
        )
    write_json_atomic(args.out, results)
    print(f"wrote {args.out}")
    return results["rows"]


def _meta(args) -> dict:
    """The JSON's ``meta``: the JAX version, backend, devices, XLA flags, host and settings."""
    return dict(
        jax=jax.__version__,
        backend=jax.default_backend(),
        devices=[str(d) for d in jax.devices()],
        xla_flags=os.environ.get("XLA_FLAGS", ""),
        cpu_count=os.cpu_count(),
        platform=platform.platform(),
        scan_steps=SCAN_STEPS,
        repeats=args.repeats,
    )


def measure_gymnax(args, results: dict) -> None:
    """vmap of the gymnax adapter's step against ``step_batch``, per model, stage count and batch,
    appended to ``results["rows"]``; the two timed alternately in one process."""
    from importlib.metadata import version

    results["meta"]["gymnax"] = version("gymnax")
    header = (
        f"{'model':7} {'N':>2} {'batch':>6} {'step':>10} {'env-steps/s':>13} {'x step_batch':>12} "
        f"{'CPU s':>7} {'x (CPU)':>7} {'compile s':>9}"
    )
    print(header + "\n" + "-" * len(header))
    for model in args.models:
        for n in args.stages:
            for b in args.batch:
                for row in measure(n, model, b, args.repeats, paths=GYMNAX_PATHS):
                    results["rows"].append(row)
                    print(
                        f"{model:7} {n:>2} {b:>6} {row['step']:>10} {row['steps_per_s']:>13,.0f} "
                        f"{row['vs_step_batch']:>12.3f} {row['median_scan_cpu_s']:>7.2f} "
                        f"{row['cpu_vs_step_batch']:>7.3f} {row['compile_s']:>9.2f}"
                    )


def measure_all(args, results: dict) -> None:
    """Every table of the benchmark, appended to ``results`` as each row is measured."""
    ref = load_reference_timing()
    rows = results["rows"]
    combos = [(m, n, b) for m in args.models for n in args.stages for b in args.batch]
    header = (
        f"{'model':7} {'N':>2} {'batch':>6} {'step':>10} {'env-steps/s':>13} {'x step_batch':>12} "
        f"{'same HLO':>8} {'us/step':>9} {'compile s':>9} {'x reference':>12}"
    )
    bar = progress(combos, desc="throughput", unit="cfg")
    bar.write(header + "\n" + "-" * len(header))
    for model, n, b in bar:
        for row in measure(n, model, b, args.repeats):
            ref_step = ref.get(str(n), {}).get("step_median_s")
            row["reference_steps_per_s"] = 1 / ref_step if ref_step else None
            row["speedup_vs_reference"] = row["steps_per_s"] * ref_step if ref_step else None
            rows.append(row)
            sp = f"{row['speedup_vs_reference']:.0f}" if row["speedup_vs_reference"] else "-"
            bar.write(
                f"{model:7} {n:>2} {b:>6} {row['step']:>10} {row['steps_per_s']:>13,.0f} "
                f"{row['vs_step_batch']:>12.2f} {str(row['same_program_as_step_batch']):>8} "
                f"{row['us_per_step_per_instance']:>9.3f} "
                f"{row['compile_s']:>9.2f} {sp:>12}"
            )
    print(
        f"\nphysics.measure alone, batch 1024 (us per instance)\n{'N':>2} "
        + " ".join(f"{m:>8}" for m in args.models)
    )
    for n in args.stages:
        t = {m: measure_only(n, m, 1024, args.repeats) for m in args.models}
        results["physics_measure"].append(
            dict(stages=n, **{f"{m}_us": 1e6 * v for m, v in t.items()})
        )
        print(f"{n:>2} " + " ".join(f"{1e6 * t[m]:>8.2f}" for m in args.models))
    ref5 = ref.get("5", {}).get("step_median_s")
    print("\nGymnasium adapters, N = 5, hard (single: ms per step; vector: env-steps/s)")
    for model in args.models:
        single = step_cost(5, model)
        vector = step_cost(5, model, num_envs=1024, number=20)
        results["gymnasium"].append(
            dict(
                model=model,
                single_ms=1e3 * single["seconds_per_call"],
                vector_1024_steps_per_s=vector["env_steps_per_second"],
            )
        )
        ratio = (
            f", {ref5 / single['seconds_per_call']:.0f}x faster than the reference's "
            f"{1e3 * ref5:.1f} ms"
            if ref5
            else ""
        )
        print(
            f"{model:7} single {1e3 * single['seconds_per_call']:.3f} ms{ratio}; "
            f"vector(1024) {vector['env_steps_per_second']:,.0f} env-steps/s"
        )
    from benchmarks.speed.gym_modes import measure_modes

    print()
    results["gymnasium_modes"] = measure_modes(args.models, repeats=args.repeats)


if __name__ == "__main__":
    main()
