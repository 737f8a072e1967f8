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
    """What the detector sees. ``power``: P (reference units), shape (...); ``samples``: the 2^N - 1
    oscilloscope samples of I(t) (W), shape (..., 2^N - 1); ``intensity``: full I(t) on the time
    grid, shape (..., 40 * 2^N) (field model only, else None)."""

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
    e = np.exp(-np.abs(g.t / T0_PS))
    shape = 2 * e / (1 + e**2)  # sech without cosh overflow at large N
    energy = g.dt * 1e-12 * np.trapezoid(shape**2)
    return np.sqrt(PULSE_ENERGY_J / energy) * shape + 0j


@functools.lru_cache(maxsize=None)
def _field_constants(stages: int):
    """Delay-independent float64 arrays of the field model, frequency axis in fftshift order and
    reshaped (2^N blocks q, 40 offsets r): frequency index k = 40 q + r."""
    g = grid(stages)
    A0 = _to_spectrum(_base_pulse(stages))
    Ep = np.zeros(g.n, complex)
    Es = np.zeros(g.n, complex)
    for k, lab in enumerate(labels(stages)):
        Ak = (-1.0 if lab.startswith("-") else 1.0) * A0 * np.exp(-1j * g.w * k * PERIOD_PS / 2)
        if lab.endswith("p"):
            Ep += Ak
        else:
            Es += Ak
    # fftshift order: position j holds frequency index (j + n/2) mod n, i.e. block q is rolled.
    order = (np.arange(g.n) + g.n // 2) % g.n
    blocks = 2**stages
    Q = ((np.arange(blocks) + blocks // 2) % blocks) * POINTS_PER_PERIOD - g.n / 2  # k - n/2 - r
    r = np.arange(POINTS_PER_PERIOD, dtype=float)
    dw = 2 * np.pi / (g.n * g.dt)
    # -w_k delta_i* = (-w0 delta* - dw delta* Q) + (-dw delta* r), reduced mod 2 pi in float64.
    delta_opt = (-2 * optimal_lengths_mm(stages) / C_MM_PER_PS)[:, None]
    shape = (blocks, POINTS_PER_PERIOD)
    return dict(
        Ep=Ep[order].reshape(shape),
        Es=Es[order].reshape(shape),
        phase_q=np.mod(-W0 * delta_opt - dw * delta_opt * Q, 2 * np.pi),  # (N, 2^N)
        phase_r=np.mod(-dw * delta_opt * r, 2 * np.pi),  # (N, 40)
        Q=Q,
        r=r,
        theta=2 * dw * WAVELENGTH_MM / C_MM_PER_PS,  # rad per frequency index per wl of offset
        dt=g.dt,
    )


_R2 = 1 / np.sqrt(2)


def _cmul(a, b):
    """Product of complex numbers held as (re, im) pairs (XLA's CPU complex ops are slow)."""
    return a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]


def _expi(phase, xp):
    return xp.cos(phase), xp.sin(phase)


def _stage(p, S):
    """The 45-degree wave plate: p' = (p + S)/sqrt2, s' = (S - p)/sqrt2 on (re, im) pairs."""
    return ((p[0] + S[0]) * _R2, (p[1] + S[1]) * _R2), ((S[0] - p[0]) * _R2, (S[1] - p[1]) * _R2)


def _field_spectra(x, stages, xp):
    """Output (p, s) spectra, (re, im) pairs of shape (..., 2^N, 40), for offsets x (..., N) wl.
    The stage-i delay factor exp(-i w_k delta_i) is the outer product of a per-block and a
    per-offset phase vector (the phase is linear in k)."""
    c = _field_constants(stages)
    as_x = lambda a: xp.asarray(a, x.dtype)
    p = tuple(
        xp.broadcast_to(as_x(v), (*x.shape[:-1], *c["Ep"].shape))
        for v in (c["Ep"].real, c["Ep"].imag)
    )
    s = tuple(xp.broadcast_to(as_x(v), p[0].shape) for v in (c["Es"].real, c["Es"].imag))

    def stage(carry, d):
        p, s = carry
        aq_re, aq_im, ar_re, ar_im = d
        S = _cmul(
            _cmul(s, (ar_re[..., None, :], ar_im[..., None, :])),
            (aq_re[..., :, None], aq_im[..., :, None]),
        )
        return _stage(p, S), None

    # Scanned so that XLA fuses within a stage only (fused across stages, each output recomputes
    # every earlier stage once per use: 2^N-fold work).
    return _over_stages(stage, (p, s), _field_delays(x, stages, xp), xp)


def _field_delays(x, stages, xp):
    """Per-stage delay factors of offsets x (..., N) wl, stage axis first: (aq_re, aq_im) of shape
    (N, ..., 2^N) per block and (ar_re, ar_im) of shape (N, ..., 40) per offset in the block."""
    c = _field_constants(stages)
    as_x = lambda a: xp.asarray(a, x.dtype)
    theta = c["theta"] * x[..., None]  # (..., N, 1)
    aq = _expi(as_x(c["phase_q"]) + theta * as_x(c["Q"]) + 4 * np.pi * x[..., None], xp)
    ar = _expi(as_x(c["phase_r"]) + theta * as_x(c["r"]), xp)
    return tuple(xp.moveaxis(a, -2, 0) for a in (*aq, *ar))


def _over_stages(fn, carry, xs, xp):
    """``lax.scan(fn, carry, xs)[0]`` for JAX, a Python loop for NumPy."""
    if xp is jnp:
        return jax.lax.scan(fn, carry, xs)[0]
    for i in range(len(xs[0])):
        carry = fn(carry, tuple(a[i] for a in xs))[0]
    return carry


def _intensity(p, s, detector, xp):
    """I(t) in time order from fftshift-ordered output spectra, (re, im) pairs (..., 2^N, 40):
    a(t) = ifftshift(fft(.)). The ideal stacked pulse leaves the last stage s-polarised, so the
    polariser passes s."""

    def abs2_field(a):
        z = (a[0] + 1j * a[1]) if xp is np else jax.lax.complex(a[0], a[1])
        f = xp.fft.fft(z.reshape(*z.shape[:-2], -1))
        return f.real**2 + f.imag**2

    I = abs2_field(s)
    if detector == "total":
        I = I + abs2_field(p)
    return xp.roll(I, I.shape[-1] // 2, axis=-1)


def _power(I, dt):
    """P = 1e9 * dt[s] * trapezoid(I^2)."""
    return 1e9 * dt * 1e-12 * ((I**2).sum(-1) - 0.5 * (I[..., 0] ** 2 + I[..., -1] ** 2))


def _field_measure(x, stages, detector, xp=jnp):
    p, s = _field_spectra(x, stages, xp)
    I = _intensity(p, s, detector, xp)
    samples = I[..., POINTS_PER_PERIOD::POINTS_PER_PERIOD][..., : 2**stages - 1]
    return Measurement(_power(I, _field_constants(stages)["dt"]), samples, I)


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
    c = _phasor_constants(stages)
    half = 2 ** (stages - 1)
    dtype = x.dtype
    d = _expi(jnp.asarray(np.angle(c["D_opt"]), dtype) + 4 * np.pi * x, jnp)  # (..., N)
    batch = x.shape[:-1]
    p = tuple(
        jnp.broadcast_to(jnp.asarray(v, dtype), (*batch, half))
        for v in (c["Ep"].real, c["Ep"].imag)
    )
    s = (jnp.asarray(c["Es"].real, dtype), jnp.asarray(c["Es"].imag, dtype))
    # Stage 1 (already aligned onto the 20 ps grid) on 2^(N-1) slots; the output window holds
    # 2^N slots, the upper half empty so far.
    p, s = _stage(p, _cmul(s, (d[0][..., :1], d[1][..., :1])))
    pad = lambda a: jnp.concatenate([a, jnp.zeros_like(a)], axis=-1)
    p, s = (pad(p[0]), pad(p[1])), (pad(s[0]), pad(s[1]))
    slots = 2**stages

    def stage(carry, d):
        # Stage i+1 delays s by 2^(i-1) slots, circularly as the FFT delay of the field model.
        p, s = carry
        shift, d_re, d_im = d
        rolled = tuple(
            jax.lax.dynamic_slice_in_dim(jnp.concatenate([a, a], -1), shift, slots, -1) for a in s
        )
        return _stage(p, _cmul(rolled, (d_re[..., None], d_im[..., None]))), None

    # Scanned, not unrolled: see _field_spectra.
    shifts = jnp.asarray(2 ** np.arange(stages - 1), jnp.int32)
    p, s = _over_stages(stage, (p, s), (shifts, *(jnp.moveaxis(a[..., 1:], -1, 0) for a in d)), jnp)
    return _phasor_detect(p, s, stages, detector)


def _phasor_detect(p, s, stages, detector):
    """Measurement from the output slot amplitudes p, s ((re, im) pairs (..., 2^N), unit: one
    pulse's peak field)."""
    c = _phasor_constants(stages)
    half = 2 ** (stages - 1)
    fields = (s, p) if detector == "total" else (s,)
    nxt = lambda a: jnp.roll(a, -1, axis=-1)
    I_slot = sum(f[0] ** 2 + f[1] ** 2 for f in fields)  # unit: one pulse's peak intensity
    coh = sum(f[0] * nxt(f[0]) + f[1] * nxt(f[1]) for f in fields)  # Re of slot j x slot j+1
    # I(t) = sum_j I_j u_j^2 + 2 coh_j u_j u_j+1 (nearest neighbours; the next are 40 ps away).
    I_next = nxt(I_slot)
    power = jnp.sum(
        c["K0"] * I_slot**2
        + 2 * c["K2"] * (I_slot * I_next + 2 * coh**2)
        + 4 * c["K3"] * coh * (I_slot + I_next),
        axis=-1,
    )
    # With a(t) = fft(A), a delay tau moves a pulse to t = -tau: slot j sits at t = -20 j ps, so
    # oscilloscope sample m (t = -W/2 + 20 m ps) reads slot (2^(N-1) - m) mod 2^N.
    idx = (half - np.arange(1, 2**stages)) % (2**stages)
    samples = c["peak"] * I_slot[..., idx]
    return Measurement(power, samples, None)


def measure(
    deltas_wl, *, stages: int, model: str = "field", detector: str = "total"
) -> Measurement:
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
        raise ValueError(
            f"deltas_wl must have shape (..., {stages}) for stages={stages}, got {x.shape}"
        )
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
    pair = lambda a: (a.real, a.imag)
    return float(_power(_intensity(pair(c["Ep"]), pair(c["Es"]), "total", np), c["dt"]))


def peak_intensity(stages: int) -> float:
    """Peak of I(t) for the ideal stacked pulse (W): the scale of the oscilloscope samples."""
    return float(2 ** check_stages(stages) * _base_pulse(stages).real.max() ** 2)
