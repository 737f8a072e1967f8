"""Brax adapter: ``OPSBraxEnv``, a ``brax.envs.base.Env`` over the OPS environment.

Importing this module registers it as ``brax.envs.get_environment("ops", stages=5, mode="hard",
...)`` (idempotent). ``import ops_jax`` does not import brax; ``import ops_jax.adapters.brax`` does.

State layout (one instance; brax's ``VmapWrapper`` batches it):
- ``pipeline_state``: the ``ops_jax.EnvState`` (offsets in wl, drift, step count, frames);
- ``obs`` (D,), ``reward`` (paper reward, float32), ``done`` (float32: 1.0 when the delays left the
  window or ``max_steps`` was reached);
- ``metrics``: ``normalized_power`` (P/Pmax after the step) and ``final_normalized_power``
  (P/Pmax on the step that ends the episode, else 0: its episode sum, which brax's evaluator
  reports as ``eval/episode_final_normalized_power``, is the final P/Pmax);
- ``info``: ``rng`` (this instance's PRNG key, advanced every step), ``time_out`` (1.0 on a
  time-limit end, for PPO's ``bootstrap_on_timeout``), ``env_params`` (the ``ops_jax.EnvParams``,
  set by ``reset`` and read by ``step``: the step program then holds no mode-specific constants,
  so a trainer's compiled programs are shared by easy, medium and hard through JAX's persistent
  compilation cache).

Fresh starts under brax's training wrappers. ``AutoResetWrapper`` replaces a finished slot's
``pipeline_state`` / ``obs`` by ``info["first_pipeline_state"]`` / ``info["first_obs"]``, cached
once at reset, so every episode of a slot would start from the same delays with the same drift.
Here each ``step`` draws the next episode's start from ``info["rng"]`` (new offsets; the episode
counter advanced, so hard mode's drift ramps and is redrawn) and, when those cache keys exist,
writes it into them: whatever the wrapper restores (on our termination or on ``EpisodeWrapper``'s
time limit) is a fresh random start. ``info["rng"]`` itself is never restored, so the per-step
noise of the next episode differs too. The start is drawn by ``OPSEnv.auto_reset`` on steps where
the environment's own episode ends (out of the window or ``max_steps``); under ``vmap`` it is
computed only on steps where some slot ends. Without ``AutoResetWrapper`` (raw use) ``step``
returns the finished state with ``done = 1``, the Brax convention.

Use ``episode_length = max_steps`` in brax's trainers (``EpisodeWrapper``'s limit then agrees with
the environment's own truncation, which ``final_normalized_power`` and the fresh starts rely on).
"""

from __future__ import annotations

import contextlib
import io

import numpy as np

import jax
import jax.numpy as jnp

from ops_jax.cli import extras

try:
    # brax.envs imports mujoco's optional warp backend, which prints "Failed to import warp" to
    # stdout when it is absent; that message concerns a backend this adapter never uses.
    with contextlib.redirect_stdout(io.StringIO()):
        from brax import envs as brax_envs
        from brax.envs.base import Env, State
except ModuleNotFoundError as e:
    if e.name is not None and e.name.split(".")[0] == "brax":
        raise ImportError(
            f"ops_jax.adapters.brax needs brax: {extras.install_command('agents')}"
        ) from e
    raise

import ops_jax

ENV_NAME = "ops"
BACKEND = "ops_jax"


class OPSBraxEnv(Env):
    """``OPSBraxEnv(stages=5, mode="hard", first_episode=0, **overrides)``: ``ops_jax.make``'s
    arguments (any ``EnvConfig`` / ``EnvParams`` field; ``model`` defaults to "phasor", the fast
    model, here). ``first_episode`` (int >= 0) is the episode count the first reset of each slot
    uses: 0 as in training from scratch; 10 puts hard mode's drift fully on (the testing
    environment of ``agents.evaluate``)."""

    def __init__(self, stages: int = 5, mode: str = "hard", first_episode: int = 0, **overrides):
        overrides.setdefault("model", "phasor")
        if (
            isinstance(first_episode, bool)
            or not isinstance(first_episode, (int, np.integer))
            or first_episode < 0
        ):
            raise ValueError(f"first_episode must be an integer >= 0, got {first_episode!r}")
        self.ops_env, self.params = ops_jax.make(stages, mode, **overrides)
        self.first_episode = int(first_episode)
        self.env_kwargs = dict(stages=stages, mode=mode, **overrides)

    # -- sizes -----------------------------------------------------------------------------
    @property
    def observation_size(self) -> int:
        return self.ops_env.observation_size

    @property
    def action_size(self) -> int:
        return self.ops_env.num_actions

    @property
    def backend(self) -> str:
        return BACKEND

    @property
    def max_steps(self) -> int:
        return self.ops_env.config.max_steps

    # -- dynamics --------------------------------------------------------------------------
    def reset(self, rng: jax.Array) -> State:
        """First state of a slot from ``rng`` (a single PRNG key)."""
        k_rng, k_reset = jax.random.split(rng)
        obs, s = self.ops_env.reset(k_reset, self.params, self.first_episode)
        npow = self.ops_env.probe(s, jnp.zeros(self.action_size, jnp.float32), self.params)
        zero = jnp.zeros((), jnp.float32)
        metrics = {"normalized_power": npow.astype(jnp.float32), "final_normalized_power": zero}
        info = {
            "rng": k_rng,
            "time_out": zero,
            "env_params": jax.tree.map(jnp.asarray, self.params),
        }
        return State(pipeline_state=s, obs=obs, reward=zero, done=zero, metrics=metrics, info=info)

    def step(self, state: State, action: jax.Array) -> State:
        """One control step (action (N,) in [-1, 1], 0.01 wl per unit by default)."""
        self.ops_env.check_action(action)
        rng, k_step, k_next = jax.random.split(state.info["rng"], 3)
        params = state.info["env_params"]
        obs, s, reward, terminated, truncated, info = self.ops_env.step_env(
            k_step, state.pipeline_state, action, params
        )
        done = (terminated | truncated).astype(jnp.float32)
        npow = info["normalized_power"].astype(jnp.float32)
        new_info = dict(state.info)
        new_info["rng"] = rng
        new_info["time_out"] = truncated.astype(jnp.float32)
        if "first_obs" in new_info or "first_pipeline_state" in new_info:
            # The next episode's fresh start (episode counter + 1): what AutoResetWrapper restores.
            cached = (new_info.get("first_obs", obs), new_info.get("first_pipeline_state", s))
            first_obs, first_s = self.ops_env.auto_reset(
                terminated | truncated, k_next, s, cached, params
            )
            new_info["first_obs"] = first_obs
            new_info["first_pipeline_state"] = first_s
        metrics = dict(state.metrics)  # wrappers may have added keys (EvalWrapper: "reward")
        metrics.update(normalized_power=npow, final_normalized_power=npow * done)
        return state.replace(
            pipeline_state=s,
            obs=obs,
            reward=reward.astype(jnp.float32),
            done=done,
            metrics=metrics,
            info=new_info,
        )


def register() -> None:
    """Register ``OPSBraxEnv`` as brax environment "ops" (idempotent)."""
    brax_envs.register_environment(ENV_NAME, OPSBraxEnv)


register()
