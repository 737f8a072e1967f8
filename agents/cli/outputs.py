"""What a training run of the command line (``agents.cli``) writes besides its checkpoint and
summary: ``curve.csv`` (``write_curve_csv``), ``curve.png`` (``plot_curve``), and its wall time in
words (``wall_time_line``)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


def write_curve_csv(path: Path, curve: dict) -> None:
    """curve.csv: every column of ``curve`` as long as its env steps."""
    cols = [k for k, v in curve.items() if np.ndim(v) == 1 and len(v) == len(curve["step"])]
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows([cols, *zip(*(np.asarray(curve[c]).tolist() for c in cols))])


def plot_curve(path: Path, curve: dict, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(curve["step"], curve["normalized_power"], marker="o", ms=3)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("evaluation P / P_max")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def wall_time_line(wall: dict) -> str:
    """The wall time of a training in words (s): its parts, compiling among them where the trainer
    timed it apart (the off-policy learners), else said to be inside them."""
    total = wall.get("total", float("nan"))
    parts = [k for k in ("compile", "simulation", "optimisation", "evaluation") if k in wall]
    said = [f"{k} {wall[k]:.1f} s" for k in parts]
    if "compile" not in wall:
        return f"wall time {total:.1f} s ({', '.join(said)}; both include compiling)"
    other = total - sum(wall[k] for k in parts)
    return f"wall time {total:.1f} s ({', '.join(said)}, other {max(0.0, other):.1f} s)"
