"""Crash injection for the sweep's crash-recovery test (on PYTHONPATH of that test's processes
only): with OPS_SWEEP_CRASH_AFTER=K, a process whose cell store has computed K cells kills itself
with SIGSEGV, once per OPS_SWEEP_CRASH_MARKER file (created first)."""

import importlib.abc
import os
import signal
import sys
from pathlib import Path

AFTER = int(os.environ.get("OPS_SWEEP_CRASH_AFTER", "0"))
MARKER = Path(os.environ.get("OPS_SWEEP_CRASH_MARKER", "/nonexistent"))


def _patch(cells_module) -> None:
    get = cells_module.CellStore.get

    def get_then_crash(self, *args, **kw):
        record = get(self, *args, **kw)
        if self.computed >= AFTER and not MARKER.exists():
            MARKER.touch()
            os.kill(os.getpid(), signal.SIGSEGV)
        return record

    cells_module.CellStore.get = get_then_crash


class _PatchOnImport(importlib.abc.MetaPathFinder):
    """Patches ``benchmarks.cells`` when it is first imported."""

    def find_spec(self, name, path, target=None):
        if name != "benchmarks.cells":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        run = spec.loader.exec_module

        def exec_module(module):
            run(module)
            _patch(module)

        spec.loader.exec_module = exec_module
        return spec


if AFTER > 0 and not MARKER.exists():
    import importlib.util

    sys.meta_path.insert(0, _PatchOnImport())
