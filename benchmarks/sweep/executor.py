"""The sweep's work units on Ray actors (a local Ray instance or a cluster); this process stores the
cells.

Each actor computes whole units (``Sweep.units``) in a scratch folder of its own node and returns
the files they wrote (cell JSON, checkpoints): no shared filesystem is needed, and this process
writes them into the output folder, so the cell store stays the one record (atomic, keyed by
configuration, resumable). A unit goes to an idle actor, preferably one that last ran the same
algorithm (its compiled programs are warm), and only once the units whose checkpoints it needs are
stored. A worker that dies (crash signal, killed, node lost) is restarted by Ray, which retries its
unit (``--restarts``).
"""

from __future__ import annotations

import dataclasses
import faulthandler
import json
import logging
import os
import shutil
import socket
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from agents.io import temp_dir, write_bytes_atomic
from benchmarks.sweep.records import EvalUnit, Unit
from benchmarks.sweep.schedule import Ledger, SmoothedTotal, pick
from benchmarks.sweep.units import Sweep, enable_compilation_cache
from ops_jax.cli import runtime
from ops_jax.cli.progress import is_terminal, progress

FORWARDED_ENV = (
    "XLA_FLAGS",
    "TF_CPP_MIN_LOG_LEVEL",
    "JAX_PLATFORMS",
    "XLA_PYTHON_CLIENT_PREALLOCATE",
    "XLA_PYTHON_CLIENT_MEM_FRACTION",
    "XLA_PYTHON_CLIENT_ALLOCATOR",
)
# the fraction of a GPU's memory that the workers sharing it divide between them
GPU_MEMORY_SHARED = 0.9
PROGRESS_EVERY_S = 5.0  # how often the progress line takes the running units' time into account
# a local instance's object store: units return kilobytes to megabytes
OBJECT_STORE_BYTES = 200 * 2**20


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Computed:
    """What a worker returns for a unit: the ``files`` it wrote ({path relative to the output
    folder: bytes}), the number of cells it ``computed`` (not found stored), its wall ``seconds``
    and where it ran (Ray ``node_id``, ``hostname``)."""

    files: dict
    computed: int
    seconds: float
    node_id: str
    hostname: str


class SweepWorker:
    """A Ray actor: computes units in a scratch folder and returns the files they wrote."""

    def __init__(self, preset: dict, env: dict, cpus: list | None = None):
        """``env``: variables set before jax starts (XLA_FLAGS, ...); ``cpus``: the CPUs this worker
        runs on (``pin``), or None for all."""
        import ray

        if cpus:
            pin(cpus)
        # a crash prints the Python stack into the worker's log (shown by the driver)
        faulthandler.enable()
        os.environ.update(env)
        enable_compilation_cache()
        self.where = dict(
            node_id=ray.get_runtime_context().get_node_id(), hostname=socket.gethostname()
        )
        self.scratch = Path(tempfile.mkdtemp(prefix="ops-jax-sweep-"))
        self.sweep = Sweep(preset, self.scratch, _stderr, meta=self.where)

    def run(
        self, unit: Unit, record: dict | None = None, checkpoint: dict | None = None
    ) -> Computed:
        """Compute ``unit`` (an eval unit gets its controller's training ``record`` and
        ``checkpoint`` files, {relative path: bytes})."""
        t0 = time.perf_counter()
        for rel, blob in (checkpoint or {}).items():
            (self.scratch / rel).parent.mkdir(parents=True, exist_ok=True)
            (self.scratch / rel).write_bytes(blob)
        computed = self.sweep.store.computed
        self.sweep.compute_unit(unit, record)
        files = {}
        for cell in unit.cells:
            path = self.sweep.store.path(cell.label, cell.config)
            files[path.relative_to(self.scratch).as_posix()] = blob = path.read_bytes()
            if unit.kind == "train":
                ckpt = self.scratch / json.loads(blob)["result"]["checkpoint"]
                files.update(
                    {f.relative_to(self.scratch).as_posix(): f.read_bytes() for f in ckpt.iterdir()}
                )
        for child in self.scratch.iterdir():  # this unit is returned: keep the node's disk clean
            shutil.rmtree(child)
        self.sweep.store.folder.mkdir()
        return Computed(
            files=files,
            computed=self.sweep.store.computed - computed,
            seconds=time.perf_counter() - t0,
            **self.where,
        )

    def close(self) -> None:
        shutil.rmtree(self.scratch, ignore_errors=True)


def pin(cpus) -> None:
    """Run every thread of this process, and the threads it starts later, on ``cpus`` only; called
    before JAX starts its CPU client, which then sizes its thread pool to them."""
    runtime.set_cores(cpus)


def cpu_shares(n: int) -> list:
    """``n`` disjoint, near-equal sets of this process's CPUs, one per local worker; ``[None] * n``
    (no pinning) when there are fewer CPUs than workers or no affinity interface. Two workers on two
    cores each with a two-thread pool share every core; one core each trained 20-25% faster,
    compilation excluded (docs/sweep.md)."""
    if not hasattr(os, "sched_getaffinity"):
        return [None] * n
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < n or n < 2:
        return [None] * n
    return [cpus[i * len(cpus) // n : (i + 1) * len(cpus) // n] for i in range(n)]


def checkpoint_files(out: Path, record: dict) -> dict:
    """The files of ``record``'s checkpoint under ``out``, {path relative to ``out``: bytes}."""
    return {
        f.relative_to(out).as_posix(): f.read_bytes()
        for f in (out / record["checkpoint"]).iterdir()
    }


def store_files(out: Path, files: dict) -> None:
    """Write a unit's returned files under ``out``: each checkpoint folder renamed into place whole,
    then each cell file renamed into place, so a stored cell always has its checkpoint."""
    folders = {}
    for rel, blob in files.items():
        if not rel.startswith("cells/"):
            folders.setdefault(Path(rel).parent, {})[Path(rel).name] = blob
    for folder, content in folders.items():
        dest = out / folder
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = temp_dir(dest.parent, dest.name)
        for name, blob in content.items():
            (tmp / name).write_bytes(blob)
        if dest.exists():
            shutil.rmtree(dest)
        os.replace(tmp, dest)
    for rel, blob in files.items():
        if rel.startswith("cells/"):
            write_bytes_atomic(out / rel, blob)


def connect(address: str | None, jobs: int | None):
    """``ray.init``: the cluster at ``address`` (the project's packages shipped to its workers), or
    a local instance with ``jobs`` CPUs."""
    import ray

    import agents
    import benchmarks
    import ops_jax

    if not is_terminal(sys.stderr):  # the workers' forwarded lines without colour codes in a log
        os.environ.setdefault("RAY_COLOR_PREFIX", "0")
    if address:
        ray.init(
            address=address,
            runtime_env={"py_modules": [ops_jax, agents, benchmarks]},
            log_to_driver=True,
        )
    else:
        # Ray starts workers at nice 15 (for the raylet's sake): on a machine running other work
        # they would get a small share of the CPU (measured: a several-fold slower sweep).
        os.environ.setdefault("RAY_worker_niceness", "0")
        # logging_level: no start-up lines of Ray's own (a local instance's token notice, "Started
        # ...").
        ray.init(
            num_cpus=jobs,
            include_dashboard=False,
            object_store_memory=OBJECT_STORE_BYTES,
            log_to_driver=True,
            logging_level=logging.ERROR,
        )


def run(
    preset: dict,
    out: Path,
    sections,
    address: str | None = None,
    jobs: int | None = None,
    restarts: int = 2,
    worker_gpus: float = 0.0,
):
    """Compute the cells of ``sections`` not stored in ``out`` on Ray workers (``jobs``, default one
    per CPU of the cluster), then write the reports. Returns (cells computed, cells reused)."""
    started = time.time()
    sweep = Sweep(preset, out, _stderr)
    units = sweep.units(sections)
    todo = {u.key: t for u in units if (t := sweep.todo(u)) is not None}
    done = {u.key for u in units} - set(todo)
    reused = sum(len(u.cells) for u in units) - sum(len(u.cells) for u in todo.values())
    workers, computed = [], 0
    if todo:
        import ray

        if (
            address is None and worker_gpus == 0
        ):  # Ray before 2.48 hid the GPUs from workers claiming none
            os.environ.setdefault("RAY_EXPERIMENTAL_NOSET_CUDA_VISIBLE_DEVICES", "1")
        connect(address, jobs)
        try:
            computed, workers = _compute(
                ray,
                sweep,
                todo,
                done,
                jobs,
                restarts,
                worker_gpus,
                out,
                preset,
                reused,
                local=address is None,
            )
        finally:
            ray.shutdown()
    return Sweep(preset, out, _stderr).run(sections, workers, computed, started)


def worker_env(n: int, worker_gpus: float, local: bool, environ=None) -> dict:
    """The variables set in each of ``n`` workers before jax starts: this process's
    ``FORWARDED_ENV``, and for workers sharing a GPU (a local instance with ``worker_gpus`` 0, or a
    fraction of a GPU each) no preallocation and each a cap on its share of the GPU's memory
    (``XLA_PYTHON_CLIENT_MEM_FRACTION``); values set in this process win."""
    environ = os.environ if environ is None else environ
    env = {k: environ[k] for k in FORWARDED_ENV if k in environ}
    env.setdefault(
        "XLA_PYTHON_CLIENT_PREALLOCATE", "false"
    )  # workers sharing a GPU must not each reserve most of it
    share = (
        GPU_MEMORY_SHARED / n if (local and worker_gpus == 0) else GPU_MEMORY_SHARED * worker_gpus
    )
    if 0 < share < GPU_MEMORY_SHARED or (local and worker_gpus == 0):
        env.setdefault("XLA_PYTHON_CLIENT_MEM_FRACTION", f"{share:.3f}")
    return env


def _submit(sweep: Sweep, out: Path, actor, unit: Unit):
    """Start ``unit`` on the worker ``actor``; an eval unit takes its controller's training record
    and checkpoint files along. Returns the task's reference."""
    record = checkpoint = None
    if isinstance(unit, EvalUnit):
        record = sweep.store.load(unit.train.label, unit.train.config)
        checkpoint = checkpoint_files(out, record)
    return actor.run.remote(unit, record, checkpoint)


def _returned(ray, ref, unit: Unit, out: Path) -> Computed:
    """What the task ``ref`` of ``unit`` returned; SystemExit saying how to resume where it
    failed."""
    try:
        return ray.get(ref)
    except (ray.exceptions.RayError, OSError) as exc:
        raise SystemExit(
            f"unit {unit.key} failed ({type(exc).__name__}: {exc}); the finished cells are "
            f"stored in {out}/cells (re-run the command to resume)"
        ) from exc


def _start_workers(ray, n: int, preset: dict, worker_gpus: float, restarts: int, local: bool):
    """``n`` ``SweepWorker`` actors of ``worker_gpus`` GPUs each, restarted up to ``restarts`` times
    (``local``: each pinned to its share of this machine's CPUs)."""
    env = worker_env(n, worker_gpus, local)
    actor = ray.remote(
        num_cpus=1, num_gpus=worker_gpus, max_restarts=restarts, max_task_retries=restarts
    )(SweepWorker)
    shares = cpu_shares(n) if local else [None] * n
    return [actor.remote(preset, env, cpus) for cpus in shares]


def _compute(
    ray,
    sweep: Sweep,
    todo: dict,
    done: set,
    jobs,
    restarts: int,
    worker_gpus: float,
    out: Path,
    preset: dict,
    reused: int = 0,
    local: bool = False,
):
    """The scheduling loop: units to idle workers, returned files into the store (``reused``: the
    plan's cells stored before, said on the progress line; ``local``: a local instance, whose
    workers get a share of the CPUs each). Returns (cells computed, a record per worker)."""
    n = max(1, min(jobs or int(ray.cluster_resources().get("CPU", 1)), len(todo)))
    actors = _start_workers(ray, n, preset, worker_gpus, restarts, local)
    ledger = Ledger.of(todo.values())
    cells_total = sum(len(u.cells) for u in todo.values())
    on = f"sweep on {n} worker{'s' if n > 1 else ''}"
    bar = progress(total=round(ledger.projected(), 1), desc=on, unit="worker-s", smoothing=0)
    earlier = f", {reused} reused from an earlier run" if reused else ""
    bar.set_postfix_str(f"cells 0/{cells_total}{earlier}")
    smoothed, tally = SmoothedTotal(), _Tally(n)
    idle, last_algo, running, running_algos = list(range(n)), [None] * n, {}, Counter()
    try:
        while todo or running:
            for i in list(idle):
                ready = [u for u in todo.values() if all(d in done for d in u.deps)]
                unit = pick(ready, last_algo[i], running_algos, ledger.remaining)
                if unit is None:
                    break
                del todo[unit.key]
                running[_submit(sweep, out, actors[i], unit)] = (i, unit, time.monotonic())
                idle.remove(i)
                last_algo[i] = unit.algo
                running_algos[unit.algo] += 1
            bar.set_description(f"{on}: " + ", ".join(u.key for _, u, _ in running.values()))
            finished, _ = ray.wait(list(running), num_returns=1, timeout=PROGRESS_EVERY_S)
            if finished:
                i, unit, _ = running.pop(finished[0])
                result = _returned(ray, finished[0], unit, out)
                store_files(out, result.files)
                done.add(unit.key)
                idle.append(i)
                running_algos[unit.algo] -= 1
                ledger.finished(unit, result.seconds)
                tally.add(i, unit, result)
                bar.set_postfix_str(f"cells {tally.cells}/{cells_total}{earlier}")
            ledger.show(bar, smoothed, running)
    finally:
        bar.close()
    ray.get([a.close.remote() for a in actors])
    bar.write("cells computed per node: " + ", ".join(f"{k}: {v}" for k, v in tally.where.items()))
    return tally.computed, tally.workers()


class _Tally:
    """What the workers did: seconds busy and algorithms run per worker, cells per node, cells
    computed."""

    def __init__(self, n: int):
        self.busy, self.algos = [0.0] * n, [set() for _ in range(n)]
        self.where, self.computed, self.cells = Counter(), 0, 0

    def add(self, worker: int, unit: Unit, result: Computed) -> None:
        """Book ``unit``, which ``worker`` returned as ``result``."""
        self.busy[worker] += result.seconds
        self.algos[worker].add(unit.algo)
        self.where[f"{result.hostname} (node {result.node_id[:8]})"] += len(unit.cells)
        self.computed += result.computed
        self.cells += len(unit.cells)

    def workers(self) -> list:
        """A record per worker: the algorithms it ran and its seconds computing."""
        return [
            dict(algos=sorted(a), timing={"computing": b}) for a, b in zip(self.algos, self.busy)
        ]
