"""TD3 (Fujimoto et al. 2018) in pure JAX, in the style of brax's trainers.

Flax (linen) networks in flax ``TrainState``s (optax Adam; targets by ``optax.incremental_update``),
brax's ``UniformSamplingQueue`` replay buffer, and the whole training loop as jitted ``lax.scan``
chunks over the batched ``ops_jax`` environment (``env.reset_batch`` / ``env.step_batch``,
``model="phasor"`` unless the env_config names a model); the loop, the seed batching and the driver
are ``agents.learners.offpolicy.driver``'s. Twin critics, target policy smoothing, delayed actor and
target updates, Gaussian exploration.

One training *iteration* = one batched env step of ``num_envs`` instances (exploration actions),
their insertion into the buffer, then ``updates_per_iter`` gradient steps (critic every step, actor
and targets every ``policy_delay`` steps); ``utd_ratio`` sets the same as gradient steps per env
step. With ``unroll`` > 1 (the paper's SB3 setting: 100 env steps, then 100 gradient steps) an
iteration collects ``unroll`` batched steps first. ``learning_starts`` >= ``batch_size`` is
required.

Presets of ``TD3Config`` (below): "paper" (the paper's Table 4), "fast" (32 envs, wall
clock on a 2-core CPU) and "budget" (few env steps: one env, many small updates per env step;
docs/learners.md).
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp

from agents import api as base  # noqa: F401  (brax_compat: quiet brax import)
from agents.learners.offpolicy import driver as offpolicy, replay
from agents.config import (
    COUNT,
    COUNT0,
    NONNEG,
    POSITIVE,
    UNIT,
    choice,
    field,
    flag,
    optional,
    widths,
)
from agents.learners.offpolicy.learner import Learner
from agents.learners.offpolicy.replay import TRAIN_REWARD, ReplayConfig
from agents.registry import Algo
from ops_jax.ranges import Range


@dataclasses.dataclass(frozen=True)
class TD3Config(ReplayConfig):
    """TD3 (``agents.learners.offpolicy.td3``): presets "paper" (the paper's Table 4), "fast" and
    "budget" (<= 20k env steps). Gradient steps per iteration: ``updates_per_iter``, or
    ``utd_ratio`` per env step (one of the two)."""

    NAME: ClassVar[str] = "TD3"
    PRESETS: ClassVar[dict] = {
        "paper": dict(
            num_envs=1,
            unroll=100,
            updates_per_iter=100,
            batch_size=100,
            hidden=(256, 256),
            actor_lr=3e-4,
            critic_lr=3e-4,
            gamma=0.98,
            tau=0.005,
            buffer_size=10_000,
            learning_starts=1000,
            expl_std=0.7,
            target_noise=0.2,
            noise_clip=0.5,
            policy_delay=2,
            normalize_obs=False,
            total_steps=300_000,
            eval_every=10_000,
            eval_episodes=16,
            utd_ratio=None,
            train_reward=None,
        ),
        "fast": dict(
            num_envs=32,
            unroll=1,
            updates_per_iter=4,
            batch_size=256,
            hidden=(256, 256),
            actor_lr=1e-3,
            critic_lr=1e-3,
            gamma=0.98,
            tau=0.005,
            buffer_size=100_000,
            learning_starts=4096,
            expl_std=0.4,
            target_noise=0.2,
            noise_clip=0.5,
            policy_delay=2,
            normalize_obs=True,
            total_steps=300_000,
            eval_every=20_000,
            eval_episodes=16,
            utd_ratio=None,
            train_reward=None,
        ),
        "budget": dict(
            num_envs=1,
            unroll=1,
            updates_per_iter=None,
            utd_ratio=10.0,
            batch_size=128,
            hidden=(64, 64),
            actor_lr=1e-3,
            critic_lr=1e-3,
            gamma=0.9,
            tau=0.005,
            buffer_size=20_000,
            learning_starts=1000,
            expl_std=0.2,
            target_noise=0.2,
            noise_clip=0.5,
            policy_delay=2,
            normalize_obs=True,
            total_steps=20_000,
            eval_every=1_000,
            eval_episodes=16,
            train_reward=None,
        ),
    }

    config: str = field(choice("paper", "fast", "budget"))
    num_envs: int = field(COUNT)
    unroll: int = field(COUNT)
    updates_per_iter: int | None = field(optional(COUNT))
    batch_size: int = field(COUNT)
    hidden: tuple = field(widths)
    actor_lr: float = field(POSITIVE)
    critic_lr: float = field(POSITIVE)
    gamma: float = field(UNIT)
    tau: float = field(UNIT)
    buffer_size: int = field(COUNT)
    learning_starts: int = field(COUNT0)
    expl_std: float = field(NONNEG)
    target_noise: float = field(NONNEG)
    noise_clip: float = field(NONNEG)
    policy_delay: int = field(COUNT)
    normalize_obs: bool = field(flag)
    total_steps: int = field(COUNT0)
    eval_every: int = field(COUNT)
    eval_episodes: int = field(COUNT)
    utd_ratio: float | None = field(optional(Range(0, 1e4, lo_open=True)))
    train_reward: str | None = field(TRAIN_REWARD)


ALGO = Algo("td3", __name__, TD3Config, "TD3", vmaps_seeds=True, off_policy=True)


# -- networks -----------------------------------------------------------------------------------


def _networks(c: TD3Config, num_actions: int):
    import flax.linen as nn

    MLP = replay.mlp_module()

    class Actor(nn.Module):
        @nn.compact
        def __call__(self, obs):
            return jnp.tanh(MLP(c.hidden, num_actions)(obs))

    class Critic(nn.Module):
        @nn.compact
        def __call__(self, obs, action):
            x = jnp.concatenate([obs, action], -1)
            return MLP(c.hidden, 1)(x)[..., 0], MLP(c.hidden, 1)(x)[..., 0]

    return Actor(), Critic()


def _greedy(actor, params, obs):
    """The deterministic action a = tanh(MLP(obs)) at standardised ``obs``."""
    return actor.apply(params, obs)


# -- training -----------------------------------------------------------------------------------

TD3State = NamedTuple(
    "TD3State",
    [
        ("actor", Any),  # flax TrainState: params, optimiser state
        ("critic", Any),
        ("actor_target", Any),
        ("critic_target", Any),
        *replay.STATE,
    ],
)


def _explorer(actor, c: TD3Config):
    """``explore(ts, key, obs, random)``: the greedy action plus Gaussian noise ``expl_std``
    (clipped to [-1, 1]), or uniform random actions where ``random``."""

    def explore(ts, key, obs, random):
        k1, k2 = jax.random.split(key)
        greedy = actor.apply(ts.actor.params, replay.normalise(ts.obs_norm, obs))
        noisy = jnp.clip(greedy + c.expl_std * jax.random.normal(k1, greedy.shape), -1, 1)
        uniform = jax.random.uniform(k2, greedy.shape, minval=-1, maxval=1)
        return jnp.where(random, uniform, noisy)

    return explore


def _losses(actor, critic, c: TD3Config):
    """(``critic_loss(critic params, ts, batch, key)``: the twin critics' squared TD errors to the
    clipped double-Q target at the smoothed target action; ``actor_loss(actor params, ts, batch)``:
    minus the first critic's Q)."""

    def critic_loss(cp, ts, batch, key):
        nobs = replay.normalise(ts.obs_norm, batch["next_obs"])
        obs = replay.normalise(ts.obs_norm, batch["obs"])
        a2 = actor.apply(ts.actor_target, nobs)
        noise = c.target_noise * jax.random.normal(key, a2.shape)
        a2 = jnp.clip(a2 + jnp.clip(noise, -c.noise_clip, c.noise_clip), -1, 1)
        q1t, q2t = critic.apply(ts.critic_target, nobs, a2)
        y = jax.lax.stop_gradient(
            batch["reward"] + c.gamma * batch["discount"] * jnp.minimum(q1t, q2t)
        )
        q1, q2 = critic.apply(cp, obs, batch["action"])
        return jnp.mean((q1 - y) ** 2 + (q2 - y) ** 2)

    def actor_loss(ap, ts, batch):
        obs = replay.normalise(ts.obs_norm, batch["obs"])
        q1, _ = critic.apply(ts.critic.params, obs, actor.apply(ap, obs))
        return -jnp.mean(q1)

    return critic_loss, actor_loss


def _updater(buffer, c: TD3Config, critic_loss, actor_loss):
    """``update(ts, _)``: one critic step on a sampled batch; every ``policy_delay`` steps an actor
    step and both targets moved by ``tau``."""
    import optax

    def actor_step(ts, batch):
        aloss, new_actor = replay.gradient_step(ts.actor, actor_loss, ts, batch)
        return ts._replace(
            actor=new_actor,
            actor_target=optax.incremental_update(new_actor.params, ts.actor_target, c.tau),
            critic_target=optax.incremental_update(ts.critic.params, ts.critic_target, c.tau),
        ), aloss

    def update(ts, _):
        buf, batch = buffer.sample(ts.buffer)
        key, k_noise = jax.random.split(ts.key)
        closs, new_critic = replay.gradient_step(ts.critic, critic_loss, ts, batch, k_noise)
        ts = ts._replace(critic=new_critic, buffer=buf, key=key)
        ts, aloss = replay.delayed(ts, c, lambda ts: actor_step(ts, batch))
        return ts, (closs, aloss)

    return update


def _build(env, c: TD3Config) -> replay.Loop:
    """TD3's training ``Loop`` on ``env``."""
    import optax

    actor, critic = _networks(c, env.num_actions)
    buffer = replay.replay_buffer(env, c)
    actor_tx, critic_tx = optax.adam(c.actor_lr), optax.adam(c.critic_lr)

    def learned(ap, cp):  # the actor and critic states, then their targets
        return replay.train_state(ap, actor_tx), replay.train_state(cp, critic_tx), ap, cp

    init = replay.initial_state(TD3State, env, c, buffer, actor, critic, learned)
    update = _updater(buffer, c, *_losses(actor, critic, c))
    return replay.replay_loop(env, c, buffer, init, _explorer(actor, c), update)


LEARNER = Learner("td3", TD3Config, _build, _networks, _greedy)
make_policy, params_template = LEARNER.make_policy, LEARNER.params_template


train, train_seeds = offpolicy.entry_points(
    LEARNER,
    __name__,
    """Train TD3 on ``built(env_config)`` (an ``ops_jax.EnvSpec`` or a dict of its options;
    phasor model unless set) for ``total_steps`` env steps (default: the config's); ``seed``
    (default 0). ``config``: a ``TD3Config`` or a preset name ("fast" default | "paper" |
    "budget"), the other keywords: overrides of its fields. ``progress_fn(step, metrics)`` is
    called after every evaluation with metrics normalized_power, critic_loss, actor_loss, reward,
    elapsed_s. Trains at most ``total_steps`` env steps (whole iterations,
    ``agents.learners.offpolicy.driver.schedule``); the curve's 'step' holds the true counts.
    ``start_from=result`` continues from an earlier run in this process
    (``agents.learners.offpolicy.driver``); ``checkpoints=Checkpoints(folder)`` checkpoints the
    run as it trains and continues the one stored there
    (``agents.learners.offpolicy.checkpoint``). Returns a ``TrainResult``.""",
    """``train`` for several ``seeds`` at once: one jitted call vmapped over the seeds (sharded
    over the local devices when they divide the seed count). Each seed makes the same random
    draws as when trained alone, but the batched matrix products round differently and training
    amplifies the difference (measured, 5-stage hard: parameters equal to 4e-7 after 40 gradient
    steps, apart by 0.13 after 800), so a seed's result depends on the seed list it was trained
    with, bitwise reproducibly for the same list; on as many devices as seeds it is the solo
    result. Wall times are the call's divided by the number of seeds
    (``wall_time["seeds_in_call"]``); ``progress_fn`` gets means over seeds. Returns one
    ``TrainResult`` per seed.""",
)
