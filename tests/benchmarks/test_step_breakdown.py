"""benchmarks.speed.step_breakdown at a tiny batch: every part timed, the JSON written, bad sizes
refused."""

import json

import pytest

from benchmarks.speed import step_breakdown


def test_the_parts_are_timed_and_written(tmp_path):
    out = tmp_path / "b.json"
    rows = step_breakdown.main(["--batch", "8", "--repeats", "1", "--out", str(out)])
    assert [r["batch"] for r in rows] == [8]
    row = rows[0]
    for part in ("step", "physics", "draws"):
        assert row[f"{part}_ns"] > 0
    assert row["physics_share"] == pytest.approx(row["physics_ns"] / row["step_ns"])
    assert json.loads(out.read_text())["rows"] == json.loads(json.dumps(rows))


def test_a_batch_below_one_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        step_breakdown.main(["--batch", "0", "--out", str(tmp_path / "b.json")])
    assert err.value.code == 2
    assert "--batch must be >= 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "b.json").exists()


def test_against_a_commit_times_both_trees_side_by_side(tmp_path):
    out = tmp_path / "b.json"
    argv = ["--against", "HEAD", "--stages", "3", "--batch", "8", "--repeats", "2"]
    rows = step_breakdown.main([*argv, "--out", str(out)])
    assert [(r["stages"], r["batch"], r["against"]) for r in rows] == [(3, 8, "HEAD")]
    row = rows[0]
    for part in ("step", "physics", "draws"):
        for tree in ("this", "other"):
            assert row[f"{part}_{tree}_cpu_ns"] > 0 and row[f"{part}_{tree}_wall_ns"] > 0
        assert row[f"{part}_speedup_cpu"] == pytest.approx(
            row[f"{part}_other_cpu_ns"] / row[f"{part}_this_cpu_ns"]
        )
    assert set(row["compile_s"]) == {"this", "HEAD"}
    assert json.loads(out.read_text())["rows"] == json.loads(json.dumps(rows))
