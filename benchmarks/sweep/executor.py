"""The sweep's work units on Ray actors (a local Ray instance or a cluster); this process stores the cells.

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
GPU_MEMORY_SHARED = (
    0.9  # the fraction of a GPU's memory that the workers sharing it divide between them
)
PROGRESS_EVERY_S = 5.0  # how often the progress line takes the running units' time into account
OBJECT_STORE_BYTES = (
    200 * 2**20
)  # a local instance's object store: units return kilobytes to megabytes


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Computed:
    """What a worker returns for a unit: the ``files`` it wrote ({path relative to the output folder: bytes}), the
    number of cells it ``computed`` (not found stored), its wall ``seconds`` and where it ran (Ray ``node_id``,
    ``hostname``)."""

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
        faulthandler.enable()  # a crash prints the Python stack into the worker's log (shown by the driver)
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
        """Compute ``unit`` (an eval unit gets its controller's training ``record`` and ``checkpoint``
        files, {relative path: bytes})."""
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
    """Run every thread of this process, and the threads it starts later, on ``cpus`` only; called before
    JAX starts its CPU client, which then sizes its thread pool to them."""
    runtime.set_cores(cpus)


def cpu_shares(n: int) -> list:
    """``n`` disjoint, near-equal sets of this process's CPUs, one per local worker; ``[None] * n`` (no
    pinning) when there are fewer CPUs than workers or no affinity interface. Two workers on two cores
    each with a two-thread pool share every core; one core each trained 20-25% faster, compilation excluded
    (docs/sweep.md)."""
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


def _kind(unit: Unit) -> str:
    """What a unit's cost is measured per: training per algorithm (its budget is the preset's), evaluation,
    or a section's own cells."""
    return {"train": f"train {unit.algo}", "eval": "eval"}.get(unit.kind, f"cell {unit.algo}")


def projected_seconds(est_left: Counter, est_done: Counter, spent: Counter) -> float:
    """Worker-seconds of the work left: each kind's estimate (``est_left``) scaled by that kind's measured
    seconds (``spent``) per estimated second of its finished units (``est_done``), or by all kinds' ratio
    for a kind not seen finish yet (1 before any)."""
    return sum(left * cost_ratio(k, est_done, spent) for k, left in est_left.items())


def cost_ratio(kind: str, est_done: Counter, spent: Counter) -> float:
    """Measured seconds per estimated second of ``kind``'s finished units (all kinds' if none, 1 before any)."""
    if est_done[kind]:
        return spent[kind] / est_done[kind]
    return sum(spent.values()) / sum(est_done.values()) if sum(est_done.values()) else 1.0


class SmoothedTotal:
    """The progress line's total worker-seconds: each new projection moves it by ``weight`` of the way
    (an exponential moving average, so the remaining time does not jump with each finished unit's
    correction; exactly the projection when nothing is left), and it is cut where needed so that the
    fraction done never decreases."""

    def __init__(self, weight: float = 0.3):
        self.weight = weight
        self.total = None
        self.fraction = 0.0

    def __call__(self, done: float, projected: float) -> float:
        """The total to show for ``done`` worker-seconds out of a ``projected`` total."""
        if (
            self.total is None or projected <= done
        ):  # the first projection, or nothing left: as projected
            total = projected
        else:
            total = self.total + self.weight * (projected - self.total)
        total = max(total, done)
        if total > 0 and done / total < self.fraction:
            total = done / self.fraction
        self.total, self.fraction = total, (done / total if total > 0 else 0.0)
        return total


def _show(bar, smoothed: SmoothedTotal, spent: Counter, in_flight: float, left: float) -> None:
    """Progress in worker-seconds: finished units' measured seconds plus the running units' time so
    far, out of that plus the projected work left beyond what is running (``SmoothedTotal``)."""
    done = sum(spent.values()) + in_flight
    bar.total = round(smoothed(done, done + max(left - in_flight, 0.0)), 1)
    bar.update(round(done - bar.n, 1))


def pick(ready: list, last_algo, running_algos: Counter, remaining: dict):
    """The unit an idle worker takes from ``ready`` (in plan order): one of the algorithm it ran last
    (warm programs), else of the algorithm with the most remaining cost that no other worker runs,
    else of the one with the most remaining cost."""
    if not ready:
        return None
    same = [u for u in ready if u.algo == last_algo]
    if same:
        return same[0]
    free = [u for u in ready if not running_algos[u.algo]] or ready
    return max(free, key=lambda u: remaining[u.algo])  # max keeps the first of equals: plan order


def connect(address: str | None, jobs: int | None):
    """``ray.init``: the cluster at ``address`` (the project's packages shipped to its workers), or a
    local instance with ``jobs`` CPUs."""
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
        # Ray starts workers at nice 15 (for the raylet's sake): on a machine running other work they
        # would get a small share of the CPU (measured: a several-fold slower sweep).
        os.environ.setdefault("RAY_worker_niceness", "0")
        # logging_level: no start-up lines of Ray's own (a local instance's token notice, "Started ...").
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
    """Compute the cells of ``sections`` not stored in ``out`` on Ray workers (``jobs``, default one per
    CPU of the cluster), then write the reports. Returns (cells computed, cells reused)."""
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
    """The variables set in each of ``n`` workers before jax starts: this process's ``FORWARDED_ENV``, and
    for workers sharing a GPU (a local instance with ``worker_gpus`` 0, or a fraction of a GPU each) no
    preallocation and each a cap on its share of the GPU's memory (``XLA_PYTHON_CLIENT_MEM_FRACTION``);
    values set in this process win."""
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
    """Start ``unit`` on the worker ``actor``; an eval unit takes its controller's training record and checkpoint
    files along. Returns the task's reference."""
    record = checkpoint = None
    if isinstance(unit, EvalUnit):
        record = sweep.store.load(unit.train.label, unit.train.config)
        checkpoint = checkpoint_files(out, record)
    return actor.run.remote(unit, record, checkpoint)


def _returned(ray, ref, unit: Unit, out: Path) -> Computed:
    """What the task ``ref`` of ``unit`` returned; SystemExit saying how to resume where it failed."""
    try:
        return ray.get(ref)
    except (ray.exceptions.RayError, OSError) as exc:
        raise SystemExit(
            f"unit {unit.key} failed ({type(exc).__name__}: {exc}); the finished cells are "
            f"stored in {out}/cells (re-run the command to resume)"
        ) from exc


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
    """The scheduling loop: units to idle workers, returned files into the store (``reused``: the plan's
    cells stored before, said on the progress line; ``local``: a local instance, whose workers get a share
    of the CPUs each). Returns (cells computed, a record per worker)."""
    n = max(1, min(jobs or int(ray.cluster_resources().get("CPU", 1)), len(todo)))
    env = worker_env(n, worker_gpus, local)
    actor = ray.remote(
        num_cpus=1, num_gpus=worker_gpus, max_restarts=restarts, max_task_retries=restarts
    )(SweepWorker)
    shares = cpu_shares(n) if local else [None] * n
    actors = [actor.remote(preset, env, cpus) for cpus in shares]
    remaining, est_left, est_done, spent = Counter(), Counter(), Counter(), Counter()
    for u in todo.values():
        remaining[u.algo] += u.cost
        est_left[_kind(u)] += u.cost
    cells_total, cells_done = sum(len(u.cells) for u in todo.values()), 0
    on = f"sweep on {n} worker{'s' if n > 1 else ''}"
    bar = progress(
        total=round(projected_seconds(est_left, est_done, spent), 1),
        desc=on,
        unit="worker-s",
        smoothing=0,
    )
    cells = lambda k: (
        f"cells {k}/{cells_total}" + (f", {reused} reused from an earlier run" if reused else "")
    )
    smoothed = SmoothedTotal()
    bar.set_postfix_str(cells(0))
    idle, last_algo, running, running_algos = list(range(n)), [None] * n, {}, Counter()
    busy, algos, where, computed = [0.0] * n, [set() for _ in range(n)], Counter(), 0
    try:
        while todo or running:
            for i in list(idle):
                ready = [u for u in todo.values() if all(d in done for d in u.deps)]
                unit = pick(ready, last_algo[i], running_algos, remaining)
                if unit is None:
                    break
                del todo[unit.key]
                running[_submit(sweep, out, actors[i], unit)] = (i, unit, time.monotonic())
                idle.remove(i)
                last_algo[i] = unit.algo
                running_algos[unit.algo] += 1
            bar.set_description(f"{on}: " + ", ".join(u.key for _, u, _ in running.values()))
            finished, _ = ray.wait(list(running), num_returns=1, timeout=PROGRESS_EVERY_S)
            # Work in flight counts as done for as long as it has run, up to 90% of its projected cost (a
            # unit running over its estimate holds the line back instead of showing nothing left): the rate
            # is then the number of busy workers from the start, not only what finished units show.
            in_flight = sum(
                min(time.monotonic() - t, 0.9 * u.cost * cost_ratio(_kind(u), est_done, spent))
                for _, u, t in running.values()
            )
            if not finished:
                _show(bar, smoothed, spent, in_flight, projected_seconds(est_left, est_done, spent))
                continue
            ref = finished[0]
            i, unit, t = running.pop(ref)
            in_flight -= min(
                time.monotonic() - t, 0.9 * unit.cost * cost_ratio(_kind(unit), est_done, spent)
            )
            result = _returned(ray, ref, unit, out)
            store_files(out, result.files)
            done.add(unit.key)
            idle.append(i)
            running_algos[unit.algo] -= 1
            remaining[unit.algo] -= unit.cost
            est_left[_kind(unit)] -= unit.cost
            est_done[_kind(unit)] += unit.cost
            spent[_kind(unit)] += result.seconds
            busy[i] += result.seconds
            algos[i].add(unit.algo)
            where[f"{result.hostname} (node {result.node_id[:8]})"] += len(unit.cells)
            computed += result.computed
            cells_done += len(unit.cells)
            bar.set_postfix_str(cells(cells_done))
            _show(bar, smoothed, spent, in_flight, projected_seconds(est_left, est_done, spent))
    finally:
        bar.close()
    ray.get([a.close.remote() for a in actors])
    bar.write("cells computed per node: " + ", ".join(f"{k}: {v}" for k, v in where.items()))
    return computed, [dict(algos=sorted(algos[i]), timing={"computing": busy[i]}) for i in range(n)]
