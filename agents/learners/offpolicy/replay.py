"""The building blocks that an off-policy learner's ``build`` wires
(``agents.learners.offpolicy.td3``, ``agents.learners.offpolicy.droq``; the training driver is
``agents.learners.offpolicy.driver``): observation statistics, train states, brax's replay queue,
the jitted exploration / update loop (``replay_loop``, its functions a ``Loop``), the MLP and the
fields every training state holds. Each reads its settings from the learner's config (a
``ReplayConfig``)."""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from agents.learners import budgets
from agents.config import COUNT, HISTORY, UNIT, AlgoConfig, choice, field, optional
from ops_jax.env import REWARDS

# the reward an off-policy learner trains on (``ops_jax.REWARDS``; None: the env_config's own)
TRAIN_REWARD = optional(choice(*REWARDS))
# what an off-policy learner adds to its observation, and whether its action corrects the fit's move
# (``agents.learners.offpolicy.observer``)
OBSERVER = choice("none", "fit", "fit-residual")


@dataclasses.dataclass(frozen=True)
class ReplayConfig(AlgoConfig):
    """Base of the off-policy learners' configs (``agents.learners.offpolicy.driver``): gradient
    steps per iteration are ``updates_per_iter``, or ``utd_ratio`` per env step (exactly one of the
    two); the observer's fields (``agents.learners.offpolicy.observer``), keyword-only, are common
    to them."""

    observer: str = field(OBSERVER, default="none", kw_only=True)
    # with observer="fit-residual": the fit's move plus this times the learner's action is sent
    residual_scale: float = field(UNIT, default=1.0, kw_only=True)
    # with an observer: the fit's random starts and iterations per start (None: the physics "frames"
    # preset's)
    fit_starts: int | None = field(optional(COUNT), default=None, kw_only=True)
    fit_iters: int | None = field(optional(COUNT), default=None, kw_only=True)
    # with an observer: the earlier frames its fit compares with the latest (None: the "frames"
    # preset's, 1)
    fit_history: int | None = field(optional(HISTORY), default=None, kw_only=True)

    def budget_layout(self) -> tuple[int, int, str]:
        """The random warm-up, then iterations of ``num_envs * unroll`` env steps
        (``agents.learners.budgets``)."""
        per_iter = self.num_envs * self.unroll
        warm = budgets.ceil_to(self.learning_starts, per_iter)
        rounded = (
            f", rounded up to iterations of {per_iter}" if warm != self.learning_starts else ""
        )
        return (
            warm,
            per_iter,
            f"the random warm-up (learning_starts = {self.learning_starts:,}{rounded})",
        )

    def trained_units(self, units: int) -> int:
        """Whole chunks of about ``eval_every`` env steps, whole iterations each."""
        per_chunk = max(1, self.eval_every // (self.num_envs * self.unroll))
        chunks = -(-units // per_chunk)
        return chunks * (units // chunks) if chunks else 0

    def updates_per_step(self) -> float:
        return updates_per_iter(self) / (self.num_envs * self.unroll)

    def check(self):
        """One of updates_per_iter and utd_ratio, a whole number of gradient steps per iteration,
        the buffer and batch sizes."""
        c = self
        if (c.updates_per_iter is None) == (c.utd_ratio is None):
            raise ValueError(
                f"set exactly one of updates_per_iter (gradient steps per iteration) and utd_ratio "
                f"(per env step), the other None; got {c.updates_per_iter!r} and {c.utd_ratio!r}"
            )
        if c.utd_ratio is not None:
            per_iter = c.utd_ratio * c.num_envs * c.unroll
            if per_iter < 1 or abs(per_iter - round(per_iter)) > 1e-6:
                raise ValueError(
                    "utd_ratio * num_envs * unroll must be a whole number >= 1 of gradient steps "
                    f"per iteration, got {c.utd_ratio!r} * {c.num_envs} * {c.unroll}"
                )
        if c.buffer_size < c.num_envs * c.unroll:
            raise ValueError(
                f"buffer_size must be >= num_envs * unroll = {c.num_envs * c.unroll}, got "
                f"{c.buffer_size}"
            )
        if c.learning_starts < c.batch_size:
            raise ValueError(
                f"learning_starts must be >= batch_size = {c.batch_size}, got {c.learning_starts}"
            )
        if c.batch_size > c.buffer_size:
            raise ValueError(
                f"batch_size must be <= buffer_size = {c.buffer_size}, got {c.batch_size}"
            )


# The fields of every training state after its learned ones (name, type):
# ``NamedTuple(name, [*learned, *STATE])``.
STATE = [
    ("obs_norm", Any),
    ("buffer", Any),
    ("env_state", Any),
    ("obs", jax.Array),
    ("key", jax.Array),
    ("updates", jax.Array),  # gradient steps so far
    ("env_params", Any),
]  # an argument, not a constant: one program serves every mode


def normalise(norm, obs):
    return (obs - norm["mean"]) / norm["std"]


def updates_per_iter(c: ReplayConfig) -> int:
    """Gradient steps per iteration: ``updates_per_iter``, or ``utd_ratio * num_envs * unroll``."""
    if c.updates_per_iter is not None:
        return c.updates_per_iter
    return round(c.utd_ratio * c.num_envs * c.unroll)


def identity_norm(d: int) -> dict:
    """Observation statistics that leave ``d``-dimensional observations unchanged."""
    return {"mean": jnp.zeros(d), "std": jnp.ones(d)}


def train_state(params, tx):
    """A flax TrainState with an array step count (vmapped over seeds like every leaf)."""
    from flax.training.train_state import TrainState

    return TrainState.create(apply_fn=None, params=params, tx=tx).replace(step=jnp.int32(0))


def replay_buffer(env, c: ReplayConfig):
    """brax's uniform replay queue of (obs, action, reward, discount, next_obs) transitions."""
    from brax.training.replay_buffers import UniformSamplingQueue

    d, n = env.observation_size, env.num_actions
    dummy = dict(
        obs=jnp.zeros(d),
        action=jnp.zeros(n),
        reward=jnp.zeros(()),
        discount=jnp.zeros(()),
        next_obs=jnp.zeros(d),
    )
    return UniformSamplingQueue(c.buffer_size, dummy, c.batch_size)


def initial_state(state_type, env, c: ReplayConfig, buffer, actor, critic, learned: Callable):
    """``init(key, env_params)``: a fresh training state of ``state_type``, its learned fields
    ``learned(actor params, critic params)`` (a tuple, in the state's order), then ``STATE``'s:
    identity observation statistics, the empty ``buffer``, the first env states and observations of
    ``num_envs`` instances, the run key, no gradient step yet."""
    d, n = env.observation_size, env.num_actions

    def init(key, env_params):
        k_a, k_c, k_buf, k_env, k_run = jax.random.split(key, 5)
        dummy_obs, dummy_act = jnp.zeros((1, d)), jnp.zeros((1, n))
        obs, env_state = env.reset_batch(jax.random.split(k_env, c.num_envs), env_params)
        ap, cp = actor.init(k_a, dummy_obs), critic.init(k_c, dummy_obs, dummy_act)
        fresh = (identity_norm(d), buffer.init(k_buf), env_state, obs, k_run, jnp.int32(0))
        return state_type(*learned(ap, cp), *fresh, env_params)

    return init


def gradient_step(state, loss: Callable, *args, has_aux: bool = False):
    """(``loss(state.params, *args)``'s value (with its aux), ``state`` after one gradient step on
    it): a flax TrainState's step."""
    value, grads = jax.value_and_grad(loss, has_aux=has_aux)(state.params, *args)
    return value, state.apply_gradients(grads=grads)


def delayed(ts, c: ReplayConfig, actor_step):
    """``actor_step(ts) -> (ts, actor loss)`` every ``policy_delay`` gradient steps (NaN loss
    otherwise), then the gradient step count advanced."""
    ts, aloss = jax.lax.cond(
        ts.updates % c.policy_delay == 0, actor_step, lambda ts: (ts, jnp.float32(jnp.nan)), ts
    )
    return ts._replace(updates=ts.updates + 1), aloss


class Loop(NamedTuple):
    """A learner's training functions (what its ``build`` returns): ``init(key, env_params) -> ts``,
    ``warmup(ts, n, random) -> (ts, observations (T, D))``, ``fit_norm(ts, obs) -> ts``,
    ``train_chunk(ts, n) -> (ts, chunk-mean metrics)``, ``explore(ts, key, obs, random) -> actions``
    and ``update(ts, _) -> (ts, (critic_loss, actor_loss))``."""

    init: Callable
    warmup: Callable
    fit_norm: Callable
    train_chunk: Callable
    explore: Callable
    update: Callable


def collector(env, c: ReplayConfig, buffer, explore):
    """``collect(ts, random) -> (ts, (rewards, observations))``: ``unroll`` batched env steps of
    ``num_envs`` instances at ``explore``'s actions (uniform random ones with ``random``), each
    step's transitions inserted into ``buffer``."""

    def env_step(ts, key, random):
        k_act, k_env = jax.random.split(key)
        action = explore(ts, k_act, ts.obs, random)
        obs2, env_state, reward, term, _, info = env.step_batch(
            jax.random.split(k_env, c.num_envs), ts.env_state, action, ts.env_params
        )
        tr = dict(
            obs=ts.obs,
            action=action,
            reward=reward,
            discount=1.0 - term.astype(jnp.float32),
            next_obs=info["final_observation"],
        )
        return ts._replace(env_state=env_state, obs=obs2), tr

    def collect(ts, random):
        def body(ts, _):
            key, k = jax.random.split(ts.key)
            ts, tr = env_step(ts._replace(key=key), k, random)
            return ts._replace(buffer=buffer.insert(ts.buffer, tr)), (tr["reward"], tr["obs"])

        return jax.lax.scan(body, ts, None, length=c.unroll)

    return collect


def fit_norm(c: ReplayConfig, ts, obs):
    """``ts`` with the observation statistics frozen from the warm-up's observations ``obs`` (T, D)
    that the buffer holds (the last ``buffer_size``); std floored at 1e-2. Unchanged without
    ``normalize_obs``."""
    if not c.normalize_obs:
        return ts
    kept = obs[-c.buffer_size :]
    mean = kept.mean(0)
    std = jnp.sqrt(((kept - mean) ** 2).mean(0))
    return ts._replace(obs_norm={"mean": mean, "std": jnp.maximum(std, 1e-2)})


def replay_loop(env, c: ReplayConfig, buffer, init, explore, update) -> Loop:
    """The ``Loop`` around ``init``, ``explore(ts, key, obs, random) -> actions`` and
    ``update(ts, _) -> (ts, (critic_loss, actor_loss))`` (one gradient step, sampling ``buffer``):
    ``warmup(ts, n, random)`` (n iterations of uniform random actions, or of the policy's
    exploration with ``random=False``; returns their observations (T, D)), ``fit_norm`` and
    ``train_chunk(ts, n)`` (n iterations, returns chunk-mean metrics); ``explore`` and ``update``
    are kept as they are (a bench learner steps them one at a time, ``agents.bench.learning``)."""
    collect, d = collector(env, c, buffer, explore), env.observation_size

    def iteration(ts, _):
        ts, (reward, _) = collect(ts, False)
        ts, (closs, aloss) = jax.lax.scan(update, ts, None, length=updates_per_iter(c))
        return ts, dict(
            reward=reward.mean(), critic_loss=closs.mean(), actor_loss=jnp.nanmean(aloss)
        )

    def train_chunk(ts, length):
        ts, m = jax.lax.scan(iteration, ts, None, length=length)
        return ts, jax.tree.map(jnp.mean, m)

    def warmup(ts, length, random=True):
        def body(ts, _):
            ts, (_, obs) = collect(ts, random)
            return ts, obs

        ts, obs = jax.lax.scan(body, ts, None, length=length)
        return ts, obs.reshape(-1, d)

    return Loop(init, warmup, functools.partial(fit_norm, c), train_chunk, explore, update)


def mlp_module():
    """The flax MLP of the off-policy learners: ``MLP(hidden, out, layer_norm, dropout)``; each
    hidden layer is Dense, then Dropout (rate ``dropout``, active when called with ``train=True``),
    then LayerNorm (if ``layer_norm``), then ReLU (DroQ's critic order)."""
    import flax.linen as nn

    class MLP(nn.Module):
        hidden: tuple
        out: int
        layer_norm: bool = False
        dropout: float = 0.0

        @nn.compact
        def __call__(self, x, train: bool = False):
            for h in self.hidden:
                x = nn.Dense(h)(x)
                if self.dropout > 0:
                    x = nn.Dropout(self.dropout, deterministic=not train)(x)
                if self.layer_norm:
                    x = nn.LayerNorm()(x)
                x = nn.relu(x)
            return nn.Dense(self.out)(x)

    return MLP
