"""The exit statuses of the project's commands (README, "Exit status"), each provoked in a real
subprocess: 0 done, 1 failed, 2 bad arguments, 3 the bench's watchdog (safety) stop, 130 interrupted
(SIGINT)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.lab import Process, ca_env
from processes import default_sigint

REPO = Path(__file__).resolve().parents[2]
START_S = 300  # an IOC's or a runner's start on a loaded 2-core machine (JAX import and compile)
BLOCKER = "import sys\nsys.modules['flax'] = None  # `import flax` raises ModuleNotFoundError\n"


def _env(**extra) -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO), "OPS_JAX_PROGRESS_INTERVAL": "0", **extra}


def _train(args, cwd: Path, env=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "agents", *args],
        capture_output=True,
        text=True,
        timeout=START_S,
        cwd=cwd,
        env=env or _env(),
    )


def reject(constant: str):
    raise ValueError(f"not strict JSON: {constant}")


def test_done_0_failed_1_bad_arguments_2(tmp_path):
    done = _train(["--algo", "spgd", "--stages", "2", "--episodes", "2", "--out", "run"], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    json.loads((tmp_path / "run" / "summary.json").read_text(), parse_constant=reject)

    bad = _train(["--algo", "td3", "--stages", "2", "--steps", "4096", "--out", "bad"], tmp_path)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr

    (tmp_path / "sitecustomize.py").write_text(BLOCKER)  # an install without the agents extra
    blocked = _env(PYTHONPATH=f"{tmp_path}{os.pathsep}{REPO}")
    failed = _train(["--algo", "td3", "--stages", "2", "--out", "failed"], tmp_path, blocked)
    assert failed.returncode == 1 and "the agents extra installs" in failed.stderr, failed.stderr
    assert not (tmp_path / "bad").exists() and not (tmp_path / "failed").exists()


def _ioc(prefix: str, env: dict, log: Path) -> subprocess.Popen:
    """``python -m ops_jax.ioc`` with SIGINT at its default (as a shell starts it), output to
    ``log``."""
    with open(log, "w") as out:
        return subprocess.Popen(
            [
                sys.executable,
                "-m",
                "ops_jax.ioc",
                "--prefix",
                prefix,
                "--stages",
                "2",
                "--rate",
                "100",
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**env, "PYTHONPATH": str(REPO)},
            cwd=REPO,
            start_new_session=True,
            preexec_fn=default_sigint,
        )


def _wait_for(log: Path, needle: str, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + START_S
    while needle not in log.read_text():
        assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.1)


def _interrupted(proc: subprocess.Popen, log: Path) -> list:
    """SIGINT ``proc``; its exit status and last line."""
    proc.send_signal(signal.SIGINT)
    try:
        rc = proc.wait(60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    text = log.read_text()
    assert "Traceback" not in text, text
    return [rc, text.strip().splitlines()[-1]]


def test_the_ioc_interrupted_while_starting_or_serving_exits_130_with_one_line(tmp_path):
    log = tmp_path / "starting.log"
    starting = _ioc("EXA:", ca_env(), log)
    time.sleep(2.0)  # importing JAX or building the simulator: before it serves
    rc, last = _interrupted(starting, log)
    assert rc == 130 and last.startswith("interrupted: ") and "serving" not in log.read_text(), last
    assert len(log.read_text().strip().splitlines()) == 1, log.read_text()

    log = tmp_path / "serving.log"
    serving = _ioc("EXB:", ca_env(), log)
    _wait_for(log, "serving", serving)
    assert _interrupted(serving, log) == [
        130,
        "interrupted: the IOC EXB: stopped; its PVs are gone",
    ]


def test_the_watchdog_stop_exits_3_and_the_bench_writes_strict_json(tmp_path):
    env = ca_env()
    ioc_log = tmp_path / "ioc.log"
    ioc = _ioc("EXW:", env, ioc_log)
    try:
        _wait_for(ioc_log, "serving", ioc)
        args = ["--prefix", "EXW:", "--stages", "2", "--controller", "spgd", "--seconds", "120"]
        runner = Process(
            "agents.bench",
            [*args, "--stale-s", "5", "--out", tmp_path / "out"],
            env,
            tmp_path / "runner.log",
        )
        documents = tmp_path / "out" / "documents.jsonl"
        deadline = time.monotonic() + START_S
        while not (documents.exists() and documents.read_text().count('"name": "event"') >= 10):
            assert runner.proc.poll() is None and time.monotonic() < deadline, runner.text()
            time.sleep(0.1)
    finally:
        os.killpg(ioc.pid, signal.SIGKILL)  # the bench lost: the watchdog stops the run
        ioc.wait(30)
    assert runner.wait(60) == 3, runner.text()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text(), parse_constant=reject)
    assert summary["stopped_by"].startswith("lost connection to PV EXW:"), summary
    parsed = [
        json.loads(line, parse_constant=reject) for line in documents.read_text().splitlines()
    ]
    names = [doc["name"] for doc in parsed]
    assert names[:2] == ["start", "descriptor"] and names[-1] == "stop", names[:3] + names[-3:]
    assert names.count("event") >= 10
