"""Process-tree helpers of the tests that start and kill real processes (Linux /proc)."""

from pathlib import Path


def descendants(pids) -> set:
    """PIDs of the live processes descending from any of ``pids``."""
    children = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(stat.parent.name))
    found, stack = set(), list(pids)
    while stack:
        for child in children.get(stack.pop(), []):
            found.add(child)
            stack.append(child)
    return found


def stop_groups(procs, grace_s: float = 5.0) -> None:
    """Stop processes started with their own process group (``start_new_session``): SIGTERM to each
    group, SIGKILL after ``grace_s``, then any descendant that left the groups."""
    import os
    import signal
    import subprocess

    spawned = descendants([p.pid for p in procs])
    for p in reversed(procs):
        os.killpg(p.pid, signal.SIGTERM)
    for p in reversed(procs):
        try:
            p.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=20)
    for pid in spawned:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def default_sigint() -> None:
    """A ``preexec_fn``: SIGINT at its default disposition and unblocked in the child, as a shell
    starts a program, whatever this test process holds (an ignored or blocked SIGINT survives
    exec)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])
