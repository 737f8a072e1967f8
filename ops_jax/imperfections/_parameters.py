"""The imperfection parameters (``Imperfections``: ranges, shapes, which errors scale), the presets
("none", "lab") and their validation into float32 leaves. Lengths in wl, time in control steps."""

from __future__ import annotations

import dataclasses
import math
from functools import partial

import jax
import numpy as np
from jax.typing import ArrayLike

from ops_jax import physics
from ops_jax.ranges import Range, ranged, ranges

NUM_RESONANCES = 2
PRESETS = ("none", "lab")


@partial(jax.tree_util.register_dataclass)
@dataclasses.dataclass(frozen=True)
class Imperfections:
    """Imperfection parameters (all zero / off by default: the ideal system).

    Optics: waveplate_error_deg (N,) half-wave plate angle error (deg); pbs_leakage (N,) intensity
    fraction 1/ER into the wrong arm; pulse_amplitude_noise, pulse_phase_noise: relative amplitude
    and phase (rad) RMS of each input pulse, redrawn every step; readout_offset (N,) wl and
    readout_gain_error (N,) of the length readout in the observation. Actuators: actuator_gain_error
    (N,); backlash_wl (play width, wl); lag_steps (first-order time constant, steps); dac_bits (0:
    exact) over actuator_span_wl. Detector (P and oscilloscope samples, in units of P_max and the
    ideal peak): detector_offset, detector_gain_error, detector_saturation (full scale), adc_bits
    (0: exact) over [0, full scale]. Vibration: vib_rms (wl RMS) of a 1/f^vib_alpha background;
    resonance_freq (R,) cycles per step, resonance_q (R,), resonance_rms (R,) wl RMS. p_best: the
    best P reachable with the static imperfections (set by ``ops_jax.make``: P_max without them).
    randomize: domain randomisation r in [0, 1]: at every reset each error magnitude (``SCALED``) is
    multiplied by 1 + r u, u ~ U[-1, 1) per entry, for that episode (r = 1: 0 to 2x the values).
    randomize_layout: probability in [0, 1] that an episode's signed per-stage error patterns
    (``LAYOUT``) are each permuted over the stages, every entry's sign flipped at random (before
    ``randomize`` scales them).
    """

    waveplate_error_deg: ArrayLike = ranged(
        Range(-10.0, 10.0, unit="deg", shape="stage", scaled=True), 0.0
    )
    pbs_leakage: ArrayLike = ranged(Range(0.0, 0.5, shape="stage", scaled=True), 0.0)
    pulse_amplitude_noise: ArrayLike = ranged(Range(0.0, 0.5, scaled=True), 0.0)
    pulse_phase_noise: ArrayLike = ranged(Range(0.0, math.pi, unit="rad", scaled=True), 0.0)
    readout_offset: ArrayLike = ranged(Range(-1.0, 1.0, unit="wl", shape="stage", scaled=True), 0.0)
    readout_gain_error: ArrayLike = ranged(Range(-0.5, 0.5, shape="stage", scaled=True), 0.0)
    actuator_gain_error: ArrayLike = ranged(Range(-0.5, 0.5, shape="stage", scaled=True), 0.0)
    backlash_wl: ArrayLike = ranged(Range(0.0, 1.0, unit="wl", scaled=True), 0.0)
    lag_steps: ArrayLike = ranged(Range(0.0, 100.0, unit="steps", scaled=True), 0.0)
    dac_bits: ArrayLike = ranged(Range(0.0, 32.0), 0.0)
    actuator_span_wl: ArrayLike = ranged(Range(1e-3, 1e4, unit="wl"), 20.0)
    detector_offset: ArrayLike = ranged(Range(-1.0, 1.0, scaled=True), 0.0)
    detector_gain_error: ArrayLike = ranged(Range(-0.5, 0.5, scaled=True), 0.0)
    detector_saturation: ArrayLike = ranged(Range(0.1, inf_ok=True), math.inf)
    adc_bits: ArrayLike = ranged(Range(0.0, 32.0), 0.0)
    vib_rms: ArrayLike = ranged(Range(0.0, 1.0, unit="wl", scaled=True), 0.0)
    vib_alpha: ArrayLike = ranged(Range(0.0, 2.0), 1.0)
    resonance_freq: ArrayLike = ranged(
        Range(1e-4, 0.5, unit="cycles per step", shape="resonance"), (0.02, 0.3)
    )
    resonance_q: ArrayLike = ranged(Range(0.5, 1e4, shape="resonance"), (20.0, 20.0))
    resonance_rms: ArrayLike = ranged(
        Range(0.0, 1.0, unit="wl", shape="resonance", scaled=True), (0.0, 0.0)
    )
    p_best: ArrayLike = ranged(Range(0.0, inf_ok=True), 0.0)
    randomize: ArrayLike = ranged(Range(0.0, 1.0), 0.0)
    randomize_layout: ArrayLike = ranged(Range(0.0, 1.0), 0.0)


FIELDS = tuple(f.name for f in dataclasses.fields(Imperfections))
RANGES = ranges(Imperfections)  # field -> Range: bounds, shape, scaled
PER_STAGE = tuple(k for k, r in RANGES.items() if r.shape == "stage")
PER_RESONANCE = tuple(k for k, r in RANGES.items() if r.shape == "resonance")
SCALED = tuple(
    k for k, r in RANGES.items() if r.scaled
)  # error magnitudes; bits, span, saturation, shapes are not
LAYOUT = tuple(
    k for k in PER_STAGE if k in SCALED and RANGES[k].lo < 0
)  # signed per-stage errors (leakage is >= 0)

# The "lab" preset (docs/imperfections.md: sources and assumptions). Per-stage patterns repeat
# over the stages; signs alternate so that no error cancels by symmetry.
_LAB = dict(
    waveplate_error_deg=(0.3, -0.2, 0.4, -0.3, 0.2),
    pbs_leakage=1e-3,
    pulse_amplitude_noise=0.01,
    pulse_phase_noise=0.017,
    readout_offset=(0.02, -0.015, 0.01, -0.02, 0.015),
    readout_gain_error=(0.02, -0.01, 0.015, -0.02, 0.01),
    actuator_gain_error=(0.1, -0.08, 0.05, -0.12, 0.07),
    backlash_wl=0.002,
    lag_steps=0.15,
    dac_bits=16.0,
    actuator_span_wl=19.4,
    detector_offset=0.02,
    detector_gain_error=0.015,
    detector_saturation=1.2,
    adc_bits=8.0,
    vib_rms=0.005,
    vib_alpha=1.0,
    resonance_freq=(0.02, 0.3),
    resonance_q=(20.0, 20.0),
    resonance_rms=(0.003, 0.002),
)


def preset(name: str, stages: int, scale: float = 1.0) -> dict:
    """The overrides of preset ``name`` ("none" | "lab") for N stages, error magnitudes x
    ``scale``."""
    physics._check_choice("imperfections", name, PRESETS)
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale >= 0):
        raise ValueError(f"imperfection_scale must be a finite number >= 0, got {scale!r}")
    if name == "none":
        return {}
    out = {}
    for k, v in _LAB.items():
        v = np.resize(np.asarray(v, float), stages) if k in PER_STAGE else np.asarray(v, float)
        out[k] = v * scale if k in SCALED else v
    return out


def build(stages: int, **values) -> Imperfections:
    """Validated float32 ``Imperfections`` (per-stage leaves broadcast to (..., N)); ValueError
    names a field out of range or of the wrong shape."""
    lab = dataclasses.replace(Imperfections(), **values)
    out = {}
    for name in FIELDS:
        v = np.asarray(getattr(lab, name), np.float32)
        if not RANGES[name].contains(v):
            raise ValueError(f"{name} must be {RANGES[name]}, got {v}")
        if name in PER_STAGE:
            if v.ndim and v.shape[-1] not in (1, stages):
                raise ValueError(
                    f"{name} must be a scalar or have trailing shape ({stages},), got {v.shape}"
                )
            v = np.broadcast_to(v, (*v.shape[:-1], stages) if v.ndim else (stages,))
        if name in PER_RESONANCE and (v.ndim == 0 or v.shape[-1] != NUM_RESONANCES):
            raise ValueError(f"{name} must have trailing shape ({NUM_RESONANCES},), got {v.shape}")
        out[name] = np.array(v)
    if np.any((out["adc_bits"] > 0) & ~np.isfinite(out["detector_saturation"])):
        raise ValueError("adc_bits > 0 needs a finite detector_saturation (the ADC's full scale)")
    return Imperfections(**out)


OPTIONS = ("imperfections", "imperfection_scale", *FIELDS)


def from_options(stages: int, options: dict):
    """Pop the imperfection options of ``ops_jax.make`` from ``options``: ``imperfections`` (preset
    name), ``imperfection_scale``, any ``Imperfections`` field, or ``lab`` (an ``Imperfections``).
    Returns (validated ``Imperfections`` without p_best, whether anything is set)."""
    values = preset(
        options.pop("imperfections", "none"), stages, options.pop("imperfection_scale", 1.0)
    )
    lab = options.pop("lab", None)
    if lab is not None:
        if not isinstance(lab, Imperfections):
            raise TypeError(
                f"lab must be an ops_jax.imperfections.Imperfections, got {type(lab).__name__}"
            )
        values.update({k: v for k, v in vars(lab).items() if k != "p_best"})
    values.update({k: options.pop(k) for k in FIELDS if k in options})
    return build(stages, **values), bool(values)


def observation_bounds(lab: Imperfections, x_max):
    """(bound of the P / sample observation entries, bound of the length readout in wl) given the
    ideal largest offset ``x_max``: detector readings lie in [0, saturation], the readout adds its
    calibration error and up to 6 RMS of vibration."""
    sat = float(np.max(lab.detector_saturation))
    vib = 6.0 * float(np.max(lab.vib_rms) + np.max(np.sum(lab.resonance_rms, axis=-1)))
    x = (x_max + vib) * (1 + float(np.max(np.abs(lab.readout_gain_error)))) + float(
        np.max(np.abs(lab.readout_offset))
    )
    return max(1.0, 2 * sat - 1), x


def batch_axes(lab: Imperfections) -> Imperfections:
    """vmap in_axes of ``lab``: 0 for leaves with a batch axis, None for shared ones."""
    base = lambda name: 1 if name in PER_STAGE + PER_RESONANCE else 0
    return Imperfections(**{n: (0 if np.ndim(getattr(lab, n)) > base(n) else None) for n in FIELDS})
