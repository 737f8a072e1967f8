"""``OPSVectorEnv``: a batch of OPS instances behind the Gymnasium ``VectorEnv`` API, one jitted
call per step, same-step auto-reset (``ops_jax.adapters.gymnasium.env`` describes the semantics)."""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ops_jax.adapters.gymnasium.codec import Unpacked
from ops_jax.adapters.gymnasium.devices import picklable_device, refuse_after_fork, resolve_device
from ops_jax.adapters.gymnasium.programs import vector_fns
from ops_jax.adapters.gymnasium.shared import (
    RENDER_FPS,
    jax_options,
    render_scope,
    reset_key,
    set_up_adapter,
)


class OPSVectorEnv(VectorEnv):
    """``num_envs`` OPS instances stepped by one jitted ``OPSEnv.step_batch`` call; same-step
    auto-reset (see the module docstring). ``device=None``: JAX's default backend."""

    metadata = {
        "autoreset_mode": AutoresetMode.SAME_STEP,
        "render_modes": ["rgb_array"],
        "render_fps": RENDER_FPS,
    }

    def __init__(
        self,
        num_envs: int = 1,
        stages: int = 5,
        mode: str = "hard",
        render_mode: str | None = None,
        device: Any = None,
        **options,
    ):
        refuse_after_fork()
        if (
            isinstance(num_envs, bool)
            or not isinstance(num_envs, (int, np.integer))
            or num_envs < 1
        ):
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        options.pop(
            "max_episode_steps", None
        )  # make_vec forwards the spec's (None); truncation is max_steps
        self.num_envs = int(num_envs)
        bound = set_up_adapter(self, stages, mode, render_mode, device, options)
        n, d = self._n, self._d
        self.single_observation_space = spaces.Box(-bound, bound, (d,), np.float32)
        self.single_action_space = spaces.Box(-1.0, 1.0, (n,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._reset = self._step = None
        self._carry = (
            None  # (key, states): on the device once started, host arrays after unpickling
        )
        self._episode = 0
        self._scopes = None

    def _start(self) -> None:
        """Start JAX for this batch: device, jitted functions (shared cache), carry on the
        device."""
        if self._step is not None:
            return
        fns = vector_fns(
            self.num_envs, self.options["stages"], self.options["mode"], jax_options(self)
        )
        self.device = resolve_device(self._device_spec)
        if self._carry is not None:
            key_data, states = self._carry
            self._carry = jax.device_put((jax.random.wrap_key_data(key_data), states), self.device)
        self._reset, self._step = fns

    def __getstate__(self):
        """Picklable state: the carry as host arrays; jitted functions, device and render scopes
        left out."""
        state = dict(self.__dict__)
        state.update(
            _reset=None,
            _step=None,
            _scopes=None,
            device=None,
            _device_spec=picklable_device(self._device_spec),
        )
        if self._carry is not None:
            key, states = self._carry
            key_data = key if isinstance(key, np.ndarray) else jax.random.key_data(key)
            state["_carry"] = (np.array(key_data), jax.tree.map(np.array, states))
        return state

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Reset every instance. ``seed`` reseeds ``np_random`` (and restarts the episode counter);
        ``options={"episode": k}`` starts every instance as its k-th episode. Returns (obs,
        infos)."""
        super().reset(seed=seed)
        key = reset_key(self, seed, options)
        episodes = np.full(self.num_envs, self._episode, np.int32)
        self._carry, obs = self._reset(key, episodes)
        self._episode += 1
        return np.asarray(obs), {}

    def step(self, actions):
        """Step every instance: returns (obs (B, D), rewards (B,) float64, terminations (B,),
        truncations (B,), infos)."""
        if self._carry is None:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, np.float32)
        if actions.shape != (self.num_envs, self._n):
            raise ValueError(
                f"actions must have shape ({self.num_envs}, {self._n}), got {actions.shape}"
            )
        self._start()
        self._carry, packed = self._step(self._carry, actions)
        u = Unpacked(np.asarray(packed), self._d, self._n)
        ones = np.ones(self.num_envs, bool)
        infos = {
            "power": u.power.copy(),
            "_power": ones,
            "normalized_power": u.normalized_power.copy(),
            "_normalized_power": ones,
            "normalized_power_best": u.normalized_power_best.copy(),
            "_normalized_power_best": ones,
            "deltas_wl": u.deltas_wl.copy(),
            "_deltas_wl": ones,
            "action_nonfinite": u.action_nonfinite.copy(),
            "_action_nonfinite": ones,
        }
        done = u.terminated | u.truncated
        if done.any():
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(done):
                final_obs[i] = u.extra[i].copy()
            infos["final_obs"], infos["_final_obs"] = final_obs, done
            infos["final_info"] = {
                k: (
                    np.where(done.reshape(-1, *[1] * (v.ndim - 1)), v, 0)
                    if not k.startswith("_")
                    else done.copy()
                )
                for k, v in infos.items()
                if k not in ("final_obs", "_final_obs")
            }
            infos["_final_info"] = done
        return (
            u.obs.copy(),
            u.reward.astype(np.float64),
            u.terminated.copy(),
            u.truncated.copy(),
            infos,
        )

    def render(self):
        """``"rgb_array"``: a tuple of (H, W, 3) uint8 oscilloscope frames, one per instance (slow
        for large batches: about 20 ms per frame)."""
        _render, self._scopes = render_scope(
            self, self._carry is not None, self._scopes, "'rgb_array'"
        )
        if _render is None:
            return None
        deltas = np.asarray(self._carry[1].deltas)
        steps = np.asarray(self._carry[1].t)
        return tuple(
            self._scopes.frame(deltas[i], step=int(steps[i])) for i in range(self.num_envs)
        )

    def close_extras(self, **kwargs):
        if self._scopes is not None:
            self._scopes.close()
            self._scopes = None
