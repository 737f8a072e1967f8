"""Episodes of a controller as pictures: an animated GIF of the oscilloscope or one frame.

Command line (``python -m agents.episode [episode|frame] ...``; default ``episode``)::

    # animated GIF of a controlled episode
    # (policy: zero | random | an algorithm | a checkpoint folder)
    python -m agents.episode --stages 5 --mode hard --policy zero --steps 100 --out episode.gif
    # one oscilloscope frame (PNG) after --steps steps of the policy
    python -m agents.episode frame --stages 5 --mode hard --policy random --steps 0 --out scope.png

Episodes start as the 10th reset (hard mode's drift fully on) and run through the same rollout
as ``agents.evaluate`` (``agents.evaluation.evaluator``); the pictures use the exact field model
(``ops_jax.render``). ``--policy PATH`` loads an ``agents.save`` checkpoint and runs on the
checkpoint's own environment configuration.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ops_jax import physics, render
from agents import api as base, evaluation, registry
from ops_jax.cli.parser import ArgumentParser, run
from ops_jax.cli.progress import keep_ctrl_c
from agents.envs import built

DRIFT_EPISODE = 10  # episodes start as this reset of their environment, as in agents.evaluate


def get_policy(name: str, env_config: dict, seed: int = 0):
    """(Policy, params, env_config) for ``name``: "zero", "random", an algorithm of ``agents.ALGOS``
    (trained with ``agents.train``) or a checkpoint folder (``agents.load``; its own env_config is
    used)."""
    if name in ("zero", "random"):
        return builtin_policy(name, env_config["stages"]), None, env_config
    if name in base.ALGOS:
        # A controller with nothing to learn is evaluated as its training; one episode, as nothing
        # reads it here.
        curve = {} if registry.get(name).learner else {"curve_episodes": 1}
        result = base.train(name, env_config, seed=seed, progress=False, **curve)
        return result.policy(), result.params, env_config
    path = Path(name)
    if not path.exists():
        raise ValueError(
            f"policy must be zero, random, one of {sorted(base.ALGOS)} or a checkpoint folder; "
            f"{name!r} is none of these"
        )
    result = base.load(path)
    return result.policy(), result.params, result.env_spec.as_dict()


def builtin_policy(kind: str, stages: int) -> base.Policy:
    """Zero or uniform random actions (``kind`` "zero" | "random") for ``stages`` delay lines."""

    def act(params, carry, obs, key, probe):
        shape = (obs.shape[0], stages)
        if kind == "zero":
            return jnp.zeros(shape), carry
        return jax.random.uniform(key, shape, minval=-1.0, maxval=1.0), carry

    return base.Policy(lambda key, obs: (), act)


def run_episode(
    env_config: dict,
    policy,
    params=None,
    *,
    steps: int | None = None,
    seed: int = 0,
    episode: int = DRIFT_EPISODE,
) -> render.Episode:
    """One episode of ``policy`` (probes allowed) through ``agents.evaluation.evaluator``: the
    offsets after the reset and after every step, and their exact P / P_max (field model)."""
    env_config = base.check_env_config(env_config)
    env, env_params = built(env_config)
    steps = int(env.config.max_steps if steps is None else steps)
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    run = evaluation.evaluator(env, policy, steps, int(episode), trajectory=True)
    deltas = run(params, env_params, jax.random.key(seed), jnp.arange(1))[-1]
    deltas = np.asarray(deltas)[:, 0]
    p, _ = render.measure_frames(deltas, env.config.stages, env.config.detector)
    return render.Episode(deltas, p, dict(env_config))


def _parser():
    ap = ArgumentParser(
        prog="python -m agents.episode",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("command", nargs="?", default="episode", choices=("episode", "frame"))
    ap.add_argument("--stages", type=int, default=5, help="number of stages N")
    ap.add_argument("--mode", default="hard", help="easy | medium | hard | custom")
    ap.add_argument("--detector", default="total", choices=physics.DETECTORS)
    ap.add_argument(
        "--policy",
        default="zero",
        help="zero | random | spgd (or another agents algo) | checkpoint folder",
    )
    ap.add_argument(
        "--steps", type=int, default=None, help="control steps (episode: max_steps; frame: 0)"
    )
    ap.add_argument("--every", type=int, default=1, help="GIF: keep every k-th step")
    ap.add_argument("--fps", type=float, default=10.0, help="GIF frames per second")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dpi", type=int, default=None)
    ap.add_argument("--out", required=True, help="output file (.gif for episode, .png for frame)")
    return ap


def main(argv=None) -> Path:
    keep_ctrl_c()
    args = _parser().parse_args(argv)
    out = Path(args.out)
    if args.every < 1:
        raise ValueError(f"--every must be >= 1, got {args.every}")
    env_config = dict(stages=args.stages, mode=args.mode, detector=args.detector)
    policy, params, env_config = get_policy(args.policy, env_config, args.seed)
    if env_config.get("stages", 5) != args.stages:
        print(f"note: the checkpoint's env_config {env_config} is used", file=sys.stderr)
    steps = args.steps if args.steps is not None else (None if args.command == "episode" else 0)
    ep = run_episode(env_config, policy, params, steps=steps, seed=args.seed)
    env, _ = built(env_config)
    stages = env.config.stages
    if args.command == "frame":
        from PIL import Image, PngImagePlugin

        scope = render.Oscilloscope(stages, env.config.detector, dpi=args.dpi or 120)
        frame = scope.frame(ep.deltas_wl[-1], len(ep.deltas_wl) - 1)
        out.parent.mkdir(parents=True, exist_ok=True)
        info = PngImagePlugin.PngInfo()
        info.add_text("Title", scope.title.get_text())  # what the frame's title reads
        Image.fromarray(frame).save(out, pnginfo=info)
    else:
        titles = [
            render.frame_title(stages, ep.normalized_power[i], i)
            for i in render.frame_steps(len(ep.deltas_wl), args.every)
        ]
        render.write_gif(
            render.episode_frames(ep, every=args.every, dpi=args.dpi or 80),
            out,
            fps=args.fps,
            comment="\n".join(titles),
        )
    print(f"wrote {out}  (final P/Pmax = {ep.normalized_power[-1]:.3f})")
    return out


if __name__ == "__main__":
    run("python -m agents.episode", main)
