"""The physics-informed controller's online identification (``agents.controllers.physics_informed``,
``identify=True``): the static unknowns theta and their recursive estimate, the length readout's
calibration and its fusion with the frames' fit; ``wrap``, an offset from the nearest optimum."""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

if TYPE_CHECKING:
    from agents.controllers.physics_informed import PhysicsConfig


def wrap(x):
    """Offset from the nearest optimum (period wl/2), in [-0.25, 0.25) wl."""
    return x - 0.5 * jnp.round(x / 0.5)


# Online identification (``identify=True``): the static unknowns theta, with their start, prior
# standard deviation and accepted range: detector gain error and offset (y = 2 ((1 + g) v + o) - 1),
# each stage's wave plate rotation error (rad) and PBS leakage amplitude sqrt(leak) (started off
# zero, where P is flat in it), each fitted line's actuator gain error; NOISE_Y: the assumed noise
# of y.
THETA = {  # block: (start, prior SD, lowest, highest)
    "detector_gain": (0.0, 0.05, -0.3, 0.3),
    "detector_offset": (0.0, 0.05, -0.3, 0.3),
    "rotation": (0.0, 0.03, -0.15, 0.15),
    "leak_amplitude": (0.02, 0.03, 1e-3, 0.3),
    "actuator_gain": (0.0, 0.15, -0.5, 0.5),
}
NOISE_Y = 0.01
# The length readout's calibration (``identify=True`` with ``use_lengths=True``): readout = (1 + g)
# x + o per fitted line, recursive least squares of the readout on the fitted lengths (their assumed
# error CAL_NOISE wl, innovations beyond CAL_CLIP times their standard deviation cut) from the prior
# o ~ N(0, CAL_PRIOR^2) wl, 1 + g ~ N(1, CAL_PRIOR^2); the controller reads the calibrated readout
# where its standard deviation is below CAL_TRUST wl, the fitted offsets elsewhere.
CAL_NOISE, CAL_CLIP, CAL_PRIOR, CAL_TRUST = 0.01, 3.0, 0.05, 0.002
# Where it is trusted, the calibrated readout (per-step noise CAL_READ_SD wl on top of its
# calibration's standard deviation) and the fit are averaged by inverse variance (``fuse``); the
# fit's variance starts at FIT_VAR0 wl^2 and is at least FIT_VAR_MIN.
CAL_READ_SD, FIT_VAR0, FIT_VAR_MIN = 1e-3, 1e-4, 1e-8


def fuse(z_fit, z_cal, sd, fit_var, forget: float):
    """One line's length (wl, modulo the period) from the frames' fit ``z_fit`` and the calibrated
    readout ``z_cal`` (standard deviation ``sd`` wl): the fit or its mirror image, whichever is
    nearer the readout (near the optimum the frames cannot tell +x from -x), averaged with the
    readout by inverse variance. The fit's variance ``fit_var`` (wl^2) is the discounted mean square
    of its distance to the readout less the readout's own variance. Returns (length, fit_var); the
    fit alone while ``sd`` >= CAL_TRUST."""
    var_cal = sd**2 + CAL_READ_SD**2
    near = jnp.where(jnp.abs(wrap(-z_fit - z_cal)) < jnp.abs(wrap(z_fit - z_cal)), -z_fit, z_fit)
    d = wrap(near - z_cal)
    trusted = sd < CAL_TRUST
    fit_var = jnp.where(trusted, forget * fit_var + (1 - forget) * d**2, fit_var)
    w_fit = var_cal / (var_cal + jnp.maximum(fit_var - var_cal, FIT_VAR_MIN))
    return jnp.where(trusted, wrap(z_cal + w_fit * d), z_fit), fit_var


def theta_layout(n: int, fit: int) -> dict:
    """Slices of theta's blocks: detector gain, offset (1 each), rotations and leak amplitudes (N
    each), actuator gains (``fit``)."""
    sizes = {
        "detector_gain": 1,
        "detector_offset": 1,
        "rotation": n,
        "leak_amplitude": n,
        "actuator_gain": fit,
    }
    out, i = {}, 0
    for k, size in sizes.items():
        out[k], i = slice(i, i + size), i + size
    return out


def per_theta(n: int, fit: int, column: int) -> np.ndarray:
    """Column ``column`` of ``THETA`` (0 start, 1 prior SD, 2 lowest, 3 highest) as a vector over
    theta."""
    layout = theta_layout(n, fit)
    out = np.zeros(max(s.stop for s in layout.values()), np.float32)
    for k, sl in layout.items():
        out[sl] = THETA[k][column]
    return out


def identify_function(
    fit: int, n_theta: int, config: PhysicsConfig, residual, max_step, theta_lo, theta_hi
):
    """The identification: ``identify_one(z, th, info, y, hist) -> (z, th, info)`` of one instance
    (``config``'s ``damping`` and ``forget``)."""

    def identify_one(z, th, info, y, hist):
        """One Gauss-Newton step on (z, theta) with theta's accumulated information as its prior,
        then the information update (the Schur complement of z: what this step tells about theta
        alone)."""

        def res(u):
            return residual(u[:fit], u[fit:], y, hist)

        u = jnp.concatenate([z, th])
        J = jax.jacfwd(res)(u)
        A = J.T @ J
        prior_full = jnp.zeros((fit + n_theta,) * 2).at[fit:, fit:].set(info)
        A_reg = (
            A
            + prior_full
            + config.damping * (jnp.diag(jnp.diag(A)) + 1e-6 * jnp.eye(fit + n_theta))
        )
        step = -jnp.linalg.solve(A_reg, J.T @ res(u))
        z_new = wrap(z + jnp.clip(step[:fit], -0.05, 0.05))
        th_new = jnp.clip(th + jnp.clip(step[fit:], -max_step, max_step), theta_lo, theta_hi)
        azz, azt, att = A[:fit, :fit], A[:fit, fit:], A[fit:, fit:]
        schur = att - azt.T @ jnp.linalg.solve(azz + 1e-6 * jnp.eye(fit), azt)
        info_new = config.forget * info + schur
        return z_new, th_new, 0.5 * (info_new + info_new.T)

    return identify_one


def calibrate_function(config: PhysicsConfig):
    """The length readout's calibration: ``calibrate_one(info, vec, z, r)`` of one line
    (``config``'s ``forget``)."""
    cal_prior = jnp.eye(2) / CAL_PRIOR**2  # information of (o, 1 + g) before any data
    cal_mean = jnp.array([0.0, 1.0])

    def calibrate_one(info, vec, z, r):
        """One line's readout calibration: the recursive least squares update with the fitted offset
        ``z`` (wl, modulo the period) and readout ``r`` (wl); returns (info, vec, the calibrated
        length (wl, modulo the period), its standard deviation (wl))."""

        def solve(info, vec):
            A = info + cal_prior
            return jnp.linalg.solve(A, vec + cal_prior @ cal_mean), jnp.linalg.inv(A)

        beta, cov = solve(info, vec)
        x = z + 0.5 * jnp.round(
            ((r - beta[0]) / beta[1] - z) / 0.5
        )  # the fitted length, unwrapped by the readout
        phi = jnp.array([1.0, x])
        innov = r - phi @ beta
        bound = CAL_CLIP * jnp.sqrt(CAL_NOISE**2 + phi @ cov @ phi)
        r_used = phi @ beta + jnp.clip(innov, -bound, bound)
        info = config.forget * info + jnp.outer(phi, phi) / CAL_NOISE**2
        vec = config.forget * vec + phi * r_used / CAL_NOISE**2
        beta, cov = solve(info, vec)
        x_cal = (r - beta[0]) / beta[1]
        d = jnp.array([-1.0, -x_cal]) / beta[1]  # gradient of x_cal in (o, 1 + g)
        return info, vec, wrap(x_cal), jnp.sqrt(d @ cov @ d)

    return calibrate_one
