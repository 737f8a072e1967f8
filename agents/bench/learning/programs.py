"""What an off-policy learner on a bench is built of (``Built``: its settings, environments and
functions) and its jitted programs (``Programs``), compiled once before the run
(``agents.bench.learning``)."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from agents.envs import built, train_env_config
from agents.learners.offpolicy import observer, replay
from ops_jax import EnvSpec


@dataclasses.dataclass(frozen=True)
class Built:
    """A learner on a bench: ``learner`` (``agents.learners.offpolicy.learner.Learner``), the
    ``env_config`` it is built for, its ``config`` (of ``learner.config_type``) and the stored form
    ``hyper`` its builders read, the ``seed``; ``env`` the simulator environment whose observations
    the bench's frames follow, ``train_env`` the one it learns on (with the observer's entries, if
    any), ``observer`` (or None), ``fns`` (``learner.build``), ``ratio``."""

    learner: Any
    env_config: dict
    config: Any
    hyper: dict
    seed: int
    env: Any
    train_env: Any
    observer: Any
    fns: Any  # agents.learners.offpolicy.replay.Loop
    ratio: float  # the target gradient steps per env step (the config's update-to-data ratio)


def build(learner, env_config: dict, config, seed: int):
    """(``Built`` of ``learner`` with ``config`` on ``env_config``, the env params)."""
    hyper = config.to_hyper()
    env, env_params = built(train_env_config(env_config, config.train_reward))
    train_env = learner.training_env(env, EnvSpec.from_options(env_config), config)
    seen = train_env.observer if isinstance(train_env, observer.Observed) else None
    fns = learner.build(train_env, config)
    ratio = config.updates_per_step()
    parts = Built(learner, env_config, config, hyper, seed, env, train_env, seen, fns, ratio)
    return parts, env_params


def acting(ts):
    """What the exploration reads of a training state: the actor's parameters and the observation
    statistics."""
    return ts._replace(
        actor=ts.actor.replace(opt_state=None),
        **{f: None for f in ts._fields if f not in ("actor", "obs_norm")},
    )


class Programs(NamedTuple):
    """The compiled programs: ``act`` (the actor's exploration; with an observer also its fit:
    ``act(carry, frame, t, snap, random) -> (obs, action, sent, carry)``, else
    ``act(snap, t, obs, random) -> action``), ``insert`` (a transition into the buffer), ``update``
    (one gradient step), ``fit_norm`` (the observation statistics of the warm-up); with an observer
    ``init_seen`` (its carry from a first frame) and ``moved`` (told the move sent), else None."""

    act: Callable
    insert: Callable
    update: Callable
    fit_norm: Callable
    init_seen: Callable | None = None
    moved: Callable | None = None


def _explore(parts: Built):
    """The exploration action (N,) of a snapshot at env step ``t`` and observation (D,)."""
    k_act = jax.random.fold_in(jax.random.key(parts.seed), 1)

    def explore(snap, t, obs, random):
        return parts.fns.explore(snap, jax.random.fold_in(k_act, t), obs[None], random)[0]

    return explore


def _insert(parts: Built):
    """Store one transition, its reward the configuration's at the next frame's power, discount 1
    (a continuing task)."""
    env, d_raw = parts.env, parts.env.observation_size
    buffer = replay.replay_buffer(parts.train_env, parts.config)

    def insert(ts, obs, action, next_obs, p_init):
        power = env.layout.power(next_obs[:d_raw]) * env.p_max
        reward = env.reward(power, p_init).astype(jnp.float32)
        tr = dict(
            obs=obs, action=action, reward=reward, discount=jnp.float32(1.0), next_obs=next_obs
        )
        return ts._replace(buffer=buffer.insert(ts.buffer, jax.tree.map(lambda x: x[None], tr)))

    return insert


def _observed(parts: Built, ts, act) -> dict:
    """The observer's programs: ``act`` (the fit's entries, the action, the move sent),
    ``init_seen``, ``moved``."""
    ob, explore, d_raw = parts.observer, _explore(parts), parts.env.observation_size
    k_observe = jax.random.fold_in(jax.random.key(parts.seed), 2)
    raw = jax.ShapeDtypeStruct((1, d_raw), jnp.float32)

    def act_observed(carry, frame, t, snap, random):
        seen, carry = ob.observe(None, carry, frame[None], jax.random.fold_in(k_observe, t))
        action = explore(snap, t, seen[0], random)
        sent = ob.command(carry, action[None])
        return seen[0], action, sent[0], ob.moved(None, carry, sent)

    carry = jax.eval_shape(ob.init, None, raw)
    frame = jax.ShapeDtypeStruct((d_raw,), jnp.float32)
    moved = jax.jit(lambda carry, sent: ob.moved(None, carry, sent[None]))
    return dict(
        act=jax.jit(act_observed)
        .lower(carry, frame, jnp.int32(0), acting(ts), jnp.bool_(True))
        .compile(),
        init_seen=jax.jit(lambda obs: ob.init(None, obs)).lower(raw).compile(),
        moved=moved.lower(carry, act).compile(),
    )


def compile_programs(parts: Built, ts) -> Programs:
    """Compile exploration, insertion, gradient step and the statistics' fit for the training state
    ``ts`` before the run."""
    d, n = parts.train_env.observation_size, parts.env.num_actions
    obs, act = jax.ShapeDtypeStruct((d,), jnp.float32), jax.ShapeDtypeStruct((n,), jnp.float32)
    if parts.observer is None:
        explore = jax.jit(_explore(parts))
        acts = {"act": explore.lower(acting(ts), jnp.int32(0), obs, jnp.bool_(True)).compile()}
    else:
        acts = _observed(parts, ts, act)
    scalar = jax.ShapeDtypeStruct((), jnp.float32)
    insert = jax.jit(_insert(parts), donate_argnums=0).lower(ts, obs, act, obs, scalar).compile()
    update = jax.jit(lambda ts: parts.fns.update(ts, None)[0], donate_argnums=0)
    warm = jax.ShapeDtypeStruct((parts.config.learning_starts, d), jnp.float32)
    fit_norm = jax.jit(parts.fns.fit_norm).lower(ts, warm).compile()
    return Programs(insert=insert, update=update.lower(ts).compile(), fit_norm=fit_norm, **acts)
