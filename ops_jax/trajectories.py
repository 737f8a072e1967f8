"""A policy run over a batch of OPS environments in one jitted scan (``rollout``), with the
trajectories and the completed episodes' summaries (``Rollout``)."""

from __future__ import annotations

from functools import partial
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from ops_jax.env import OPSEnv
from ops_jax.records import EnvParams


class Rollout(NamedTuple):
    """Trajectories (num_steps, num_envs, ...) and per-episode summaries of completed episodes."""

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    normalized_power: jax.Array
    metrics: dict


def rollout(
    env: OPSEnv, params: EnvParams, policy_fn: Callable, key, num_envs: int, num_steps: int
):
    """Run ``policy_fn(key, obs (num_envs, D)) -> actions (num_envs, N)`` for ``num_steps`` in one
    jitted ``lax.scan``. Instance i uses keys folded from ``key`` by i, so its trajectory does not
    depend on ``num_envs``. Returns a ``Rollout``; ``metrics`` holds the mean return, final P/Pmax
    and count of the episodes that ended within the rollout."""
    return _rollout(env, policy_fn, num_envs, num_steps, params, key)


@partial(jax.jit, static_argnums=(0, 1, 2, 3))
def _rollout(env, policy_fn, num_envs, num_steps, params, key):
    ids = jnp.arange(num_envs)
    k_reset, k_run = jax.random.split(key)
    obs, state = env.reset_batch(jax.vmap(jax.random.fold_in, (None, 0))(k_reset, ids), params)

    def body(carry, t):
        obs, state, ret = carry
        k_t = jax.random.fold_in(k_run, t)
        k_pol, k_env = jax.random.split(k_t)
        action = policy_fn(k_pol, obs)
        keys = jax.vmap(jax.random.fold_in, (None, 0))(k_env, ids)
        obs2, state2, reward, term, trunc, info = env.step_batch(keys, state, action, params)
        ret = ret + reward
        done = term | trunc
        out = (obs, action, reward, term, trunc, info["normalized_power"], ret, done)
        return (obs2, state2, jnp.where(done, 0.0, ret)), out

    _, (o, a, r, te, tr, npow, ret, done) = jax.lax.scan(
        body, (obs, state, jnp.zeros(num_envs)), jnp.arange(num_steps)
    )
    count = done.sum()
    safe = jnp.maximum(count, 1)
    metrics = {
        "num_episodes": count,
        "episode_return": jnp.where(done, ret, 0.0).sum() / safe,
        "final_normalized_power": jnp.where(done, npow, 0.0).sum() / safe,
    }
    return Rollout(o, a, r, te, tr, npow, metrics)
