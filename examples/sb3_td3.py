"""Interoperability proof: stable-baselines3 TD3 on the Gymnasium adapter of ops-jax.

Trains TD3 on ``gymnasium.make("ops_jax/OPS-v0", stages=3, mode="easy")`` for a short budget and
prints the final P/Pmax of test episodes (deterministic policy) next to doing nothing.

    pip install torch stable-baselines3   # not part of ops-jax's extras
    python examples/sb3_td3.py [--steps 6000] [--seed 0] [--torch-threads 1]

The budget is tiny next to the paper's (TD3 on 5 stages: about 1e6 steps); it shows the plumbing,
not a tuned result.
"""

from __future__ import annotations

import os

# torch's thread pool, sized to every core, competes with JAX's for the same cores: one thread keeps
# the small networks fast on a laptop. Read when torch loads, so set before anything imports it.
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402

import ops_jax  # noqa: F401, E402  (registers "ops_jax/OPS-v0")

ENV_KWARGS = dict(stages=3, mode="easy", model="phasor", max_steps=100)


def final_power(env, act, episodes: int, seed: int) -> np.ndarray:
    """P/Pmax after the last step of ``episodes`` test episodes run with ``act(obs) -> action``."""
    finals = []
    for i in range(episodes):
        obs, _ = env.reset(seed=seed + i, options={"episode": 10})
        done = False
        while not done:
            obs, _, term, trunc, info = env.step(act(obs))
            done = term or trunc
        finals.append(info["normalized_power"])
    return np.array(finals)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=6000, help="TD3 training steps")
    ap.add_argument("--episodes", type=int, default=10, help="test episodes")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        help="torch's CPU threads (default 1: JAX uses the cores)",
    )
    args = ap.parse_args(argv)

    try:
        import torch
        from stable_baselines3 import TD3
        from stable_baselines3.common.noise import NormalActionNoise
    except ImportError as exc:
        raise SystemExit(
            f"examples/sb3_td3.py needs torch and stable-baselines3 ({exc}): "
            "pip install torch stable-baselines3"
        )
    torch.set_num_threads(args.torch_threads)

    env = gymnasium.make("ops_jax/OPS-v0", **ENV_KWARGS)
    n = env.action_space.shape[0]
    model = TD3(
        "MlpPolicy",
        env,
        learning_rate=1e-3,
        buffer_size=100_000,
        learning_starts=500,
        batch_size=256,
        train_freq=1,
        gradient_steps=1,
        action_noise=NormalActionNoise(np.zeros(n), 0.2 * np.ones(n)),
        policy_kwargs=dict(net_arch=[64, 64]),
        seed=args.seed,
        verbose=0,
    )
    t0 = time.perf_counter()
    model.learn(total_timesteps=args.steps)
    train_s = time.perf_counter() - t0

    test_env = gymnasium.make("ops_jax/OPS-v0", **ENV_KWARGS)
    td3 = final_power(
        test_env, lambda obs: model.predict(obs, deterministic=True)[0], args.episodes, 10_000
    )
    idle = final_power(test_env, lambda obs: np.zeros(n, np.float32), args.episodes, 10_000)
    print(f"TD3, {args.steps} steps on {ENV_KWARGS} ({train_s:.0f} s)")
    print(
        f"final P/Pmax  TD3: {td3.mean():.3f} +- {td3.std():.3f}   no control: {idle.mean():.3f} "
        f"+- {idle.std():.3f}"
    )
    return td3


if __name__ == "__main__":
    main()
