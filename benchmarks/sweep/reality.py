"""The ``reality`` section of ``benchmarks.sweep``: every controller trained on the ideal system
(the learners also with domain randomisation: lab imperfections, ``randomize=1``, i.e. 0 to 2x the
lab errors per episode; the physics-informed controller also identifying the imperfections online,
and identifying them while reading the length readout through its identified calibration) and tested
at imperfection levels none / lab / 2x lab (5 stages, hard mode, phasor model; see
docs/imperfections.md). Score: final P / P_best of 200-step test episodes (P_best: the best P
reachable with the level's static optics). Its trainings and evaluations are cells of the sweep's
store like every other section's (resumable, computed by the sweep's workers); this module holds the
section (``Reality``: its cells and its report: reality.md / .csv / .json and reality.png).

    python -m benchmarks.sweep --only reality
    python -m benchmarks.sweep --quick --only reality --out results/quick
"""

from __future__ import annotations

import csv
import platform
import time
from pathlib import Path

import numpy as np

from agents.io import write_json_atomic
from benchmarks.sweep.records import Controller, Evaluation, seed_label
from benchmarks.sweep.section import TEST_SEED_OFFSET, Section

LEVELS = (("none", 0.0), ("lab", 1.0), ("2x lab", 2.0))
BASE_ENV = dict(stages=5, mode="hard", model="phasor")
RANDOMISED = dict(BASE_ENV, imperfections="lab", randomize=1.0)  # the learners' randomised training


def level_env(scale: float) -> dict:
    """The ``ops_jax.make`` options of an imperfection level (``scale`` x the lab preset; 0:
    ideal)."""
    return (
        dict(BASE_ENV, imperfections="lab", imperfection_scale=scale)
        if scale > 0
        else dict(BASE_ENV)
    )


def trainings(algos, learners) -> list:
    """(algo, training, env options, hyperparameter overrides) of each controller of the section:
    every algorithm on the ideal system; the ``learners`` also randomised; the physics-informed
    controller as the ideal model ("ideal": the "frames" preset), with online identification
    ("identify") and, its default, with it reading the calibrated length readout ("readout")."""
    out = []
    for algo in algos:
        out.append(
            (algo, "ideal", level_env(0.0), {"config": "frames"} if algo == "physics" else {})
        )
        if algo in learners:
            out.append((algo, "randomised", dict(RANDOMISED), {}))
        if algo == "physics":
            out.append((algo, "identify", level_env(0.0), {"config": "frames", "identify": True}))
            out.append((algo, "readout", level_env(0.0), {}))
    return out


class Reality(Section):
    """The reality section: each controller of ``trainings`` trained (``reality_seeds`` seeds, the
    preset's ``reality_budgets`` where given), then tested at each of ``LEVELS``."""

    name = "reality"
    default = False

    @staticmethod
    def _trainings(sweep) -> list:
        """(training, controller) of each controller of the section."""
        from agents.registry import REGISTRY

        learners = [a for a in sweep.algos if REGISTRY[a].learner]
        return [
            (
                training,
                Controller(
                    prefix=f"reality-{training}-{algo}",
                    algo=algo,
                    env=env,
                    hyper=hyper,
                    steps=sweep.preset.get("reality_budgets", {}).get(algo),
                ),
            )
            for algo, training, env, hyper in trainings(sweep.algos, learners)
        ]

    @staticmethod
    def _seeds(sweep) -> range:
        return range(sweep.preset.get("reality_seeds", sweep.preset["seeds"]))

    @staticmethod
    def _tests(controller: Controller, seed: int) -> list:
        """(level, Evaluation) of seed ``seed`` of ``controller`` at each level."""
        return [
            (
                level,
                Evaluation(
                    label=seed_label(f"{controller.prefix}-{level.replace(' ', '')}", seed),
                    env=level_env(scale),
                    seed=seed + TEST_SEED_OFFSET,
                ),
            )
            for level, scale in LEVELS
        ]

    def units(self, sweep) -> list:
        units = []
        for _, controller in self._trainings(sweep):
            units += sweep.train_units(controller, self._seeds(sweep))
            units += [
                sweep.eval_unit(
                    f"evals-{controller.label(seed)}",
                    controller,
                    seed,
                    [evaluation for _, evaluation in self._tests(controller, seed)],
                )
                for seed in self._seeds(sweep)
            ]
        return units

    def results(self, sweep) -> dict:
        """{"algo/training": {level: [final P / P_best per seed]}} (each seed: the mean over its
        test episodes)."""
        ratios = best_ratios()
        res = {}
        for training, controller in self._trainings(sweep):
            row = res[f"{controller.algo}/{training}"] = {level: [] for level, _ in LEVELS}
            for seed, record in sweep.trained_seeds(controller, self._seeds(sweep)).items():
                for level, evaluation in self._tests(controller, seed):
                    ev = sweep.evaluated(evaluation, record)
                    row[level].append(float(np.mean(ev["final"]) * ratios[level]))
        return res

    def report(self, sweep, results) -> None:
        report(
            sweep.out,
            results,
            sweep.preset,
            sweep.preset.get("command", "python -m benchmarks.sweep --only reality"),
            ceilings=level_ceilings(),
        )


def best_ratios() -> dict:
    """P_max / P_best of each level (1 for the ideal level)."""
    from agents.envs import best_ratio

    return {name: best_ratio(level_env(scale)) for name, scale in LEVELS}


def level_ceilings() -> dict:
    """The ``ops_jax.imperfections.ceilings`` of each level's test environment (None with the
    reason for the ideal level)."""
    from ops_jax import EnvSpec
    from ops_jax.imperfections import ceilings

    return {name: ceilings(EnvSpec.from_options(level_env(scale))) for name, scale in LEVELS}


def _ceiling(value) -> str:
    """A ceiling or a fraction of one to 4 decimals, a dash where there is none."""
    return "–" if value is None else f"{value:.4f}"


def _ceiling_lines(results: dict, ceilings: dict, names: list) -> list:
    """reality.md's table against the ceilings: per controller and level the mean score, both
    ceilings and the score as a fraction of each."""
    first = next(c for c in ceilings.values())
    reasons = sorted({f"{n}: {c.reason}" for n, c in ceilings.items() if c.reason is not None})
    lines = [
        "",
        "Against the ceilings (`ops_jax.imperfections.ceilings`, P / P_best, "
        f"{first.samples:,} draws from seed {first.seed}): held, the lines held at the P_best "
        "offsets through the vibration and the pulses' noise (the drift followed exactly, the "
        "vibration not at all); predicted, the same less the vibration's one-step prediction from "
        "its exact past. The mean score over seeds as a fraction of each: above 1 on held, the "
        "controller follows part of the vibration. –: " + ("; ".join(reasons) or "none") + ".",
        "",
        "| controller | level | final P / P_best | held | predicted | / held | / predicted |",
        "|---|---|---|---|---|---|---|",
    ]
    for algo in results:
        for n in names:
            score = float(np.mean(results[algo][n]))
            cells = [ceilings[n].held, ceilings[n].predicted, *ceilings[n].fractions(score)]
            lines.append(
                f"| {_label(algo)} | {n} | {score:.4f} | " + " | ".join(map(_ceiling, cells)) + " |"
            )
    return lines


def _label(algo: str) -> str:
    """A result's row label: the controller's name (its training)."""
    from benchmarks.sweep.report import NAMES

    a, training = algo.split("/")
    return f"{NAMES.get(a, a)} ({training})"


def _score_lines(results: dict, preset: dict, names: list, intervals: dict) -> list:
    """reality.md's tables: the Welch-bolded means ± std, then the IQM over seeds [95 % CI]."""
    from benchmarks.sweep.report import bold_mask, bold_rule, mean_std_cell

    bold = {n: bold_mask({a: results[a][n] for a in results}) for n in names}
    seeds = len(next(iter(results.values()))[names[0]])
    lines = [
        "# Reality gap: controllers tested with lab imperfections",
        "",
        f"Final P / P_best (mean ± std over {seeds} seeds; each seed: {preset['episodes']} test "
        "episodes of 200 steps), 5 stages, hard mode, phasor model. Levels: the lab preset of "
        "docs/imperfections.md x 0, 1, 2.",
        "",
        "| controller | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for algo in results:
        cells = [
            mean_std_cell(np.mean(results[algo][n]), np.std(results[algo][n]), bold[n][algo])
            for n in names
        ]
        lines.append(f"| {_label(algo)} | " + " | ".join(cells) + " |")
    lines += [
        "",
        bold_rule(seeds),
        "",
        "IQM over seeds [95 % CI] of the same scores (not bolded):",
        "",
        "| controller | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for algo in results:
        lines.append(
            f"| {_label(algo)} | "
            + " | ".join("{:.3f} [{:.3f}, {:.3f}]".format(*intervals[algo][n]) for n in names)
            + " |"
        )
    return lines


def _aggregate_lines(matrices: dict, command: str, wall_s: float | None) -> list:
    """reality.md after its tables: the aggregate over the levels, the trainings and the command."""
    from benchmarks import robust
    from benchmarks.sweep.report import aggregate_table

    took = "" if wall_s is None else f", {wall_s / 60:.1f} min"
    return [
        "",
        robust.NOTE,
        "",
        "Over the three levels (as tasks): IQM [95 % CI] and the probability of improvement P(row "
        "> column), a seed of the row's controller above one of the column's at the same level "
        "(ties count half), averaged over the levels. No bold.",
        "",
        *aggregate_table(matrices),
        "",
        "![performance profile](reality_profile.png)",
        "",
        "Training: ideal (the ideal system), randomised (lab imperfections x U[0, 2) per episode), "
        "identify (ideal, with online identification of the imperfections), readout (identify, "
        "also reading the length readout through its identified calibration).",
        "",
        f"Command: `{command}`; {time.strftime('%Y-%m-%d', time.gmtime())}, host {platform.node()} "
        f"({platform.processor() or platform.machine()}){took}.",
    ]


def _write_csv(path: Path, results: dict, names: list, intervals: dict, ceilings: dict) -> None:
    """reality.csv: per controller, training and level, the mean, std, seeds, IQM [95 % CI], the
    held and predicted ceilings and the mean as a fraction of each (empty where none)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
                "controller",
                "trained",
                "level",
                "mean",
                "std",
                "seeds",
                "iqm",
                "iqm_ci_lo",
                "iqm_ci_hi",
                "held",
                "predicted",
                "mean_over_held",
                "mean_over_predicted",
            ]
        )
        for algo in results:
            for n in names:
                v = results[algo][n]
                w.writerow(
                    [
                        *algo.split("/"),
                        n,
                        f"{np.mean(v):.6f}",
                        f"{np.std(v):.6f}",
                        len(v),
                        *(f"{x:.6f}" for x in intervals[algo][n]),
                        *(
                            "" if x is None else f"{x:.6f}"
                            for x in (
                                ceilings[n].held,
                                ceilings[n].predicted,
                                *ceilings[n].fractions(float(np.mean(v))),
                            )
                        ),
                    ]
                )


def _plot_levels(path: Path, results: dict, names: list) -> None:
    """reality.png: each controller's final P / P_best (mean ± std) per level, a line style per
    training."""
    from benchmarks.sweep.report import _plt

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.array([s for _, s in LEVELS])
    algos = list(dict.fromkeys(a.split("/")[0] for a in results))
    color = {
        a: f"C{i}" for i, a in enumerate(algos)
    }  # one colour per controller, a line style per training
    for algo in results:
        m = np.array([np.mean(results[algo][n]) for n in names])
        s = np.array([np.std(results[algo][n]) for n in names])
        a, training = algo.split("/")
        ax.errorbar(
            x,
            m,
            yerr=s,
            marker="o",
            capsize=3,
            label=_label(algo),
            color=color[a],
            linestyle={"randomised": "--", "identify": ":", "readout": "-."}.get(training, "-"),
        )
    ax.set_xticks(x, names)
    ax.set_xlabel("imperfection level")
    ax.set_ylabel("final P / P_best")
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def report(
    out: Path,
    results: dict,
    preset: dict,
    command: str,
    wall_s: float | None = None,
    *,
    ceilings: dict,
) -> None:
    """reality.md (Welch-bolded table, IQM [95 % CI], the scores against the ``ceilings``, {level:
    ``ops_jax.imperfections.Ceilings``}, probability of improvement), reality.csv, reality.json,
    reality.png and reality_profile.png (performance profile over the levels) in ``out``."""
    from benchmarks import robust
    from benchmarks.sweep.report_table1 import performance_profile

    names = [n for n, _ in LEVELS]
    intervals = {
        algo: {n: robust.bootstrap_ci(results[algo][n]) for n in names} for algo in results
    }
    matrices = {_label(a): np.array([results[a][n] for n in names]).T for a in results}
    lines = _score_lines(results, preset, names, intervals)
    lines += _ceiling_lines(results, ceilings, names)
    lines += _aggregate_lines(matrices, command, wall_s)
    out.mkdir(parents=True, exist_ok=True)
    (out / "reality.md").write_text("\n".join(lines) + "\n")
    _write_csv(out / "reality.csv", results, names, intervals, ceilings)
    write_json_atomic(out / "reality.json", results)
    _plot_levels(out / "reality.png", results, names)
    performance_profile(
        out / "reality_profile.png", matrices, "final P / P_best, levels none + lab + 2x lab"
    )
