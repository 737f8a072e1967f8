"""Optical pulse stacking physics: the exact interference-field model and the fast phasor model.

Units: time ps, length mm, angular frequency rad/ps, power as in the reference (``P`` is the
"f2 power" of physics.md section 4). Delay-line offsets are given in wavelengths (wl) from the
optimal lengths ``L_i*``.

Every stage acts on the (p, s) Jones pair of *each* train entry with the same linear map
``(p, s) -> ((p + D s) / sqrt2, (D s - p) / sqrt2)`` (``D`` = delay of stage i) and sums each pair
of entries. By linearity the N stages therefore act on the *sum of all entries* once:
``out = M_N ... M_1 sum_k e_k``. The delay-independent sum is precomputed per configuration, so
a step costs N phase vectors, 2N complex multiplies per frequency and one FFT per polarisation.
The delay phase ``-w_k * delta_i`` is split into a float64 precomputed part (the optimal delay,
~1e6 rad) and the small offset part ``4 pi x + 2 dw_k x wl / c``; the latter is linear in the
frequency index and is built as an outer product of two short phase vectors (2^N + 40 sin/cos per
stage instead of 40 * 2^N).
"""

from __future__ import annotations

import functools
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

# Physical constants of the reference (physics.md section 1).
C_MM_PER_PS = 0.299792458
WAVELENGTH_MM = 1030e-6
PERIOD_PS = 20.0
FWHM_PS = 4.0
T0_PS = FWHM_PS / 1.76
PULSE_ENERGY_J = 2e-10
POINTS_PER_PERIOD = 40  # n = 40 * 2^N, dt = 0.5 ps
W0 = 2 * np.pi * C_MM_PER_PS / WAVELENGTH_MM  # rad/ps

MODELS = ("field", "phasor")
DETECTORS = ("total", "polariser")


class Measurement(NamedTuple):
    """What the detector sees. ``power``: P (reference units), shape (...);
    ``samples``: the 2^N - 1 oscilloscope samples of I(t) (W), shape (..., 2^N - 1);
    ``intensity``: full I(t) on the time grid, shape (..., 40 * 2^N) (field model only, else None)."""

    power: jax.Array
    samples: jax.Array
    intensity: Optional[jax.Array]


def check_stages(stages) -> int:
    """Validate the stage count N (an integer >= 1) and return it as int."""
    if isinstance(stages, bool) or not isinstance(stages, (int, np.integer)):
        raise TypeError(f"stages must be an integer >= 1, got {stages!r} ({type(stages).__name__})")
    if stages < 1:
        raise ValueError(f"stages must be an integer >= 1, got {stages}")
    return int(stages)


def _check_choice(name, value, accepted):
    if value not in accepted:
        raise ValueError(f"{name} must be one of {accepted}, got {value!r}")
    return value


def labels(stages: int) -> list:
    """Sign/polarisation label of each of the 2^N train entries (physics.md section 2)."""
    rule = {"p": ("p", "s"), "-p": ("-p", "-s"), "s": ("-p", "s"), "-s": ("p", "-s")}
    seq = ["-s"]
    for _ in range(check_stages(stages)):
        seq = [x for lab in seq for x in rule[lab]]
    return seq


class Grid(NamedTuple):
    """Time/frequency grid of an N-stage configuration (float64 NumPy)."""

    n: int
    dt: float  # ps
    t: np.ndarray  # ps, centred, no end point
    w: np.ndarray  # absolute angular frequency, rad/ps


@functools.lru_cache(maxsize=None)
def grid(stages: int) -> Grid:
    n = POINTS_PER_PERIOD * 2 ** check_stages(stages)
    window = 2**stages * PERIOD_PS
    dt = window / n
    t = -window / 2 + np.arange(n) * dt
    w = W0 + 2 * np.pi * (np.arange(n) - n / 2) / (n * dt)
    return Grid(n, dt, t, w)


def _to_spectrum(a):
    return np.fft.ifftshift(np.fft.ifft(np.fft.fftshift(a)))


def optimal_lengths_mm(stages: int) -> np.ndarray:
    """L_i* = 2^(i-1) * (T/2) * c / 2 (mm)."""
    return 2.0 ** np.arange(check_stages(stages)) * (PERIOD_PS / 2) * C_MM_PER_PS / 2


@functools.lru_cache(maxsize=None)
def _base_pulse(stages: int) -> np.ndarray:
    """Complex field a(t) of one input pulse (sqrt W), energy 2e-10 J by the trapezoid rule."""
    g = grid(stages)
    shape = 1 / np.cosh(g.t / T0_PS)
    energy = g.dt * 1e-12 * np.trapezoid(shape**2)
    return np.sqrt(PULSE_ENERGY_J / energy) * shape + 0j


def _delay_np(A, w, tau):
    return A * np.exp(-1j * w * tau)


@functools.lru_cache(maxsize=None)
def _field_constants(stages: int):
    """Delay-independent float64 arrays of the field model, frequency axis in fftshift order."""
    g = grid(stages)
    A0 = _to_spectrum(_base_pulse(stages))
    Ep = np.zeros(g.n, complex)
    Es = np.zeros(g.n, complex)
    for k, lab in enumerate(labels(stages)):
        Ak = (-1.0 if lab.startswith("-") else 1.0) * _delay_np(A0, g.w, k * PERIOD_PS / 2)
        if lab.endswith("p"):
            Ep += Ak
        else:
            Es += Ak
    delta_opt = -2 * optimal_lengths_mm(stages) / C_MM_PER_PS  # ps
    D_opt = np.exp(-1j * g.w[None, :] * delta_opt[:, None])  # (N, n)
    # fftshift order: position j holds frequency index (j + n/2) mod n.
    order = (np.arange(g.n) + g.n // 2) % g.n
    blocks = 2**stages
    # Frequency index k = 40 * q + r; in fftshift order the block index q is rolled by 2^(N-1).
    q = (np.arange(blocks) + blocks // 2) % blocks
    return dict(
        Ep=Ep[order],
        Es=Es[order],
        D_opt=D_opt[:, order],
        q=q * POINTS_PER_PERIOD - g.n / 2,  # offset part of (k - n/2) carried by the block
        r=np.arange(POINTS_PER_PERIOD, dtype=float),
        dw=2 * np.pi / (g.n * g.dt),
        dt=g.dt,
    )


def _offset_phase_field(x, c, xp):
    """exp(i (4 pi x + 2 dw (k - n/2) x wl/c)) in fftshift order for offsets x (..., N) in wl."""
    theta = 2 * c["dw"] * WAVELENGTH_MM / C_MM_PER_PS * x[..., None]  # rad per index
    phase_r = 4 * np.pi * x[..., None] + theta * xp.asarray(c["r"], x.dtype)
    phase_q = theta * xp.asarray(c["q"], x.dtype)
    outer = xp.exp(1j * phase_q)[..., :, None] * xp.exp(1j * phase_r)[..., None, :]
    return outer.reshape(*x.shape, -1)


def _stack(p, s, delays):
    """Apply the N stacking stages to the summed (p, s) Jones pair; delays (..., N, m)."""
    for i in range(delays.shape[-2]):
        S = delays[..., i, :] * s
        p, s = (p + S) / np.sqrt(2), (S - p) / np.sqrt(2)
    return p, s


def _intensity(p, s, detector, xp):
    """I(t) in time order from fftshift-ordered output spectra (a(t) = ifftshift(fft(.)))."""
    # The ideal stacked pulse leaves the last stage s-polarised: the polariser passes s.
    I = xp.abs(xp.fft.fft(s)) ** 2
    if detector == "total":
        I = I + xp.abs(xp.fft.fft(p)) ** 2
    return xp.roll(I, I.shape[-1] // 2, axis=-1)


def _power(I, dt):
    """P = 1e9 * dt[s] * trapezoid(I^2)."""
    return 1e9 * dt * 1e-12 * ((I**2).sum(-1) - 0.5 * (I[..., 0] ** 2 + I[..., -1] ** 2))


def _field_measure(x, stages, detector, xp=jnp):
    cplx = np.result_type(x.dtype, np.complex64)
    c = _field_constants(stages)
    D = xp.asarray(c["D_opt"], cplx) * _offset_phase_field(x, c, xp).astype(cplx)
    p, s = _stack(xp.asarray(c["Ep"], cplx), xp.asarray(c["Es"], cplx), D)
    I = _intensity(p, s, detector, xp)
    samples = I[..., POINTS_PER_PERIOD :: POINTS_PER_PERIOD][..., : 2**stages - 1]
    return Measurement(_power(I, c["dt"]), samples, I)


@functools.lru_cache(maxsize=None)
def _phasor_constants(stages: int):
    """Slot-domain constants. After stage 1 all light sits on the 20 ps grid: 2^N circular slots
    (slot j at t = -20 j ps). Entry k (at 10 k ps) carries its label sign and the carrier phase of
    its k*T/2 delay; stage 1 moves the odd (s) entries onto the even slots."""
    g = grid(stages)
    lab = labels(stages)
    sign = np.array([-1.0 if x.startswith("-") else 1.0 for x in lab])
    carrier = sign * np.exp(-1j * W0 * np.arange(2**stages) * PERIOD_PS / 2)
    delta_opt = -2 * optimal_lengths_mm(stages) / C_MM_PER_PS
    u = _base_pulse(stages).real
    u1 = np.roll(u, POINTS_PER_PERIOD)  # the neighbouring slot's pulse, 20 ps away
    return dict(
        Ep=carrier[0::2],  # p entries 2m at slot m
        Es=carrier[1::2],  # s entries 2m+1, shifted to slot m by stage 1's optimal delay
        D_opt=np.exp(-1j * W0 * delta_opt),  # (N,) carrier phase of the optimal delays
        # Overlap integrals (P units) of a slot with its 20 ps neighbour, for unit peak intensity:
        # K0 = int u^4 (one pulse), K2 = int u^2 u1^2, K3 = int u^3 u1.
        K0=1e9 * g.dt * 1e-12 * np.sum(u**4),
        K2=1e9 * g.dt * 1e-12 * np.sum(u**2 * u1**2),
        K3=1e9 * g.dt * 1e-12 * np.sum(u**3 * u1),
        peak=u.max() ** 2,  # W, peak intensity of one pulse
    )


def _phasor_measure(x, stages, detector):
    real = x.dtype
    cplx = jnp.complex128 if real == jnp.float64 else jnp.complex64
    c = _phasor_constants(stages)
    slots = 2 ** (stages - 1)
    D = jnp.asarray(c["D_opt"], cplx) * jnp.exp(1j * (4 * np.pi) * x).astype(cplx)  # (..., N)
    batch = x.shape[:-1]
    p = jnp.broadcast_to(jnp.asarray(c["Ep"], cplx), (*batch, slots))
    s = jnp.asarray(c["Es"], cplx) * D[..., :1]
    # Stage 1 (already aligned onto the 20 ps grid): p' = (p + S)/sqrt2, s' = (S - p)/sqrt2 on
    # 2^(N-1) slots; the output window holds 2^N slots, the upper half empty so far.
    zeros = jnp.zeros_like(p)
    p, s = (p + s) / np.sqrt(2), (s - p) / np.sqrt(2)
    p = jnp.concatenate([p, zeros], axis=-1)
    s = jnp.concatenate([s, zeros], axis=-1)
    for i in range(1, stages):
        # Stage i+1 delays s by 2^(i-1) slots (circularly, as the FFT delay of the field model).
        S = jnp.roll(s, -(2 ** (i - 1)), axis=-1) * D[..., i : i + 1]
        p, s = (p + S) / np.sqrt(2), (S - p) / np.sqrt(2)
    I_slot = jnp.abs(s) ** 2  # unit: one pulse's peak intensity
    coh = s * jnp.conj(jnp.roll(s, -1, axis=-1))  # interference of slot j with slot j+1
    if detector == "total":
        I_slot = I_slot + jnp.abs(p) ** 2
        coh = coh + p * jnp.conj(jnp.roll(p, -1, axis=-1))
    # I(t) = sum_j I_j u_j^2 + 2 Re(coh_j) u_j u_j+1 (nearest neighbours; the next are 40 ps away).
    I_next = jnp.roll(I_slot, -1, axis=-1)
    re = coh.real
    power = jnp.sum(
        c["K0"] * I_slot**2 + 2 * c["K2"] * (I_slot * I_next + 2 * re**2) + 4 * c["K3"] * re * (I_slot + I_next),
        axis=-1,
    )
    # With a(t) = fft(A), a delay tau moves a pulse to t = -tau: slot j sits at t = -20 j ps, so
    # oscilloscope sample m (t = -W/2 + 20 m ps) reads slot (2^(N-1) - m) mod 2^N.
    idx = (slots - np.arange(1, 2**stages)) % (2**stages)
    samples = c["peak"] * I_slot[..., idx]
    return Measurement(power, samples, None)


def measure(deltas_wl, *, stages: int, model: str = "field", detector: str = "total") -> Measurement:
    """Detect the stacked output for delay-line offsets ``deltas_wl`` (..., N) in wavelengths.

    ``model="field"`` is the exact model of physics.md (FFT on the 40 * 2^N grid);
    ``model="phasor"`` keeps one complex amplitude per 20 ps slot and polarisation (<= 1e-3
    relative in P, see README). ``detector="total"`` sums both polarisations (the reference);
    ``"polariser"`` passes only the s polarisation of the ideal stacked pulse, which makes the
    last stage interferometric too. Works under jit, vmap and grad; dtype follows ``deltas_wl``
    (float32 by default, float64 with ``jax_enable_x64``).
    """
    stages = check_stages(stages)
    _check_choice("model", model, MODELS)
    _check_choice("detector", detector, DETECTORS)
    x = jnp.asarray(deltas_wl)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    if x.ndim < 1 or x.shape[-1] != stages:
        raise ValueError(f"deltas_wl must have shape (..., {stages}) for stages={stages}, got {x.shape}")
    fn = _field_measure if model == "field" else _phasor_measure
    return fn(x, stages, detector)


@functools.lru_cache(maxsize=None)
def p_max(stages: int, detector: str = "total") -> float:
    """P at the optimal lengths (all energy in one pulse), float64 field model."""
    _check_choice("detector", detector, DETECTORS)
    return float(_field_measure(np.zeros(check_stages(stages)), stages, detector, np).power)


@functools.lru_cache(maxsize=None)
def p_orig(stages: int) -> float:
    """P of the unstacked input train (the reference's ``orig_f2_power``), float64."""
    c = _field_constants(check_stages(stages))
    return float(_power(_intensity(c["Ep"], c["Es"], "total", np), c["dt"]))


def peak_intensity(stages: int) -> float:
    """Peak of I(t) for the ideal stacked pulse (W): the scale of the oscilloscope samples."""
    return float(2 ** check_stages(stages) * _base_pulse(stages).real.max() ** 2)
