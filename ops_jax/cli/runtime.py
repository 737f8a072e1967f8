"""Which CPU cores this process's threads run on, and how a latency-bound process starts JAX's CPU
backend."""

from __future__ import annotations

import os


def start_single_threaded() -> bool:
    """Start JAX's CPU backend with its thread pools one thread each, the process's threads free to
    run on the cores they could before (Linux; before JAX's first computation: later it changes
    nothing). For a process whose calls are small and each waits for its result (a controller's
    step, the simulated bench's tick): with a pool thread per core such a call spends CPU time in
    the pool's other threads as well. False where the process cannot set its cores (the backend then
    starts as usual)."""
    import jax

    if not hasattr(os, "sched_setaffinity"):
        jax.devices()
        return False
    allowed, before = os.sched_getaffinity(0), threads()
    os.sched_setaffinity(
        0, {min(allowed)}
    )  # XLA sizes its pools by the cores the starting thread may use
    try:
        jax.devices()
    finally:  # this thread and those the backend started
        set_cores(allowed, {0} | (threads() - before))
    return True


def threads() -> set:
    """The ids of this process's threads (Linux)."""
    return {int(tid) for tid in os.listdir("/proc/self/task")}


def set_cores(cores: set, tids: set | None = None) -> None:
    """Let the threads ``tids`` (None: every thread of this process; 0: the calling one) run on CPU
    ``cores`` only (Linux); a thread that has ended meanwhile, or that this process may not move, is
    skipped."""
    for tid in threads() if tids is None else tids:
        try:
            os.sched_setaffinity(tid, cores)
        except (ProcessLookupError, PermissionError):
            pass
