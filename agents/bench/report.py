"""What a run on the bench shows as it goes and when it ends: a controller's progress line
(``progress``, the one a learner's run shows: a bar on a terminal, a plain line every 30 s
elsewhere), the run's summary in a few lines (``summary.json`` keeps the numbers) and the bench's
ceilings in the summary (``ceilings``, ``add_ceilings``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from agents.io import read_json, write_json_atomic
from ops_jax.cli.progress import progress

# why a run's summary holds no ceilings: the runner reads no imperfections off a bench
UNKNOWN_BENCH = (
    "the bench's imperfections are unknown to the runner (neither the mapping nor the bench's PVs "
    "state them); benchmarks.lab, which starts the simulated bench, adds them"
)

# (event key, name) of what the progress line shows of the score: the first the bench maps
SCORES = (
    ("bench_evaluation_p_pbest", "P / P_best"),
    ("bench_evaluation_p_pmax", "P / P_max"),
    ("bench_detector_power", "detector"),
)


class RunProgress:
    """A document callback of the RunEngine: each event page (the loop's steps, every 0.2 s)
    advances the progress line by its steps and sets its postfix to the page's mean score and the
    moves clipped and wrapped so far (read off ``lines``, the bench's ``Lines``). Runs in the
    RunEngine's thread, not the loop's."""

    def __init__(self, label: str, steps: int, lines):
        self.bar = progress(total=steps or None, desc=label, unit="step")
        self.lines = lines

    def __call__(self, name: str, doc: dict) -> None:
        if name != "event_page" or not doc["seq_num"]:
            return
        self.bar.set_postfix_str(self.postfix(doc["data"]))
        self.bar.update(len(doc["seq_num"]))

    def postfix(self, data: dict) -> str:
        """The page's mean P / P_best (else P / P_max, else the detector's reading) and the clipped
        and wrapped moves so far."""
        score = next(
            (f"{name} {np.mean(data[key]):.3f}, " for key, name in SCORES if key in data), ""
        )
        return f"{score}clipped {self.lines.clipped.get()}, wrapped {self.lines.wraps.get()}"

    def close(self) -> None:
        self.bar.close()


def _number(value, digits: str) -> str:
    """``value`` formatted with ``digits`` (a format spec), "n/a" where it is NaN or missing."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    return format(value, digits)


def ceilings(summary: dict, bench_env: dict | None = None) -> dict:
    """The summary's ceilings: ``held_power`` and ``held_power_predicted`` (P / P_best,
    ``ops_jax.imperfections.ceilings``) of the bench whose ``ops_jax.make`` options are
    ``bench_env`` (None: unknown), the run's ``p_over_pbest_mean`` as a fraction of each
    (``p_over_held_mean``, ``p_over_held_predicted_mean``), ``held_power_reason`` where there are
    none."""
    from ops_jax import EnvSpec, imperfections

    if bench_env is None:
        found = imperfections.Ceilings(
            None, None, UNKNOWN_BENCH, imperfections.CEILING_SAMPLES, imperfections.CEILING_SEED
        )
    else:
        found = imperfections.ceilings(EnvSpec.from_options(bench_env))
    score = summary.get("p_over_pbest_mean")
    score = score if isinstance(score, float) and math.isfinite(score) else None
    over_held, over_predicted = found.fractions(score)
    return {
        **found.to_json(),
        "held_power_samples": found.samples,
        "p_over_held_mean": over_held,
        "p_over_held_predicted_mean": over_predicted,
    }


def add_ceilings(folder: Path, bench_env: dict) -> dict:
    """Rewrite ``folder``'s summary.json with the ``ceilings`` of the bench ``bench_env`` (the
    simulated bench's ``ops_jax.make`` options, as the tooling that started it knows them); the
    summary."""
    summary = read_json(Path(folder) / "summary.json")
    summary.update(ceilings(summary, bench_env))
    write_json_atomic(Path(folder) / "summary.json", summary)
    return summary


def readable(summary: dict, out: Path) -> str:
    """The run's summary in a few lines: how it ended, the score, the pace, the limits' work, the
    learner's counts (a learning run), where the files are."""
    s = summary
    lines = [
        f"{s['controller']}: {s['steps']:,} steps in {s['seconds']:.1f} s ({s['rate_hz']:.1f} "
        f"steps/s, {_number(s['frames_per_step'], '.2f')} frames per step), stopped by "
        f"{s['stopped_by']}",
        f"  P / P_best {_number(s['p_over_pbest_mean'], '.4f')}, P / P_max "
        f"{_number(s['p_over_pmax_mean'], '.4f')} (the mean over the last 80 % of the run)",
        f"  latency p50 / p99 {_number(s['latency_ms_p50'], '.2f')} / "
        f"{_number(s['latency_ms_p99'], '.2f')} ms, decide p50 "
        f"{_number(s['decide_ms_p50'], '.2f')} ms, CPU {_number(s['cpu_ms_per_step'], '.2f')} ms "
        "per step",
        f"  moves clipped {s['clipped_moves']:,}, wrapped {s['wrapped_moves']:,}; actions cut "
        f"{s['actions_cut']:,}",
    ]
    if "env_steps_total" in s:
        lines.append(
            f"  learning: {s['env_steps_total']:,} env steps, {s['learn_steps_total']:,} gradient "
            f"steps in all, {s['update_ratio']:.2f} per env step of {s['update_ratio_target']:g}"
            + (f"; the learner failed: {s['learner_error']}" if s["learner_error"] else "")
        )
    lines.append(f"  written: {out / 'summary.json'} (every number), documents.jsonl, power.png")
    return "\n".join(lines)
