"""The report of ``benchmarks.budget``: budget.md, budget.png and budget.json from its records."""

from __future__ import annotations

import platform
import time
from pathlib import Path

import numpy as np

from agents.registry import NAMES

BENCH = "unseen bench"  # protocol (b)'s environment name
TARGET = 0.9


def steps_to_target(checkpoints, scores: dict, target: float = TARGET):
    """The first checkpoint whose score reaches ``target``, or None."""
    return next((k for k in checkpoints if scores.get(str(k), -np.inf) >= target), None)


def _groups(records) -> dict:
    """{(env, algo): [record, ...]} in first-seen order."""
    groups = {}
    for r in records:
        groups.setdefault((r["cell"].env, r["cell"].algo), []).append(r)
    return groups


def _median_steps(rs) -> str:
    """Median over seeds of the env steps to reach the target ("not reached" when most seeds never
    do)."""
    reached = [steps_to_target(r["cell"].checkpoints, r["result"]["scores"]) for r in rs]
    ks = sorted(np.inf if k is None else k for k in reached)
    m = float(np.median(ks))
    return (
        "not reached"
        if not np.isfinite(m)
        else f"{m:,.0f} ({sum(k is not None for k in reached)}/{len(rs)})"
    )


def _target_panel(ax, env: str, groups: dict, algos: list) -> None:
    """Protocol (a)'s panel of ``env``: each controller's mean P / P_best over seeds, min-max
    band."""
    for i, algo in enumerate(algos):
        rs = groups.get((env, algo))
        if not rs:
            continue
        ks = [
            k for k in rs[0]["cell"].checkpoints if all(str(k) in r["result"]["scores"] for r in rs)
        ]
        y = np.array([[r["result"]["scores"][str(k)] for k in ks] for r in rs])
        style = "--" if rs[0]["cell"].kind == "reference" else "-"
        ax.plot(ks, y.mean(0), style, marker="o", ms=3, color=f"C{i}", label=NAMES.get(algo, algo))
        ax.fill_between(ks, y.min(0), y.max(0), color=f"C{i}", alpha=0.15, lw=0)
    ax.axhline(TARGET, color="grey", lw=0.8, ls=":")
    ax.set_xscale("log")
    ax.set_xlabel("env steps of the target system")
    ax.set_title(env)
    ax.grid(alpha=0.3)


def _bench_panel(ax, adapted: list, on_bench: dict) -> None:
    """Protocol (b)'s panel: each pretraining seed's P / P_best before and while adapting (and
    trimmed), the references' mean over the benches."""
    for i, r in enumerate(adapted):
        ks = [0, *r["cell"].checkpoints]
        ax.plot(
            ks,
            [r["result"]["before"]] + [r["result"]["scores"][str(k)] for k in ks[1:]],
            marker="o",
            ms=3,
            color=f"C{i}",
            label=f"pretraining seed {r['cell'].seed}",
        )
        if "trimmed" in r["result"]:
            ax.plot(
                ks,
                [r["result"]["trimmed"][str(k)] for k in ks],
                "--",
                marker="^",
                ms=3,
                color=f"C{i}",
                label="with the trim" if i == 0 else None,
            )
    for j, (algo, scores) in enumerate(on_bench.items()):
        ax.axhline(
            np.mean(list(scores.values())),
            color="k",
            lw=1,
            ls=("--", "-.", ":")[j % 3],
            label=f"{NAMES.get(algo, algo)} (reference, mean over the benches)",
        )
    ax.axhline(0.95, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("env steps on the bench (0: pretrained only)")
    ax.set_title(f"{BENCH}: simulator to bench")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")


def _figure(groups: dict, adapted: list, on_bench: dict, path: Path) -> None:
    """budget.png: a panel per protocol (a) environment, and protocol (b)'s where there are adapted
    cells."""
    from benchmarks.sweep.report import _plt

    plt = _plt()
    envs = list(dict.fromkeys(env for env, _ in groups))
    panels = len(envs) + bool(adapted)
    fig, axes = plt.subplots(1, panels, figsize=(5.5 * panels, 4), squeeze=False, sharey=True)
    algos = list(dict.fromkeys(a for _, a in groups))
    for ax, env in zip(axes[0], envs):
        _target_panel(ax, env, groups, algos)
    axes[0][0].set_ylabel("final P / P_best (mean over seeds, band: min-max)")
    if envs:
        axes[0][len(envs) - 1].legend(fontsize=8, loc="lower right")
    if adapted:
        _bench_panel(axes[0][-1], adapted, on_bench)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _bench_references(records) -> dict:
    """{reference: {bench seed: P / P_best on that bench}} of the ``bench reference`` records."""
    out = {}
    for r in records:
        c = r["cell"]
        out.setdefault(c.algo, {})[c.bench_seed] = r["result"]["scores"][str(c.checkpoints[0])]
    return out


def _adapt_columns(checkpoints, trimmed: bool) -> list:
    """Protocol (b)'s score columns: (title, P / P_best of a record) before and after adapting, and
    with ``trimmed`` around the pretrained and the last adapted policy."""
    ks = checkpoints
    cols = [("before", lambda r: r["result"]["before"])]
    cols += [(f"after {k:,}", lambda r, k=k: r["result"]["scores"][str(k)]) for k in ks]
    if trimmed:
        cols += [
            ("before, trimmed", lambda r: r["result"]["trimmed"]["0"]),
            (f"after {ks[-1]:,}, trimmed", lambda r: r["result"]["trimmed"][str(ks[-1])]),
        ]
    return cols


def _adapt_intro(c, trimmed: bool) -> list:
    """Protocol (b)'s heading and the sentence on what cell ``c`` pretrained and adapted on."""
    return [
        f"## Simulator to bench ({NAMES.get(c.algo, c.algo)})",
        "",
        f"Pretrained {c.pretrain_steps:,} env steps on the randomised simulator "
        f"({c.pretrain_env}, {c.pretrain_hyper}), then trained on for up to "
        f"{c.checkpoints[-1]:,} env steps on an unseen bench (the lab preset at "
        f"{c.env_config.get('imperfection_scale')}x, per-stage errors re-drawn "
        "from the bench seed); final P / P_best on that bench"
        + (
            "; trimmed: with the extremum-seeking trim (agents.controllers.trim, "
            f"{c.trim or 'default'})."
            if trimmed
            else "."
        ),
        "",
    ]


def _adapt_table(adapted: list, on_bench: dict) -> list:
    """Protocol (b)'s lines: per pretraining seed, P / P_best on its unseen bench before and after
    adapting, with the trim around the pretrained and the last adapted policy, and the references'
    on the same bench."""
    c = adapted[0]["cell"]
    trimmed = all("trimmed" in r["result"] for r in adapted)
    refs = {NAMES.get(a, a): scores for a, scores in on_bench.items()}
    cols = _adapt_columns(c.checkpoints, trimmed)
    lines = _adapt_intro(c, trimmed) + [
        "| pretraining seed | bench seed | "
        + " | ".join(t for t, _ in cols)
        + "".join(f" | {name} on the bench" for name in refs)
        + " | pretraining s | adapting s |",
        "|---|---|" + "---|" * (len(cols) + len(refs)) + "---|---|",
    ]
    for r in adapted:
        res, bench_seed = r["result"], r["cell"].bench_seed
        lines.append(
            f"| {r['cell'].seed} | {bench_seed} | "
            + " | ".join(f"{f(r):.3f}" for _, f in cols)
            + " |"
            + "".join(
                f" {scores[bench_seed]:.3f} |" if bench_seed in scores else " - |"
                for scores in refs.values()
            )
            + f" {res['pretrain_s']:.0f} | {res['train_s']:.0f} |"
        )
    bench_seeds = [r["cell"].bench_seed for r in adapted]
    held = [
        [scores[b] for b in bench_seeds if b in scores] for scores in refs.values()
    ]  # each reference's, these benches
    for name, agg in (("mean", np.mean), ("worst", np.min)):
        lines.append(
            f"| {name} | | "
            + " | ".join(f"{agg([f(r) for r in adapted]):.3f}" for _, f in cols)
            + " |"
            + "".join(f" {agg(v):.3f} |" if v else " - |" for v in held)
            + " | |"
        )
    return lines


def _cells(rs: list, checkpoints, fmt) -> list:
    """One table cell per checkpoint: ``fmt`` of the seeds' scores there, "-" where none has one."""
    cells = []
    for k in checkpoints:
        v = [r["result"]["scores"][str(k)] for r in rs if str(k) in r["result"]["scores"]]
        cells.append(fmt(v) if v else "-")
    return cells


def _robust_lines(groups: dict, checkpoints) -> list:
    """IQM [95 % CI] over seeds per row and checkpoint, and per environment the probability of
    improvement between its controllers at the last checkpoint all of them reached."""
    from benchmarks import robust
    from benchmarks.sweep.report import aggregate_table

    lines = [
        "IQM over seeds [95 % CI] of the same scores:",
        "",
        "| environment | controller | " + " | ".join(f"{k:,}" for k in checkpoints) + " |",
        "|---|---|" + "---|" * len(checkpoints),
    ]
    for (env, algo), rs in groups.items():
        row = _cells(
            rs, checkpoints, lambda v: "{:.3f} [{:.3f}, {:.3f}]".format(*robust.bootstrap_ci(v))
        )
        lines.append(f"| {env} | {NAMES.get(algo, algo)} | " + " | ".join(row) + " |")
    lines += ["", robust.NOTE]
    for env in dict.fromkeys(e for e, _ in groups):
        rows = {a: rs for (e, a), rs in groups.items() if e == env}
        common = [
            k
            for k in checkpoints
            if all(str(k) in r["result"]["scores"] for rs in rows.values() for r in rs)
        ]
        if len(rows) < 2 or not common:
            continue
        k = common[-1]
        scores = {
            NAMES.get(a, a): np.array([r["result"]["scores"][str(k)] for r in rs])
            for a, rs in rows.items()
        }
        lines += [
            "",
            f"{env}, after {k:,} env steps: probability of improvement P(row > column), a seed of "
            "the row's controller above one of the column's (ties count half).",
            "",
            *aggregate_table(scores),
        ]
    return lines


def _target_table(groups: dict, checkpoints: list, first) -> list:
    """Protocol (a)'s lines: per environment and controller the mean ± std over seeds at each
    checkpoint and the median env steps to the target; ``first``: a cell (its ``episodes`` and
    ``eval_seed``)."""
    lines = [
        "# Learning on a lab's budget",
        "",
        "Final P / P_best after each number of env steps of the target system (mean ± std over "
        f"seeds; each seed: {first.episodes} test episodes of 200 steps, evaluation seed "
        f"{first.eval_seed}), trained from scratch; median env steps to reach {TARGET} over seeds "
        "(seeds that reach it / seeds; "
        '"not reached" when most never do within the budget). References learn nothing.',
        "",
        "| environment | controller | median steps to 0.9 | "
        + " | ".join(f"{k:,}" for k in checkpoints)
        + " |",
        "|---|---|---|" + "---|" * len(checkpoints),
    ]
    for (env, algo), rs in groups.items():
        row = _cells(rs, checkpoints, lambda v: f"{np.mean(v):.3f} ± {np.std(v):.3f}")
        if rs[0]["cell"].kind == "reference":
            who, steps = f"{NAMES.get(algo, algo)} (reference)", "no training"
        else:
            seeds = ", ".join(str(r["cell"].seed) for r in rs)
            who, steps = f"{NAMES.get(algo, algo)} (seeds {seeds})", _median_steps(rs)
        lines.append(f"| {env} | {who} | {steps} | " + " | ".join(row) + " |")
    return lines


def _wall_lines(groups: dict) -> list:
    """The median wall time per cell of each controller (none without cells)."""
    walls = {
        algo: np.median(
            [r["result"]["train_s"] for (_, a), rs in groups.items() if a == algo for r in rs]
        )
        for algo in dict.fromkeys(a for _, a in groups)
    }
    if not walls:
        return []
    return [
        "",
        "Median wall time per cell (training to the last checkpoint, s): "
        + ", ".join(f"{NAMES.get(a, a)} {w:.0f}" for a, w in walls.items())
        + ".",
    ]


def report(records: list[dict], out_dir) -> str:
    """budget.md (returned), budget.png and budget.json in ``out_dir``; ``records``: [{"cell":
    ``Cell``, "result"}]."""
    from agents.io import write_json_atomic

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    adapted = [r for r in records if r["cell"].kind == "adapt"]
    on_bench = _bench_references([r for r in records if r["cell"].kind == "bench reference"])
    groups = _groups([r for r in records if r["cell"].kind in ("learner", "reference")])
    checkpoints = sorted(
        {k for (_, _), rs in groups.items() for r in rs for k in r["cell"].checkpoints}
    )
    lines = _target_table(groups, checkpoints, records[0]["cell"])
    lines += ["", "No bold in these tables.", "", *_robust_lines(groups, checkpoints)]
    lines += _wall_lines(groups)
    if adapted:
        lines += ["", *_adapt_table(adapted, on_bench)]
    lines += [
        "",
        f"{time.strftime('%Y-%m-%d', time.gmtime())}, host {platform.node()} "
        f"({platform.processor() or platform.machine()}).",
        "",
        "![P / P_best against env steps](budget.png)",
    ]
    _figure(groups, adapted, on_bench, out / "budget.png")
    stored = [{"cell": r["cell"].to_dict(), "result": r["result"]} for r in records]
    write_json_atomic(out / "budget.json", stored)
    text = "\n".join(lines) + "\n"
    (out / "budget.md").write_text(text)
    return text
