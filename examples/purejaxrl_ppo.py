"""A purejaxrl-style PPO (``ppo_continuous_action.py``'s structure) on the gymnax adapter of
ops-jax: the whole training run, environment steps included, is one jitted function of a PRNG key.

    pip install -e ".[gymnax,agents]"   # gymnax >= 1.0; flax and optax: network, optimiser
    python examples/purejaxrl_ppo.py [--timesteps 200000] [--num-envs 32] [--seed 0]

Written against gymnax's API only: ``env.reset`` / ``env.step`` (six values) vmapped over
``--num-envs``, gymnax's ``LogWrapper`` for episode returns, ``env.action_space(params)`` for the
action bounds. As in purejaxrl, ``done = terminated or truncated`` cuts the GAE (no bootstrap at
truncation). The budget is tiny next to the paper's; it shows the plumbing, not a tuned result.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

ENV_KWARGS = dict(stages=3, mode="easy", model="phasor", max_steps=50)
CONFIG = dict(
    lr=3e-4,
    num_envs=32,
    num_steps=50,
    update_epochs=4,
    num_minibatches=4,
    gamma=0.99,
    gae_lambda=0.95,
    clip_eps=0.2,
    ent_coef=0.0,
    vf_coef=0.5,
    max_grad_norm=0.5,
    hidden=64,
)


def _libraries():
    try:
        import flax.linen as nn
        import optax
        from gymnax.wrappers import LogWrapper

        from ops_jax.adapters import gymnax as gymnax_env
    except ImportError as e:
        sys.exit(
            f"examples/purejaxrl_ppo.py needs gymnax >= 1.0, flax and optax ({e}): pip install -e "
            '".[gymnax,agents]"'
        )
    if not gymnax_env.SIX_VALUE_STEP:
        sys.exit('examples/purejaxrl_ppo.py needs gymnax >= 1.0: pip install -e ".[gymnax,agents]"')
    return nn, optax, LogWrapper, gymnax_env


class Transition(NamedTuple):
    done: jax.Array
    action: jax.Array
    value: jax.Array
    reward: jax.Array
    log_prob: jax.Array
    obs: jax.Array
    info: dict


def gaussian_log_prob(x, mean, log_std):
    """log N(x; mean, exp(log_std)^2) summed over the last axis."""
    return jnp.sum(
        -0.5 * ((x - mean) / jnp.exp(log_std)) ** 2 - log_std - 0.5 * jnp.log(2 * jnp.pi), axis=-1
    )


def make_train(timesteps: int, config: dict | None = None, **env_kwargs):
    """purejaxrl's ``make_train``: returns ``train(key) -> (runner state, metrics)``, jittable, and
    the config."""
    nn, optax, LogWrapper, gymnax_env = _libraries()
    c = {**CONFIG, **(config or {})}
    c["num_updates"] = max(1, timesteps // (c["num_envs"] * c["num_steps"]))
    c["minibatch_size"] = c["num_envs"] * c["num_steps"] // c["num_minibatches"]
    env, env_params = gymnax_env.make(**{**ENV_KWARGS, **env_kwargs})
    env = LogWrapper(env)
    space = env.action_space(env_params)
    n_act = space.shape[0]

    class ActorCritic(nn.Module):
        @nn.compact
        def __call__(self, x):
            h = nn.tanh(nn.Dense(c["hidden"])(x))
            h = nn.tanh(nn.Dense(c["hidden"])(h))
            mean = nn.Dense(n_act, kernel_init=nn.initializers.orthogonal(0.01))(h)
            log_std = self.param("log_std", nn.initializers.constant(-0.5), (n_act,))
            v = nn.tanh(nn.Dense(c["hidden"])(x))
            v = nn.tanh(nn.Dense(c["hidden"])(v))
            return (
                mean,
                log_std,
                jnp.squeeze(nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0))(v), -1),
            )

    network = ActorCritic()
    tx = optax.chain(optax.clip_by_global_norm(c["max_grad_norm"]), optax.adam(c["lr"], eps=1e-5))
    vreset = jax.vmap(env.reset, in_axes=(0, None))
    vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def train(key):
        key, k_net, k_reset = jax.random.split(key, 3)
        obs_dim = env.observation_space(env_params).shape[0]
        params = network.init(k_net, jnp.zeros(obs_dim))
        opt_state = tx.init(params)
        obs, env_state = vreset(jax.random.split(k_reset, c["num_envs"]), env_params)

        def update_step(runner, _):
            def env_step(runner, _):
                params, opt_state, env_state, obs, key = runner
                key, k_act, k_env = jax.random.split(key, 3)
                mean, log_std, value = network.apply(params, obs)
                action = mean + jnp.exp(log_std) * jax.random.normal(k_act, mean.shape)
                log_prob = gaussian_log_prob(action, mean, log_std)
                clipped = jnp.clip(action, space.low, space.high)
                obs2, env_state, reward, terminated, truncated, info = vstep(
                    jax.random.split(k_env, c["num_envs"]), env_state, clipped, env_params
                )
                t = Transition(terminated | truncated, action, value, reward, log_prob, obs, info)
                return (params, opt_state, env_state, obs2, key), t

            runner, traj = jax.lax.scan(env_step, runner, None, c["num_steps"])
            params, opt_state, env_state, last_obs, key = runner
            _, _, last_val = network.apply(params, last_obs)

            def gae(carry, t):
                adv, next_value = carry
                delta = t.reward + c["gamma"] * next_value * (1 - t.done) - t.value
                adv = delta + c["gamma"] * c["gae_lambda"] * (1 - t.done) * adv
                return (adv, t.value), adv

            _, advantages = jax.lax.scan(
                gae, (jnp.zeros_like(last_val), last_val), traj, reverse=True
            )
            targets = advantages + traj.value

            def update_epoch(state, _):
                params, opt_state, key = state
                key, k_perm = jax.random.split(key)
                batch = jax.tree.map(
                    lambda x: x.reshape((-1,) + x.shape[2:]),
                    (traj.obs, traj.action, traj.log_prob, advantages, targets),
                )
                perm = jax.random.permutation(k_perm, batch[0].shape[0])
                mbs = jax.tree.map(
                    lambda x: x[perm].reshape((c["num_minibatches"], -1) + x.shape[1:]), batch
                )

                def update_minibatch(state, mb):
                    params, opt_state = state
                    obs, action, old_log_prob, adv, target = mb

                    def loss_fn(params):
                        mean, log_std, value = network.apply(params, obs)
                        log_prob = gaussian_log_prob(action, mean, log_std)
                        ratio = jnp.exp(log_prob - old_log_prob)
                        a = (adv - adv.mean()) / (adv.std() + 1e-8)
                        actor = -jnp.minimum(
                            ratio * a, jnp.clip(ratio, 1 - c["clip_eps"], 1 + c["clip_eps"]) * a
                        ).mean()
                        critic = 0.5 * ((value - target) ** 2).mean()
                        entropy = jnp.sum(log_std + 0.5 * jnp.log(2 * jnp.pi * jnp.e))
                        return actor + c["vf_coef"] * critic - c["ent_coef"] * entropy, (
                            actor,
                            critic,
                        )

                    (loss, (actor, critic)), grads = jax.value_and_grad(loss_fn, has_aux=True)(
                        params
                    )
                    updates, opt_state = tx.update(grads, opt_state)
                    return (optax.apply_updates(params, updates), opt_state), (loss, actor, critic)

                (params, opt_state), losses = jax.lax.scan(
                    update_minibatch, (params, opt_state), mbs
                )
                return (params, opt_state, key), losses

            (params, opt_state, key), losses = jax.lax.scan(
                update_epoch, (params, opt_state, key), None, c["update_epochs"]
            )
            info = traj.info
            done = info["returned_episode"]
            metrics = {
                "episode_return": jnp.where(done, info["returned_episode_returns"], 0).sum()
                / jnp.maximum(done.sum(), 1),
                "final_normalized_power": jnp.where(done, info["normalized_power"], 0).sum()
                / jnp.maximum(done.sum(), 1),
                "episodes": done.sum(),
                "loss": losses[0].mean(),
            }
            return (params, opt_state, env_state, last_obs, key), metrics

        runner = (params, opt_state, env_state, obs, key)
        return jax.lax.scan(update_step, runner, None, c["num_updates"])

    return train, c


def train(
    timesteps: int = 200_000, seed: int = 0, config: dict | None = None, **env_kwargs
) -> dict:
    """Run ``make_train`` jitted; returns per update the env steps, mean episode return, final
    P/Pmax, loss."""
    fn, c = make_train(timesteps, config, **env_kwargs)
    start = time.perf_counter()
    _, metrics = jax.block_until_ready(jax.jit(fn)(jax.random.key(seed)))
    metrics = jax.tree.map(np.asarray, metrics)
    per_update = c["num_envs"] * c["num_steps"]
    return {
        "env_steps": [per_update * (i + 1) for i in range(c["num_updates"])],
        "seconds": time.perf_counter() - start,
        **{k: v.tolist() for k, v in metrics.items()},
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--timesteps", type=int, default=200_000, help="env steps in all")
    ap.add_argument("--num-envs", type=int, default=CONFIG["num_envs"])
    ap.add_argument(
        "--num-steps", type=int, default=CONFIG["num_steps"], help="steps per instance per update"
    )
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    out = train(a.timesteps, a.seed, {"num_envs": a.num_envs, "num_steps": a.num_steps})
    every = max(1, len(out["env_steps"]) // 10)
    for i in range(0, len(out["env_steps"]), every):
        print(
            f"{out['env_steps'][i]:>8} env steps   return {out['episode_return'][i]:8.3f}   "
            f"final P/Pmax {out['final_normalized_power'][i]:.3f}   loss {out['loss'][i]:.4f}"
        )
    print(f"{out['env_steps'][-1]} env steps in {out['seconds']:.1f} s (compilation included)")


if __name__ == "__main__":
    main()
