"""Where a controller loses under the lab imperfections: P / P_best on each bench, then on the same
bench with one group of imperfections taken away at a time (the same test seed).

    python -m benchmarks.imperfection_groups --algo physics --set config=frames --scale 2 \\
        --unseen --benches 1011 1012 1013 1014 1015 --episodes 32 --out results/imperfection_groups

A bench: 5-stage hard mode (phasor model), the lab preset at ``--scale`` times its magnitudes,
frames only (no length readouts; ``--lengths`` to observe them); with ``--unseen`` each bench's
per-stage errors are re-drawn from its seed as protocol (b)'s unseen benches
(``benchmarks.budget.plan.unseen_bench``). The controller: ``--algo`` (one with nothing to learn:
``physics`` or ``spgd``) with ``--set`` overrides, or ``--policy DIR`` (an ``agents.save`` folder).
Score: the final step's P / P_best, mean over ``--episodes`` test episodes (``--eval-seed``), P_best
of the bench as changed. ``--ceiling`` adds two columns for the bench as it is: "held", P / P_best
with the lines held at the P_best offsets through the vibration and the pulses' noise (the most a
controller that follows the drift exactly but not the vibration can hold), and "predicted", the same
less the vibration's exact one-step prediction (``ops_jax.imperfections.held_power``). Prints the
table (a column per group: the score without it) and writes ``imperfection_groups.json``.
"""

from __future__ import annotations

import platform
import sys
import time
from argparse import Namespace
from pathlib import Path

import numpy as np

from agents.io import write_json_atomic
from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import keep_ctrl_c

# The lab preset's fields by what they model; taking a group away sets its fields to the ideal
# values (``ops_jax.imperfections.Imperfections()``). "backlash" and "actuator gain" are parts of
# "actuators".
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


def bench(seed: int, scale: float, unseen: bool, lengths: bool, probe: str = "instant") -> dict:
    """The ``ops_jax.make`` options of bench ``seed``: the reality section's level ``scale`` (> 0),
    its probes measured as ``probe`` says (``ops_jax.env.PROBES``)."""
    from benchmarks.budget.plan import unseen_bench
    from benchmarks.sweep.reality import BASE_ENV, level_env

    if unseen:
        return dict(unseen_bench(dict(BASE_ENV, observe_lengths=lengths), seed, scale), probe=probe)
    return dict(level_env(scale), observe_lengths=lengths, probe=probe)


def without(env_config: dict, group: str) -> dict:
    """``env_config`` with the fields of ``GROUPS[group]`` at their ideal values."""
    from ops_jax.imperfections import Imperfections

    ideal = Imperfections()
    return dict(env_config, **{k: np.asarray(getattr(ideal, k)).tolist() for k in GROUPS[group]})


def score(args, env_config: dict) -> float:
    """Final-step P / P_best of the controller on ``env_config``, mean over the test episodes: a
    stored policy evaluated, or ``--algo`` built for this bench (its one evaluation, seed
    ``--eval-seed``, is the score)."""
    import agents
    from agents.envs import best_ratio

    if args.policy:
        ev = agents.evaluate(
            agents.load(args.policy), env_config, episodes=args.episodes, seed=args.eval_seed
        )
        return float(ev.normalized_power_best[:, -1].mean())
    result = agents.train(
        args.algo,
        env_config,
        seed=args.eval_seed,
        curve_episodes=args.episodes,
        progress=False,
        **args.sets,
    )
    return float(result.curve["normalized_power"][-1] * best_ratio(env_config))


def measure(args) -> list[dict]:
    """One row per bench: the score as it is and without each group."""
    rows, t_start = [], time.perf_counter()
    for i, seed in enumerate(args.benches, 1):
        t0 = time.perf_counter()
        env = bench(seed, args.scale, args.unseen, args.lengths, args.probe)
        row = {
            "bench": seed,
            "all": score(args, env),
            **(ceiling(env, args.eval_seed) if args.ceiling else {}),
            **{group: score(args, without(env, group)) for group in args.groups},
        }
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        print(table(rows[-1:], columns(args)).splitlines()[-1], flush=True)
        elapsed = time.perf_counter() - t_start
        print(
            f"bench {i}/{len(args.benches)} in {row['seconds']:.0f} s; about "
            f"{elapsed / i * (len(args.benches) - i):.0f} s left",
            file=sys.stderr,
            flush=True,
        )
    return rows


def ceiling(env_config: dict, seed: int, samples: int = 8192) -> dict:
    """P / P_best of lines held at the P_best offsets on bench ``env_config``: "held" through the
    vibration, and "predicted" with the vibration's one-step prediction taken off
    (``ops_jax.imperfections.ceilings``)."""
    from ops_jax import EnvSpec
    from ops_jax.imperfections import ceilings

    found = ceilings(EnvSpec.from_options(env_config), seed=seed, samples=samples)
    return {"held": found.held, "predicted": found.predicted}


def columns(args) -> list:
    """The table's score columns: the bench as it is, its ceilings (``--ceiling``), then without
    each group."""
    return ["all", *(["held", "predicted"] if args.ceiling else []), *args.groups]


def table(rows: list, cols) -> str:
    title = lambda c: c if c in ("all", "held", "predicted") else f"no {c}"
    head = "| bench | " + " | ".join(map(title, cols)) + " |\n" + "|---" * (len(cols) + 1) + "|"
    body = [f"| {r['bench']} | " + " | ".join(f"{r[c]:.4f}" for c in cols) + " |" for r in rows]
    if len(rows) > 1:
        body.append(
            "| mean | " + " | ".join(f"{np.mean([r[c] for r in rows]):.4f}" for c in cols) + " |"
        )
    return "\n".join([head, *body])


def parser() -> ArgumentParser:
    """The command line of ``python -m benchmarks.imperfection_groups``."""
    from ops_jax.env import PROBES

    ap = ArgumentParser(
        prog="python -m benchmarks.imperfection_groups", description=__doc__.split("\n")[0]
    )
    ap.add_argument(
        "--algo",
        default="physics",
        choices=["physics", "spgd"],
        help="a controller with nothing to learn",
    )
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="its hyperparameters")
    ap.add_argument(
        "--policy",
        type=Path,
        default=None,
        metavar="DIR",
        help="instead: a policy stored by agents.save",
    )
    ap.add_argument(
        "--scale", type=float, default=1.0, help="the lab preset's magnitudes x this, in (0, 10]"
    )
    ap.add_argument(
        "--unseen", action="store_true", help="per-stage errors re-drawn from each bench's seed"
    )
    ap.add_argument(
        "--lengths", action="store_true", help="benches with the length readouts in the observation"
    )
    ap.add_argument(
        "--benches", nargs="+", type=int, default=[1011, 1012, 1013], help="the benches' seeds"
    )
    ap.add_argument(
        "--groups",
        nargs="*",
        default=list(GROUPS),
        choices=list(GROUPS),
        help="groups to take away one at a time (none: the bench as it is only)",
    )
    ap.add_argument(
        "--probe",
        choices=PROBES,
        default="instant",
        help="how a probe is measured: instant (the default) or frame (a frame later, as on a "
        "bench)",
    )
    ap.add_argument(
        "--ceiling", action="store_true", help="add the held and predicted ceilings of each bench"
    )
    ap.add_argument("--episodes", type=int, default=32)
    ap.add_argument("--eval-seed", type=int, default=4242)
    ap.add_argument("--out", type=Path, default=Path("results/imperfection_groups"))
    return ap


def _parse(argv) -> Namespace:
    """The parsed command line (``sets``: the parsed ``--set``); bad arguments fail naming them."""
    from agents.cli import parse_set
    from agents.registry import get

    ap = parser()
    args = ap.parse_args(argv)
    ap.check_least(args, episodes=1)
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
    return args


def main(argv=None) -> dict:
    """Measure, print the table and write ``OUT/imperfection_groups.json``: its content."""
    keep_ctrl_c()
    args = _parse(argv)
    rows = measure(args)
    result = {
        "command": "python -m benchmarks.imperfection_groups",
        "args": {k: str(v) for k, v in vars(args).items()},
        "host": platform.node(),
        "date": time.strftime("%Y-%m-%d"),
        "rows": rows,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / "imperfection_groups.json", result)
    print(table(rows, columns(args)))
    return result


if __name__ == "__main__":
    main()
