"""Physics-informed controller (algo "physics"): estimate the delay offsets by fitting the
differentiable simulator to what the detector shows, then step straight to the nearest optimum.

State estimation (every control step, batched over B instances, jitted, no learning):
- Measured vector y = [2 P/Pmax - 1, 2 I_m/I_peak - 1 (m = 1..2^N-1)], the observation's power
  and oscilloscope entries (latest frame). The model f(x) is the same map through
  ``ops_jax.physics.measure(x, model="phasor")`` for offsets x (wl).
- Unknowns: the offsets of the interferometric stages, modulo the wl/2 period (all N stages with
  detector "polariser"; stages 1..N-1 with "total", whose last stage's carrier phase is invisible:
  P does not depend on it, so the controller leaves it alone).
- Residual r(z) = [f(z) - y_t, w_hist (f(z - dx_{t-1}) - y_{t-1}), ..., w_hist (f(z - dx_{t-1} -
  ... - dx_{t-H}) - y_{t-H})], where dx_{t-k} is the move the controller itself commanded before
  y_{t-k+1} (carried) and H is ``history`` (1: the frame before the latest alone). The history
  blocks resolve the ambiguities of a single snapshot (the intensity pattern is nearly invariant
  under x -> -x): no probe is needed, so the controller makes 1 measurement per step. Under
  vibration, which moves the lines between frames, more frames (``history`` 2-3) average that motion
  out of the comparison: docs/imperfections.md ("Frames compared").
- Gauss-Newton / Levenberg-Marquardt from ``starts`` random points on the period torus plus the
  tracked prediction (last estimate + last move), ``iters`` iterations each (Jacobian by jacfwd);
  the start with the lowest residual wins (the model, its residual and the fit:
  ``agents.controllers.physics_fit``).

Control: a = clip(-gain * wrap(z) / action_scale, -1, 1) on the fitted stages, 0 elsewhere
(``wrap`` maps to the nearest optimum, [-wl/4, wl/4)).

The hold (``hold``, preset "frames-hold"): where the measured P/Pmax is at or above ``hold``, the
move is SPGD's proportional step instead (``agents.controllers.spgd``, its preset's gain schedule
and fine dither, one probe per step there: 2 measurements per step; under ``hold`` the probe is left
out), and the fit follows the lines through the moves really sent. The fit acquires from anywhere
(no trap of a hill climber), the dither reads the slope at every step, where the fit compares frames
that the vibration has moved apart: docs/imperfections.md ("The hold"). The trim's ``hold`` around
the "frames" preset (``agents.controllers.trim``) runs the same episodes.

The length channel: the observation also holds the (noisy, normalised) delay-line lengths
x / window, which reveal the offsets directly (obs noise 1e-4 -> 3e-4 wl). ``use_lengths=True``
adds them as one more start of the fit (and, with ``lengths_only=True``, the controller just reads
them: legitimate but trivial, and useless when the channel is noisy, miscalibrated or absent). With
``use_lengths=False`` (the "frames" preset) the controller never looks at them. On an environment
whose observation holds no length readouts (``observe_lengths=False``), ``use_lengths=True`` or
``lengths_only=True`` raises ValueError when the policy is built: use ``config="frames"``.
``drift_gain`` > 0 integrates the prediction innovation into a drift estimate (wl/step) that is
added to the prediction and pre-compensated in the action (off by default: it slows the approach at
feedback_k = 1 and helps only at long feedback delays).

Online identification (``identify=True``, the default preset's; ``config="frames"`` or
``identify=False`` turns it off): the model also carries static unknowns theta (the detector's gain
and offset, shared by P and the samples; each stage's wave-plate rotation error and PBS leakage;
each fitted line's actuator gain error; ``identification.THETA``), estimated recursively. After the
multi-start fit of the offsets (theta held), one Gauss-Newton step on (offsets, theta) with theta's
accumulated information as its prior; the information then grows by what that step tells about theta
alone (the Schur complement of the offsets), discounted by ``forget`` per step. Moves are divided by
the identified actuator gains. With ``use_lengths=True`` as well, each fitted line's length readout
is calibrated against the fit (readout = (1 + g) x + o, recursive least squares, discounted by
``forget``) and, once the calibrated length is known to CAL_TRUST, averaged with the fitted offset
(``identification.fuse``): the readout sees the length at once and has no sign ambiguity, where the
fit, near the optimum, has to tell +x from -x through the moves since earlier frames; the fit is
sharper where the model holds.

Measured scores and costs: docs/results.md (the physics-informed controller) and
docs/imperfections.md (with lab imperfections).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ops_jax import EnvSpec
from ops_jax.ranges import Range
from agents.controllers import spgd
from agents.controllers.identification import FIT_VAR0, fuse, theta_layout, wrap
from agents.controllers.physics_fit import Shape, Steps, Theta, shape_of
from agents.controllers.physics_fit import fitted_stages  # noqa: F401  (its place in the public API)
from agents.controllers.physics_fit import steps_of, theta_of
from agents.api import Policy, TrainResult, evaluated_result
from agents.config import HISTORY, AlgoConfig, field, flag, optional
from agents.registry import Algo
from agents.envs import built, check_env_spec


@dataclasses.dataclass(frozen=True)
class PhysicsConfig(AlgoConfig):
    """The physics-informed controller (``agents.controllers.physics_informed``): the fit and the
    control gain."""

    NAME: ClassVar[str] = "physics"
    DEFAULT_PRESET: ClassVar[str] = "default"
    PRESETS: ClassVar[dict] = {
        "default": dict(  # identifies the imperfections and reads the calibrated length readout
            starts=16,
            iters=8,
            damping=1e-3,
            w_hist=1.0,
            gain=1.0,
            drift_gain=0.0,
            use_lengths=True,
            lengths_only=False,
            identify=True,
            forget=0.98,
        ),
        # the detector's frames alone, the ideal model: no identification, no length readout
        "frames": dict(
            starts=16,
            iters=8,
            damping=1e-3,
            w_hist=1.0,
            gain=1.0,
            drift_gain=0.0,
            use_lengths=False,
            lengths_only=False,
            identify=False,
            forget=0.98,
        ),
    }
    # the frames' fit to acquire, SPGD's dither step to hold near the top (2 measurements per step);
    # it gains over "frames" only where a probe is read in the frame's instant (ops_jax
    # EnvConfig.probe; docs/imperfections.md)
    PRESETS["frames-hold"] = dict(PRESETS["frames"], hold=0.85)

    starts: int = field(Range(0, 4096, integer=True))
    iters: int = field(Range(1, 1000, integer=True))
    damping: float = field(Range(0, 1e6))
    w_hist: float = field(Range(0, 1e6))
    gain: float = field(Range(0, 10))
    drift_gain: float = field(Range(0, 1))
    use_lengths: bool = field(flag)
    lengths_only: bool = field(flag)
    identify: bool = field(flag)
    forget: float = field(Range(0, 1, lo_open=True))
    history: int = field(HISTORY, default=1)
    # the measured P/Pmax at and above which SPGD's proportional step from one dither probe (its
    # preset's gains) moves the lines instead of the fit (None: the fit's move throughout, 1
    # measurement per step)
    hold: float | None = field(optional(Range(0, 1)), default=None)

    def check(self):
        if self.starts == 0 and not self.use_lengths:
            raise ValueError(
                "starts must be >= 1 unless use_lengths=True (nothing to start the fit from)"
            )


ALGO = Algo("physics", __name__, PhysicsConfig, "Physics")


# the hold's dither: the step's key folded with this, apart from the fit's random starts
HOLD_STREAM = 1


def params_template(env_spec, config):
    del env_spec, config
    return {"action_scale": np.float32(0), "window": np.float32(0)}


def policy_params(env_config: EnvSpec | dict) -> dict:
    """The controller's numbers from its environment: ``action_scale`` (wl per action unit) and
    ``window`` (wl, the observation's length normalisation). Parameters, not constants of the
    program, so one compiled policy serves every mode (make_policy reads only the static config)."""
    _, env_params = built(env_config)
    return params_of(env_params, np)


def params_of(env_params, xp=jnp) -> dict:
    """``policy_params`` of an ``EnvParams`` (``xp``: ``jax.numpy``, which keeps traced fields
    traced, or ``numpy``)."""
    return {
        "action_scale": xp.float32(env_params.action_scale),
        "window": xp.float32(env_params.window),
    }


def init_carry(shape: Shape, theta: Theta, b: int) -> dict:
    """The carry of ``b`` instances before their first step: no earlier frame, move, estimate or
    drift; theta at its start and prior (``identify``); the readout's calibration empty
    (``readout``)."""
    ny, fit, older = shape.ny, shape.fit, shape.older
    carry = {
        "y_prev": jnp.zeros((b, ny), jnp.float32),
        "dz_prev": jnp.zeros((b, fit), jnp.float32),
        "z": jnp.zeros((b, fit), jnp.float32),
        "v": jnp.zeros((b, fit), jnp.float32),
        "valid": jnp.zeros((b,), jnp.float32),
    }
    if older:
        carry.update(
            y_older=jnp.zeros((b, older, ny), jnp.float32),
            dz_older=jnp.zeros((b, older, fit), jnp.float32),
            valid_older=jnp.zeros((b, older), jnp.float32),
        )
    if shape.identify:
        n_theta = theta.start.size
        carry.update(
            theta=jnp.broadcast_to(theta.start, (b, n_theta)),
            info=jnp.broadcast_to(theta.prior, (b, n_theta, n_theta)),
        )
    if shape.readout:
        carry.update(
            cal_info=jnp.zeros((b, fit, 2, 2), jnp.float32),
            cal_vec=jnp.zeros((b, fit, 2), jnp.float32),
            fit_var=jnp.full((b, fit), FIT_VAR0, jnp.float32),
        )
    return carry


def earlier_frames(shape: Shape, carry: dict) -> tuple:
    """(frames (B, H, ny), moves (B, H, fit), valid (B, H)) of the H frames before the latest,
    newest first, and the carry's update that shifts them by one."""
    frames, moves, valid = (
        carry["y_prev"][:, None],
        carry["dz_prev"][:, None],
        carry["valid"][:, None],
    )
    older = shape.older
    if not older:
        return frames, moves, valid, {}
    # ``dz_prev`` is read here, so that an observer may record the move really sent
    frames = jnp.concatenate([frames, carry["y_older"]], axis=1)
    moves = jnp.concatenate([moves, carry["dz_older"]], axis=1)
    valid = jnp.concatenate([valid, carry["valid_older"]], axis=1)
    shifted = dict(
        y_older=frames[:, :older], dz_older=moves[:, :older], valid_older=valid[:, :older]
    )
    return frames, moves, valid, shifted


def estimate(shape: Shape, steps: Steps, carry: dict, inputs: tuple, key) -> tuple:
    """The offsets (B, fit) wl from the latest frame, the earlier ones and the length readouts: (z,
    theta, the carry's update). ``inputs``: (theta (B, n_theta), y (B, ny), x_len (B, n) wl, z_pred
    (B, fit) wl, frames, moves, valid of ``earlier_frames``)."""
    th, y, x_len, z_pred, frames, moves, valid = inputs
    config, fit = shape.config, shape.fit
    if config.lengths_only or fit == 0:
        return wrap(x_len[:, :fit]), th, {}
    new = {}
    hist = (frames, moves, carry["v"], config.w_hist * valid)
    keys = jax.random.split(key, y.shape[0])
    z = jax.vmap(steps.estimate_one)(keys, th, y, hist, z_pred, wrap(x_len[:, :fit]))
    if shape.identify:
        z, th, info = jax.vmap(steps.identify_one)(z, th, carry["info"], y, hist)
        new.update(theta=th, info=info)
    if shape.readout:
        cal_info, cal_vec, z_cal, sd = jax.vmap(jax.vmap(steps.calibrate_one))(
            carry["cal_info"], carry["cal_vec"], z, x_len[:, :fit]
        )
        z, fit_var = fuse(z, z_cal, sd, carry["fit_var"], config.forget)
        new.update(cal_info=cal_info, cal_vec=cal_vec, fit_var=fit_var)
    return z, th, new


def control(shape: Shape, carry: dict, z, z_pred, th, scale) -> tuple:
    """The move to the nearest optimum: (action (B, n) in [-1, 1], the drift estimate v (B, fit) wl
    per step); ``scale``: wl per action unit."""
    config, fit, layout = shape.config, shape.fit, theta_layout(shape.n, shape.fit)
    # Drift (free-running mean, wl per step): integrate the innovation of the prediction.
    v = carry["v"] + config.drift_gain * carry["valid"][:, None] * wrap(z - z_pred)
    # wl moved per action unit
    per_unit = scale * (1 + th[:, layout["actuator_gain"]]) if shape.identify else scale
    a_fit = jnp.clip(-(config.gain * z + v) / per_unit, -1.0, 1.0)
    b = z.shape[0]
    return jnp.concatenate([a_fit, jnp.zeros((b, shape.n - fit), jnp.float32)], axis=1), v


def held(obs_layout, hold: float, action, obs, key, probe):
    """``action`` where the measured P/Pmax is under ``hold``, SPGD's proportional step
    elsewhere."""
    if probe is None:
        raise ValueError(
            "hold needs a probe (one more detector reading per step): run the controller "
            "through agents.evaluate or agents.bench.runner, or set hold=None"
        )
    amp = spgd.HOLD["delta"]  # the hold's dither (wl)
    s = spgd.dither(jax.random.fold_in(key, HOLD_STREAM), action.shape)
    p0 = obs_layout.power(obs)
    p1 = probe(amp * s, p0 >= hold)  # none under the hold, where the fit's move is sent
    return spgd.held(action, p0, spgd.slope(p0, p1, s, amp), hold)


def act_step(shape: Shape, steps: Steps, obs_layout, params: dict, carry: dict, obs, key, probe):
    """One control step of B instances: (action (B, n), the next carry); ``params``:
    ``policy_params``."""
    scale, window = params["action_scale"], params["window"]
    b, n, fit = obs.shape[0], shape.n, shape.fit
    y = obs_layout.detector(obs)
    if obs_layout.lengths:
        x_len = obs_layout.length_readouts(obs, window)
    else:
        x_len = jnp.zeros((b, n), jnp.float32)
    th = carry["theta"] if shape.identify else jnp.zeros((b, 0), jnp.float32)
    move = (
        jax.vmap(steps.moved)(carry["dz_prev"], th) + carry["v"]
    )  # length change + drift since y_prev
    z_pred = wrap(carry["z"] + move)
    frames, moves, valid, new = earlier_frames(shape, carry)
    inputs = (th, y, x_len, z_pred, frames, moves, valid)
    z, th, estimated = estimate(shape, steps, carry, inputs, key)
    action, v = control(shape, carry, z, z_pred, th, scale)
    if shape.config.hold is not None:
        action = held(obs_layout, shape.config.hold, action, obs, key, probe)
    dz = action[:, :fit] * scale
    step = {"y_prev": y, "dz_prev": dz, "z": z, "v": v, "valid": jnp.ones((b,), jnp.float32)}
    return action, {**step, **new, **estimated}


def make_policy(env_spec: EnvSpec, config: PhysicsConfig | None = None) -> Policy:
    """The physics-informed policy on the environment of ``env_spec`` (an ``EnvSpec`` or a dict of
    its options), with ``config`` (None: the default preset); ``params``: ``policy_params(...)``
    (None: those of ``env_spec``)."""
    env_spec = check_env_spec(env_spec)
    env, _ = built(env_spec)
    obs_layout = env.layout
    shape = shape_of(PhysicsConfig.of(config), env.config, obs_layout)
    default = policy_params(env_spec)
    theta = theta_of(shape)
    steps = steps_of(shape, env.config.detector, theta)

    def init(key, obs):
        del key
        return init_carry(shape, theta, obs.shape[0])

    def act(params, carry, obs, key, probe):
        p = default if params is None else params
        return act_step(shape, steps, obs_layout, p, carry, obs, key, probe)

    def sent(params, carry, action):
        scale = (default if params is None else params)["action_scale"]
        return dict(carry, dz_prev=jnp.clip(action[:, : shape.fit], -1.0, 1.0) * scale)

    return Policy(init, act, sent)


def train(
    env_config: dict,
    *,
    seed: int = 0,
    total_steps: int | None = None,
    progress_fn=None,
    curve_episodes: int = 32,
    config: PhysicsConfig | str | None = None,
    **hyper,
) -> TrainResult:
    """Nothing to learn (the model is the simulator): validates; the curve is
    ``agents.evaluate(result, env_config, episodes=curve_episodes, seed=seed)``, reported once to
    ``progress_fn(0, metrics)``. ``total_steps`` is ignored."""
    env_spec = check_env_spec(env_config)
    c = PhysicsConfig.make(config, **hyper)
    return evaluated_result(
        "physics", env_spec, c, policy_params(env_spec), seed, curve_episodes, progress_fn
    )
