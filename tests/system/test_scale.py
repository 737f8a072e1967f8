"""docs/scale.md's test-cluster recipe, run as written on the Ray that the agents extra installs:
the token exported, a head and a second node started with real ``ray start`` on 127.0.0.1,
``ray status``, a small sweep on that cluster. Each ``ray start`` gets ``--block`` and its own
process group, which the test kills (``ray stop`` would stop every Ray process of this user on the
machine, other jobs' included)."""

import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from processes import stop_groups

REPO = Path(__file__).resolve().parents[2]
RECIPE_TITLE = "# test cluster:"
SMALL_SWEEP = ["--only", "table1", "--algos", "spgd"]
WATCHDOG_S = 240


def recipe() -> list:
    """The commands of docs/scale.md's test-cluster block, in order (comments dropped)."""
    blocks = re.findall(
        r"^```bash\n(.*?)^```", (REPO / "docs" / "scale.md").read_text(), re.S | re.M
    )
    block = next(b for b in blocks if b.startswith(RECIPE_TITLE))
    return [line for line in block.splitlines() if line.strip() and not line.startswith("#")]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ray_start(argv, log: Path, env: dict, deadline: float) -> subprocess.Popen:
    proc = subprocess.Popen(
        [*argv, "--block"],
        stdout=open(log, "w"),
        stderr=subprocess.STDOUT,
        env=env,
        start_new_session=True,
    )
    while "Ray runtime started" not in log.read_text():
        assert proc.poll() is None and time.monotonic() < deadline, (
            f"{shlex.join(argv)}:\n{log.read_text()[-3000:]}"
        )
        time.sleep(0.5)
    return proc


def test_the_recipe_starts_two_nodes_with_a_token_and_runs_the_sweep_on_them():
    assert shutil.which("ray"), 'the ray command is missing: pip install -e ".[agents]"'
    tmp = Path(
        tempfile.mkdtemp(prefix="ojs-", dir="/tmp")
    )  # short: Ray's socket paths have a length limit
    port = str(_free_port())
    env = {
        **os.environ,
        "PYTHONPATH": str(REPO),
        "RAY_USAGE_STATS_ENABLED": "0",
        "RAY_worker_niceness": "0",
    }
    deadline = time.monotonic() + WATCHDOG_S
    procs, ran = [], []
    try:
        for line in recipe():
            line = line.replace("6399", port).replace("/tmp/ray-loopback", str(tmp / "ray"))
            argv = shlex.split(line)
            ran.append(argv[:2])
            if (
                argv[0] == "export"
            ):  # the shell evaluates it; its variables go to the following commands
                out = subprocess.run(
                    ["bash", "-c", f"{line} && env -0"],
                    capture_output=True,
                    text=True,
                    env=env,
                    timeout=60,
                    check=True,
                )
                env = dict(kv.split("=", 1) for kv in out.stdout.split("\0") if "=" in kv)
            elif argv[:2] == ["ray", "start"]:
                procs.append(_ray_start(argv, tmp / f"node{len(procs)}.log", env, deadline))
            elif argv[:2] == [
                "ray",
                "status",
            ]:  # the worker registers within seconds of its `ray start`
                while True:
                    out = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=60)
                    nodes = len(re.findall(r"^\s*1 node_", out.stdout, re.M))
                    if out.returncode != 0 or nodes == 2 or time.monotonic() > deadline:
                        break
                    time.sleep(1.0)
                assert out.returncode == 0 and nodes == 2, out.stdout
            elif argv[0] == "python":
                argv = [sys.executable, *argv[1:-1], str(tmp / "results"), *SMALL_SWEEP]
                out = subprocess.run(
                    argv,
                    capture_output=True,
                    text=True,
                    env=env,
                    cwd=tmp,
                    timeout=max(1.0, deadline - time.monotonic()),
                )
                assert out.returncode == 0, out.stderr[-3000:]
                assert "cells computed per node" in out.stderr + out.stdout
        assert env["RAY_AUTH_MODE"] == "token" and env["RAY_AUTH_TOKEN"]
        assert ran == [
            ["export", "RAY_AUTH_MODE=token"],
            ["ray", "start"],
            ["ray", "start"],
            ["ray", "status"],
            ["python", "-m"],
            ["ray", "stop"],
        ]
    finally:
        stop_groups(procs, grace_s=10.0)
        shutil.rmtree(tmp, ignore_errors=True)
