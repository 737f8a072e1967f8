"""A batched rollout sharded over JAX processes, checked instance by instance against one process.

    python -m benchmarks.speed.multiprocess --processes 2 [--instances 64] [--steps 100]

Starts ``--processes`` local JAX processes joined by ``jax.distributed.initialize`` (CPU
collectives: gloo), shards ``--instances`` independent rollouts over their devices (one global
mesh, the instance axis split across processes), gathers the result on every process
(``process_allgather``), and compares it with the same rollouts run in this one process: instance
i's keys are ``fold_in(key, i)`` in both, so every instance must match bit for bit. Exit code 0
when they all do. On a multi-host GPU/TPU slice the same ``sharded_rollout`` runs unchanged, with
``jax.distributed.initialize()`` taking its arguments from the cluster (docs/scale.md).
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import keep_ctrl_c

WORKER_TIMEOUT_S = 300


def instance_rollout(env, params, key, i, steps: int):
    """P/Pmax (steps,) of instance ``i``: reset and ``steps`` uniform random actions in [-1, 1], all
    drawn from ``fold_in(key, i)``."""
    import jax

    k_reset, k_run = jax.random.split(jax.random.fold_in(key, i))
    _, state = env.reset(k_reset, params)

    def body(state, t):
        k_act, k_env = jax.random.split(jax.random.fold_in(k_run, t))
        action = jax.random.uniform(k_act, (env.config.stages,), minval=-1.0, maxval=1.0)
        _, state, _, _, _, info = env.step(k_env, state, action, params)
        return state, info["normalized_power"]

    return jax.lax.scan(body, state, jax.numpy.arange(steps))[1]


def batched_rollout(instances: int, steps: int, seed: int, sharding=None):
    """P/Pmax (instances, steps) of instances 0..``instances``-1 in one jitted call; with
    ``sharding`` (a ``NamedSharding`` of the instance axis) split over its devices, in any
    process."""
    import jax
    import jax.numpy as jnp

    import ops_jax

    env, params = ops_jax.make(stages=5, mode="hard")
    run = jax.vmap(lambda i: instance_rollout(env, params, jax.random.key(seed), i, steps))
    if sharding is None:
        return np.asarray(jax.jit(run)(jnp.arange(instances)))
    ids = jax.make_array_from_callback(
        (instances,), sharding, lambda index: np.arange(instances, dtype=np.int32)[index]
    )
    out = jax.jit(run, out_shardings=sharding)(ids)
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(out, tiled=True))


def sharded_rollout(instances: int, steps: int, seed: int):
    """``batched_rollout`` over every device of every process (call after
    ``jax.distributed.initialize``)."""
    import jax

    if instances % jax.device_count():
        raise ValueError(
            f"instances must be a multiple of the {jax.device_count()} devices, got {instances}"
        )
    mesh = jax.sharding.Mesh(np.array(jax.devices()), ("instances",))
    return batched_rollout(
        instances,
        steps,
        seed,
        jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("instances")),
    )


def worker(args) -> None:
    """One of the processes: join the others, run its share, write the gathered result (process
    0)."""
    import jax

    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        coordinator_address=args.coordinator,
        num_processes=args.processes,
        process_id=args.process_id,
        initialization_timeout=120,
    )
    t0 = time.perf_counter()
    npow = sharded_rollout(args.instances, args.steps, args.seed)
    if jax.process_index() == 0:
        np.savez(
            Path(args.result),
            npow=npow,
            seconds=time.perf_counter() - t0,
            devices=jax.device_count(),
        )
    jax.distributed.shutdown()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def check(processes: int, instances: int, steps: int, seed: int) -> dict:
    """Run the rollouts over ``processes`` local processes and in this one; returns {"equal",
    "instances", "max_abs_diff", "seconds_multi", "seconds_single", "devices"}. Raises RuntimeError
    if a process fails."""
    coordinator = f"127.0.0.1:{_free_port()}"
    with tempfile.TemporaryDirectory() as tmp:
        result = Path(tmp) / "npow.npz"
        procs = [
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "benchmarks.speed.multiprocess",
                    "--processes",
                    str(processes),
                    "--instances",
                    str(instances),
                    "--steps",
                    str(steps),
                    "--seed",
                    str(seed),
                    "--process-id",
                    str(i),
                    "--coordinator",
                    coordinator,
                    "--result",
                    str(result),
                ],
                env={**os.environ, "JAX_PLATFORMS": "cpu"},
            )
            for i in range(processes)
        ]
        try:
            t0 = time.perf_counter()
            single = batched_rollout(instances, steps, seed)
            seconds_single = time.perf_counter() - t0
            codes = [p.wait(timeout=WORKER_TIMEOUT_S) for p in procs]
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
        if any(codes):
            raise RuntimeError(f"JAX processes exited with codes {codes}")
        data = np.load(result)
        multi = data["npow"]
        per_instance = np.all(multi == single, axis=1)
        return dict(
            equal=bool(per_instance.all()),
            instances=int(per_instance.size),
            equal_instances=int(per_instance.sum()),
            max_abs_diff=float(np.max(np.abs(multi - single))),
            seconds_multi=float(data["seconds"]),
            seconds_single=seconds_single,
            devices=int(data["devices"]),
        )


def main(argv=None) -> int:
    keep_ctrl_c()
    ap = ArgumentParser(
        prog="python -m benchmarks.speed.multiprocess",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--processes", type=int, default=2, help="JAX processes to start (>= 1)")
    ap.add_argument(
        "--instances", type=int, default=64, help="rollouts, a multiple of the processes' devices"
    )
    ap.add_argument("--steps", type=int, default=100, help="control steps per rollout (>= 1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--process-id", type=int, help=argparse.SUPPRESS
    )  # set in the started processes
    ap.add_argument("--coordinator", help=argparse.SUPPRESS)
    ap.add_argument("--result", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    ap.check_least(args, processes=1, instances=1, steps=1)
    if args.process_id is not None:
        worker(args)
        return 0
    if args.instances % args.processes:
        ap.error(
            f"--instances must be a multiple of --processes ({args.processes}), got "
            f"{args.instances}"
        )
    r = check(args.processes, args.instances, args.steps, args.seed)
    print(
        f"{r['instances']} instances x {args.steps} steps over {args.processes} processes "
        f"({r['devices']} devices): {r['equal_instances']} equal to the single-process run (max "
        "|diff| "
        f"{r['max_abs_diff']:.3g}); {r['seconds_multi']:.2f} s sharded (compile included), "
        f"{r['seconds_single']:.2f} s in one process"
    )
    return 0 if r["equal"] else 1


if __name__ == "__main__":
    sys.exit(main())
