"""What a run on the bench shows as it goes and when it ends: the runner's lines on stderr
(``say``), a controller's progress line (``progress``, the one a learner's run shows: a bar on a
terminal, a plain line every 30 s elsewhere), ``summary.json`` (``summarize``) with the bench's
ceilings (``ceilings``, ``add_ceilings``), ``power.png`` (``plot``) and the run's summary in a few
lines (``readable``)."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

from agents.bench.loop import USER_STOP, Loop
from agents.io import read_json, write_json_atomic
from ops_jax import lock
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


def say(line: str) -> None:
    """A line of the runner's on stderr."""
    print(f"agents.bench.runner: {line}", file=sys.stderr, flush=True)


def stopped_by(loop: Loop) -> str:
    """How the run ended: ``"time"``, ``"steps"``, ``"user"`` (``USER_STOP``) or the watchdog's
    reason."""
    user = USER_STOP if loop.user_stop else None
    return (
        loop.stop_reason
        or user
        or ("steps" if 0 < loop.max_steps <= len(loop.rec["time_s"]) else "time")
    )


def summarize(loop: Loop, controller: str, elapsed: float) -> dict:
    """``summary.json``: the score (the last 80 % of the run: of its time, in lockstep of its
    frames, so that a lockstep score does not depend on the host's pace), achieved rates, latencies,
    how it ended; the lock figures of P / P_best over the whole run at its achieved rate
    (``ops_jax.lock.trace_json``)."""
    rec = {k: np.asarray(v, float) for k, v in loop.rec.items()}
    steps, t = len(rec["time_s"]), rec["time_s"]
    if loop.advance is not None and steps:
        tail = rec["tick"] >= rec["tick"][0] + 0.2 * (rec["tick"][-1] - rec["tick"][0])
    else:
        tail = t >= 0.2 * elapsed
    pct = lambda v, q: float(np.percentile(v, q)) if v.size else float("nan")
    mean = lambda v: float(np.mean(v)) if v.size else float("nan")
    frames = float(rec["tick"][-1] - rec["tick"][0]) if steps > 1 else 0.0
    return {
        "controller": controller,
        "stopped_by": stopped_by(loop),
        "watchdog_time": loop.stopped_at,
        "steps": steps,
        "seconds": elapsed,
        "rate_hz": steps / elapsed if elapsed > 0 else 0.0,
        "frames_per_step": frames / (steps - 1) if steps > 1 else float("nan"),
        "probes_per_step": loop.agent.probes,
        "latency_ms_p50": pct(rec["latency_ms"], 50),
        "latency_ms_p99": pct(rec["latency_ms"], 99),
        "latency_ms_max": float(rec["latency_ms"].max())
        if rec["latency_ms"].size
        else float("nan"),
        "decide_ms_p50": pct(rec["decide_ms"], 50),
        "decide_ms_p99": pct(rec["decide_ms"], 99),
        "cpu_ms_per_step": 1e3 * (time.process_time() - loop.cpu0) / steps
        if steps
        else float("nan"),
        "p_over_pbest_mean": mean(rec["p_pbest"][tail]),
        "p_over_pmax_mean": mean(rec["p_pmax"][tail]),
        "clipped_moves": int(loop.lines.clipped.get()),
        "wrapped_moves": int(loop.lines.wraps.get()),
        "actions_cut": loop.actions_cut,
        **lock.trace_json(rec["p_pbest"], steps / elapsed if elapsed > 0 and steps else None),
    }


def pyplot():
    """matplotlib's pyplot on the Agg backend (imported before a run: the end of a run is kept
    short)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot(path: Path, loop: Loop, title: str, ratio=None, rate_hz=None) -> None:
    """P / P_max and P / P_best against time; ``ratio``: (times (s), gradient steps per env step) on
    a second axis; beside it the PSD of P / P_best after lock at ``rate_hz`` (control steps/s;
    ``ops_jax.lock``)."""
    plt = pyplot()
    t = np.asarray(loop.rec["time_s"])
    fig, (ax, psd_ax) = plt.subplots(1, 2, figsize=(11, 3.5), width_ratios=(3, 2))
    _draw_psd(psd_ax, loop.rec["p_pbest"], rate_hz)
    ax.plot(t, loop.rec["p_pbest"], lw=1, label="P / P_best")
    ax.plot(t, loop.rec["p_pmax"], lw=1, alpha=0.7, label="P / P_max")
    ax.set(xlabel="time (s)", ylabel="stacked power", ylim=(0, 1.05), title=title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    if ratio is not None:
        twin = ax.twinx()
        twin.plot(*ratio, color="C3", lw=1)
        twin.set_ylabel("gradient steps per env step", color="C3")
        twin.set_ylim(bottom=0)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _draw_psd(ax, trace, rate_hz) -> None:
    """The PSD after lock of ``trace`` on ``ax``, or a note that the run is too short to score."""
    if len(trace) < lock.MIN_STEPS:
        ax.text(0.5, 0.5, "too short to score a lock", transform=ax.transAxes, ha="center")
        return
    lock.draw_psd(ax, lock.lock_figures(trace, rate_hz or None), label="P / P_best")


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
