"""benchmarks.learning: a run is stored, reused when asked for again with the same settings, and
rerun when asked for with other ones (a stale result is never passed off as the new one)."""

import json

from benchmarks import learning


def test_runs_are_reused_only_for_the_same_request(tmp_path, capsys):
    argv = ["--algos", "spgd", "--modes", "easy", "--seeds", "1", "--stages", "2", "--episodes", "4",
            "--out", str(tmp_path), "--no-checkpoints"]
    agg = learning.main(argv)
    assert agg["spgd/easy"]["seeds"] == 1 and 0 < agg["spgd/easy"]["p_pmax_mean"] <= 1
    first = json.loads((tmp_path / "learning.json").read_text())["runs"]
    assert [r["asked"] for r in first] == [dict(steps=None, config=None, episodes=4)]
    capsys.readouterr()

    learning.main(argv)
    assert "reusing the stored run" in capsys.readouterr().out
    assert json.loads((tmp_path / "learning.json").read_text())["runs"] == first

    learning.main(argv[:-5] + ["--episodes", "6", "--out", str(tmp_path), "--no-checkpoints"])
    out = capsys.readouterr().out
    assert "rerunning" in out and "reusing" not in out
    (run,) = json.loads((tmp_path / "learning.json").read_text())["runs"]
    assert run["asked"]["episodes"] == 6
