"""The quick preset's reports say its budgets are too small to learn; the summary lists every
report."""

from benchmarks.sweep import presets
from benchmarks.sweep import report


def test_the_quick_presets_tables_say_its_budgets_cannot_learn():
    quick, default = presets.preset("quick"), presets.preset("default")
    note = report.quick_note(quick)
    assert note[0].startswith(
        "**Quick preset: its training budgets (env steps: PPO 32,768, SAC 3,000"
    )
    assert "far too small to learn" in note[0] and "SPGD" not in note[0]
    assert report.quick_note(default) == []


def test_the_summary_lists_the_budget_sections_report_in_its_folder(tmp_path):
    (tmp_path / "budget").mkdir()
    (tmp_path / "budget" / "budget.md").write_text("# budget\n")
    (tmp_path / "table1.md").write_text("# t\n")
    (tmp_path / "cells").mkdir()
    (tmp_path / "cells" / "x.json").write_text("{}")
    report.summary(tmp_path, presets.preset("quick"), ["budget"], {"budget": 1.0}, (1, 0))
    text = (tmp_path / "summary.md").read_text()
    assert "- [budget/budget.md](budget/budget.md)" in text and "- [table1.md](table1.md)" in text
    assert "x.json" not in text
