"""Gymnasium adapters: ``OPSGymEnv`` (one instance) and ``OPSVectorEnv`` (a batch, one jitted call
per step), registered as ``"ops_jax/OPS-v0"`` by ``import ops_jax``::

    env = gymnasium.make("ops_jax/OPS-v0", stages=5, mode="hard", render_mode="rgb_array")
    envs = gymnasium.make_vec(
        "ops_jax/OPS-v0", num_envs=1024, vectorization_mode="vector_entry_point"
    )

Keywords: ``stages``, ``mode`` and every ``ops_jax.make`` option (``model``, ``reward``, ``max_steps``,
``obs_noise``, ...), plus ``render_mode`` and ``device`` (the JAX device the state lives on:
"cpu" by default for the single instance, whose per-step cost is dispatch-bound; the default
backend for the vector env).

Semantics (both adapters):
- observation: the ``OPSEnv`` observation (float32 NumPy), in a finite ``Box`` whose bounds are
  derived from the parameters (10 std of observation noise as margin); action: ``Box(-1, 1, (N,))``
  float32 (0.01 wl per unit by default).
- reward: the configured reward (``"paper"``: in [-1, 0]); ``terminated`` when a delay leaves the
  +-window; ``truncated`` after ``max_steps`` (the environment truncates itself, so the registered
  spec has no ``TimeLimit``; ``env.unwrapped.max_episode_steps`` is ``max_steps``).
- info: ``power``, ``normalized_power`` (P / P_max), ``normalized_power_best`` (P / P_best: the best P
  reachable with the configured static imperfections; P / P_max without them), ``deltas_wl`` (N,),
  ``action_nonfinite``.
- randomness: ``reset(seed=s)`` seeds ``np_random`` and restarts the episode counter (hard mode's
  drift ramps with it); the JAX key of the episode is drawn from ``np_random``. ``reset(options=
  {"episode": k})`` starts as the k-th episode (k >= 10: hard mode's drift fully on).
- JAX starts at the first ``reset`` (construction only validates and builds the spaces), so
  Gymnasium's ``"async"`` mode may fork its workers after building one env for the spaces. An
  adapter constructed in a process forked after JAX started (JAX is multithreaded: it would
  deadlock) raises ``RuntimeError`` at once, naming the fixes (``vectorization_mode=
  "vector_entry_point"``, or ``vector_kwargs={"context": "forkserver"}``).
- ``copy.deepcopy`` and ``pickle`` copy a live adapter (options, parameters, state, JAX key,
  ``np_random``, episode counter); the copy looks its jitted functions up again.
- the vector env auto-resets in the same step (``AutoresetMode.SAME_STEP``): the returned obs of a
  finished instance is its next episode's first; ``infos["final_obs"]`` (object array, ``None`` where
  not finished) and ``infos["final_info"]`` hold the finished episode's last observation and info.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ops_jax import imperfections, noise
from ops_jax.env import make
from ops_jax.adapters.gymnasium.codec import Unpacked
from ops_jax.adapters.gymnasium.devices import (
    FORK_ERROR,
    check_device,
    picklable_device,
    refuse_after_fork,
    resolve_device,
)
from ops_jax.adapters.gymnasium.programs import single_fns, vector_fns

__all__ = ["ENV_ID", "FORK_ERROR", "OPSGymEnv", "OPSVectorEnv", "register"]

ENV_ID = "ops_jax/OPS-v0"
RENDER_FPS = 10


def register() -> None:
    """Register ``"ops_jax/OPS-v0"`` (entry point and vector entry point) with Gymnasium; idempotent."""
    if ENV_ID in gymnasium.registry:
        return
    gymnasium.register(
        id=ENV_ID,
        entry_point="ops_jax.adapters.gymnasium.env:OPSGymEnv",
        vector_entry_point="ops_jax.adapters.gymnasium.env:OPSVectorEnv",
        max_episode_steps=None,  # the environment truncates itself after its own max_steps
    )


def _observation_bounds(env, params) -> np.ndarray:
    """Per-entry bound B (obs in [-B, B]) of one frame, from the physics and the noise parameters."""
    p = {k: float(np.max(np.asarray(v))) for k, v in vars(params).items() if k != "lab"}
    margin = 10.0 * p["obs_noise"] + 1e-3
    k = env.config.feedback_k
    mu_max = p["drift_cap"] * p["step_sigma"] + p["drift_amplitude"]
    # Largest |offset| seen: a reset ((cap + 2) s0) or the step that leaves the window.
    x_max = max(
        (p["drift_cap"] + 2.0) * p["init_spread"],
        p["window"] + p["action_scale"] + k * (mu_max + 3.0 * p["step_sigma"]),
    )
    signal = 1.0
    if env.config.imperfect:
        signal, x_max = imperfections.observation_bounds(params.lab, x_max)
    layout = env.layout
    bound = np.full(layout.frame_size, signal + margin)  # the detector's entries
    if layout.lengths:
        bound[layout.lengths_slice] = x_max / p["window"] + margin
    if layout.noise:
        bound[layout.noise_slice] = mu_max / noise.REFERENCE_SIGMA_WL + margin
    return np.tile(bound, layout.frame_stack).astype(np.float32)


def _reset_key(env, seed, options):
    """The episode counter after ``reset(seed, options)`` set on ``env``, its compiled functions
    started, and the reset's PRNG key drawn from ``env.np_random`` (on ``env.device``)."""
    if seed is not None:
        env._episode = 0
    if options:
        unknown = set(options) - {"episode"}
        if unknown:
            raise ValueError(f"reset options accept only 'episode', got {sorted(unknown)}")
        episode = options["episode"]
        if isinstance(episode, bool) or not isinstance(episode, (int, np.integer)) or episode < 0:
            raise ValueError(f"options['episode'] must be an integer >= 0, got {episode!r}")
        env._episode = int(episode)
    env._start()
    key = jax.random.key(int(env.np_random.integers(0, 2**32, dtype=np.uint64)))
    return key if env.device is None else jax.device_put(key, env.device)


def _setup(adapter, stages: int, mode: str, render_mode, device, options: dict):
    """What both adapters' constructors set: the environment and its options, render mode, device spec,
    sizes; returns the observation bound."""
    if render_mode is not None and render_mode not in adapter.metadata["render_modes"]:
        raise ValueError(
            f"render_mode must be None or one of {adapter.metadata['render_modes']}, got {render_mode!r}"
        )
    adapter.env, adapter.params = make(stages, mode, **options)
    adapter.options = dict(stages=stages, mode=mode, **options)
    adapter.render_mode = render_mode
    adapter._device_spec = check_device(device)
    adapter.device = None  # resolved when JAX starts (first reset)
    adapter._n, adapter._d = adapter.env.num_actions, adapter.env.observation_size
    adapter.max_episode_steps = adapter.env.config.max_steps
    return _observation_bounds(adapter.env, adapter.params)


def _jax_options(adapter) -> dict:
    """The ``make`` options of a starting adapter's jitted functions (refused in a forked child)."""
    refuse_after_fork()
    return {k: v for k, v in adapter.options.items() if k not in ("stages", "mode")}


def _render_scope(adapter, started: bool, scope, modes: str):
    """``(ops_jax.render, oscilloscope)`` for an adapter's ``render()`` (the scope made on first use), or
    ``(None, scope)`` with a warning naming ``modes`` without a render_mode; RuntimeError before reset."""
    if adapter.render_mode is None:
        gymnasium.logger.warn(f"render() called without a render_mode; pass render_mode={modes}")
        return None, scope
    if not started:
        raise RuntimeError("call reset() before render()")
    from ops_jax import render as _render

    return _render, scope if scope is not None else _render.Oscilloscope(
        adapter._n, detector=adapter.env.config.detector
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
        bound = _setup(self, stages, mode, render_mode, device, options)
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
        """Start JAX for this instance: device, jitted functions (shared cache), carry on the device."""
        if self._step is not None:
            return
        fns = single_fns(self.options["stages"], self.options["mode"], _jax_options(self))
        self.device = resolve_device(self._device_spec)
        buf = self._buf if self._buf is not None else np.zeros(fns[3] + fns[2].size, np.float32)
        self._buf = jax.device_put(buf, self.device)
        self._step, self._reset, self._codec, self._head = fns

    def __getstate__(self):
        """Picklable state: the carry as a host array; jitted functions, device and render scope left out."""
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
        ``options={"episode": k}`` sets the counter (drift ramp of hard mode). Returns (obs, info)."""
        super().reset(seed=seed)
        key = _reset_key(self, seed, options)
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
        field model); ``"human"``: the same frame in a matplotlib window (no-op without a display)."""
        _render, self._scope = _render_scope(
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
        bound = _setup(self, stages, mode, render_mode, device, options)
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
        """Start JAX for this batch: device, jitted functions (shared cache), carry on the device."""
        if self._step is not None:
            return
        fns = vector_fns(
            self.num_envs, self.options["stages"], self.options["mode"], _jax_options(self)
        )
        self.device = resolve_device(self._device_spec)
        if self._carry is not None:
            key_data, states = self._carry
            self._carry = jax.device_put((jax.random.wrap_key_data(key_data), states), self.device)
        self._reset, self._step = fns

    def __getstate__(self):
        """Picklable state: the carry as host arrays; jitted functions, device and render scopes left out."""
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
        ``options={"episode": k}`` starts every instance as its k-th episode. Returns (obs, infos)."""
        super().reset(seed=seed)
        key = _reset_key(self, seed, options)
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
        _render, self._scopes = _render_scope(
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
