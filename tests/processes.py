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
