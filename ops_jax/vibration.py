"""Coloured vibration of the delay lines: a 1/f^alpha background plus damped resonances (wl).

Time is counted in control steps, frequencies in cycles per step (Nyquist 0.5). Every process is
stationary from its first step: the state drawn at reset comes from the stationary distribution.
Pure functions of standard normals ``z`` (the caller draws them from its own key), so a line's
vibration depends only on its instance's key, never on the batch.

- Background: an FIR (moving-average) filter of length ``FIR_TAPS`` with the coefficients of
  (1 - B)^(-alpha/2), psi_0 = 1, psi_k = psi_(k-1) (k - 1 + alpha/2) / k; its power spectrum is
  |1 - e^(-2 pi i f)|^(-alpha) ~ f^(-alpha) for 1/FIR_TAPS < f < 0.5 and flat below. The taps are
  scaled so that the stationary RMS is exactly ``rms``.
- Resonance r: the damped oscillator sampled once per step, an AR(2)
  y_t = 2 rho cos(w) y_(t-1) - rho^2 y_(t-2) + s e_t with w = 2 pi f, rho = exp(-w / (2 Q)),
  s chosen so that the stationary RMS of y is ``rms``; its spectrum peaks at f (Q >~ 2).
"""

from __future__ import annotations

import jax.numpy as jnp

FIR_TAPS = 64  # background memory (steps): the 1/f^alpha shape holds above 1/64 cycles per step


def fir_taps(alpha, rms):
    """(FIR_TAPS,) background filter taps (wl per unit innovation) for slope ``alpha`` in [0, 2]."""
    k = jnp.arange(1, FIR_TAPS, dtype=jnp.float32)
    psi = jnp.concatenate([jnp.ones((1,)), jnp.cumprod((k - 1 + alpha / 2) / k)])
    return psi * (rms / jnp.sqrt(jnp.sum(psi**2)))


def ar2(freq, q):
    """(phi1, phi2, gamma0, rho1) of a resonance: AR(2) coefficients, stationary variance per unit
    innovation variance and lag-1 autocorrelation."""
    w = 2 * jnp.pi * freq
    rho = jnp.exp(-w / (2 * q))
    phi1, phi2 = 2 * rho * jnp.cos(w), -(rho**2)
    gamma0 = (1 - phi2) / ((1 + phi2) * ((1 - phi2) ** 2 - phi1**2))
    return phi1, phi2, gamma0, phi1 / (1 - phi2)


def step(fir, osc, z_bg, z_res, alpha, bg_rms, freq, q, res_rms):
    """Advance one control step. ``fir`` (FIR_TAPS, N) past innovations (newest first); ``osc``
    (2, R, N) the oscillators' last two values in units of their stationary RMS (y_(t-1), y_(t-2));
    ``z_bg`` (N,), ``z_res`` (R, N) new standard normals; ``freq``, ``q``, ``res_rms`` (R,).
    Returns (fir, osc, displacement (N,) wl)."""
    fir = jnp.concatenate([z_bg[None], fir[:-1]])
    background = jnp.tensordot(fir_taps(alpha, bg_rms), fir, axes=1)
    phi1, phi2, gamma0, _ = ar2(freq[:, None], q[:, None])
    # Unit-variance oscillator: y_t = phi1 y_(t-1) + phi2 y_(t-2) + e_t / sqrt(gamma0).
    y = phi1 * osc[0] + phi2 * osc[1] + z_res / jnp.sqrt(gamma0)
    osc = jnp.stack([y, osc[0]])
    return fir, osc, background + jnp.sum(res_rms[:, None] * y, axis=0)


def stationary_lags(z, freq, q):
    """(2, R, N) unit-variance oscillator lags (y_(t-1), y_(t-2)) with the AR(2)'s lag-1
    correlation, from standard normals ``z`` (2, R, N)."""
    _, _, _, rho1 = ar2(freq[:, None], q[:, None])
    return jnp.stack([z[0], rho1 * z[0] + jnp.sqrt(1 - rho1**2) * z[1]])


def displacement(fir, osc, alpha, bg_rms, res_rms):
    """The current displacement (N,) wl from a state (without advancing it)."""
    return jnp.tensordot(fir_taps(alpha, bg_rms), fir, axes=1) + jnp.sum(
        res_rms[:, None] * osc[0], axis=0
    )
