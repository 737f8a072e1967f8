"""The sweep on a real two-node Ray cluster (two raylets on this machine), one worker killed
mid-run. The sweep is the quick preset's Table 1 (SPGD and TD3) and budget section: Table 1's
batched TD3 seeds, protocol (b) end to end, and reports from cells computed on both nodes."""

import argparse
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from benchmarks.sweep import command as sweep
from benchmarks.sweep.units import Sweep
from processes import descendants, stop_groups

REPO = Path(__file__).resolve().parents[2]
START_TIMEOUT_S = 180
SECTIONS, ALGOS = ["table1", "budget"], ["spgd", "td3"]  # the sweep's sections and algorithms here
# Loopback test cluster: no token; workers at the normal priority (Ray's default nice 15 starves
# them on a busy machine).
CLUSTER_ENV = {
    "RAY_AUTH_MODE": "disabled",
    "RAY_worker_niceness": "0",
    "RAY_USAGE_STATS_ENABLED": "0",
}


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _ray_start(args, log: Path, env: dict) -> subprocess.Popen:
    """``ray start ARGS --block`` in its own process group; returns once it reports the node
    started."""
    proc = subprocess.Popen(
        ["ray", "start", *args, "--num-cpus", "1", "--block", "--disable-usage-stats"],
        stdout=open(log, "w"),
        stderr=subprocess.STDOUT,
        env=env,
        preexec_fn=os.setsid,
    )
    deadline = time.time() + START_TIMEOUT_S
    while "Ray runtime started" not in log.read_text():
        if proc.poll() is not None or time.time() > deadline:
            raise RuntimeError(f"ray start {' '.join(args)} failed:\n{log.read_text()[-3000:]}")
        time.sleep(0.5)
    return proc


@pytest.fixture
def two_node_cluster():
    """A head and a second raylet, 1 CPU each, on 127.0.0.1; yields (address, environment); torn
    down by process group (SIGTERM, then SIGKILL), never by name."""
    assert shutil.which("ray"), 'the ray command is missing: pip install -e ".[agents]"'
    tmp = Path(
        tempfile.mkdtemp(prefix="ojr-", dir="/tmp")
    )  # short: Ray's socket paths have a length limit
    port = _free_port()
    env = {**os.environ, "PYTHONPATH": str(REPO), **CLUSTER_ENV}
    procs = []
    try:
        procs.append(
            _ray_start(
                [
                    "--head",
                    "--port",
                    str(port),
                    "--include-dashboard",
                    "false",
                    "--temp-dir",
                    str(tmp / "ray"),
                ],
                tmp / "head.log",
                env,
            )
        )
        procs.append(_ray_start(["--address", f"127.0.0.1:{port}"], tmp / "node.log", env))
        yield f"127.0.0.1:{port}", env, procs
    finally:
        stop_groups(procs)
        shutil.rmtree(tmp, ignore_errors=True)


def test_quick_sweep_on_two_nodes_survives_a_killed_worker(tmp_path, two_node_cluster):
    address, env, cluster = two_node_cluster
    out = tmp_path / "quick"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "benchmarks.sweep",
            "--quick",
            "--only",
            *SECTIONS,
            "--algos",
            *ALGOS,
            "--ray",
            address,
            "--out",
            str(out),
        ],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        killed = None
        deadline = time.time() + 600
        while killed is None and time.time() < deadline and proc.poll() is None:
            if list(
                (out / "cells").glob("*.json")
            ):  # mid-run: cells stored, workers computing more
                running = [
                    pid
                    for pid in descendants([p.pid for p in cluster])
                    if _cmdline(pid).startswith("ray::SweepWorker.run")
                ]
                if running:
                    killed = running[0]
                    os.kill(killed, signal.SIGKILL)
            time.sleep(0.5)
        stdout, stderr = proc.communicate(timeout=900)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert killed is not None, f"no worker computing a unit was found to kill\n{stderr[-3000:]}"
    assert proc.returncode == 0, stderr[-3000:]
    assert "\x1b[" not in stderr and "\r" not in stderr  # a log file: plain lines, no control codes
    assert stderr.count("sweep on 2 workers") >= 1
    preset = sweep.build_preset(argparse.Namespace(quick=True, seeds=None, algos=ALGOS))
    units = Sweep(preset, tmp_path / "plan", print).units(SECTIONS)
    expected = {c.label for u in units for c in u.cells}
    cells = {}
    for path in (out / "cells").glob("*.json"):
        data = json.loads(path.read_text())
        cells[path.name.rsplit("-", 1)[0]] = data
    assert set(cells) == expected  # every cell, once
    for label, data in cells.items():
        result = data["result"]
        if (
            "scores" in result
        ):  # a budget cell: P / P_best at each checkpoint (P_best may be a fit's, a hair low)
            assert result["scores"] and all(0.0 <= v <= 1.05 for v in result["scores"].values()), (
                label
            )
        else:
            finals = result.get("final") or result["test_env"]["final"]
            assert finals and all(0.0 <= v <= 1.0 for v in finals), label
        if "checkpoint" in result:
            assert (out / result["checkpoint"] / "params.msgpack").stat().st_size > 0, label
        assert data["hostname"] and len(data["node_id"]) >= 16, label
    assert len({data["node_id"] for data in cells.values()}) == 2  # computed on both nodes
    (adapt,) = [
        d for d in cells.values() if d["config"].get("kind") == "adapt"
    ]  # protocol (b), end to end
    result = adapt["result"]
    assert set(result["scores"]) == {"300", "600"} and 0.0 < result["before"] <= 1.0
    assert result["pretrain_steps"] <= adapt["config"]["pretrain_steps"]
    assert set(result["trimmed"]) == {"0", "300", "600"} and all(
        0.0 < v <= 1.0 for v in result["trimmed"].values()
    )
    td3 = [d for label, d in cells.items() if label.startswith("table1-") and "-td3-" in label]
    assert len(td3) == 6 and all(d["result"]["wall_time"]["seeds_in_call"] == 2 for d in td3)
    summary = (out / "summary.md").read_text()
    assert "worker 1 (" in summary and "worker 2 (" in summary and "whole command:" in summary
    for name in [
        "table1.md",
        "table1.csv",
        "training_curves.png",
        "testing_curves.png",
        "performance_profile.png",
        "budget/budget.md",
    ]:
        assert (out / name).stat().st_size > 0, name
    rows = list(csv.DictReader(open(out / "table1.csv")))
    assert {r["algo"] for r in rows} == set(ALGOS)
    assert all(0.0 <= float(r["mean"]) <= 1.0 for r in rows)
