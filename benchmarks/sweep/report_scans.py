"""The scans of ``benchmarks.sweep``: the stage scan (stages.md / .png), the transfer between modes
(transfer.md / .png) and the feedback delay (feedback.md / .png)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agents.registry import NAMES
from benchmarks.sweep.paper import MODES
from benchmarks.sweep.report import _plt, convergence_step, quick_note, save_figure


def _stage_finals_panel(ax, res: dict, p: dict, ns: list, mode: str) -> list:
    """Final testing P/Pmax vs stage count of each algorithm in ``mode`` (mean ± std over seeds)
    drawn on ``ax``; the table's lines of ``mode``."""
    for algo in p["stage_algos"]:
        finals = [
            [np.mean(res[n, mode, algo, s]["test_env"]["final"]) for s in range(p["stage_seeds"])]
            for n in ns
        ]
        ax.errorbar(
            ns,
            np.mean(finals, 1),
            yerr=np.std(finals, 1),
            marker="o",
            capsize=3,
            label=NAMES[algo],
        )
    ax.set_title(f"{mode}")
    ax.set_xlabel("stages N")
    ax.set_ylabel("final testing P/Pmax")
    ax.set_ylim(0, 1.05)
    ax.grid(alpha=0.3)
    lines = []
    for n in ns:
        vals = [
            np.mean(
                [np.mean(res[n, mode, a, s]["test_env"]["final"]) for s in range(p["stage_seeds"])]
            )
            for a in p["stage_algos"]
        ]
        lines.append(f"| {n} | {mode} | " + " | ".join(f"{v:.3f}" for v in vals) + " |")
    return lines


def _stage_convergence_panel(ax, res: dict, p: dict, ns: list) -> None:
    """Training convergence step (environment steps, mean over seeds) vs stage count in the hardest
    mode."""
    hardest = p["stage_modes"][-1]
    for algo in p["stage_algos"]:
        conv = [
            np.mean(
                [
                    convergence_step(
                        res[n, hardest, algo, s]["curve"].get("step", []),
                        res[n, hardest, algo, s]["curve"].get("normalized_power", []),
                    )
                    for s in range(p["stage_seeds"])
                ]
            )
            for n in ns
        ]
        ax.plot(ns, conv, marker="o", label=NAMES[algo])
    ax.set_title(f"training convergence step ({hardest})")
    ax.set_xlabel("stages N")
    ax.set_ylabel("environment steps")
    ax.grid(alpha=0.3)


def stages(out: Path, res: dict, p: dict):
    """stages.md (final testing P/Pmax per stage count, mode and algorithm) and stages.png (a panel
    per mode and one of the convergence steps)."""
    plt = _plt()
    ns = sorted({k[0] for k in res})
    fig, axes = plt.subplots(
        1, len(p["stage_modes"]) + 1, figsize=(5 * (len(p["stage_modes"]) + 1), 4)
    )
    lines = [
        "# Stage scan: final testing P/Pmax vs stage count N",
        "",
        *quick_note(p),
        "| N | mode | " + " | ".join(NAMES[a] for a in p["stage_algos"]) + " |",
        "|" + "---|" * (len(p["stage_algos"]) + 2),
    ]
    for ax, mode in zip(axes, p["stage_modes"]):
        lines += _stage_finals_panel(ax, res, p, ns, mode)
    _stage_convergence_panel(axes[-1], res, p, ns)
    save_figure(fig, axes[0], out / "stages.png")
    (out / "stages.md").write_text("\n".join(lines) + "\n")


def transfer(out: Path, res: dict, p: dict):
    plt = _plt()
    algos = p["algos"]
    fig, axes = plt.subplots(1, len(algos), figsize=(3.6 * len(algos), 3.4))
    lines = [
        "# Transfer: trained on one mode (rows), tested on each (columns), final P/Pmax",
        "",
        *quick_note(p),
    ]
    for ax, algo in zip(np.atleast_1d(axes), algos):
        seeds = sorted({k[3] for k in res})
        m = np.array(
            [
                [np.mean([np.mean(res[a, b, algo, s]["final"]) for s in seeds]) for b in MODES]
                for a in MODES
            ]
        )
        im = ax.imshow(m, vmin=0, vmax=1, cmap="viridis")
        for i in range(3):
            for j in range(3):
                ax.text(
                    j,
                    i,
                    f"{m[i, j]:.2f}",
                    ha="center",
                    va="center",
                    color="w" if m[i, j] < 0.6 else "k",
                )
        ax.set_xticks(range(3), MODES)
        ax.set_yticks(range(3), MODES)
        ax.set_xlabel("tested on")
        ax.set_ylabel("trained on")
        ax.set_title(NAMES[algo])
        lines += [
            f"## {NAMES[algo]}",
            "",
            "| trained \\ tested | " + " | ".join(MODES) + " |",
            "|---|---|---|---|",
        ]
        lines += [
            f"| {MODES[i]} | " + " | ".join(f"{v:.3f}" for v in m[i]) + " |" for i in range(3)
        ] + [""]
    fig.colorbar(im, ax=np.atleast_1d(axes).tolist(), shrink=0.8, label="P/Pmax")
    fig.savefig(out / "transfer.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    (out / "transfer.md").write_text("\n".join(lines) + "\n")


def feedback(out: Path, res: dict, p: dict):
    plt = _plt()
    ks = p["feedback_ks"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    lines = [
        "# Feedback delay: trained at k = 1 (hard), tested at k",
        "",
        *quick_note(p),
        "| algo | " + " | ".join(f"k={k} final / mean" for k in ks) + " |",
        "|" + "---|" * (len(ks) + 1),
    ]
    seeds = sorted({key[2] for key in res})
    for algo in p["algos"]:
        finals = [np.mean([np.mean(res[k, algo, s]["final"]) for s in seeds]) for k in ks]
        cum = [np.mean([np.mean(res[k, algo, s]["mean_curve"]) for s in seeds]) for k in ks]
        axes[0].plot(ks, finals, marker="o", label=NAMES[algo])
        axes[1].plot(ks, cum, marker="o", label=NAMES[algo])
        lines.append(
            f"| {NAMES[algo]} | "
            + " | ".join(f"{f:.3f} / {c:.3f}" for f, c in zip(finals, cum))
            + " |"
        )
    axes[0].set_ylabel("final P/Pmax")
    axes[1].set_ylabel("P/Pmax averaged over the episode")
    for ax in axes:
        ax.set_xlabel("feedback delay factor k (free-run draws per control step)")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    save_figure(fig, axes[0], out / "feedback.png")
    (out / "feedback.md").write_text("\n".join(lines) + "\n")
