"""benchmarks.speed.bench_transport: its rows, the medians it reports and its table (no IOC)."""

import pytest

pytest.importorskip("ophyd")

from benchmarks.speed import bench_transport  # noqa: E402


def run(cpu: float, load: float) -> dict:
    figures = {key: cpu * (i + 1) for i, (key, _) in enumerate(bench_transport.FIGURES)}
    return {**figures, "load_before": load, "load_after": load + 1.0}


def test_medians_are_each_figures_median_and_the_load_its_range():
    m = bench_transport.medians([run(1.0, 2.0), run(3.0, 5.0), run(2.0, 4.0)])
    assert m["cpu_ms_per_step"] == 2.0 and m["latency_ms_p50"] == 4.0
    assert (m["load_min"], m["load_max"], m["runs"]) == (2.0, 6.0, 3)


def test_the_table_has_a_row_per_transport_and_checkout(tmp_path):
    table = bench_transport.render({"pyepics": [run(1.5, 1.0)], "today": [run(2.5, 3.0)]})
    lines = table.splitlines()
    assert lines[0].startswith("row | CPU ms/step") and len(lines) == 4
    assert lines[2].startswith("pyepics | 1.50 |") and lines[3].endswith("| 3.0-4.0")


def test_a_tree_row_needs_a_name_and_an_existing_folder(tmp_path):
    args = bench_transport.parser().parse_args(
        ["--out", str(tmp_path), "--transports", "caproto", "--tree", f"old={tmp_path}"]
    )
    assert [(name, transport) for name, _, transport in bench_transport.rows(args)] == [
        ("caproto", "caproto"),
        ("old", None),
    ]
    args.tree = [f"old={tmp_path / 'missing'}"]
    with pytest.raises(SystemExit, match="--tree"):
        bench_transport.rows(args)
