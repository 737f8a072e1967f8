"""The fit observer (``observer="fit"`` of the off-policy learners,
``agents.learners.offpolicy.driver``): the line offsets that the physics-informed controller's fit
reads from the detector's frames (``agents.controllers.physics_informed``, preset "frames", its
state estimation alone) appended to the learner's observation, so that a learner without length
readouts (``observe_lengths=False``) sees an estimate of the state instead of a sign-ambiguous
frame. With ``observer="fit-residual"`` the learner's action is also a correction added to the fit's
own move.

The appended entries: the fitted stages' offsets from the nearest optimum (wl, in [-0.25, 0.25)),
estimated from the newest frame and, through the move the learner commanded before it, the frame
before (``fit_history`` H: the H frames before, through the moves since each). On the first frame of
an episode (or of a bench run) the fit has no history. Training (``Observed``) and the stored policy
(``Learner.make_policy``) run the same estimate, so a checkpoint acts on the raw observation of the
env or bench.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from agents.controllers import physics_informed
from agents.api import Policy
from agents.envs import built
from ops_jax import EnvSpec


class Observer(NamedTuple):
    """``size``: entries appended; ``init(key, obs (B, D)) -> carry``;
    ``observe(params, carry, obs, key) -> (obs (B, D + size), carry)``;
    ``command(carry, action (B, N)) -> (B, N)`` the move sent for the learner's action;
    ``moved(params, carry, command (B, N)) -> carry`` records the move sent. ``params``:
    ``physics_informed.policy_params`` (None: those of the env_config)."""

    size: int
    init: Callable
    observe: Callable
    command: Callable
    moved: Callable


def fit_observer(
    env_config: EnvSpec | dict,
    residual: bool = False,
    residual_scale: float = 1.0,
    starts: int | None = None,
    iters: int | None = None,
    history: int | None = None,
) -> Observer:
    """The fit observer of the environment ``env_config`` (an ``EnvSpec`` or a dict of its
    options); with ``residual``, ``residual_scale`` times the learner's action is a correction
    added to the fitted model's own move (the physics-informed controller's, clipped to [-1, 1]
    after the sum). ``starts``, ``iters``, ``history``: the fit's random starts,
    Levenberg-Marquardt iterations per start and earlier frames compared (None: the "frames"
    preset's)."""
    sizes = {
        k: v
        for k, v in (("starts", starts), ("iters", iters), ("history", history))
        if v is not None
    }
    estimator = physics_informed.make_policy(
        env_config, physics_informed.PhysicsConfig.make("frames", **sizes)
    )
    default = physics_informed.policy_params(env_config)
    env = built(env_config)[0]
    fit = physics_informed.fitted_stages(env.config)

    def init(key, obs):
        return dict(
            estimator.init(key, obs), prior=jnp.zeros((obs.shape[0], env.num_actions), jnp.float32)
        )

    def observe(params, carry, obs, key):
        prior, carry = estimator.act(default if params is None else params, carry, obs, key, None)
        carry = dict(
            carry, dz_prev=jnp.zeros_like(carry["dz_prev"]), prior=prior
        )  # ``moved`` records the real move
        return jnp.concatenate([obs, carry["z"]], axis=-1), carry

    def command(carry, action):
        return jnp.clip(carry["prior"] + residual_scale * action, -1.0, 1.0) if residual else action

    return Observer(
        fit, init, observe, command, estimator.sent
    )  # moved: the fit records the move sent


def of_learner(env_spec: EnvSpec, c) -> Observer | None:
    """The observer of a learner's config ``c`` (a ``ReplayConfig``: ``observer`` "fit" or
    "fit-residual"; None for "none"; ``residual_scale``, ``fit_starts``, ``fit_iters``,
    ``fit_history``) on its training environment ``env_spec``."""
    if c.observer == "none":
        return None
    return fit_observer(
        env_spec,
        residual=c.observer == "fit-residual",
        residual_scale=c.residual_scale,
        starts=c.fit_starts,
        iters=c.fit_iters,
        history=c.fit_history,
    )


def policy(observer: Observer, act: Callable):
    """``agents.api.Policy`` that observes, then acts by
    ``act(params, obs (B, D + size)) -> action (B, N)``."""

    def act_observed(params, carry, obs, key, probe):
        del probe
        seen, carry = observer.observe(None, carry, obs, key)
        sent = observer.command(carry, act(params, seen))
        return sent, observer.moved(None, carry, sent)

    return Policy(
        observer.init, act_observed, lambda params, carry, sent: observer.moved(None, carry, sent)
    )


class Observed:
    """The batched environment a learner with the fit observer trains on: ``reset_batch`` and
    ``step_batch`` of ``env`` with the observer's entries appended (the final observation's too) and
    its carry in the state (``(env state, carry)``); the estimate's random starts are drawn from the
    first instance's step key. Other attributes are ``env``'s."""

    def __init__(self, env, observer: Observer):
        self.env, self.observer = env, observer
        self.observation_size = env.observation_size + observer.size

    def __getattr__(self, name):
        return getattr(self.env, name)

    def _first(self, p, obs, key):
        """(observation, carry) of a fit without history at ``obs``."""
        return self.observer.observe(p, self.observer.init(key, obs), obs, key)

    def reset_batch(self, keys, params):
        obs, state = self.env.reset_batch(keys, params)
        seen, carry = self._first(
            physics_informed.params_of(params), obs, jax.random.fold_in(keys[0], 1)
        )
        return seen, (state, carry)

    def step_batch(self, keys, states, actions, params):
        state, carry = states
        sent = self.observer.command(carry, actions)
        obs, state, reward, terminated, truncated, info = self.env.step_batch(
            keys, state, sent, params
        )
        p = physics_informed.params_of(params)
        k_final, k_reset = jax.random.split(jax.random.fold_in(keys[0], 1))
        final, carry = self.observer.observe(
            p, self.observer.moved(p, carry, sent), info["final_observation"], k_final
        )
        done = terminated | truncated

        def restarted(carry):
            seen, fresh = self._first(p, obs, k_reset)
            pick = lambda a, b: jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
            return pick(seen, final), jax.tree.map(pick, fresh, carry)

        seen, carry = jax.lax.cond(jnp.any(done), restarted, lambda carry: (final, carry), carry)
        info = dict(info, final_observation=final)
        return seen, (state, carry), reward, terminated, truncated, info
