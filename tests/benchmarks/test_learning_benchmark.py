"""benchmarks.learning: a run is stored, reused when asked for again with the same settings, and
rerun when its hyperparameters (here: an older default) or episode count differ (a stale result is
never passed off as the new one)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from agents import SPGDConfig
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
    """A run its trainer refuses (TD3 with fewer steps than its warm-up) is recorded, and the command exits 1."""
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
