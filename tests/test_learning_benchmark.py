"""benchmarks.learning: a run is stored, reused when asked for again with the same settings, and
rerun when its hyperparameters (here: an older default) or episode count differ (a stale result is
never passed off as the new one)."""

import json

from agents import SPGDConfig
from benchmarks import learning


def test_runs_are_reused_only_for_the_same_request(tmp_path, capsys):
    argv = ["--algos", "spgd", "--modes", "easy", "--seeds", "1", "--stages", "2", "--episodes", "4",
            "--out", str(tmp_path), "--no-checkpoints"]
    agg = learning.main(argv)
    assert agg["spgd/easy"]["seeds"] == 1 and 0 < agg["spgd/easy"]["p_pmax_mean"] <= 1
    first = json.loads((tmp_path / "learning.json").read_text())["runs"]
    assert [(r["episodes"], r["hyper"]["kp"]) for r in first] == [(4, SPGDConfig.preset().kp)]
    capsys.readouterr()

    learning.main(argv)
    assert "reusing the stored run" in capsys.readouterr().out
    assert json.loads((tmp_path / "learning.json").read_text())["runs"] == first

    stale = json.loads((tmp_path / "learning.json").read_text())
    stale["runs"][0]["hyper"]["kp"] += 1.0  # as if stored before the default gain changed
    (tmp_path / "learning.json").write_text(json.dumps(stale))
    learning.main(argv)
    out = capsys.readouterr().out
    assert "rerunning" in out and "reusing" not in out
    (rerun,) = json.loads((tmp_path / "learning.json").read_text())["runs"]
    assert rerun["hyper"] == first[0]["hyper"] and rerun["testing_p_pmax"] == first[0]["testing_p_pmax"]

    learning.main(argv[:-5] + ["--episodes", "6", "--out", str(tmp_path), "--no-checkpoints"])
    out = capsys.readouterr().out
    assert "rerunning" in out and "reusing" not in out
    (run,) = json.loads((tmp_path / "learning.json").read_text())["runs"]
    assert run["episodes"] == 6
