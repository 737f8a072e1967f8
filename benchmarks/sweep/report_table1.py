"""Table 1 of ``benchmarks.sweep``: table1.md / .csv (final P/Pmax per mode, evaluation environment
and algorithm), its aggregate over the modes and the performance profile."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from agents.registry import NAMES
from benchmarks.sweep.paper import MODES, PAPER_TABLE1
from benchmarks.sweep.report import (
    quick_note,
    ENVS,
    aggregate_table,
    bold_mask,
    bold_rule,
    mean_std_cell,
    _plt,
    save_figure,
)


def _per_seed_final(record, env):
    return float(np.mean(record["train_env" if env == "training" else "test_env"]["final"]))


CSV_HEADER = [
    "mode",
    "env",
    "algo",
    "mean",
    "std",
    "seeds",
    "bold",
    "iqm",
    "iqm_ci_lo",
    "iqm_ci_hi",
    "paper_mean",
    "paper_std",
]


def _cell_rows(mode: str, env: str, runs: dict, p: dict, finals: dict) -> tuple[list, list]:
    """The markdown lines (scores, IQM [95 % CI], paper) and csv rows of one mode and evaluation
    env; each algorithm's per-seed finals appended to ``finals[env, algo]``."""
    from benchmarks import robust

    algos = p["algos"]
    samples = {
        a: [_per_seed_final(runs[mode, a, s], env) for s in range(p["seeds"])] for a in algos
    }
    bold = bold_mask(samples)
    paper = PAPER_TABLE1[mode, env]
    cells = [mean_std_cell(np.mean(samples[a]), np.std(samples[a]), bold[a]) for a in algos]
    paper_cells = [mean_std_cell(*paper[a]) if a in paper else "–" for a in algos]
    intervals = {a: robust.bootstrap_ci(samples[a]) for a in algos}
    rows_md = [
        f"| {mode} | {env} | " + " | ".join(cells) + " |",
        "| | IQM [95 % CI] | "
        + " | ".join("{:.4f} [{:.4f}, {:.4f}]".format(*intervals[a]) for a in algos)
        + " |",
        "| | paper | " + " | ".join(paper_cells) + " |",
    ]
    rows_csv = []
    for a in algos:
        finals.setdefault((env, a), []).append(samples[a])
        rows_csv.append(
            [
                mode,
                env,
                a,
                np.mean(samples[a]),
                np.std(samples[a]),
                len(samples[a]),
                bold[a],
                *intervals[a],
                *(paper[a] if a in paper else ("", "")),
            ]
        )
    return rows_md, rows_csv


def _table1_text(p: dict, rows_md: list, finals: dict) -> str:
    """table1.md: the per-mode table under its caption, the bolding rule and the aggregate
    tables."""
    from benchmarks import robust

    algos = p["algos"]
    header = "| mode | evaluation env | " + " | ".join(NAMES[a] for a in algos) + " |"
    sep = "|" + "---|" * (len(algos) + 2)
    return (
        f"# Table 1: final P/Pmax, 5-stage OPS ({p['seeds']} seeds x {p['episodes']} test "
        f"episodes, preset {p['name']})\n\n"
        + "".join(f"{line}\n" for line in quick_note(p))
        + "Mean ± std over seeds of each seed's mean final P/Pmax (200-step test episodes), and "
        "the IQM over seeds with its 95 % confidence interval. The 'paper' rows are the published "
        "values (20 seeds, stable-baselines3).\n\n"
        + "\n".join([header, sep, *rows_md])
        + "\n\n"
        + bold_rule(p["seeds"])
        + " The IQM rows are not bolded.\n\n"
        + robust.NOTE
        + "\n\n"
        + "\n".join(robust_tables(finals, algos))
        + "\n"
    )


def table1(out: Path, runs: dict, p: dict):
    """table1.md / .csv (mean ± std, Welch bolding, IQM [95 % CI] per cell; per algorithm the IQM
    over modes; the probability of improvement between algorithms) and performance_profile.png."""
    rows_md, rows_csv = [], []
    finals = {}  # (env, algo): (seeds, modes) matrix of final P/Pmax
    for mode in MODES:
        for env in ENVS:
            md, rows = _cell_rows(mode, env, runs, p, finals)
            rows_md += md
            rows_csv += rows
    finals = {k: np.array(v).T for k, v in finals.items()}
    (out / "table1.md").write_text(_table1_text(p, rows_md, finals))
    with open(out / "table1.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_HEADER)
        w.writerows(rows_csv)
    performance_profile(
        out / "performance_profile.png",
        {NAMES[a]: finals["testing", a] for a in p["algos"]},
        "final testing P/Pmax, 5-stage easy + medium + hard",
    )


def robust_tables(finals: dict, algos) -> list:
    """Markdown lines: per evaluation env, each algorithm's IQM over seeds x modes [95 % CI], and
    the probability that a seed of the row's algorithm beats one of the column's on the same
    mode."""
    lines = [
        "## Aggregate over the three modes",
        "",
        "IQM over every seed and mode (the three modes as tasks of a stratified bootstrap), and "
        "the probability of improvement P(row > column): the chance that a seed of the row's "
        "algorithm ends above a seed of the column's on the same mode (ties count half), "
        "averaged over the modes. No bold in these tables.",
        "",
    ]
    for env in ENVS:
        lines += [f"**{env}**", "", *aggregate_table({NAMES[a]: finals[env, a] for a in algos}), ""]
    return lines


def performance_profile(path: Path, scores: dict, xlabel: str, taus=None) -> None:
    """A performance-profile figure: per algorithm, the fraction of runs (seeds x tasks) scoring
    above tau, with its 95 % stratified-bootstrap band; ``scores``: {label: (seeds, tasks)
    matrix}."""
    from benchmarks import robust

    taus = np.linspace(0.0, 1.0, 201) if taus is None else np.asarray(taus)
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for i, (label, x) in enumerate(scores.items()):
        prof, lo, hi = robust.profile_ci(x, taus)
        ax.plot(taus, prof, color=f"C{i}", label=label)
        ax.fill_between(taus, lo, hi, color=f"C{i}", alpha=0.15, lw=0)
    ax.set_xlabel(f"tau ({xlabel})")
    ax.set_ylabel("fraction of runs with score > tau")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.set_title("performance profile (band: 95 % bootstrap CI)")
    save_figure(fig, ax, path)
