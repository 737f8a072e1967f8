"""The budget run (5-stage hard, 20,000 env steps from scratch) with stable-baselines3 TD3 or SBX
CrossQ / DroQ on the Gymnasium adapter, for comparison with ``agents.train(..., config="budget")``.

    pip install torch stable-baselines3 sbx-rl   # not part of ops-jax's dependencies
    python examples/budget_baselines.py --algo sb3-td3 [--steps 20000] [--seed 11] [--episodes 32]
    python examples/budget_baselines.py --algo sbx-crossq
    python examples/budget_baselines.py --algo sbx-droq

Test episodes start as the 10th reset (hard mode's drift fully on), as in ``agents.evaluate``;
the score is the final-step P / P_max, mean over episodes. Torch uses one thread unless
OMP_NUM_THREADS says otherwise. Each library runs at its own documented defaults except the
update-to-data ratio of DroQ (20, the paper's; SBX's recipe: SAC with ``dropout_rate`` and
``layer_norm`` critics) and learning from 1,000 steps.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402

import ops_jax  # noqa: E402,F401  (registers "ops_jax/OPS-v0")

ENV_KWARGS = dict(stages=5, mode="hard", model="phasor")
ALGOS = ("sb3-td3", "sbx-crossq", "sbx-droq")


def _final_power():
    """The evaluation helper of examples/sb3_td3.py (one rollout loop for both examples)."""
    spec = importlib.util.spec_from_file_location("sb3_td3", Path(__file__).with_name("sb3_td3.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.final_power


def make_model(algo: str, env, seed: int):
    """The learner ``algo`` on ``env`` (imports torch / sbx only here)."""
    n = env.action_space.shape[0]
    if algo == "sb3-td3":
        import torch
        from stable_baselines3 import TD3
        from stable_baselines3.common.noise import NormalActionNoise

        torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))
        return TD3(
            "MlpPolicy",
            env,
            learning_starts=1000,
            action_noise=NormalActionNoise(np.zeros(n), 0.1 * np.ones(n)),
            seed=seed,
            verbose=0,
        )
    if algo == "sbx-crossq":
        from sbx import CrossQ

        return CrossQ("MlpPolicy", env, seed=seed, verbose=0)
    if (
        algo == "sbx-droq"
    ):  # SBX's DroQ recipe: SAC with dropout + LayerNorm critics, 20 updates per step
        from sbx import SAC

        return SAC(
            "MlpPolicy",
            env,
            learning_starts=1000,
            gradient_steps=20,
            policy_delay=20,
            policy_kwargs=dict(dropout_rate=0.01, layer_norm=True),
            seed=seed,
            verbose=0,
        )
    raise ValueError(f"algo must be one of {list(ALGOS)}, got {algo!r}")


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--algo", choices=ALGOS, default="sb3-td3")
    ap.add_argument("--steps", type=int, default=20_000, help="env steps of training")
    ap.add_argument("--episodes", type=int, default=32, help="test episodes")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--eval-seed", type=int, default=4242)
    args = ap.parse_args(argv)

    env = gymnasium.make("ops_jax/OPS-v0", **ENV_KWARGS)
    try:
        model = make_model(args.algo, env, args.seed)
    except ImportError as exc:
        raise SystemExit(
            f"{exc}: install the baselines with `pip install torch stable-baselines3 sbx-rl`"
        )
    t0 = time.perf_counter()
    model.learn(total_timesteps=args.steps)
    train_s = time.perf_counter() - t0
    test_env = gymnasium.make("ops_jax/OPS-v0", **ENV_KWARGS)
    finals = _final_power()(
        test_env,
        lambda obs: model.predict(obs, deterministic=True)[0],
        args.episodes,
        args.eval_seed,
    )
    out = dict(
        algo=args.algo,
        steps=args.steps,
        seed=args.seed,
        final_mean=float(finals.mean()),
        final_std=float(finals.std()),
        train_s=train_s,
    )
    print(
        f"{args.algo}, {args.steps} steps on {ENV_KWARGS}, seed {args.seed}: final P/Pmax "
        f"{finals.mean():.3f} +- {finals.std():.3f} over {args.episodes} episodes ({train_s:.0f} "
        "s of training)"
    )
    return out


if __name__ == "__main__":
    main()
