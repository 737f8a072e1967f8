"""Training that never loses work, in real subprocesses of ``python -m agents``: TD3 stopped by
SIGINT and DroQ killed by SIGKILL mid-run, after a checkpoint, then resumed, end with the same env
steps, curve, parameters and testing score as the run never stopped (bit for bit); a run stopped
after its training, before its evaluation was written, is evaluated by --resume; a second run into
the same --out is refused and leaves the first run's files byte for byte; --overwrite replaces it.
The refusals of the other algorithms, in process."""

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import agents
from agents import cli
from agents.learners.offpolicy.driver import schedule
from agents.registry import CONFIG_TYPES
from processes import default_sigint

REPO = Path(__file__).resolve().parents[2]
WATCHDOG_S = 300
STEPS, EVERY = (
    2000,
    640,
)  # 30 chunks of 64 env steps after a warm-up of 64; a checkpoint every 10 chunks
TINY = dict(
    num_envs=4,
    hidden=(16, 16),
    batch_size=32,
    learning_starts=64,
    eval_every=64,
    eval_episodes=2,
    buffer_size=2000,
    updates_per_iter=4,
    utd_ratio=None,
)
SMALL = {"td3": TINY, "droq": dict(TINY, critic_hidden=(16, 16))}


def _argv(algo: str, *extra) -> list:
    sets = [f"{k}={v!r}" for k, v in SMALL[algo].items()]
    return [
        "--algo",
        algo,
        "--stages",
        "2",
        "--mode",
        "easy",
        "--steps",
        str(STEPS),
        "--episodes",
        "2",
    ] + [
        "--checkpoint-every",
        str(EVERY),
        "--out",
        "run",
        *extra,
        "--set",
        *sets,
    ]


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO), "PYTHONUNBUFFERED": "1"}


def _run(argv, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "agents", *argv],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=WATCHDOG_S,
        env=_env(),
    )


def _checkpointed_step(out: Path) -> int:
    """The env steps of the training state in ``out/checkpoint`` (0: none yet, or being renamed)."""
    try:
        return json.loads((out / "checkpoint" / "training.json").read_text())["step"]
    except (OSError, ValueError, KeyError):
        return 0


def _stopped_after_a_checkpoint(argv, cwd: Path, sig: int) -> subprocess.CompletedProcess:
    """Run ``python -m agents ARGV``, send ``sig`` once it has written a checkpoint past the
    warm-up, and wait."""
    log = cwd / "output.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "agents", *argv],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=_env(),
            cwd=cwd,
            start_new_session=True,
            preexec_fn=default_sigint,
        )
    deadline = time.monotonic() + WATCHDOG_S
    try:
        while _checkpointed_step(cwd / "run") < EVERY:
            assert proc.poll() is None, f"exited {proc.returncode}:\n{log.read_text()[-2000:]}"
            assert time.monotonic() < deadline, f"no checkpoint in time:\n{log.read_text()[-2000:]}"
            time.sleep(0.02)
        proc.send_signal(sig)
        proc.wait(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return subprocess.CompletedProcess(argv, proc.returncode, log.read_text(), "")


def _files(out: Path) -> dict:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def _refused(argv, cwd: Path, words: str) -> None:
    """``argv`` into the run in ``cwd/run``: exit 2, one line naming ``words``, the run's files byte
    for byte."""
    before = _files(cwd / "run")
    out = _run(argv, cwd)
    assert out.returncode == 2 and out.stdout == "", (out.returncode, out.stdout, out.stderr)
    assert out.stderr.strip().splitlines() == [out.stderr.strip()], out.stderr
    assert words in out.stderr, out.stderr
    assert _files(cwd / "run") == before


def _score(files: dict) -> dict:
    """The testing score of a finished run's ``summary.json``: all of its evaluation but a wall
    time."""
    evaluation = json.loads(files["summary.json"])["evaluation"]
    return {k: v for k, v in evaluation.items() if k != "inference_s_per_step"}


def _the_same_as_never_stopped(argv, cwd: Path) -> None:
    """The finished run in ``cwd/run`` is refused a second time, then ``--overwrite`` trains it
    again from the start without a stop: the same steps, curve, parameters and testing score, bit
    for bit."""
    _refused(argv, cwd, "give --resume to continue it or --overwrite to replace it")
    resumed = _files(cwd / "run")
    again = _run([*argv, "--overwrite"], cwd)
    assert again.returncode == 0, again.stderr[-3000:]
    never_stopped = _files(cwd / "run")
    summary = [json.loads(files["summary.json"]) for files in (resumed, never_stopped)]
    h = CONFIG_TYPES[summary[0]["algo"]].make(None, total_steps=STEPS, **SMALL[summary[0]["algo"]])
    warm, n_chunks, chunk = schedule(h)
    assert summary[0]["train_steps"] == summary[1]["train_steps"] == (warm + n_chunks * chunk) * 4
    assert _score(resumed) == _score(never_stopped)
    for name in ("checkpoint/params.msgpack", "curve.csv"):
        assert resumed[name] == never_stopped[name], name
    assert sorted(resumed) == sorted(
        never_stopped
    )  # the finished checkpoints hold no training state


def test_td3_stopped_by_ctrl_c_resumes_to_the_same_result(tmp_path, this_build):
    argv = _argv("td3")
    stopped = _stopped_after_a_checkpoint(argv, tmp_path, signal.SIGINT)
    last = stopped.stdout.strip().splitlines()[-1]
    assert stopped.returncode == 130 and "Traceback" not in stopped.stdout, stopped.stdout[-3000:]
    assert last.startswith("interrupted: stopped at step ") and f"of {STEPS:,}" in last, last
    step = int(last.split()[4].replace(",", ""))
    assert EVERY <= step < STEPS and f"the run up to step {step:,} is in run/checkpoint" in last, (
        last
    )
    kept = agents.load(tmp_path / "run" / "checkpoint")  # the policy trained so far
    assert kept.algo == "td3" and kept.env_steps == step
    _refused(argv, tmp_path, "give --resume to continue it or --overwrite to replace it")
    _refused(["--seed", "1", *argv, "--resume"], tmp_path, "seeds (stored [0], now [1])")
    command = shlex.split(last.split("continue it with: ", 1)[1])
    assert command[:3] == ["python", "-m", "agents"] and command[-1] == "--resume", command
    resumed = _run(command[3:], tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    finished = _files(tmp_path / "run")
    for name in ("summary.json", "curve.csv", "curve.png"):  # as if killed while it evaluated
        (tmp_path / "run" / name).unlink()
    evaluated = _run([*argv, "--resume"], tmp_path)  # the trained policy's evaluation, no training
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    again = _files(tmp_path / "run")
    assert _score(again) == _score(finished) and again["curve.csv"] == finished["curve.csv"]
    assert again["checkpoint/params.msgpack"] == finished["checkpoint/params.msgpack"]
    _the_same_as_never_stopped(argv, tmp_path)


def test_droq_killed_mid_run_resumes_to_the_same_result(tmp_path, this_build):
    argv = _argv("droq")
    killed = _stopped_after_a_checkpoint(argv, tmp_path, signal.SIGKILL)
    assert killed.returncode == -signal.SIGKILL, killed.stdout[-3000:]
    assert not (tmp_path / "run" / "summary.json").exists()  # killed while training
    resumed = _run([*argv, "--resume"], tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    _the_same_as_never_stopped(argv, tmp_path)


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--algo", "ppo", "--resume"], "--resume: ppo does not checkpoint while it trains"),
        (
            ["--algo", "sac", "--checkpoint-every", "5"],
            "--checkpoint-every: sac does not checkpoint",
        ),
        (["--algo", "spgd", "--resume", "--overwrite"], "give --resume (continue the run"),
        (["--algo", "td3", "--resume"], "--resume: no run in"),
        (
            ["--algo", "ppo"],
            "holds a run (summary.json): give --resume to continue it or --overwrite",
        ),
    ],
)
def test_refusals_are_one_line_before_any_work(argv, words, tmp_path, capsys):
    out = tmp_path / "run"
    if "--resume" not in argv:  # a finished run of another algorithm's
        out.mkdir()
        (out / "summary.json").write_text("{}")
    else:
        out = tmp_path / "none"
    with pytest.raises(SystemExit) as stop:
        cli.main([*argv, "--out", str(out)])
    captured = capsys.readouterr()
    assert stop.value.code == 2 and captured.out == "", captured
    assert captured.err.startswith("python -m agents: error: ") and words in captured.err, (
        captured.err
    )
    assert len(captured.err.strip().splitlines()) == 1
    assert not (tmp_path / "none").exists()
    assert not out.exists() or (out / "summary.json").read_text() == "{}"
