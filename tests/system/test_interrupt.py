"""Ctrl-C on the training command (TD3: its checkpoint written), the throughput benchmark and the
GIF command, in real subprocesses under a watchdog: one line saying what was kept, exit status 130,
no traceback."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import agents
from processes import default_sigint

REPO = Path(__file__).resolve().parents[2]
WATCHDOG_S = 150


def _interrupt_after(args, ready: str, cwd: Path) -> subprocess.CompletedProcess:
    """Run ``python ARGS``, send SIGINT once ``ready`` appears in its output, and wait (killed at
    the watchdog)."""
    env = {
        **os.environ,
        "PYTHONPATH": str(REPO),
        "PYTHONUNBUFFERED": "1",
        "OPS_JAX_PROGRESS_INTERVAL": "1",
    }
    log = cwd / "output.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(
            [sys.executable, *args],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
            cwd=cwd,
            start_new_session=True,
            preexec_fn=default_sigint,
        )
    deadline = time.monotonic() + WATCHDOG_S
    try:
        while ready not in log.read_text():
            assert proc.poll() is None, (
                f"exited {proc.returncode} before {ready!r}:\n{log.read_text()[-2000:]}"
            )
            assert time.monotonic() < deadline, (
                f"no {ready!r} within {WATCHDOG_S} s:\n{log.read_text()[-2000:]}"
            )
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return subprocess.CompletedProcess(args, proc.returncode, log.read_text(), "")


def _last_line(out: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in out.stdout, out.stdout[-3000:]
    return out.stdout.strip().splitlines()[-1]


def test_ctrl_c_during_training_exits_130_with_one_line(tmp_path):
    args = ["-m", "agents", "--algo", "td3", "--stages", "2", "--steps", "1000000", "--out", "run"]
    out = _interrupt_after(args, "step/s", tmp_path)
    line = _last_line(out)
    assert out.returncode == 130, out.stdout[-2000:]
    assert line.startswith("interrupted: stopped at step ") and "of 1,000,000" in line, line
    step = int(
        line.split()[4].replace(",", "")
    )  # TD3 ends its chunk and writes its checkpoint there
    assert f"the run up to step {step:,} is in run/checkpoint (agents.load reads it)" in line, line
    assert line.endswith("continue it with: python -m agents " + " ".join(args[2:]) + " --resume")
    assert agents.load(tmp_path / "run" / "checkpoint").env_steps == step


def test_ctrl_c_during_throughput_keeps_the_measured_rows(tmp_path):
    args = [
        "-m",
        "benchmarks.speed.throughput",
        "--stages",
        "2",
        "3",
        "--batch",
        "4",
        "--models",
        "phasor",
        "--repeats",
        "1",
        "--out",
        "t.json",
    ]
    out = _interrupt_after(args, "phasor   2      4", tmp_path)  # the first measured row
    line = _last_line(out)
    assert out.returncode == 130, out.stdout[-2000:]
    assert line.startswith("interrupted: ") and "kept in t.json" in line, line
    kept = json.loads((tmp_path / "t.json").read_text())
    assert kept["meta"]["interrupted"] is True and len(kept["rows"]) >= 2
    assert int(line.split()[1]) == len(kept["rows"]) // 2


def test_ctrl_c_while_a_gif_is_drawn_writes_nothing(tmp_path):
    out = _interrupt_after(
        [
            "-m",
            "agents.episode",
            "episode",
            "--stages",
            "2",
            "--policy",
            "zero",
            "--steps",
            "2000",
            "--out",
            "e.gif",
        ],
        "frames:",
        tmp_path,
    )
    assert out.returncode == 130 and _last_line(out) == "interrupted: nothing written", out.stdout[
        -2000:
    ]
    assert not (tmp_path / "e.gif").exists()


CTRL_C_IN_A_GC_CALLBACK = """
import gc, signal, sys, time
from ops_jax.cli.progress import keep_ctrl_c
if sys.argv[1] == "keep":
    keep_ctrl_c()
fired = []
def callback(phase, info):  # as JAX's: Python code that runs inside every collection
    if not fired:
        fired.append(phase)
        signal.raise_signal(signal.SIGINT)  # the Ctrl-C lands here, where Python can only report it
gc.callbacks.append(callback)
try:
    gc.collect()
    time.sleep(2.0)
    print("ran on")
except KeyboardInterrupt:
    print("stopped")
"""


def test_a_ctrl_c_landing_in_a_gc_callback_still_stops_the_program():
    def run(mode):
        return subprocess.run(
            [sys.executable, "-c", CTRL_C_IN_A_GC_CALLBACK, mode],
            capture_output=True,
            text=True,
            timeout=60,
            env={**os.environ, "PYTHONPATH": str(REPO)},
            preexec_fn=default_sigint,
        )

    plain, kept = run("plain"), run("keep")
    assert (
        plain.stdout.strip() == "ran on" and "KeyboardInterrupt" in plain.stderr
    )  # Python's own behaviour
    assert kept.stdout.strip() == "stopped" and kept.stderr == "", kept.stderr
