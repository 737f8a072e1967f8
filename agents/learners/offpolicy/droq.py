"""DroQ (Hiraoka et al., ICLR 2022): SAC whose twin critics carry dropout and LayerNorm, trained at
a high update-to-data ratio, in pure JAX (flax, optax) on ``agents.learners.offpolicy.driver``'s
replay loop.

- Actor: tanh-squashed Gaussian, an MLP ``hidden`` giving the mean and log std (clipped to
  [-5, 2]); the evaluated policy is deterministic, tanh(mean).
- Critics: two MLPs ``critic_hidden``, each hidden layer Dense -> Dropout(``dropout``) ->
  LayerNorm (``layer_norm``) -> ReLU; dropout is on in every critic pass of training (targets too).
- Targets: y = r + gamma d (min_j Q'_j(s', a') - alpha log pi(a'|s')), a' ~ pi(s'); Polyak ``tau``
  after every critic step. Actor loss: alpha log pi(a|s) - mean_j Q_j(s, a), every ``policy_delay``
  critic steps, with the temperature alpha (log-parametrised, from ``init_alpha``, Adam
  ``alpha_lr``; 0 keeps it fixed) tuned to the entropy ``target_entropy`` per action dimension.
- Exploration: actions sampled from the policy; uniform random during the warm-up.

Preset "budget" of ``DroQConfig`` (below): one env, 10 gradient steps per env step, 2 x 64 networks,
LayerNorm critics without dropout (dropout doubled the cost of a step for no measured gain), gamma
0.97, the linear reward (``train_reward``), 20k env steps (docs/learners.md). Preset "bench": the
same, learning a bounded correction to the physics-informed fit's move
(``observer="fit-residual"``), for learning on a bench from its frames (docs/lab.md).
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
class DroQConfig(ReplayConfig):
    """DroQ (``agents.learners.offpolicy.droq``): SAC with dropout + LayerNorm critics at a high
    update-to-data ratio; preset "budget" (<= 20k env steps). Gradient steps as in ``TD3Config``."""

    NAME: ClassVar[str] = "DroQ"
    DEFAULT_PRESET: ClassVar[str] = "budget"
    PRESETS: ClassVar[dict] = {
        "budget": dict(
            num_envs=1,
            unroll=1,
            updates_per_iter=None,
            utd_ratio=10.0,
            batch_size=128,
            hidden=(64, 64),
            critic_hidden=(64, 64),
            dropout=0.0,
            layer_norm=True,
            actor_lr=1e-3,
            critic_lr=1e-3,
            alpha_lr=1e-3,
            init_alpha=0.1,
            target_entropy=-1.0,
            gamma=0.97,
            tau=0.005,
            buffer_size=20_000,
            learning_starts=1000,
            policy_delay=1,
            normalize_obs=True,
            total_steps=20_000,
            eval_every=1_000,
            eval_episodes=16,
            train_reward="linear",
        )
    }
    # learning on a bench from its frames (``agents.bench --learn droq``): a correction, a quarter
    # of the action range at most, added to the physics-informed fit's move, the fit at 4 starts x 6
    # iterations (a bench's pace)
    PRESETS["bench"] = dict(
        PRESETS["budget"], observer="fit-residual", residual_scale=0.25, fit_starts=4, fit_iters=6
    )

    config: str = field(choice("budget", "bench"))
    num_envs: int = field(COUNT)
    unroll: int = field(COUNT)
    updates_per_iter: int | None = field(optional(COUNT))
    utd_ratio: float | None = field(optional(Range(0, 1e4, lo_open=True)))
    batch_size: int = field(COUNT)
    hidden: tuple = field(widths)
    critic_hidden: tuple = field(widths)
    dropout: float = field(Range(0, 0.9))
    layer_norm: bool = field(flag)
    actor_lr: float = field(POSITIVE)
    critic_lr: float = field(POSITIVE)
    alpha_lr: float = field(NONNEG)
    init_alpha: float = field(POSITIVE)
    target_entropy: float = field(Range(-100, 100))
    gamma: float = field(UNIT)
    tau: float = field(UNIT)
    buffer_size: int = field(COUNT)
    learning_starts: int = field(COUNT0)
    policy_delay: int = field(COUNT)
    normalize_obs: bool = field(flag)
    total_steps: int = field(COUNT0)
    eval_every: int = field(COUNT)
    eval_episodes: int = field(COUNT)
    train_reward: str | None = field(TRAIN_REWARD)


ALGO = Algo("droq", __name__, DroQConfig, "DroQ", vmaps_seeds=True, off_policy=True)


LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


def _networks(c: DroQConfig, num_actions: int):
    import flax.linen as nn

    MLP = replay.mlp_module()

    class Actor(nn.Module):
        """(mean, log std) of the pre-tanh Gaussian."""

        @nn.compact
        def __call__(self, obs):
            out = MLP(c.hidden, 2 * num_actions)(obs)
            mean, log_std = jnp.split(out, 2, axis=-1)
            return mean, jnp.clip(log_std, LOG_STD_MIN, LOG_STD_MAX)

    class Critic(nn.Module):
        @nn.compact
        def __call__(self, obs, action, train: bool = False):
            x = jnp.concatenate([obs, action], -1)
            q = [
                MLP(c.critic_hidden, 1, c.layer_norm, c.dropout)(x, train)[..., 0] for _ in range(2)
            ]
            return jnp.stack(q)

    return Actor(), Critic()


def _greedy(actor, params, obs):
    """The deterministic action a = tanh(mean) at standardised ``obs``."""
    return jnp.tanh(actor.apply(params, obs)[0])


DroQState = NamedTuple(
    "DroQState",
    [
        ("actor", Any),
        ("critic", Any),
        ("critic_target", Any),
        ("log_alpha", Any),  # flax TrainState of {"log_alpha": the log temperature}
        *replay.STATE,
    ],
)


def _sample(actor, params, obs, key):
    """(action, log prob) of the tanh-Gaussian policy at normalised ``obs``."""
    mean, log_std = actor.apply(params, obs)
    u = mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape)
    logp = jnp.sum(
        -0.5 * ((u - mean) / jnp.exp(log_std)) ** 2 - log_std - 0.5 * jnp.log(2 * jnp.pi), -1
    )
    a = jnp.tanh(u)
    return a, logp - jnp.sum(jnp.log(1 - a**2 + 1e-6), -1)


def _explorer(actor):
    """``explore(ts, key, obs, random)``: an action sampled from the policy, or a uniform random one
    where ``random``."""

    def explore(ts, key, obs, random):
        k1, k2 = jax.random.split(key)
        sampled, _ = _sample(actor, ts.actor.params, replay.normalise(ts.obs_norm, obs), k1)
        uniform = jax.random.uniform(k2, sampled.shape, minval=-1, maxval=1)
        return jnp.where(random, uniform, sampled)

    return explore


def _losses(actor, critic, c: DroQConfig):
    """(``critic_loss(critic params, ts, obs, batch, key)``: both critics' squared errors to the
    soft target, dropout on; ``actor_loss(actor params, ts, obs, key) -> (loss, log probs)``:
    alpha log pi - the critics' mean Q)."""

    def critic_loss(cp, ts, obs, batch, key):
        k_pi, k_drop_t, k_drop = jax.random.split(key, 3)
        nobs = replay.normalise(ts.obs_norm, batch["next_obs"])
        a2, logp2 = _sample(actor, ts.actor.params, nobs, k_pi)
        q_t = critic.apply(ts.critic_target, nobs, a2, True, rngs={"dropout": k_drop_t}).min(0)
        alpha = jnp.exp(ts.log_alpha.params["log_alpha"])
        y = jax.lax.stop_gradient(
            batch["reward"] + c.gamma * batch["discount"] * (q_t - alpha * logp2)
        )
        q = critic.apply(cp, obs, batch["action"], True, rngs={"dropout": k_drop})
        return jnp.mean(jnp.sum((q - y) ** 2, 0))

    def actor_loss(ap, ts, obs, key):
        k_pi, k_drop = jax.random.split(key)
        a, logp = _sample(actor, ap, obs, k_pi)
        q = critic.apply(ts.critic.params, obs, a, True, rngs={"dropout": k_drop}).mean(0)
        return jnp.mean(jnp.exp(ts.log_alpha.params["log_alpha"]) * logp - q), logp

    return critic_loss, actor_loss


def _updater(buffer, c: DroQConfig, num_actions: int, critic_loss, actor_loss):
    """``update(ts, _)``: one critic step on a sampled batch, the critic target moved by ``tau``;
    every ``policy_delay`` steps an actor step and a temperature step towards the entropy
    ``target_entropy`` per action dimension."""
    import optax

    target_entropy = c.target_entropy * num_actions

    def actor_step(ts, obs, key):
        (aloss, logp), new_actor = replay.gradient_step(
            ts.actor, actor_loss, ts, obs, key, has_aux=True
        )
        alpha_grad = jax.lax.stop_gradient(-logp.mean() - target_entropy)  # d/d log_alpha
        return ts._replace(
            actor=new_actor,
            log_alpha=ts.log_alpha.apply_gradients(grads={"log_alpha": alpha_grad}),
        ), aloss

    def update(ts, _):
        buf, batch = buffer.sample(ts.buffer)
        key, k_critic, k_actor = jax.random.split(ts.key, 3)
        obs = replay.normalise(ts.obs_norm, batch["obs"])
        closs, new_critic = replay.gradient_step(ts.critic, critic_loss, ts, obs, batch, k_critic)
        ts = ts._replace(
            critic=new_critic,
            buffer=buf,
            key=key,
            critic_target=optax.incremental_update(new_critic.params, ts.critic_target, c.tau),
        )
        ts, aloss = replay.delayed(ts, c, lambda ts: actor_step(ts, obs, k_actor))
        return ts, (closs, aloss)

    return update


def _build(env, c: DroQConfig) -> replay.Loop:
    """DroQ's training ``Loop`` on ``env``."""
    import optax

    actor, critic = _networks(c, env.num_actions)
    buffer = replay.replay_buffer(env, c)
    actor_tx, critic_tx = optax.adam(c.actor_lr), optax.adam(c.critic_lr)
    alpha_tx = optax.adam(c.alpha_lr) if c.alpha_lr > 0 else optax.set_to_zero()

    def learned(ap, cp):  # the actor and critic states, the critic target, the temperature
        log_alpha = {"log_alpha": jnp.log(jnp.float32(c.init_alpha))}
        states = replay.train_state(ap, actor_tx), replay.train_state(cp, critic_tx)
        return *states, cp, replay.train_state(log_alpha, alpha_tx)

    init = replay.initial_state(DroQState, env, c, buffer, actor, critic, learned)
    update = _updater(buffer, c, env.num_actions, *_losses(actor, critic, c))
    return replay.replay_loop(env, c, buffer, init, _explorer(actor), update)


LEARNER = Learner("droq", DroQConfig, _build, _networks, _greedy)
make_policy, params_template = LEARNER.make_policy, LEARNER.params_template


train, train_seeds = offpolicy.entry_points(
    LEARNER,
    __name__,
    """Train DroQ on ``built(env_config)`` (an ``ops_jax.EnvSpec`` or a dict of its options;
    phasor model unless set) for ``total_steps`` env steps (default: the config's); ``seed``
    (default 0). ``config``: a ``DroQConfig`` or a preset name ("budget" default | "bench"), the
    other keywords: overrides of its fields; ``progress_fn`` and the curve as in
    ``agents.learners.offpolicy.td3.train``; ``start_from=result`` continues from an earlier run in
    this process (``agents.learners.offpolicy.driver``), ``checkpoints=Checkpoints(folder)``
    checkpoints it as it trains (``agents.learners.offpolicy.checkpoint``). Returns a
    ``TrainResult``.""",
    """``train`` for several ``seeds`` in one vmapped call (as
    ``agents.learners.offpolicy.td3.train_seeds``). Returns one ``TrainResult`` per seed.""",
)
