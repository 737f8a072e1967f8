"""The jitted functions of the Gymnasium adapters (``ops_jax.adapters.gymnasium.env``), built once
per configuration and shared by every adapter of it."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from ops_jax.env import make
from ops_jax.adapters.gymnasium.codec import SCALARS, FlatCodec, pack


def split_step_keys(key, num_envs: int):
    """The vector env's key schedule: (next carried key, one key per instance for this step)."""
    key, sub = jax.random.split(key)
    return key, jax.random.split(sub, num_envs)


def _options_key(stages, mode, options):
    try:
        key = (stages, mode, tuple(sorted(options.items())))
        hash(key)
        return key
    except TypeError:  # unhashable option values: build without caching
        return None


_FN_CACHE: dict = {}


def _cached(kind, stages, mode, options, build):
    """Jitted functions shared by all adapters of one configuration (gymnasium.make, check_env and
    make_vec re-create environments; sharing avoids recompiling each time)."""
    key = _options_key(stages, mode, options)
    if key is None:
        return build()
    key = (kind,) + key
    if key not in _FN_CACHE:
        _FN_CACHE[key] = build()
    return _FN_CACHE[key]


def single_fns(stages, mode, options):
    """(step, reset, codec, head) of the single-instance adapter. The whole carry (key, state)
    travels as one float32 vector behind the packed step output, so a step is one jitted call with
    two inputs and one output (the adapter is dispatch-bound otherwise)."""

    def build():
        env, params = make(stages, mode, **options)
        n, d = env.num_actions, env.observation_size
        key0 = jax.random.key(0)
        template = jax.eval_shape(lambda k: (jax.random.key_data(k), env.reset(k, params)[1]), key0)
        codec = FlatCodec(template)
        head = d + SCALARS + n

        def step(buf, action):
            key_data, state = codec.unflatten(buf[head:])
            key, sub = jax.random.split(jax.random.wrap_key_data(key_data))
            obs, state, reward, term, trunc, info = env.step_env(sub, state, action, params)
            packed = pack(obs, reward, term, trunc, info)
            return jnp.concatenate([packed, codec.flatten((jax.random.key_data(key), state))])

        def reset(key, episode, buf, fresh):
            # fresh (a seeded start): p_init measured now; else carried from buf (the "reference"
            # reward's P at the first reset of the run).
            key, k_reset = jax.random.split(key)
            obs, state = env.reset(k_reset, params, episode)
            p_init = jnp.where(fresh, state.p_init, codec.unflatten(buf[head:])[1].p_init)
            state = dataclasses.replace(state, p_init=p_init)
            packed = (
                jnp.zeros(head, jnp.float32).at[:d].set(obs).at[d + SCALARS :].set(state.deltas)
            )
            return jnp.concatenate([packed, codec.flatten((jax.random.key_data(key), state))])

        return jax.jit(step), jax.jit(reset), codec, head

    return _cached("single", stages, mode, options, build)


def vector_fns(num_envs, stages, mode, options):
    """(reset, step) of the vector adapter: one jitted call over the batch each."""

    def build():
        env, params = make(stages, mode, **options)
        b = num_envs

        def reset(key, episodes):
            key, sub = jax.random.split(key)
            keys = jax.random.split(sub, b)
            obs, states = jax.vmap(env.reset, in_axes=(0, None, 0))(keys, params, episodes)
            return (key, states), obs

        def step(carry, actions):
            key, states = carry
            key, keys = split_step_keys(key, b)
            obs, states, reward, term, trunc, info = env.step_batch(keys, states, actions, params)
            return (key, states), pack(obs, reward, term, trunc, info, (info["final_observation"],))

        return jax.jit(reset), jax.jit(step)

    return _cached(f"vector{num_envs}", stages, mode, options, build)
