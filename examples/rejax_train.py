"""rejax's PPO and SAC on the gymnax adapter of ops-jax, unchanged:
``rejax.get_algo(name).create(env=env, env_params=env_params, ...)`` and one jitted
``algo.train(key)``.

rejax 0.1.3 unpacks gymnax 0.0.x's five-value step, so it runs with gymnax 0.0.9 (rejax's own
trainers stop on gymnax 1.x's six-value step); the adapter steps five values there.

    # a venv of its own: gymnax 0.0.x, not the [gymnax] extra
    pip install -e . "gymnax==0.0.9" "rejax==0.1.3"
    python examples/rejax_train.py [--algo ppo|sac] [--timesteps 20000] [--seed 0]

Each evaluation (every ``--eval-freq`` env steps) runs ``--eval-envs`` test episodes with the
deterministic policy and reports the mean return and the final P/Pmax. The budgets are tiny next to
the paper's; they show the plumbing, not a tuned result.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp

ENV_KWARGS = dict(stages=3, mode="easy", model="phasor", max_steps=50)
CONFIGS = {  # rejax keywords per algorithm (small networks, small batches: a CPU-sized run)
    "ppo": dict(
        num_envs=16,
        num_steps=50,
        num_epochs=4,
        num_minibatches=4,
        learning_rate=3e-4,
        agent_kwargs=dict(hidden_layer_sizes=(64, 64)),
    ),
    "sac": dict(
        num_envs=4,
        buffer_size=20_000,
        fill_buffer=500,
        batch_size=128,
        learning_rate=1e-3,
        agent_kwargs=dict(hidden_layer_sizes=(64, 64)),
    ),
}


def _rejax():
    """The rejax module; one line naming the install command when it (or gymnax) is missing."""
    try:
        import rejax
        from ops_jax.adapters import gymnax as gymnax_env
    except ImportError as e:
        sys.exit(
            f"examples/rejax_train.py needs rejax 0.1.3 on gymnax 0.0.x ({e}): "
            'pip install -e . "gymnax==0.0.9" "rejax==0.1.3"'
        )
    if gymnax_env.SIX_VALUE_STEP:
        sys.exit(
            "examples/rejax_train.py needs gymnax 0.0.x (rejax 0.1.3 unpacks five values per "
            "step): "
            'pip install "gymnax==0.0.9" "rejax==0.1.3"'
        )
    return rejax, gymnax_env


def eval_callback(num_envs: int, max_steps: int):
    """A rejax ``eval_callback``: (mean return, mean final P/Pmax) of ``num_envs`` test episodes,
    each ``max_steps`` steps from a reset (the adapter truncates there)."""

    def callback(algo, ts, rng):
        act = algo.make_act(ts)
        env, params = algo.env, algo.env_params
        keys = jax.random.split(rng, num_envs + 1)
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys[1:], params)

        def body(carry, k):
            obs, state, ret = carry
            ks = jax.random.split(k, (num_envs, 2))
            action = jax.vmap(act)(obs, ks[:, 0])
            obs, state, reward, _, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                ks[:, 1], state, action, params
            )
            return (obs, state, ret + reward), info["normalized_power"]

        (_, _, ret), power = jax.lax.scan(
            body, (obs, state, jnp.zeros(num_envs)), jax.random.split(keys[0], max_steps)
        )
        return ret.mean(), power[-1].mean()

    return callback


def train(
    algo: str = "ppo",
    timesteps: int = 20_000,
    seed: int = 0,
    eval_freq: int = 5_000,
    eval_envs: int = 16,
    config: dict | None = None,
    **env_kwargs,
) -> dict:
    """Train rejax's ``algo`` (``config``: rejax keywords over ``CONFIGS[algo]``) on the adapter;
    returns the evaluations (env steps, return, final P/Pmax) and the wall time (s, compilation
    included)."""
    rejax, gymnax_env = _rejax()
    kwargs = {**ENV_KWARGS, **env_kwargs}
    env, env_params = gymnax_env.make(**kwargs)
    agent = rejax.get_algo(algo).create(
        env=env,
        env_params=env_params,
        total_timesteps=timesteps,
        eval_freq=eval_freq,
        **{**CONFIGS[algo], **(config or {})},
    )
    agent = agent.replace(eval_callback=eval_callback(eval_envs, kwargs["max_steps"]))
    start = time.perf_counter()
    ts, (returns, power) = jax.block_until_ready(jax.jit(agent.train)(jax.random.key(seed)))
    seconds = time.perf_counter() - start
    steps = [i * eval_freq for i in range(len(returns))]
    return {
        "algo": algo,
        "env_steps": steps,
        "episode_return": [float(r) for r in returns],
        "final_normalized_power": [float(p) for p in power],
        "seconds": seconds,
        "global_step": int(ts.global_step),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--algo", default="ppo", choices=sorted(CONFIGS))
    ap.add_argument("--timesteps", type=int, default=20_000, help="env steps in all")
    ap.add_argument("--eval-freq", type=int, default=5_000, help="env steps between evaluations")
    ap.add_argument("--eval-envs", type=int, default=16, help="test episodes per evaluation")
    ap.add_argument(
        "--max-steps", type=int, default=ENV_KWARGS["max_steps"], help="steps per episode"
    )
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    out = train(a.algo, a.timesteps, a.seed, a.eval_freq, a.eval_envs, max_steps=a.max_steps)
    for step, ret, power in zip(
        out["env_steps"], out["episode_return"], out["final_normalized_power"]
    ):
        print(f"{a.algo}: {step:>8} env steps   return {ret:8.3f}   final P/Pmax {power:.3f}")
    print(f"{out['global_step']} env steps in {out['seconds']:.1f} s (compilation included)")


if __name__ == "__main__":
    main()
