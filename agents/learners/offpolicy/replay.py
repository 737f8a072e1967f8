"""The building blocks that an off-policy learner's ``build`` wires
(``agents.learners.offpolicy.td3``, ``agents.learners.offpolicy.droq``; the training driver is
``agents.learners.offpolicy.driver``): observation statistics, train states, brax's replay queue,
the jitted exploration / update loop, the MLP and the fields every training state holds."""

from __future__ import annotations

import dataclasses
from typing import Any

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
        return updates_per_iter(self.to_hyper()) / (self.num_envs * self.unroll)

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


def updates_per_iter(h: dict) -> int:
    """Gradient steps per iteration: ``updates_per_iter``, or ``utd_ratio * num_envs * unroll``."""
    if h["updates_per_iter"] is not None:
        return h["updates_per_iter"]
    return round(h["utd_ratio"] * h["num_envs"] * h["unroll"])


def identity_norm(d: int) -> dict:
    """Observation statistics that leave ``d``-dimensional observations unchanged."""
    return {"mean": jnp.zeros(d), "std": jnp.ones(d)}


def train_state(params, tx):
    """A flax TrainState with an array step count (vmapped over seeds like every leaf)."""
    from flax.training.train_state import TrainState

    return TrainState.create(apply_fn=None, params=params, tx=tx).replace(step=jnp.int32(0))


def replay_buffer(env, h):
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
    return UniformSamplingQueue(h["buffer_size"], dummy, h["batch_size"])


def start(env, h, buffer, actor, critic, key, env_params):
    """(actor params, critic params, buffer state, env state, first observations, run key) of a
    fresh run."""
    k_a, k_c, k_buf, k_env, k_run = jax.random.split(key, 5)
    dummy_obs, dummy_act = jnp.zeros((1, env.observation_size)), jnp.zeros((1, env.num_actions))
    obs, env_state = env.reset_batch(jax.random.split(k_env, h["num_envs"]), env_params)
    return (
        actor.init(k_a, dummy_obs),
        critic.init(k_c, dummy_obs, dummy_act),
        buffer.init(k_buf),
        env_state,
        obs,
        k_run,
    )


def delayed(ts, h, actor_step):
    """``actor_step(ts) -> (ts, actor loss)`` every ``policy_delay`` gradient steps (NaN loss
    otherwise), then the gradient step count advanced."""
    ts, aloss = jax.lax.cond(
        ts.updates % h["policy_delay"] == 0, actor_step, lambda ts: (ts, jnp.float32(jnp.nan)), ts
    )
    return ts._replace(updates=ts.updates + 1), aloss


def replay_loop(env, h, buffer, explore, update) -> dict:
    """The jitted-scan pieces of training around ``explore(ts, key, obs, random) -> actions`` and
    ``update(ts, _) -> (ts, (critic_loss, actor_loss))`` (one gradient step, sampling ``buffer``):
    ``warmup(ts, n, random)`` (n iterations of uniform random actions, or of the policy's
    exploration with ``random=False``; returns their observations (T, D)), ``fit_norm(ts, obs)`` and
    ``train_chunk(ts, n)`` (n iterations, returns chunk-mean metrics); and ``explore`` and
    ``update`` themselves (a bench learner steps them one at a time, ``agents.bench.learning``)."""
    b, d = h["num_envs"], env.observation_size

    def env_step(ts, key, random):
        k_act, k_env = jax.random.split(key)
        action = explore(ts, k_act, ts.obs, random)
        obs2, env_state, reward, term, _, info = env.step_batch(
            jax.random.split(k_env, b), ts.env_state, action, ts.env_params
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

        return jax.lax.scan(body, ts, None, length=h["unroll"])

    def iteration(ts, _):
        ts, (reward, _) = collect(ts, False)
        ts, (closs, aloss) = jax.lax.scan(update, ts, None, length=updates_per_iter(h))
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

    def fit_norm(ts, obs):
        """Freeze the observation statistics from the warm-up's observations ``obs`` (T, D) that
        the buffer holds (the last ``buffer_size``); std floored at 1e-2."""
        if not h["normalize_obs"]:
            return ts
        kept = obs[-h["buffer_size"] :]
        mean = kept.mean(0)
        std = jnp.sqrt(((kept - mean) ** 2).mean(0))
        return ts._replace(obs_norm={"mean": mean, "std": jnp.maximum(std, 1e-2)})

    return dict(
        warmup=warmup, fit_norm=fit_norm, train_chunk=train_chunk, explore=explore, update=update
    )


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
