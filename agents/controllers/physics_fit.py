"""The physics-informed controller's fit (``agents.controllers.physics_informed``): the measurement
model of the offsets (and, with ``identify``, of theta), its misfit to the latest frames and the
multi-start Levenberg-Marquardt estimate of the offsets of one instance; the static structure of a
policy (``Shape``, ``Theta``, ``Steps``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ops_jax import optics, physics
from agents.controllers.identification import NOISE_Y, calibrate_function, identify_function
from agents.controllers.identification import per_theta, theta_layout, wrap

if TYPE_CHECKING:
    from agents.controllers.physics_informed import PhysicsConfig


def model_function(n: int, fit: int, detector: str, identify: bool, layout: dict):
    """``model(z, th) -> y``: the measured vector (..., 1 + 2^n - 1) of offsets ``z`` (..., fit) wl,
    the unfitted stages at 0, with theta ``th`` (n_theta,) read where ``identify`` (the ideal
    detector and optics elsewhere)."""
    p_max = physics.p_max(n, detector)
    peak = physics.peak_intensity(n)

    def full(z):
        return jnp.concatenate([z, jnp.zeros((*z.shape[:-1], n - fit), z.dtype)], axis=-1)

    def model(z, th):
        if not identify:
            m = physics.measure(full(z), stages=n, model="phasor", detector=detector)
            return jnp.concatenate(
                [(2 * m.power / p_max - 1)[..., None], 2 * m.samples / peak - 1], axis=-1
            )
        m = optics.measure(
            full(z),
            np.pi / 4 + th[layout["rotation"]],
            th[layout["leak_amplitude"]] ** 2,
            optics.ideal_pulses(n),
            stages=n,
            model="phasor",
            detector=detector,
        )
        v = jnp.concatenate([(m.power / p_max)[..., None], m.samples / peak], axis=-1)
        return 2 * ((1 + th[layout["detector_gain"]]) * v + th[layout["detector_offset"]]) - 1

    return model


def fit_functions(
    n: int, fit: int, detector: str, identify: bool, layout: dict, config: PhysicsConfig
) -> tuple:
    """The fit: ``(moved, residual, estimate_one)``: the length change of a commanded move, the
    misfit of the measurement model and the multi-start Levenberg-Marquardt estimate of the offsets
    of one instance (``config``'s ``starts``, ``iters``, ``damping`` and ``use_lengths``)."""
    model = model_function(n, fit, detector, identify, layout)

    def moved(dz, th):
        """The length change of a commanded move ``dz`` (wl) with the identified actuator gains."""
        return dz * (1 + th[layout["actuator_gain"]]) if identify else dz

    def residual(z, th, y, hist):
        """Misfit of the latest frame ``y`` and, through the moves since, of the H frames before it.
        ``hist``: (their frames y_prev (H, ny), newest first; the moves commanded after each dz_prev
        (H, fit); the drift estimate v (fit,); their weights w (H,))."""
        y_prev, dz_prev, v, w = hist
        back = jnp.cumsum(
            jax.vmap(moved, in_axes=(0, None))(dz_prev, th) + v, axis=0
        )  # length change since each
        out = model(jnp.concatenate([z[None], z[None] - back]), th)  # one pass of the model for all
        return jnp.concatenate([out[0] - y, (w[:, None] * (out[1:] - y_prev)).ravel()])

    def lm(z, th, y, hist):
        def body(z, _):
            r = residual(z, th, y, hist)
            J = jax.jacfwd(residual)(z, th, y, hist)
            A = J.T @ J
            A = A + config.damping * (jnp.diag(jnp.diag(A)) + 1e-6 * jnp.eye(fit))
            step = -jnp.linalg.solve(A, J.T @ r)
            return z + jnp.clip(step, -0.05, 0.05), None

        z, _ = jax.lax.scan(body, z, None, length=config.iters)
        r = residual(z, th, y, hist)
        return wrap(z), jnp.sum(r**2)

    def estimate_one(key, th, y, hist, z_pred, z_len):
        cands = [z_pred[None]]
        if config.starts:
            cands.append(jax.random.uniform(key, (config.starts, fit), minval=-0.25, maxval=0.25))
        if config.use_lengths:
            cands.append(z_len[None])
        cands = jnp.concatenate(cands)
        zs, cost = jax.vmap(lm, in_axes=(0, None, None, None))(cands, th, y, hist)
        return zs[jnp.argmin(cost)]

    return moved, residual, estimate_one


def fitted_stages(config) -> int:
    """The stages the fit estimates (the interferometric ones) of an ``EnvConfig``: all N with the
    detector "polariser", 1..N-1 with "total" (its last stage's carrier phase is invisible)."""
    return config.stages if config.detector == "polariser" else config.stages - 1


class Shape(NamedTuple):
    """The static structure of one physics policy: its ``config``, the environment's ``n`` stages,
    the ``fit`` stages it estimates, the detector's vector size ``ny``, whether it identifies theta
    (``identify``) and calibrates the length readout (``readout``)."""

    config: PhysicsConfig
    n: int
    fit: int
    ny: int
    identify: bool
    readout: bool

    @property
    def older(self) -> int:
        """The frames kept beyond the one before the latest."""
        return self.config.history - 1


class Theta(NamedTuple):
    """Theta's start, accepted range (``lo``, ``hi``), prior information and largest step per
    control step (empty without ``identify``)."""

    start: jax.Array
    lo: jax.Array
    hi: jax.Array
    prior: jax.Array
    max_step: jax.Array


class Steps(NamedTuple):
    """The per-instance functions of the estimate: ``physics_fit.fit_functions``'s ``moved`` and
    ``estimate_one``, ``identification``'s ``identify_one`` and ``calibrate_one``."""

    moved: Callable
    estimate_one: Callable
    identify_one: Callable
    calibrate_one: Callable


def shape_of(config: PhysicsConfig, env_config, obs_layout) -> Shape:
    """The ``Shape`` of ``config`` on an ``EnvConfig`` and its observation layout (ValueError where
    the config reads length readouts the observation does not hold)."""
    if not obs_layout.lengths and (config.use_lengths or config.lengths_only):
        raise ValueError(
            "use_lengths and lengths_only must be False on an environment without length readouts "
            '(observe_lengths=False): use config="frames"'
        )
    fit = fitted_stages(env_config)
    identify = config.identify and fit > 0 and not config.lengths_only
    readout = identify and config.use_lengths
    return Shape(config, env_config.stages, fit, obs_layout.detector_size, identify, readout)


def theta_of(shape: Shape) -> Theta:
    """Theta's start, range, prior and step bound (``identification.THETA``) of ``shape``."""
    n, fit = shape.n, shape.fit

    def column(c):
        return jnp.asarray(per_theta(n, fit, c) if shape.identify else np.zeros(0), jnp.float32)

    lo, hi = column(2), column(3)
    if shape.identify:
        prior = jnp.diag((NOISE_Y / column(1)) ** 2)
    else:
        prior = jnp.zeros((0, 0), jnp.float32)
    return Theta(column(0), lo, hi, prior, 0.1 * (hi - lo))


def steps_of(shape: Shape, detector: str, theta: Theta) -> Steps:
    """The ``Steps`` of ``shape`` on ``detector`` ("polariser" or "total")."""
    fit, layout = shape.fit, theta_layout(shape.n, shape.fit)
    moved, residual, estimate_one = fit_functions(
        shape.n, fit, detector, shape.identify, layout, shape.config
    )
    identify_one = identify_function(
        fit, theta.start.size, shape.config, residual, theta.max_step, theta.lo, theta.hi
    )
    return Steps(moved, estimate_one, identify_one, calibrate_function(shape.config))
