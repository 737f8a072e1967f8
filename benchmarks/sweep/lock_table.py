"""lock.md of ``benchmarks.sweep``: each controller's lock figures (``ops_jax.lock``) per mode and
evaluation environment, from the table-1 cells' evaluations (``agents.evaluate``'s summary), and its
final score against the environment's ceilings (``ops_jax.imperfections.ceilings``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agents.registry import NAMES
from benchmarks.sweep.paper import MODES
from benchmarks.sweep.report import ENVS, _steps_cell
from ops_jax.lock import DEFAULT_HOLD

DASH = "–"


def _env_summary(record: dict, env: str) -> dict:
    """The stored ``agents.evaluate`` summary of a cell's evaluation in ``env`` ("training" or
    "testing")."""
    return record["train_env" if env == "training" else "test_env"].get("summary", {})


def lock_cells(summaries: list) -> tuple:
    """Table cells (locked episodes, lock step, RMS after lock) over seeds' evaluation summaries:
    the mean fraction of episodes that locked, the seeds' median lock steps and RMS (mean ± std over
    the seeds where some episode locked); a dash for each figure when no summary holds the lock
    figures (older cells)."""
    scored = [s for s in summaries if s.get("fraction_locked") is not None]
    if not scored:
        return DASH, DASH, DASH
    fraction = np.mean([s["fraction_locked"] for s in scored])
    steps = [np.nan if s["lock_step_median"] is None else s["lock_step_median"] for s in scored]
    rms = np.array(
        [s["rms_after_lock_median"] for s in scored if s["rms_after_lock_median"] is not None]
    )
    rms_cell = f"{100 * rms.mean():.2f} ± {100 * rms.std():.2f}" if rms.size else "not locked"
    seeds = "" if len(scored) == len(summaries) else f" ({len(scored)} of {len(summaries)} seeds)"
    return f"{fraction:.0%}{seeds}", _steps_cell(steps), rms_cell


def ceiling_cells(summaries: list, ceiling) -> tuple:
    """Table cells (final P / P_best, held, predicted, / held, / predicted): the seeds' mean final
    score (``final_mean_best``, else ``final_mean``: the ideal system's P / P_max), the ceilings of
    ``ceiling`` (an ``ops_jax.imperfections.Ceilings``) and the score as a fraction of each; a dash
    where there is none."""
    finals = [s.get("final_mean_best", s.get("final_mean")) for s in summaries]
    score = float(np.mean(finals)) if finals and None not in finals else None
    values = (score, ceiling.held, ceiling.predicted, *ceiling.fractions(score))
    return tuple(DASH if v is None else f"{v:.4f}" for v in values)


def _ceiling_note(ceilings: dict) -> str:
    """The lines under lock.md's table on its ceiling columns (and why some are dashes)."""
    first = next(iter(ceilings.values()))
    reasons = sorted({f"{m}: {c.reason}" for m, c in ceilings.items() if c.reason is not None})
    return (
        "Ceilings (`ops_jax.imperfections.ceilings`, P / P_best, "
        f"{first.samples:,} draws from seed {first.seed}): held, the lines held at the P_best "
        "offsets through the vibration (the drift followed exactly); predicted, the same less the "
        "vibration's one-step prediction from its exact past; the seeds' mean final score as a "
        "fraction of each. –: " + ("; ".join(reasons) or "no ceiling missing") + "."
    )


def lock_table(out: Path, runs: dict, p: dict, ceilings: dict) -> None:
    """lock.md: per mode, evaluation environment and controller, the table-1 cells' lock figures
    and final score against the mode's ``ceilings`` ({mode: ``ops_jax.imperfections.Ceilings``})."""
    band = next(
        (
            _env_summary(r, env)["lock_band"]
            for r in runs.values()
            for env in ENVS
            if "lock_band" in _env_summary(r, env)
        ),
        None,
    )
    rule = "" if band is None else f" within {band:.0%}"
    lines = [
        f"# Lock figures, 5-stage OPS ({p['seeds']} seeds x {p['episodes']} test episodes, preset "
        f"{p['name']})",
        "",
        "Per episode (`ops_jax.lock`): the lock step is the control steps made when P enters the "
        f"band{rule} of its held level (the median of the episode's last half) for good, lasting "
        f"at least the last {DEFAULT_HOLD:.0%} of the episode; the RMS after lock is std / mean "
        "of P from then on. Per seed the medians over the episodes that locked; here the mean "
        "fraction of episodes that locked and the seeds' medians, mean ± std over the seeds "
        "where some episode locked. –: cells stored before the lock figures were recorded (they "
        "keep only the mean curve over episodes, not each episode's).",
        "",
        _ceiling_note(ceilings),
        "",
        "| mode | evaluation env | controller | episodes locked | lock step | RMS after lock (%) | "
        "final P / P_best | held | predicted | / held | / predicted |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for mode in MODES:
        for env in ENVS:
            for algo in p["algos"]:
                summaries = [_env_summary(runs[mode, algo, s], env) for s in range(p["seeds"])]
                cells = " | ".join(lock_cells(summaries) + ceiling_cells(summaries, ceilings[mode]))
                lines.append(f"| {mode} | {env} | {NAMES[algo]} | {cells} |")
    (out / "lock.md").write_text("\n".join(lines) + "\n")
