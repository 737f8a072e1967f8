"""Where a controller loses under the lab imperfections: P / P_best on each bench, then on the same bench with one
group of imperfections taken away at a time (the same test seed).

    python -m benchmarks.imperfection_groups --algo physics --set config=frames --scale 2 --unseen \\
        --benches 1011 1012 1013 1014 1015 --episodes 32 --out results/imperfection_groups

A bench: 5-stage hard mode (phasor model), the lab preset at ``--scale`` times its magnitudes, frames only (no
length readouts; ``--lengths`` to observe them); with ``--unseen`` each bench's per-stage errors are re-drawn from its
seed as protocol (b)'s unseen benches (``benchmarks.budget.unseen_bench``). The controller: ``--algo`` (one with
nothing to learn: ``physics`` or ``spgd``) with ``--set`` overrides, or ``--policy DIR`` (an ``agents.save``
folder). Score: the final step's P / P_best, mean over ``--episodes`` test episodes (``--eval-seed``), P_best of
the bench as changed. Prints the table (a column per group: the score without it) and writes
``imperfection_groups.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

# The lab preset's fields by what they model; taking a group away sets its fields to the ideal values
# (``ops_jax.imperfections.Imperfections()``). "backlash" and "actuator gain" are parts of "actuators".
GROUPS = {
    "vibration": ("vib_rms", "resonance_rms"),
    "actuators": ("actuator_gain_error", "backlash_wl", "lag_steps", "dac_bits"),
    "backlash": ("backlash_wl",),
    "actuator gain": ("actuator_gain_error",),
    "detector": ("detector_offset", "detector_gain_error", "detector_saturation", "adc_bits"),
    "pulse noise": ("pulse_amplitude_noise", "pulse_phase_noise"),
    "optics": ("waveplate_error_deg", "pbs_leakage"),
    "length readout": ("readout_offset", "readout_gain_error"),
}


def bench(seed: int, scale: float, unseen: bool, lengths: bool) -> dict:
    """The ``ops_jax.make`` options of bench ``seed``: the reality section's level ``scale`` (> 0)."""
    from benchmarks.budget import unseen_bench
    from benchmarks.reality import BASE_ENV, level_env

    if unseen:
        return unseen_bench(dict(BASE_ENV, observe_lengths=lengths), seed, scale)
    return dict(level_env(scale), observe_lengths=lengths)


def without(env_config: dict, group: str) -> dict:
    """``env_config`` with the fields of ``GROUPS[group]`` at their ideal values."""
    from ops_jax.imperfections import Imperfections

    ideal = Imperfections()
    return dict(env_config, **{k: np.asarray(getattr(ideal, k)).tolist() for k in GROUPS[group]})


def score(args, env_config: dict) -> float:
    """Final-step P / P_best of the controller on ``env_config``, mean over the test episodes: a stored policy
    evaluated, or ``--algo`` built for this bench (its one evaluation, seed ``--eval-seed``, is the score)."""
    import agents
    from agents.envs import best_ratio

    if args.policy:
        ev = agents.evaluate(agents.load(args.policy), env_config, episodes=args.episodes, seed=args.eval_seed)
        return float(ev.normalized_power_best[:, -1].mean())
    result = agents.train(args.algo, env_config, seed=args.eval_seed, curve_episodes=args.episodes, **args.sets)
    return float(result.curve["normalized_power"][-1] * best_ratio(env_config))


def measure(args) -> list[dict]:
    """One row per bench: the score as it is and without each group."""
    rows, t_start = [], time.perf_counter()
    for i, seed in enumerate(args.benches, 1):
        t0 = time.perf_counter()
        env = bench(seed, args.scale, args.unseen, args.lengths)
        row = {"bench": seed, "all": score(args, env), **{group: score(args, without(env, group)) for group in args.groups}}
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        print(table(rows[-1:], args.groups).splitlines()[-1], flush=True)
        elapsed = time.perf_counter() - t_start
        print(f"bench {i}/{len(args.benches)} in {row['seconds']:.0f} s; about "
              f"{elapsed / i * (len(args.benches) - i):.0f} s left", file=sys.stderr, flush=True)
    return rows


def table(rows: list, groups) -> str:
    head = "| bench | all | " + " | ".join(f"no {g}" for g in groups) + " |\n" + "|---" * (len(groups) + 2) + "|"
    body = [f"| {r['bench']} | {r['all']:.4f} | " + " | ".join(f"{r[g]:.4f}" for g in groups) + " |" for r in rows]
    if len(rows) > 1:
        body.append("| mean | " + " | ".join(f"{np.mean([r[k] for r in rows]):.4f}" for k in ["all", *groups]) + " |")
    return "\n".join([head, *body])


def main(argv=None) -> dict:
    from agents.cli import parse_set
    from agents.registry import get

    ap = argparse.ArgumentParser(prog="python -m benchmarks.imperfection_groups", description=__doc__.split("\n")[0])
    ap.add_argument("--algo", default="physics", choices=["physics", "spgd"], help="a controller with nothing to learn")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="its hyperparameters")
    ap.add_argument("--policy", type=Path, default=None, metavar="DIR", help="instead: a policy stored by agents.save")
    ap.add_argument("--scale", type=float, default=1.0, help="the lab preset's magnitudes x this, in (0, 10]")
    ap.add_argument("--unseen", action="store_true", help="per-stage errors re-drawn from each bench's seed")
    ap.add_argument("--lengths", action="store_true", help="benches with the length readouts in the observation")
    ap.add_argument("--benches", nargs="+", type=int, default=[1011, 1012, 1013], help="the benches' seeds")
    ap.add_argument("--groups", nargs="+", default=list(GROUPS), choices=list(GROUPS))
    ap.add_argument("--episodes", type=int, default=32)
    ap.add_argument("--eval-seed", type=int, default=4242)
    ap.add_argument("--out", type=Path, default=Path("results/imperfection_groups"))
    args = ap.parse_args(argv)
    if args.episodes < 1:
        ap.error(f"--episodes must be an integer >= 1, got {args.episodes}")
    if not 0 < args.scale <= 10:
        ap.error(f"--scale must be a number in (0, 10], got {args.scale}")
    if args.policy is not None and not args.policy.is_dir():
        ap.error(f"--policy must be a folder written by agents.save, got {args.policy}")
    try:
        args.sets = parse_set(args.set)
        if args.policy is None:
            get(args.algo).config.make(**args.sets)
    except (TypeError, ValueError) as exc:
        ap.error(str(exc))
    rows = measure(args)
    result = {"command": "python -m benchmarks.imperfection_groups",
              "args": {k: str(v) for k, v in vars(args).items()}, "host": platform.node(),
              "date": time.strftime("%Y-%m-%d"), "rows": rows}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "imperfection_groups.json").write_text(json.dumps(result, indent=1))
    print(table(rows, args.groups))
    return result


if __name__ == "__main__":
    main()
