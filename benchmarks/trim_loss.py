"""Whether the trim (``agents.controllers.trim``) loses: policies alone and trimmed, on the same
test episodes.

    python -m benchmarks.trim_loss --seeds 0 1 2 3 4 5 6 7 --episodes 128 --out results/trim_loss
    python -m benchmarks.trim_loss --trims default guarded --envs "hard + lab" --seeds 4 5 6 7
    python -m benchmarks.trim_loss --trims default guarded --offsets 0.001 -0.001 \\
        --envs "hard + lab"
    python -m benchmarks.trim_loss --algo physics --config frames \\
        --envs "hard + 2x lab, frames only" --seeds 0
    python -m benchmarks.trim_loss --trims default guarded bench --envs "hard + lab" \\
        --seeds 4 5 6 7 --probe frame

``--algo`` at its ``--config`` preset (DroQ at its budget preset by default: 20,000 env steps, the
seeds in one vmapped call; a controller with nothing to learn, e.g. ``physics``, once per seed) on
each environment, each policy evaluated alone and with each of the trim's presets (``TrimConfig``)
on the same test episodes (``agents.evaluate``'s ``--eval-seed``: the same starts and the same
noise; the trim's dither has a key stream of its own). Per (environment, seed, trim): the mean final
P / P_best of both, the episodes the trim loses by more than ``--margin`` of P / P_best and those it
gains by more, and the worst paired difference. ``--offsets``: the same comparison for the policy
alone with every action shifted by a constant (no trim), the floor of what any perturbation of that
size loses or gains episode by episode. ``--probe frame``: the test episodes read the trim's probe a
frame later, as a bench does (``ops_jax`` ``EnvConfig.probe``; training is the same). Prints the
table and writes ``trim_loss.json``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from agents import TrimConfig
from agents.io import write_json_atomic
from ops_jax.env import PROBES
from ops_jax.cli.progress import keep_ctrl_c
from benchmarks.sweep.reality import LEVELS, level_env

ENVS = {
    "hard": dict(stages=5, mode="hard", model="phasor"),
    "hard + lab": dict(stages=5, mode="hard", model="phasor", imperfections="lab"),
    # the reality section's 2x lab, the detector's frames alone
    "hard + 2x lab, frames only": dict(level_env(dict(LEVELS)["2x lab"]), observe_lengths=False),
}
DEFAULT_ENVS = ("hard", "hard + lab")


def paired(alone: np.ndarray, trimmed: np.ndarray, margin: float) -> dict:
    """The comparison of final P / P_best per episode, alone against trimmed (same episodes, same
    order)."""
    diff = trimmed - alone
    return {
        "alone": float(alone.mean()),
        "trimmed": float(trimmed.mean()),
        "episodes": int(diff.size),
        "lost": int(np.sum(diff < -margin)),
        "gained": int(np.sum(diff > margin)),
        "worst": float(diff.min()),
        "worst_alone": float(alone[diff.argmin()]),
        "worst_trimmed": float(trimmed[diff.argmin()]),
    }


def shifted(result, offset: float):
    """``(Policy, params)``: ``result``'s policy with every action shifted by ``offset`` (clipped to
    [-1, 1])."""
    import jax.numpy as jnp

    from agents.api import Policy

    policy = result.policy()

    def act(params, carry, obs, key, probe):
        action, carry = policy.act(params, carry, obs, key, probe)
        return jnp.clip(action + offset, -1.0, 1.0), carry

    return Policy(policy.init, act), result.params


def measure(
    env_name: str,
    seeds,
    episodes: int,
    eval_seed: int,
    margin: float,
    steps: int,
    trims=("default",),
    offsets=(),
    algo: str = "droq",
    config: str = "budget",
    probe: str = "instant",
) -> list[dict]:
    """Train ``algo`` (its ``config`` preset) on ``ENVS[env_name]`` for ``seeds``; one row per seed
    and trim preset, then per seed and offset, the test episodes' probes read as ``probe`` says
    (``ops_jax.env.PROBES``)."""
    import agents
    from agents.controllers import trim

    env = ENVS[env_name]
    t0 = time.perf_counter()
    results = agents.train_seeds(
        algo, env, seeds=seeds, total_steps=steps, config=config, progress=False
    )
    train_s = time.perf_counter() - t0
    rows = []
    for seed, result in zip(seeds, results):
        final = lambda policy: agents.evaluate(
            policy, dict(env, probe=probe), episodes=episodes, seed=eval_seed
        ).normalized_power_best[:, -1]
        alone = final(result)
        variants = [(name, trim.trimmed(result, {"config": name})) for name in trims]
        variants += [(f"none, action {offset:+g}", shifted(result, offset)) for offset in offsets]
        rows += [
            {
                "env": env_name,
                "algo": algo,
                "seed": int(seed),
                "trim": name,
                **paired(alone, final(policy), margin),
                "train_s": train_s / len(seeds),
            }
            for name, policy in variants
        ]
    return rows


def table(rows: list, margin: float) -> str:
    head = (
        f"| environment | seed | trim | alone | trimmed | episodes | lost by > {margin:g} | "
        f"gained by > {margin:g} | worst difference (alone -> trimmed) |\n" + "|---" * 9 + "|"
    )
    body = [
        f"| {r['env']} | {r['seed']} | {r['trim']} | {r['alone']:.4f} | {r['trimmed']:.4f} | "
        f"{r['episodes']} | {r['lost']} | {r['gained']} | "
        f"{r['worst']:+.3f} ({r['worst_alone']:.3f} -> {r['worst_trimmed']:.3f}) |"
        for r in rows
    ]
    return "\n".join([head, *body])


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.trim_loss``."""
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.trim_loss", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--algo", default="droq", help="the policy's algorithm (agents.train's name)")
    ap.add_argument("--config", default="budget", help="its preset")
    ap.add_argument("--envs", nargs="+", default=list(DEFAULT_ENVS), choices=list(ENVS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    ap.add_argument("--episodes", type=int, default=128)
    ap.add_argument("--eval-seed", type=int, default=4242)
    ap.add_argument(
        "--margin", type=float, default=0.05, help="a loss or gain counts beyond this P / P_best"
    )
    ap.add_argument("--steps", type=int, default=20_000, help="env steps of training per seed")
    ap.add_argument(
        "--trims",
        nargs="+",
        default=["default"],
        choices=sorted(TrimConfig.PRESETS),
        help="the trim's presets (TrimConfig)",
    )
    ap.add_argument(
        "--offsets",
        nargs="*",
        type=float,
        default=[],
        metavar="A",
        help="also the policy alone with every action shifted by A (action units, |A| "
        "< 1), no trim",
    )
    ap.add_argument(
        "--probe",
        choices=PROBES,
        default="instant",
        help="how the test episodes read a probe: instant (the default) or frame (a frame later, "
        "as on a bench)",
    )
    ap.add_argument("--out", type=Path, default=Path("results/trim_loss"))
    return ap


def _parse(argv) -> argparse.Namespace:
    """The parsed command line; bad arguments fail naming them."""
    ap = parser()
    args = ap.parse_args(argv)
    if args.episodes < 1 or args.steps < 1 or not args.margin >= 0:
        ap.error("--episodes and --steps must be >= 1 and --margin >= 0")
    if not all(abs(a) < 1 for a in args.offsets):
        ap.error(f"--offsets must be numbers in (-1, 1) (action units), got {args.offsets}")
    from agents.registry import REGISTRY, get

    if args.algo not in REGISTRY:
        ap.error(f"--algo must be one of {sorted(REGISTRY)}, got {args.algo!r}")
    if args.config not in get(args.algo).config.PRESETS:
        ap.error(
            f"--config must be one of {args.algo}'s presets "
            f"{sorted(get(args.algo).config.PRESETS)}, got {args.config!r}"
        )
    return args


def main(argv=None) -> dict:
    """Measure each environment, print the table and write ``OUT/trim_loss.json``: its content."""
    keep_ctrl_c()
    args = _parse(argv)
    rows = []
    for env_name in args.envs:
        new = measure(
            env_name,
            args.seeds,
            args.episodes,
            args.eval_seed,
            args.margin,
            args.steps,
            args.trims,
            args.offsets,
            args.algo,
            args.config,
            args.probe,
        )
        print("\n".join(table(new, args.margin).splitlines()[2:]), flush=True)
        rows += new
    result = {
        "command": "python -m benchmarks.trim_loss",
        "args": {k: str(v) for k, v in vars(args).items()},
        "rows": rows,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / "trim_loss.json", result)
    print(table(rows, args.margin))
    return result


if __name__ == "__main__":
    main()
