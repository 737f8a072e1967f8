"""Stacking with imperfect optics, in both physics models (field: exact; phasor: fast).

Each stage i is the ideal one (physics.md section 3) with two changes (docs/imperfections.md derives
both):
- a leaky PBS (``leak_i``, intensity fraction 1/ER sent to the wrong port on every pass): the light
  passes the PBS twice, at the split and at the recombination, each pass a unitary split whose
  unused output port is lost. The intended path keeps amplitude 1 - leak, the path that leaks on
  both passes amplitude leak: P = (1 - leak) p + leak delay(p), S = (1 - leak) delay(s) + leak s.
  The stage map has norm <= 1, so no configuration creates energy.
- wave plate rotation ``rot_i`` (rad; 45 degrees ideal, 45 + 2 eps for a half-wave plate set eps
  off, followed by the turning mirror's reflection): p' = cos(rot) P + sin(rot) S, s' = -sin(rot)
  P + cos(rot) S; the next stage splits sin^2(rot):cos^2(rot).
The 2^N input pulses carry complex weights ``pulses`` (re, im) (..., 2^N) (1 for identical pulses).
The stage map is still linear and the same for every train entry, so the entries are summed first
as in ``physics``. The phasor model drops the light that stage 1's leakage puts half a period
(10 ps) off the 20 ps slot grid (error bound ``phasor_error_bound``).
Lengths in wavelengths; works under jit, vmap and grad.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ops_jax import physics


def rotation(waveplate_error_deg):
    """Polarisation rotation (rad) of a half-wave plate set ``waveplate_error_deg`` off 22.5 deg."""
    return np.pi / 4 + 2 * jnp.deg2rad(waveplate_error_deg)


@functools.lru_cache(maxsize=None)
def _entry_spectra(stages: int):
    """Spectra of the p and the s input entries, (2^(N-1), 2^N, 40) complex each, in the
    fftshift block layout of ``physics._field_constants``."""
    g = physics.grid(stages)
    A0 = physics._to_spectrum(physics._base_pulse(stages))
    order = (np.arange(g.n) + g.n // 2) % g.n
    p, s = [], []
    for k, lab in enumerate(physics.labels(stages)):
        Ak = (
            (-1.0 if lab.startswith("-") else 1.0)
            * A0
            * np.exp(-1j * g.w * k * physics.PERIOD_PS / 2)
        )
        (p if lab.endswith("p") else s).append(
            Ak[order].reshape(2**stages, physics.POINTS_PER_PERIOD)
        )
    return np.stack(p), np.stack(s)


def _weighted(w, basis, dtype):
    """sum_k w_k basis_k for complex weights (re, im) (..., K) and basis (K, Q, R): (re, im)."""
    br, bi = jnp.asarray(basis.real, dtype), jnp.asarray(basis.imag, dtype)
    dot = lambda a, b: jnp.tensordot(a, b, axes=1)
    return dot(w[0], br) - dot(w[1], bi), dot(w[0], bi) + dot(w[1], br)


def _split_recombine_rotate(p, S_del, P_del, s, a, l, c, sn):
    """Leaky PBS (intended path a, doubly leaked path l) then the wave plate, on (re, im) pairs;
    a, l, c, sn broadcast."""
    P = tuple(a * u + l * v for u, v in zip(p, P_del))
    S = tuple(a * u + l * v for u, v in zip(S_del, s))
    return tuple(c * u + sn * v for u, v in zip(P, S)), tuple(c * v - sn * u for u, v in zip(P, S))


def _per_stage(rot, leak):
    """(cos, sin, a, l) per stage, stage axis first: a = 1 - leak (split and recombined as
    intended), l = leak (sent to the wrong arm and recombined from it: two leaks, amplitudes
    sqrt(leak) each)."""
    a, l = 1 - leak, leak
    return tuple(jnp.moveaxis(v, -1, 0) for v in (jnp.cos(rot), jnp.sin(rot), a, l))


def _field(x, rot, leak, pulses, stages, detector):
    bp, bs = _entry_spectra(stages)
    p = _weighted((pulses[0][..., 0::2], pulses[1][..., 0::2]), bp, x.dtype)
    s = _weighted((pulses[0][..., 1::2], pulses[1][..., 1::2]), bs, x.dtype)

    def stage(carry, d):
        p, s = carry
        aq_re, aq_im, ar_re, ar_im, *k = d
        delay = lambda f: physics._cmul(
            physics._cmul(f, (ar_re[..., None, :], ar_im[..., None, :])),
            (aq_re[..., :, None], aq_im[..., :, None]),
        )
        k = [v[..., None, None] for v in k]
        return _split_recombine_rotate(p, delay(s), delay(p), s, k[2], k[3], k[0], k[1]), None

    xs = (*physics._field_delays(x, stages, jnp), *_per_stage(rot, leak))
    p, s = jax.lax.scan(stage, (p, s), xs)[0]
    I = physics._intensity(p, s, detector, jnp)
    ppp = physics.POINTS_PER_PERIOD
    return physics.Measurement(
        physics._power(I, physics._field_constants(stages)["dt"]),
        I[..., ppp::ppp][..., : 2**stages - 1],
        I,
    )


def _phasor(x, rot, leak, pulses, stages, detector):
    c = physics._phasor_constants(stages)
    dtype = x.dtype
    d = physics._expi(jnp.asarray(np.angle(c["D_opt"]), dtype) + 4 * np.pi * x, jnp)  # (..., N)
    cw = lambda carrier, sl: physics._cmul(
        (pulses[0][..., sl], pulses[1][..., sl]),
        (jnp.asarray(carrier.real, dtype), jnp.asarray(carrier.imag, dtype)),
    )
    p, s = cw(c["Ep"], slice(0, None, 2)), cw(c["Es"], slice(1, None, 2))
    k = _per_stage(rot, leak)
    # Stage 1 (s already on the 20 ps grid); its leaked light lies off the grid and is dropped.
    zero = (jnp.zeros_like(p[0]), jnp.zeros_like(p[1]))
    first = [v[0][..., None] for v in k]
    p, s = _split_recombine_rotate(
        p,
        physics._cmul(s, (d[0][..., :1], d[1][..., :1])),
        zero,
        zero,
        first[2],
        0.0,
        first[0],
        first[1],
    )
    pad = lambda a: jnp.concatenate([a, jnp.zeros_like(a)], axis=-1)
    p, s = (pad(p[0]), pad(p[1])), (pad(s[0]), pad(s[1]))
    slots = 2**stages

    def stage(carry, d):
        p, s = carry
        shift, d_re, d_im, *k = d
        roll = lambda f: tuple(
            jax.lax.dynamic_slice_in_dim(jnp.concatenate([a, a], -1), shift, slots, -1) for a in f
        )
        delay = lambda f: physics._cmul(roll(f), (d_re[..., None], d_im[..., None]))
        k = [v[..., None] for v in k]
        return _split_recombine_rotate(p, delay(s), delay(p), s, k[2], k[3], k[0], k[1]), None

    shifts = jnp.asarray(2 ** np.arange(stages - 1), jnp.int32)
    xs = (shifts, *(jnp.moveaxis(a[..., 1:], -1, 0) for a in d), *(v[1:] for v in k))
    p, s = jax.lax.scan(stage, (p, s), xs)[0]
    return physics._phasor_detect(p, s, stages, detector)


def measure(
    deltas_wl, rot, leak, pulses, *, stages: int, model: str = "field", detector: str = "total"
):
    """Detect the stacked output of imperfect optics: offsets ``deltas_wl`` (..., N) wl, wave plate
    rotations ``rot`` (..., N) rad, PBS leakage ``leak`` (..., N), input pulse weights ``pulses``
    (re, im) each (..., 2^N). With rot = pi/4, leak = 0 and unit pulses this is
    ``physics.measure``."""
    x = jnp.asarray(deltas_wl)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    shape = x.shape
    rot, leak = (jnp.broadcast_to(jnp.asarray(v, x.dtype), shape) for v in (rot, leak))
    pulses = tuple(
        jnp.broadcast_to(jnp.asarray(v, x.dtype), (*shape[:-1], 2**stages)) for v in pulses
    )
    fn = _field if model == "field" else _phasor
    return fn(x, rot, leak, pulses, stages, detector)


def ideal_pulses(stages: int, batch=()):
    """Unit weights (re, im) of identical input pulses."""
    return jnp.ones((*batch, 2**stages)), jnp.zeros((*batch, 2**stages))


PHASOR_ERROR = (
    2e-4,
    0.2,
)  # |P_phasor - P_field| <= (c0 + c1 leak_1) P_max (E / E_ideal)^2, docs/imperfections.md


def phasor_error_bound(leak_1, pulses=None, *, stages: int, detector: str = "total"):
    """The documented bound on |P_phasor - P_field| (P units) for stage 1's leakage ``leak_1`` and
    the input pulse weights ``pulses`` (re, im) (..., 2^N) (None: identical pulses), whose mean
    energy E / E_ideal scales P_max by its square."""
    energy = 1.0 if pulses is None else jnp.mean(pulses[0] ** 2 + pulses[1] ** 2, axis=-1)
    return (
        (PHASOR_ERROR[0] + PHASOR_ERROR[1] * leak_1) * physics.p_max(stages, detector) * energy**2
    )
