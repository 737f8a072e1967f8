"""benchmarks.learning: a run is stored, reused when asked for again with the same settings, and
rerun when its hyperparameters (here: an older default) or episode count differ (a stale result is
never passed off as the new one); a TD3 run stopped by Ctrl-C goes on from its checkpoint when the
command is run again."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from agents import SPGDConfig
from agents.learners.offpolicy import checkpoint
from benchmarks import learning

REPO = Path(__file__).resolve().parents[2]


def test_runs_are_reused_only_for_the_same_request(tmp_path):
    argv = [
        "--algos",
        "spgd",
        "--modes",
        "easy",
        "--seeds",
        "1",
        "--stages",
        "2",
        "--episodes",
        "4",
        "--out",
        str(tmp_path),
        "--no-checkpoints",
    ]
    agg = learning.main(argv)
    assert agg["spgd/easy"]["seeds"] == 1 and 0 < agg["spgd/easy"]["p_pmax_mean"] <= 1
    stored = lambda: json.loads((tmp_path / "learning.json").read_text())["runs"]  # noqa: E731
    first = stored()
    assert [(r["episodes"], r["hyper"]["kp"]) for r in first] == [(4, SPGDConfig.preset().kp)]

    learning.main(argv)
    assert stored() == first  # reused: the stored record, its measured call time included

    stale = json.loads((tmp_path / "learning.json").read_text())
    stale["runs"][0]["hyper"]["kp"] += 1.0  # as if stored before the default gain changed
    (tmp_path / "learning.json").write_text(json.dumps(stale))
    learning.main(argv)
    (rerun,) = stored()
    assert (
        rerun["hyper"] == first[0]["hyper"]
        and rerun["testing_p_pmax"] == first[0]["testing_p_pmax"]
    )
    assert rerun["train_call_s"] != first[0]["train_call_s"]  # trained again

    learning.main(argv[:-5] + ["--episodes", "6", "--out", str(tmp_path), "--no-checkpoints"])
    (run,) = stored()
    assert run["episodes"] == 6 and run["train_call_s"] != rerun["train_call_s"]


def test_a_run_stopped_by_ctrl_c_goes_on_from_its_checkpoint(tmp_path, monkeypatch, capsys):
    """TD3's budget preset, 2,200 env steps: points at 1,000 (the warm-up), 1,600 and 2,200; Ctrl-C
    (a real SIGINT, raised once the checkpoint at 1,600 is written) stops it there, one line; run
    again, it trains the last chunk."""
    argv = ["--algos", "td3", "--modes", "easy", "--seeds", "1", "--stages", "2", "--steps", "2200"]
    argv += [
        "--config",
        "budget",
        "--episodes",
        "2",
        "--checkpoint-every",
        "1",
        "--out",
        str(tmp_path),
    ]
    write = checkpoint.Checkpoints.write

    def write_then_ctrl_c(self, run, *rest):
        write(self, run, *rest)
        if run.step == 1600:
            signal.raise_signal(signal.SIGINT)

    def exit_interrupted(line, status=130):
        raise SystemExit((status, line))

    monkeypatch.setattr(checkpoint.Checkpoints, "write", write_then_ctrl_c)
    monkeypatch.setattr(learning, "exit_interrupted", exit_interrupted)
    with pytest.raises(SystemExit) as stop:
        learning.main(argv)
    status, line = stop.value.code
    folder = tmp_path / "checkpoints" / "td3_easy_s0"
    assert status == 130 and line.startswith(
        "stopped during td3/easy/0; the 0 finished runs are in"
    ), line
    assert f"this run's checkpoint in {folder}; run the same command again" in line, line
    assert json.loads((folder / "training.json").read_text())["step"] == 1600
    assert not (tmp_path / "learning.json").exists()
    capsys.readouterr()
    agg = learning.main(argv)
    assert "td3/easy/0: continuing from its checkpoint at step 1,600" in capsys.readouterr().err
    (run,) = json.loads((tmp_path / "learning.json").read_text())["runs"]
    assert run["train_steps"] == 2200 and run["curve"]["step"] == [1000, 1600, 2200]
    assert agg["td3/easy"]["seeds"] == 1 and not (folder / "training.json").exists()


def test_help_shows_the_whole_description(capsys):
    with pytest.raises(SystemExit) as stop:
        learning.main(["--help"])
    out = capsys.readouterr().out
    assert stop.value.code == 0 and out.startswith("usage: python -m benchmarks.learning")
    assert (
        learning.__doc__.strip().splitlines()[-1].strip() in out
    )  # the description's last line too


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--steps", "-1"], "--steps must be >= 0, got -1"),
        (["--episodes", "0"], "--episodes must be >= 1, got 0"),
    ],
)
def test_a_value_out_of_range_stops_before_any_run(argv, words, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        learning.main([*argv, "--out", str(tmp_path)])
    assert stop.value.code == 2 and words in capsys.readouterr().err
    assert not (tmp_path / "learning.json").exists()


def test_a_failed_run_is_the_commands_failure(tmp_path):
    """A run its trainer refuses (TD3 with fewer steps than its warm-up) is recorded, and the
    command exits 1."""
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "benchmarks.learning",
            "--algos",
            "td3",
            "--modes",
            "easy",
            "--seeds",
            "1",
            "--stages",
            "2",
            "--steps",
            "10",
            "--out",
            str(tmp_path),
            "--no-checkpoints",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert out.returncode == 1 and "1 run(s) failed" in out.stderr, out.stderr[-2000:]
    (run,) = json.loads((tmp_path / "learning.json").read_text())["runs"]
    assert run["status"] == "error" and "learning_starts" in run["error"], run
