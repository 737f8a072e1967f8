"""gymnax adapter: ``make(stages, mode, **options) -> (env, env_params)`` as ``gymnax.make``
returns, for the gymnax generation installed (needs ``pip install -e ".[gymnax]"``;
``import ops_jax`` does not import gymnax)::

    from ops_jax.adapters import gymnax as gymnax_env
    env, env_params = gymnax_env.make(stages=5, mode="hard", model="phasor")
    obs, state = env.reset(key, env_params)
    # gymnax >= 1.0
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, env_params)

- ``env`` is a ``gymnax.environments.environment.Environment`` (``OPSGymnax``); ``env_params`` an
  ``OPSGymnaxParams``, a gymnax ``EnvParams`` holding ``max_steps_in_episode`` (the truncation, from
  ``max_steps``; a dynamic field: ``env_params.replace(max_steps_in_episode=50)``) and ``ops``, the
  ``ops_jax.EnvParams``. The state is the ``ops_jax.EnvState``. Spaces: gymnax ``Box`` (observation:
  the Gymnasium adapter's bounds; action: [-1, 1]^N float32, 0.01 wl per unit by default).
- gymnax >= 1.0: the six-value step ``(obs, state, reward, terminated, truncated, info)`` from
  ``step_env`` (the transition without reset), ``is_truncated`` (``t >= max_steps_in_episode`` and
  not terminated) and the auto-reset; ``info`` has ``terminated``, ``truncated``,
  ``final_observation`` (the finished episode's last observation) and the ``OPSEnv`` step's keys
  (``normalized_power``, ...).
- gymnax 0.0.x: the five-value step ``(obs, state, reward, done, info)``,
  ``done = terminated or truncated``, with ``info["terminated"]``, ``info["truncated"]`` and
  ``info["final_observation"]``.
- auto-reset: ``OPSEnv.auto_reset``, not a fresh ``reset_env``: the next episode carries the episode
  count (hard mode's drift ramps with it, as in every ops-jax adapter), and under ``jax.vmap`` the
  reset is computed only on steps where some instance ends, so ``vmap(env.step)`` costs what
  ``OPSEnv.step_batch`` does.
- transition gradients (gymnax >= 1.0, ``env.with_transition_gradients()``): the observation and
  state after ``step`` are differentiable with respect to the action and the incoming state (offsets
  in wl, frames) through the physics model, field or phasor; the PRNG draws are constants, the
  action's gradient is zero where it is clipped to [-1, 1], and through an auto-reset the new
  episode's start carries no gradient. Without it the observation and state are detached (gymnax's
  default); the reward is differentiable with respect to the action either way.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

from ops_jax.cli import extras
from ops_jax.env import OPSEnv
from ops_jax.env import make as make_ops
from ops_jax.adapters.gymnasium.shared import observation_bounds
from ops_jax.records import EnvParams, EnvState

try:
    from flax import struct
    from gymnax.environments import environment, spaces
except ModuleNotFoundError as e:
    if e.name is not None and e.name.split(".")[0] in ("gymnax", "flax"):
        raise ImportError(
            f"ops_jax.adapters.gymnax needs gymnax: {extras.install_command('gymnax')}"
        ) from e
    raise

SIX_VALUE_STEP = hasattr(environment.Environment, "is_truncated")  # gymnax >= 1.0
"""True where the installed gymnax steps ``(obs, state, reward, terminated, truncated, info)``."""


@struct.dataclass
class OPSGymnaxParams(environment.EnvParams):
    """gymnax ``EnvParams``: ``max_steps_in_episode`` (steps) and ``ops``, the
    ``ops_jax.EnvParams``."""

    max_steps_in_episode: int = 200
    ops: EnvParams = None


class OPSGymnax(environment.Environment):
    """N-stage optical pulse stacking as a gymnax ``Environment`` over ``OPSEnv`` (see the module
    docstring)."""

    _supports_transition_gradients = True

    def __init__(self, ops_env: OPSEnv, ops_params: EnvParams):
        super().__init__()
        self.ops_env = ops_env
        self._default_params = OPSGymnaxParams(
            max_steps_in_episode=ops_env.config.max_steps, ops=ops_params
        )

    @property
    def default_params(self) -> OPSGymnaxParams:
        return self._default_params

    @property
    def name(self) -> str:
        return "OPS-v0"

    @property
    def num_actions(self) -> int:
        return self.ops_env.num_actions

    def action_space(self, params: OPSGymnaxParams | None = None) -> spaces.Box:
        """[-1, 1]^N float32 (wl per unit: ``params.ops.action_scale``)."""
        return spaces.Box(-1.0, 1.0, (self.ops_env.num_actions,), jnp.float32)

    def observation_space(self, params: OPSGymnaxParams | None = None) -> spaces.Box:
        """A finite Box from the parameters' physics and noise (the Gymnasium adapter's bounds)."""
        ops_params = (self.default_params if params is None else params).ops
        try:
            bound = observation_bounds(self.ops_env, ops_params)
        except (
            jax.errors.ConcretizationTypeError,
            jax.errors.TracerArrayConversionError,
        ):  # traced: the defaults' bounds
            bound = observation_bounds(self.ops_env, self.default_params.ops)
        return spaces.Box(
            jnp.asarray(-bound), jnp.asarray(bound), (self.ops_env.observation_size,), jnp.float32
        )

    def reset_env(self, key: jax.Array, params: OPSGymnaxParams) -> tuple[jax.Array, EnvState]:
        """A first episode: (obs, state)."""
        return self.ops_env.reset(key, params.ops)

    def is_terminated(self, state: EnvState, params: OPSGymnaxParams) -> jax.Array:
        """A delay left the +-window (wl)."""
        return jnp.any(jnp.abs(state.deltas) > params.ops.window)

    def is_truncated(self, state: EnvState, params: OPSGymnaxParams) -> jax.Array:
        """``max_steps_in_episode`` steps done and not terminated."""
        return (state.t >= params.max_steps_in_episode) & ~self.is_terminated(state, params)

    def is_terminal(self, state: EnvState, params: OPSGymnaxParams) -> jax.Array:
        """Terminated or truncated (gymnax 0.0.x's ``done``)."""
        return self.is_terminated(state, params) | self.is_truncated(state, params)

    def step_env(self, key: jax.Array, state: EnvState, action, params: OPSGymnaxParams):
        """The transition without reset: (obs, state, reward, terminated, info) for gymnax >= 1.0,
        (obs, state, reward, done, info) with ``info["terminated"]`` / ``info["truncated"]`` for
        gymnax 0.0.x."""
        self.ops_env.check_action(action)
        obs, state, reward, terminated, _, info = self.ops_env.step_env(
            key, state, action, params.ops
        )
        if SIX_VALUE_STEP:
            obs, state = self._apply_transition_gradient_policy(obs, state)
            return obs, state, reward, terminated, info
        truncated = self.is_truncated(state, params)
        return (
            obs,
            state,
            reward,
            terminated | truncated,
            {**info, "terminated": terminated, "truncated": truncated},
        )

    @partial(jax.jit, static_argnames=("self",))
    def step(self, key: jax.Array, state: EnvState, action, params: OPSGymnaxParams | None = None):
        """One step with auto-reset: six values on gymnax >= 1.0, five on 0.0.x (module
        docstring)."""
        params = self.default_params if params is None else params
        k_step, k_reset = jax.random.split(key)
        obs_st, state_st, reward, done, info = self.step_env(k_step, state, action, params)
        if SIX_VALUE_STEP:
            terminated, truncated = done, self.is_truncated(state_st, params)
            done = terminated | truncated
            info = {**info, "terminated": terminated, "truncated": truncated}
        obs, state = self.ops_env.auto_reset(
            done, k_reset, state_st, (obs_st, state_st), params.ops
        )
        info = {**info, "final_observation": obs_st}
        if SIX_VALUE_STEP:
            return obs, state, reward, info["terminated"], info["truncated"], info
        return obs, state, reward, done, info


def make(stages: int = 5, mode: str = "hard", **options: Any) -> tuple[OPSGymnax, OPSGymnaxParams]:
    """``(env, env_params)`` as ``gymnax.make`` returns; every ``ops_jax.make`` option is accepted
    (checked there: a bad value raises naming the option and its range)."""
    ops_env, ops_params = make_ops(stages, mode, **options)
    env = OPSGymnax(ops_env, ops_params)
    return env, env.default_params
