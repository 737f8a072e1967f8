"""The OPS control environment, gymnax-style: static ``EnvConfig``, dynamic ``EnvParams`` pytree,
``EnvState`` pytree (``ops_jax.records``), ``reset(key, params)`` / ``step(key, state, action,
params)`` with auto-reset (``ops_jax.batching``).

Lengths are offsets from the optimal delay-line lengths in wavelengths (wl).

Observation (dimension 2^N + N, times ``frame_stack``; - N with ``observe_lengths=False``, + N with
``include_noise``), laid out as ``OPSEnv.layout`` (``ops_jax.observation``) says, each entry mapped
affinely to about [-1, 1]:
- ``2 P / P_max - 1`` (the stacked energy),
- ``2 I_m / I_peak - 1`` for the 2^N - 1 oscilloscope samples (I_peak: peak of the ideal pulse),
- ``x_i / window`` for the N offsets (window = 3 wl, the termination bound), unless
  ``observe_lengths=False`` (the detector's frames alone, the paper's state),
- with ``include_noise``: ``mu_t / 5e-4 wl``, the current free-running mean per stage (the
  paper's POMDP noise state e),
then Gaussian observation noise of std ``obs_noise`` on every entry (the reference adds 1e-4).
With ``EnvConfig.imperfect`` the P and sample entries are what the detector reads and the lengths
what the calibrated readout reports (docs/imperfections.md); the reward uses the read P.
Frames are stacked oldest first; at reset every frame is the first observation.

Non-finite actions (inside jit): every non-finite entry is replaced by 0 before clipping to
[-1, 1], so NaN never reaches the state; ``info["action_nonfinite"]`` flags the step.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ops_jax import batching, imperfections, noise, physics
from ops_jax.observation import ObservationLayout
from ops_jax.ranges import check_fields, ranges
from ops_jax.records import EnvConfig, EnvParams, EnvState

MODES = ("easy", "medium", "hard", "custom")
REWARDS = ("paper", "reference", "linear")
PROBES = (
    "instant",
    "frame",
)  # EnvConfig.probe: how a dither probe (``OPSEnv.probe_step``) is measured

# Reference values of the difficulty modes (physics.md section 5).
MODE_PARAMS = {
    "easy": dict(init_spread=0.08, step_sigma=5e-4, drift_cap=0.0),
    "medium": dict(init_spread=0.13, step_sigma=5e-4, drift_cap=0.0),
    "hard": dict(init_spread=0.15, step_sigma=5e-4, drift_cap=1.0),
}


def _validate_params(params: EnvParams) -> None:
    check_fields(params)
    if not np.all(np.asarray(params.window) > np.asarray(params.init_spread)):
        raise ValueError(
            f"window must be > init_spread (most episodes would end at their first step), "
            f"got window={params.window!r}, init_spread={params.init_spread!r}"
        )


def _validate_config(cfg: EnvConfig) -> None:
    physics.check_stages(cfg.stages)
    physics._check_choice("model", cfg.model, physics.MODELS)
    physics._check_choice("detector", cfg.detector, physics.DETECTORS)
    physics._check_choice("reward", cfg.reward, REWARDS)
    physics._check_choice("probe", cfg.probe, PROBES)
    for name, accepted in ranges(cfg).items():
        accepted(name, getattr(cfg, name))
    for name in ("observe_lengths", "include_noise", "imperfect"):
        if not isinstance(getattr(cfg, name), (bool, np.bool_)):
            raise TypeError(f"{name} must be a bool, got {getattr(cfg, name)!r}")


class OPSEnv:
    """N-stage optical pulse stacking. One instance per call; ``jax.vmap(env.step)`` (or its alias
    ``step_batch``) for many: both compute the auto-reset only on steps where some instance ends."""

    def __init__(self, config: EnvConfig):
        _validate_config(config)
        self.config = config
        n = config.stages
        self.p_max = physics.p_max(n, config.detector)
        self.p_orig = physics.p_orig(n)
        self.peak = physics.peak_intensity(n)

    # -- sizes ---------------------------------------------------------------------------
    @property
    def num_actions(self) -> int:
        return self.config.stages

    @property
    def layout(self) -> ObservationLayout:
        """Where each reading sits in an observation, and its scale (``ops_jax.observation``)."""
        c = self.config
        return ObservationLayout(c.stages, c.frame_stack, c.observe_lengths, c.include_noise)

    @property
    def frame_size(self) -> int:
        return self.layout.frame_size

    @property
    def observation_size(self) -> int:
        return self.layout.size

    def default_params(self) -> EnvParams:
        return EnvParams()

    # -- internals -----------------------------------------------------------------------
    def _measure(self, deltas):
        c = self.config
        return physics.measure(deltas, stages=c.stages, model=c.model, detector=c.detector)

    def _sense(self, deltas, lab):
        """(true measurement, detected measurement, length readout (N,) wl) at offsets
        ``deltas``."""
        if not self.config.imperfect:
            m = self._measure(deltas)
            return m, m, deltas
        return imperfections.sense(self.config, deltas, lab, self.p_max, self.peak)

    def _mu(self, state, params):
        drift = noise.piecewise_linear(
            state.knots[0], state.knots[1], state.t, params.drift_segment
        )
        return state.mu_episode + drift

    def _frame(self, z, m, deltas, mu, params):
        """The observation frame; ``z`` (frame_size,) standard normals for the observation noise."""
        frame = self.layout.encode(
            m.power / self.p_max, m.samples / self.peak, deltas, params.window, mu
        )
        return frame.astype(jnp.float32) + params.obs_noise * z

    def reward(self, power, p_init):
        """The reward at detected power ``power`` (units of ``p_max``; ``p_init``: P at the first
        reset, "reference")."""
        if self.config.reward == "paper":
            return -((power - self.p_max) ** 2) / (self.p_orig - self.p_max) ** 2
        if self.config.reward == "linear":
            return (power - self.p_max) / (self.p_max - self.p_orig)
        return 1 - (power - self.p_max) ** 2 / (self.p_max * p_init) / self.config.stages

    def _reset_draws(self, key):
        n = self.config.stages
        d = noise.draws(
            key,
            normal={"init": (n,), "obs": (self.frame_size,)},
            uniform={"drift": (), "knots": (2, n)},
        )
        return {**d, "key": key} if self.config.imperfect else d

    def _reset_state(self, d, params, episode, p_init):
        """New episode state (offsets, drift) from ``_reset_draws`` ``d``, without measuring;
        p_init < 0 means 'take P now'."""
        n = self.config.stages
        r = noise.episode_drift(d["drift"], episode, params.drift_cap, params.drift_ramp)
        deltas = noise.initial_offsets(d["init"], r * params.init_spread, params.init_spread)
        knots = noise.drift_knot(d["knots"], params.drift_amplitude)
        mu_episode = jnp.full((n,), r * params.step_sigma)
        frames = jnp.zeros((self.config.frame_stack, self.frame_size), jnp.float32)
        lab = imperfections.reset(d["key"], n, params.lab) if self.config.imperfect else ()
        return EnvState(
            deltas,
            mu_episode,
            knots,
            jnp.int32(0),
            jnp.asarray(episode, jnp.int32),
            jnp.asarray(p_init, jnp.float32),
            frames,
            jnp.zeros((n,), jnp.float32),
            lab,
        )

    def _observe_reset(self, z, state, params):
        _, m, x_seen = self._sense(state.deltas, state.lab)
        frame = self._frame(z, m, x_seen, self._mu(state, params), params)
        frames = jnp.broadcast_to(frame, state.frames.shape)
        p_init = jnp.where(state.p_init < 0, m.power, state.p_init).astype(jnp.float32)
        return frames.reshape(-1), dataclasses.replace(state, frames=frames, p_init=p_init)

    def reset(self, key, params: EnvParams, episode=0):
        """Start an episode: returns (obs, state). ``episode`` counts earlier resets (0: the first);
        it scales the hard-mode drift, so evaluation can start with the drift fully on."""
        d = self._reset_draws(key)
        state = self._reset_state(d, params, episode, -1.0)
        return self._observe_reset(d["obs"], state, params)

    def check_action(self, action):
        """Raise ValueError unless ``action`` has trailing shape (N,) (checked at trace time)."""
        n = self.config.stages
        if jnp.shape(action)[-1:] != (n,):
            raise ValueError(
                f"action must have shape ({n},) for stages={n}, got {jnp.shape(action)}"
            )

    def _tick(self, key, state: EnvState, move, params: EnvParams):
        """One frame: free run, the lines moved by ``move`` (N,) wl through the actuators, the
        drift's clock advanced, the detector read. Returns (state, true measurement, detected
        measurement, frame)."""
        c = self.config
        d = noise.draws(
            key,
            normal={"run": (c.feedback_k, c.stages), "obs": (self.frame_size,)},
            uniform={"knot": (c.stages,)},
        )
        mu = self._mu(state, params)
        deltas = state.deltas + noise.free_run(d["run"], mu, params.step_sigma)
        lab = state.lab
        if c.imperfect:
            lab, move = imperfections.advance(key, lab, move)
        deltas = deltas + move
        t = state.t + 1
        # Advance the piecewise-linear drift to the next segment when one ends.
        new_knot = noise.drift_knot(d["knot"], params.drift_amplitude)
        seg_end = (t % params.drift_segment) == 0
        knots = jnp.where(seg_end, jnp.stack([state.knots[1], new_knot]), state.knots)
        m_true, m, x_seen = self._sense(deltas, lab)
        frame = self._frame(d["obs"], m, x_seen, mu, params)
        return (
            dataclasses.replace(state, deltas=deltas, knots=knots, t=t, lab=lab),
            m_true,
            m,
            frame,
        )

    def step_env(self, key, state: EnvState, action, params: EnvParams):
        """One control period without auto-reset: free run, action, measurement. After a "frame"
        probe the move also takes the lines back from the probed offsets."""
        c = self.config
        action = jnp.asarray(action, jnp.float32)
        finite = jnp.isfinite(action)
        action = jnp.clip(jnp.where(finite, action, 0.0), -1.0, 1.0)
        move = action * params.action_scale
        if (
            c.probe == "frame"
        ):  # back from the probed offsets (static: an instant probe never moves the lines)
            move = move - state.probed
        state, m_true, m, frame = self._tick(key, state, move, params)
        frames = jnp.concatenate([state.frames[1:], frame[None]])
        state = dataclasses.replace(state, frames=frames, probed=jnp.zeros_like(state.probed))
        terminated = jnp.any(jnp.abs(state.deltas) > params.window)
        truncated = (state.t >= c.max_steps) & ~terminated
        info = {
            "power": m_true.power,
            "normalized_power": m_true.power / self.p_max,
            "normalized_power_best": m_true.power
            / jnp.where(params.lab.p_best > 0, params.lab.p_best, self.p_max),
            "deltas_wl": state.deltas,
            "action_nonfinite": ~jnp.all(finite),
        }
        reward = self.reward(m.power, state.p_init).astype(jnp.float32)
        return frames.reshape(-1), state, reward, terminated, truncated, info

    def next_episode(self, key, state, params):
        """The next episode's (obs, state) after ``state`` (episode count and p_init carried)."""
        d = self._reset_draws(key)
        new = self._reset_state(d, params, state.episode + 1, state.p_init)
        return self._observe_reset(d["obs"], new, params)

    def auto_reset(self, done, key, state: EnvState, fallback, params: EnvParams):
        """``next_episode(key, state, params)`` where ``done``, else ``fallback`` (obs, state).
        Under ``jax.vmap`` (nested too) the reset is computed only on calls where some instance is
        done."""
        return batching.auto_reset(self, done, key, state, fallback, params)

    def step(self, key, state: EnvState, action, params: EnvParams):
        """One control step with auto-reset. Returns (obs, state, reward, terminated, truncated,
        info); when the episode ends, obs and state are the next episode's first and
        ``info["final_observation"]`` is the last observation of the finished one."""
        self.check_action(action)
        k_step, k_reset = jax.random.split(key)
        obs, state, reward, terminated, truncated, info = self.step_env(
            k_step, state, action, params
        )
        info["final_observation"] = obs
        new_obs, new_state = self.auto_reset(
            terminated | truncated, k_reset, state, (obs, state), params
        )
        return new_obs, new_state, reward, terminated, truncated, info

    def probe(self, state: EnvState, offsets, params: EnvParams):
        """P / P_max read at the current lengths plus ``offsets`` (N,) wl in the same instant,
        nothing moved."""
        del params
        return self._sense(state.deltas + offsets, state.lab)[1].power / self.p_max

    def probe_step(self, key, state: EnvState, offsets, params: EnvParams):
        """A dither probe (e.g. SPGD's): (P / P_max read with the lines at ``offsets`` (N,) wl from
        where the last step left them, the state after it). ``EnvConfig.probe`` "instant":
        ``probe``, the state unchanged; "frame": the lines move there through the actuators and one
        frame passes (free run, vibration, drift, the episode's clock), as a bench measures it; the
        next step's move starts there. Agents count each call as a measurement."""
        if self.config.probe == "instant":
            return self.probe(state, offsets, params), state
        move = jnp.asarray(offsets, jnp.float32) - state.probed
        state, _, m, _ = self._tick(key, state, move, params)
        return m.power / self.p_max, dataclasses.replace(
            state, probed=jnp.asarray(offsets, jnp.float32)
        )

    def reset_batch(self, keys, params: EnvParams):
        """Reset a batch; ``keys`` (B, ...) one per instance, ``params`` shared or batched (B,)."""
        return jax.vmap(self.reset, in_axes=(0, batching.params_axes(params)))(keys, params)

    def step_batch(self, keys, states: EnvState, actions, params: EnvParams):
        """``jax.vmap(step)`` over a batch (B instances, one key each); ``params`` shared or batched
        (B,)."""
        return jax.vmap(self.step, in_axes=(0, 0, 0, batching.params_axes(params)))(
            keys, states, actions, params
        )


def option_names() -> tuple:
    """The keyword options ``make`` accepts besides ``stages`` and ``mode``: every ``EnvConfig`` and
    ``EnvParams`` field (``lab`` excepted) and the imperfection options."""
    fields = [f.name for f in dataclasses.fields(EnvConfig) if f.name != "stages"]
    fields += [f.name for f in dataclasses.fields(EnvParams) if f.name != "lab"]
    return tuple(fields) + tuple(imperfections.OPTIONS)


def make(stages: int = 5, mode: str = "hard", **overrides):
    """Build ``(env, params)``. ``mode`` in easy / medium / hard (reference values) or custom
    (medium values unless overridden). ``overrides`` may set any ``EnvConfig`` or ``EnvParams``
    field, e.g. ``make(5, "easy", model="phasor", obs_noise=0.0)``. Lab imperfections:
    ``imperfections="lab"`` (or "none"), ``imperfection_scale`` (x the preset's errors) and any
    ``imperfections.Imperfections`` field; setting any turns ``imperfect`` on and fills in
    p_best."""
    config, params = configure(stages, mode, **overrides)
    env = OPSEnv(config)
    p_best = imperfections.best_power(config, params.lab) if config.imperfect else env.p_max
    params = dataclasses.replace(
        params, lab=dataclasses.replace(params.lab, p_best=np.asarray(p_best, np.float32))
    )
    return env, params


def configure(stages: int = 5, mode: str = "hard", **overrides):
    """The validated ``(EnvConfig, EnvParams)`` of ``make(stages, mode, **overrides)`` (raises what
    ``make`` raises), without building the environment or searching P_best (``params.lab.p_best``
    unset)."""
    physics._check_choice("mode", mode, MODES)
    physics.check_stages(stages)
    cfg_fields = {f.name for f in dataclasses.fields(EnvConfig)}
    par_fields = {f.name for f in dataclasses.fields(EnvParams)} - {
        "lab"
    }  # lab: built from the options below
    unknown = set(overrides) - set(option_names())
    if unknown:
        raise TypeError(f"unknown option(s) {sorted(unknown)}; accepted: {sorted(option_names())}")
    overrides = dict(overrides)
    lab, any_lab = imperfections.from_options(stages, overrides)
    overrides.setdefault("imperfect", any_lab)
    config = EnvConfig(stages=stages, **{k: v for k, v in overrides.items() if k in cfg_fields})
    base = dict(MODE_PARAMS.get(mode, {}))
    base.update({k: v for k, v in overrides.items() if k in par_fields})
    params = EnvParams(**base)
    _validate_params(params)
    # Fixed dtypes (not Python scalars): a jitted step then never retraces on a weak-type change.
    params = EnvParams(
        **{
            k: np.asarray(v, np.int32 if k == "drift_segment" else np.float32)
            for k, v in vars(params).items()
            if k != "lab"
        },
        lab=lab,
    )
    _validate_config(config)
    return config, params
