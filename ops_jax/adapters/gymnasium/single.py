"""``OPSGymEnv``: one OPS instance behind the Gymnasium ``Env`` API
(``ops_jax.adapters.gymnasium.env`` describes the semantics)."""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import numpy as np
from gymnasium import spaces

from ops_jax.adapters.gymnasium.codec import Unpacked
from ops_jax.adapters.gymnasium.devices import picklable_device, refuse_after_fork, resolve_device
from ops_jax.adapters.gymnasium.programs import single_fns
from ops_jax.adapters.gymnasium.shared import (
    ENV_ID,
    RENDER_FPS,
    jax_options,
    render_scope,
    reset_key,
    set_up_adapter,
)


class OPSGymEnv(gymnasium.Env):
    """One OPS instance behind the Gymnasium 1.x ``Env`` API (see the module docstring).

    ``OPSGymEnv(stages=5, mode="hard", render_mode=None, device="cpu", **options)``; ``options`` are
    ``ops_jax.make`` overrides. The step is one jitted call (state kept on ``device``) returning one
    packed array (key and state travel in it too): at N = 5 the adapter's step costs about
    0.05-0.07 ms with model="phasor" and 0.15 ms with "field" on a (shared, noisy) 2-core CPU."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": RENDER_FPS}

    def __init__(
        self,
        stages: int = 5,
        mode: str = "hard",
        render_mode: str | None = None,
        device: Any = "cpu",
        **options,
    ):
        refuse_after_fork()
        bound = set_up_adapter(self, stages, mode, render_mode, device, options)
        n, d = self._n, self._d
        self.observation_space = spaces.Box(-bound, bound, (d,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (n,), np.float32)
        self._step = self._reset = self._codec = self._head = None
        self._buf = (
            None  # (packed step, key, state): a device array once started, host after unpickling
        )
        self._started = False
        self._episode = 0
        self._last = None
        self._scope = None

    def _start(self) -> None:
        """Start JAX for this instance: device, jitted functions (shared cache), carry on the
        device."""
        if self._step is not None:
            return
        fns = single_fns(self.options["stages"], self.options["mode"], jax_options(self))
        self.device = resolve_device(self._device_spec)
        buf = self._buf if self._buf is not None else np.zeros(fns[3] + fns[2].size, np.float32)
        self._buf = jax.device_put(buf, self.device)
        self._step, self._reset, self._codec, self._head = fns

    def __getstate__(self):
        """Picklable state: the carry as a host array; jitted functions, device and render scope
        left out."""
        state = dict(self.__dict__)
        state.update(
            _step=None,
            _reset=None,
            _codec=None,
            _head=None,
            _scope=None,
            device=None,
            _device_spec=picklable_device(self._device_spec),
        )
        if self._buf is not None:
            state["_buf"] = np.array(self._buf)
        return state

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode. ``seed`` reseeds ``np_random`` and restarts the episode counter;
        ``options={"episode": k}`` sets the counter (drift ramp of hard mode). Returns (obs,
        info)."""
        super().reset(seed=seed)
        key = reset_key(self, seed, options)
        fresh = not self._started or seed is not None
        self._buf = self._reset(key, np.int32(self._episode), self._buf, fresh)
        self._started = True
        self._episode += 1
        u = Unpacked(np.asarray(self._buf)[: self._head], self._d, self._n)
        obs, deltas = u.obs.copy(), u.deltas_wl.copy()
        self._last = dict(step=0, deltas_wl=deltas)
        if self.render_mode == "human":
            self.render()
        return obs, {"deltas_wl": deltas}

    def step(self, action):
        """One control step: returns (obs, reward, terminated, truncated, info)."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, np.float32)
        if action.shape != (self._n,):
            raise ValueError(
                f"action must have shape ({self._n},) for stages={self._n}, got {action.shape}"
            )
        self._start()
        self._buf = self._step(self._buf, action)
        u = Unpacked(np.asarray(self._buf)[: self._head], self._d, self._n)
        info = {
            "power": float(u.power),
            "normalized_power": float(u.normalized_power),
            "normalized_power_best": float(u.normalized_power_best),
            "deltas_wl": u.deltas_wl.copy(),
            "action_nonfinite": bool(u.action_nonfinite),
        }
        self._last = dict(step=self._last["step"] + 1, deltas_wl=info["deltas_wl"])
        if self.render_mode == "human":
            self.render()
        return u.obs.copy(), float(u.reward), bool(u.terminated), bool(u.truncated), info

    def _codec_state(self):
        """(key data, EnvState) of the instance now (for tests and debugging)."""
        self._start()
        return self._codec.unflatten(jax.device_get(self._buf)[self._head :])

    def render(self):
        """``"rgb_array"``: an (H, W, 3) uint8 oscilloscope frame of the current pulse train (exact
        field model); ``"human"``: the same frame in a matplotlib window (no-op without a
        display)."""
        _render, self._scope = render_scope(
            self, self._last is not None, self._scope, "'rgb_array' or 'human'"
        )
        if _render is None:
            return None
        frame = self._scope.frame(self._last["deltas_wl"], step=self._last["step"])
        if self.render_mode == "rgb_array":
            return frame
        _render.show(frame, title=ENV_ID)
        return None

    def close(self):
        if self._scope is not None:
            self._scope.close()
            self._scope = None
        super().close()
