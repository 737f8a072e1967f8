"""How a latency-bound process starts JAX's CPU backend."""

from __future__ import annotations

import os


def start_single_threaded() -> bool:
    """Start JAX's CPU backend with its thread pools one thread each, the process's threads free to run on the
    cores they could before (Linux; before JAX's first computation: later it changes nothing). For a process
    whose calls are small and each waits for its result (a controller's step, the simulated bench's tick): with
    a pool thread per core such a call spends CPU time in the pool's other threads as well. False where the
    process cannot set its cores (the backend then starts as usual)."""
    import jax

    if not hasattr(os, "sched_setaffinity"):
        jax.devices()
        return False
    allowed, before = os.sched_getaffinity(0), set(os.listdir("/proc/self/task"))
    os.sched_setaffinity(0, {min(allowed)})  # XLA sizes its pools by the cores the starting thread may use
    try:
        jax.devices()
    finally:  # this thread and those the backend started
        for tid in ["0", *set(os.listdir("/proc/self/task")) - before]:
            try:
                os.sched_setaffinity(int(tid), allowed)
            except ProcessLookupError:  # a thread that has ended meanwhile
                pass
    return True
