"""The reports of ``benchmarks.sweep`` (results/<name>/): the shared formatting (bolding, cells, the
aggregate table, figures), table 2, the training and testing curves and the summary page; table 1:
report_table1.py; the stage, transfer and feedback scans: report_scans.py."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numpy as np

from agents.registry import NAMES
from benchmarks.sweep.paper import MODES, PAPER_TABLE2

ENVS = ("training", "testing")


MIN_BOLD_SEEDS = 3  # fewer seeds per cell cannot support a Welch's t-test verdict: nothing is bold


def quick_note(p: dict) -> list:
    """The lines under a table's title that say a quick preset's budgets are too small to learn
    (none for the other presets)."""
    if p["name"] != "quick":
        return []
    learners = ", ".join(f"{NAMES[a]} {n:,}" for a, n in p["budgets"].items() if n)
    return [
        f"**Quick preset: its training budgets (env steps: {learners}) are far too small to "
        "learn.** These numbers show that the sweep runs, not how well the learners control; "
        "the default preset's do.",
        "",
    ]


def bold_rule(seeds: int) -> str:
    """The bolding rule as stated under a table of ``seeds`` seeds per cell."""
    if seeds < MIN_BOLD_SEEDS:
        return (
            f"No bold: {seeds} seeds per cell are too few to tell values apart (bold needs "
            f"{MIN_BOLD_SEEDS} or more)."
        )
    return (
        "Bold: the best mean of the row and every value not significantly different from it "
        f"(Welch's t-test, p >= 0.05 over the {seeds} seeds); nothing is bold with fewer than "
        f"{MIN_BOLD_SEEDS} seeds."
    )


def bold_mask(samples: dict, alpha: float = 0.05) -> dict:
    """Best mean per row, and every algorithm not significantly different from it (Welch's
    t-test, p >= alpha), are bold; nothing is with fewer than ``MIN_BOLD_SEEDS`` samples in any
    cell. Identical constant samples count as not different."""
    from scipy.stats import ttest_ind

    if min(len(v) for v in samples.values()) < MIN_BOLD_SEEDS:
        return {a: False for a in samples}
    means = {a: float(np.mean(v)) for a, v in samples.items()}
    best = max(means, key=means.get)
    mask = {}
    for algo, values in samples.items():
        if algo == best:
            mask[algo] = True
            continue
        p = ttest_ind(samples[best], values, equal_var=False).pvalue
        mask[algo] = bool(np.isnan(p) and means[algo] == means[best]) or bool(p >= alpha)
    return mask


def mean_std_cell(mean, std, bold=False) -> str:
    """``mean ± std`` to 4 decimals, in bold if ``bold``."""
    s = f"{mean:.4f} ± {std:.4f}"
    return f"**{s}**" if bold else s


def _plt():
    """matplotlib.pyplot on the Agg backend (no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def aggregate_table(scores: dict) -> list:
    """Markdown table lines: per label, the IQM of its (seeds, tasks) matrix [95 % CI] and the
    probability of improvement over every other label (P(row > column), averaged over tasks)."""
    from benchmarks import robust

    labels = list(scores)
    lines = [
        "| | IQM [95 % CI] | " + " | ".join(f"P(> {b})" for b in labels) + " |",
        "|---|---|" + "---|" * len(labels),
    ]
    for a in labels:
        ci = "{:.4f} [{:.4f}, {:.4f}]".format(*robust.bootstrap_ci(scores[a]))
        poi = [
            "–" if b == a else f"{robust.probability_of_improvement(scores[a], scores[b]):.2f}"
            for b in labels
        ]
        lines.append(f"| {a} | {ci} | " + " | ".join(poi) + " |")
    return lines


def convergence_step(steps, values, tol=0.02):
    """First step from which the curve stays within ``tol`` (P/Pmax) of its final value (the mean of
    its last three points): where it 'reaches its peak and stops changing'. NaN ("not reached") for
    an empty curve or one that never left that band: it did not change, so it converged to
    nothing."""
    steps, values = np.asarray(steps, float), np.asarray(values, float)
    if len(values) == 0:
        return float("nan")
    final = values[-3:].mean()
    outside = np.nonzero(np.abs(values - final) > tol)[0]
    if len(outside) == 0:
        return float("nan")
    return float(steps[min(outside[-1] + 1, len(values) - 1)])


def _steps_cell(values) -> str:
    """Mean ± std of convergence steps, "not reached" where none is, the count where some are
    not."""
    values = np.asarray(values, float)
    reached = values[~np.isnan(values)]
    if not reached.size:
        return "not reached"
    cell = f"{reached.mean():.0f} ± {reached.std():.0f}"
    return (
        cell if reached.size == values.size else f"{cell} ({reached.size} of {values.size} seeds)"
    )


def table2(out: Path, runs: dict, p: dict):
    lines = [
        "# Table 2: time usage, 5-stage hard (TPS = seconds per step)",
        "",
        *quick_note(p),
        "Ours: this machine, batched JAX; per-step times are wall time divided by environment "
        "steps (simulation = stepping the environment, optimisation = the rest of training). "
        "Convergence "
        "step: first step from which the evaluation curve stays within 0.02 P/Pmax of its final "
        'value; "not reached": the curve never changed by more than that (nothing converged). '
        "Inference TPS: one batched control step (policy, probes and environment) divided by the "
        "number of test episodes. Test-time convergence step: the same rule on the mean test "
        "curve. Total control time = test-time convergence steps x inference TPS (the paper adds "
        "its simulation TPS; ours is inside).",
        "",
        "| algo | simulation TPS | optimisation TPS | convergence step | total training time (s) | "
        "inference TPS | test-time convergence step | total control time (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for algo in p["algos"]:
        recs = [runs["hard", algo, s] for s in range(p["seeds"])]
        inf = np.mean(
            [
                r["test_env"]["summary"]["inference_s_per_step"]
                / r["test_env"]["summary"]["episodes"]
                for r in recs
            ]
        )
        test_conv = [
            convergence_step(
                np.arange(1, len(r["test_env"]["mean_curve"]) + 1), r["test_env"]["mean_curve"]
            )
            for r in recs
        ]
        ctrl = [c * inf for c in test_conv]
        steps = p["budgets"][algo]
        if steps:
            sim = np.mean([r["wall_time"].get("simulation", 0.0) for r in recs]) / steps
            opt = np.mean([r["wall_time"].get("optimisation", 0.0) for r in recs]) / steps
            conv = [
                convergence_step(r["curve"].get("step", []), r["curve"].get("normalized_power", []))
                for r in recs
            ]
            total = [r["wall_time"].get("total", 0.0) for r in recs]
            train_cols = (
                f"{sim:.2e} | {opt:.2e} | {_steps_cell(conv)} | "
                f"{np.mean(total):.1f} ± {np.std(total):.1f}"
            )
        else:  # no training (SPGD, physics-informed)
            train_cols = "– | – | – | –"
        lines.append(
            f"| {NAMES[algo]} | {train_cols} | {inf:.2e} | {_steps_cell(test_conv)} | "
            f"{np.nanmean(ctrl):.4f} ± {np.nanstd(ctrl):.4f} |"
        )
        if algo in PAPER_TABLE2:
            lines.append("| paper | " + " | ".join(str(v) for v in PAPER_TABLE2[algo]) + " |")
    (out / "table2.md").write_text("\n".join(lines) + "\n")


def _band(ax, x, runs_y, label):
    y = np.asarray(runs_y)
    m, s = y.mean(0), y.std(0)
    (line,) = ax.plot(x, m, label=label)
    ax.fill_between(x, m - s, m + s, alpha=0.2, color=line.get_color())


def save_figure(fig, legend_ax, path: Path) -> None:
    """Legend on ``legend_ax``, tight layout, ``path`` written at 110 dpi, figure closed."""
    legend_ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _plt().close(fig)


def _per_mode_figure(
    out: Path, filename: str, title: str, xlabel: str, ylabel: str, draw, ylim=None
):
    """One panel per mode (``draw(ax, mode)`` plots into it), shared y axis, written to
    ``out/filename``."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4), sharey=True)
    for ax, mode in zip(axes, MODES):
        draw(ax, mode)
        ax.set_title(f"{title}, 5-stage {mode}")
        ax.set_xlabel(xlabel)
        if ylim is not None:
            ax.set_ylim(*ylim)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(ylabel)
    save_figure(fig, axes[0], out / filename)


def training_curves(out: Path, runs: dict, p: dict):
    def draw(ax, mode):
        for algo in p["algos"]:
            curves = [runs[mode, algo, s]["curve"] for s in range(p["seeds"])]
            if not all(len(c.get("step", [])) >= 2 for c in curves):
                continue
            grid = np.linspace(0, min(c["step"][-1] for c in curves), 50)
            ys = [np.interp(grid, c["step"], c["normalized_power"]) for c in curves]
            _band(ax, grid, ys, NAMES[algo])

    _per_mode_figure(
        out, "training_curves.png", "training", "environment steps", "evaluation P/Pmax", draw
    )


def testing_curves(out: Path, runs: dict, p: dict):
    def draw(ax, mode):
        for algo in p["algos"]:
            ys = [runs[mode, algo, s]["test_env"]["mean_curve"] for s in range(p["seeds"])]
            _band(ax, np.arange(1, len(ys[0]) + 1), ys, NAMES[algo])

    _per_mode_figure(
        out,
        "testing_curves.png",
        "testing",
        "control iteration",
        "P/Pmax (mean over test episodes)",
        draw,
        ylim=(0, 1.02),
    )


def _wall_times(timing: dict, workers, wall: float) -> list:
    """summary.md's wall-time lines (s): the whole command's ``wall`` if known (not NaN), then each
    part worker's in ``workers`` and this process's ``timing``."""
    if workers:
        times = [
            f"- worker {i + 1} ({'+'.join(w['algos'])}): "
            + ", ".join(f"{k} {v:.1f} s" for k, v in w["timing"].items())
            for i, w in enumerate(workers)
        ]
        times += [
            "- then, in one process: " + ", ".join(f"{k} {v:.1f} s" for k, v in timing.items()),
            "",
            f"The {len(workers)} workers ran at once, so the times per step in table2 were "
            "measured beside the other workers' work.",
        ]
    else:
        times = [f"- {k}: {v:.1f} s" for k, v in timing.items()]
    if wall == wall:
        times = [f"- whole command: {wall:.1f} s", *times]
    return times


def summary(out: Path, p: dict, sections, timing: dict, counts, workers=(), wall=float("nan")):
    """summary.md: configuration, machine, cells (``counts``: computed, reused), wall times (this
    process's ``timing``; each part worker's in ``workers``; ``wall``, the whole command's, if
    known) and every table and figure."""
    import jax

    computed, reused = counts
    times = _wall_times(timing, workers, wall)

    files = sorted(  # the reports and those of a section in its own folder (budget/budget.md)
        f.relative_to(out).as_posix()
        for f in (*out.glob("*"), *out.glob("*/*"))
        if f.suffix in (".md", ".csv", ".png") and f.name != "summary.md"
    )
    lines = [
        f"# ops-jax sweep: preset {p['name']}",
        "",
        f"- sections: {', '.join(sections)}",
        f"- algorithms: {', '.join(p['algos'])}; seeds per cell: {p['seeds']}; test episodes: "
        f"{p['episodes']}",
        f"- training budgets (env steps): {p['budgets']}; hyperparameter config: "
        f"{p['algo_config']}",
        *(
            [f"- the reality section's own budgets: {p['reality_budgets']}"]
            if "reality" in sections and p.get("reality_budgets")
            else []
        ),
        f"- machine: {platform.platform()}, {os.cpu_count()} CPUs, "
        f"{platform.processor() or platform.machine()}",
        f"- versions: python {platform.python_version()}, jax {jax.__version__}, devices "
        f"{jax.devices()}",
        f"- XLA_FLAGS: {os.environ.get('XLA_FLAGS') or '(none)'}",
        f"- cells computed this run: {computed}, reused from earlier runs: {reused}",
        "",
        "## Wall time per section (this run)",
        "",
        *times,
        "",
        "## Files",
        "",
        *[f"- [{f}]({f})" for f in files],
        "",
    ]
    for f in files:
        if f.endswith(".png"):
            lines += [f"![{f}]({f})", ""]
    (out / "summary.md").write_text("\n".join(lines))
