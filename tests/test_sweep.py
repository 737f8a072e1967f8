"""The sweep: Welch bolding against scipy, the resumable cell store, --quick end to end, resume
after SIGKILL."""

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import ttest_ind

from benchmarks import sweep
from benchmarks.cells import CellStore
from benchmarks.sweep_report import bold_mask, convergence_step

REPO = Path(__file__).resolve().parents[1]


def test_bold_rule_matches_welch():
    samples = {
        "a": [0.90, 0.92, 0.91, 0.93, 0.89],
        "b": [0.88, 0.93, 0.90, 0.94, 0.86],  # not significantly below a
        "c": [0.50, 0.52, 0.49, 0.51, 0.50],  # clearly below
    }
    mask = bold_mask(samples)
    assert mask == {"a": True, "b": ttest_ind(samples["a"], samples["b"], equal_var=False).pvalue >= 0.05, "c": False}
    assert mask["b"] is True
    # Equal constant samples: not different; different constants: different.
    assert bold_mask({"x": [1.0, 1.0], "y": [1.0, 1.0], "z": [0.5, 0.5]}) == {"x": True, "y": True, "z": False}


def test_convergence_step():
    steps = np.arange(10) * 100
    values = [0.1, 0.3, 0.6, 0.8, 0.9, 0.95, 0.94, 0.95, 0.96, 0.95]
    assert convergence_step(steps, values) == 500


def test_cell_store_resumes_and_detects_corruption(tmp_path):
    logs = []
    store = CellStore(tmp_path, logs.append)
    calls = []
    compute = lambda: calls.append(1) or {"value": len(calls)}
    assert store.get("a", {"x": 1}, compute) == {"value": 1}
    assert store.get("a", {"x": 1}, compute) == {"value": 1} and len(calls) == 1
    assert store.get("a", {"x": 2}, compute) == {"value": 2}  # another configuration: another cell
    path = store.path("a", {"x": 1})
    path.write_text(path.read_text()[:10])  # truncated
    assert store.get("a", {"x": 1}, compute) == {"value": 3}
    assert any("unreadable" in m for m in logs)
    assert not list(tmp_path.glob("*.tmp"))


def test_partition_balances_algorithms_over_workers():
    algos = sweep.PRESETS["default"]["algos"]
    for jobs in (1, 2, 3, 7):
        parts = sweep.partition(algos, jobs)
        assert len(parts) == min(jobs, len(algos)) and all(parts)
        assert sorted(a for part in parts for a in part) == sorted(algos)  # each algorithm in exactly one part
        load = [sum(sweep.ALGO_COST[a] for a in part) for part in parts]
        assert max(load) - min(load) <= max(sweep.ALGO_COST.values())
    assert sweep.partition(["spgd"], 2) == [["spgd"]]


def _run_sweep(args, env_extra=None, **kw):
    env = {**os.environ, "PYTHONPATH": str(REPO), **(env_extra or {})}
    return subprocess.Popen([sys.executable, "-m", "benchmarks.sweep", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def _sweep_processes(out):
    """PIDs of live processes whose command line names ``out``."""
    pids = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if str(out).encode() in cmdline.read_bytes():
                pids.append(cmdline.parent.name)
        except OSError:
            pass
    return pids


def test_resume_after_sigkill(tmp_path):
    out = tmp_path / "run"
    args = ["--quick", "--algos", "spgd", "--only", "table1", "--out", str(out)]
    proc = _run_sweep(args)
    deadline = time.time() + 240
    while time.time() < deadline and not list((out / "cells").glob("*.json")):
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    if sys.platform == "linux":  # the worker process dies with its supervisor (an orphan would run on for seconds)
        deadline = time.time() + 2
        while time.time() < deadline and _sweep_processes(out):
            time.sleep(0.2)
        assert not _sweep_processes(out)
    first = sorted((out / "cells").glob("*.json"))
    assert first, "no cell finished before the deadline"
    stamp = {p.name: p.stat().st_mtime_ns for p in first}
    stdout, stderr = _run_sweep(args).communicate(timeout=400)
    assert "reused" in stdout, stderr[-2000:]
    for p in first:
        assert p.stat().st_mtime_ns == stamp[p.name], f"{p.name} was recomputed"
    reused = int(stdout.split(" reused")[0].rsplit(", ", 1)[1])
    assert reused >= len(first)
    assert (out / "table1.md").exists()
    # A checkpoint that no longer loads (here: corrupted) is reported and its cell trained again.
    cell = first[0]
    blob = out / json.loads(cell.read_text())["result"]["checkpoint"] / "params.msgpack"
    blob.write_bytes(blob.read_bytes()[:-3] + b"xyz")
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")}
    stdout, stderr = _run_sweep(args).communicate(timeout=400)
    assert "unusable" in stderr, stderr[-2000:]
    assert cell.stat().st_mtime_ns != stamps[cell.name]
    assert all(p.stat().st_mtime_ns == t for p, t in ((out / "cells" / n, t) for n, t in stamps.items())
               if p.name != cell.name)


def test_quick_sweep_end_to_end(tmp_path):
    out = tmp_path / "quick"
    proc = _run_sweep(["--quick", "--jobs", "2", "--out", str(out)])
    stdout, stderr = proc.communicate(timeout=900)
    assert proc.returncode == 0, stderr[-3000:]
    # Two workers computed every cell once; the report pass only loaded them.
    preset = sweep.build_preset(argparse.Namespace(quick=True, seeds=None, algos=None))
    total = sweep.Sweep(preset, tmp_path / "count", print).count(sweep.SECTIONS)
    assert f"({total} cells computed, 0 reused)" in stdout, stdout[-2000:]
    summary = (out / "summary.md").read_text()
    assert "worker 1 (" in summary and "worker 2 (" in summary and "whole command:" in summary
    for name in ["table1.md", "table1.csv", "table2.md", "stages.md", "transfer.md", "feedback.md", "summary.md",
                 "training_curves.png", "testing_curves.png", "stages.png", "transfer.png", "feedback.png"]:
        assert (out / name).stat().st_size > 0, name
    rows = list(__import__("csv").DictReader(open(out / "table1.csv")))
    assert {r["algo"] for r in rows} == {"spgd", "physics", "ppo", "sac", "td3"}
    assert {r["mode"] for r in rows} == {"easy", "medium", "hard"}
    assert all(0.0 <= float(r["mean"]) <= 1.0 for r in rows)
    td3_cells = 0
    for cell in (out / "cells").glob("*.json"):
        data = json.loads(cell.read_text())["result"]
        finals = data.get("final") or data["test_env"]["final"]
        assert all(0.0 <= v <= 1.0 for v in finals)
        if cell.name.startswith("table1-") and "-td3-" in cell.name:  # both seeds of a cell in one vmapped call
            td3_cells += 1
            assert data["wall_time"]["seeds_in_call"] == 2, cell.name
    assert td3_cells == 6
    if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):  # --quick compiles at -O0
        assert sweep.QUICK_XLA_FLAG in summary


def test_worker_crash_is_resumed(tmp_path):
    """The command runs the sweep in a worker and resumes it after a crash signal (here injected:
    SIGSEGV after the second computed cell)."""
    out = tmp_path / "run"
    args = ["--quick", "--algos", "spgd", "--only", "table1", "--out", str(out)]
    proc = _run_sweep(args, env_extra={"OPS_SWEEP_CRASH_AFTER": "2"})
    stdout, stderr = proc.communicate(timeout=400)
    assert proc.returncode == 0, stderr[-2000:]
    assert "died with SIGSEGV" in stderr and "restart 1 of 2" in stderr
    assert "Fatal Python error: Segmentation fault" in stderr  # the worker runs with faulthandler
    reused = int(stdout.split(" reused")[0].rsplit(", ", 1)[1])
    assert reused == 2 and len(list((out / "cells").glob("*.json"))) == 6  # 3 modes x 2 seeds
    assert (out / "table1.md").exists()
