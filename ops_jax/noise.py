"""Noise processes of the OPS control loop (physics.md section 5). Lengths in wavelengths (wl).

All functions are pure and keyed; shapes follow the stage count N of ``mu`` / ``shape``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

# The reference's free-running noise std (wl); observation entry e is mu_t in these units.
REFERENCE_SIGMA_WL = 5e-4


def clipped_normal(key, loc, scale, width, shape):
    """Normal(loc, scale) clipped to loc +- width * scale."""
    z = jnp.clip(jax.random.normal(key, shape), -width, width)
    return loc + scale * z


def free_run(key, mu, sigma, feedback_k: int):
    """Length change (wl) over one control period: the sum of ``feedback_k`` free-running draws,
    each clip(Normal(mu, sigma), mu +- 3 sigma) per stage. ``mu`` (N,) is the current mean."""
    draws = clipped_normal(key, 0.0, 1.0, 3.0, (feedback_k, *jnp.shape(mu)))
    return feedback_k * mu + sigma * draws.sum(0)


def initial_offsets(key, init_loc, spread, stages: int):
    """Reset offsets from the optimum: clip(Normal(init_loc, s0), init_loc +- 2 s0) per stage."""
    return clipped_normal(key, init_loc, spread, 2.0, (stages,))


def episode_drift(key, episode, cap, ramp):
    """The reference's hard-mode drift factor r ~ Uniform(-s, s), s = min(cap, episode * ramp),
    where ``episode`` counts the resets before this one (0 at the first: no drift)."""
    s = jnp.minimum(cap, episode * ramp)
    return s * jax.random.uniform(key, minval=-1.0, maxval=1.0)


def drift_knot(key, amplitude, stages: int):
    """A knot of the within-episode piecewise-linear drift mean: Uniform(-amplitude, amplitude) (wl)."""
    return amplitude * jax.random.uniform(key, (stages,), minval=-1.0, maxval=1.0)


def piecewise_linear(prev_knot, next_knot, t, segment):
    """Value at step t of the line from ``prev_knot`` (at the segment start) to ``next_knot``."""
    frac = (t % segment) / segment
    return prev_knot + frac * (next_knot - prev_knot)
