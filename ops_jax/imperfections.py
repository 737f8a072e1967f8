"""Lab imperfections of the OPS loop as batched parameters, their state, presets and the best
reachable P. Lengths in wavelengths (wl), time in control steps; docs/imperfections.md has the
model, the preset values and their sources.

``Imperfections`` is the ``lab`` field of ``EnvParams``: a pytree whose leaves may differ per batch
instance (domain randomisation). Per-stage / per-line leaves have shape (N,) (or (B, N) batched),
resonance leaves (R,) (or (B, R)), the others are scalars (or (B,)). The environment applies them
only when its static ``EnvConfig.imperfect`` is set; otherwise the step is the ideal one.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from functools import partial
import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from ops_jax import hardware, noise, optics, physics, vibration
from ops_jax.ranges import Range, ranged, ranges

NUM_RESONANCES = 2
PRESETS = ("none", "lab")
_TAG = (
    0x1AB  # folded into a step's key for the imperfection draws (the ideal draws stay as they were)
)


@partial(jax.tree_util.register_dataclass)
@dataclasses.dataclass(frozen=True)
class Imperfections:
    """Imperfection parameters (all zero / off by default: the ideal system).

    Optics: waveplate_error_deg (N,) half-wave plate angle error (deg); pbs_leakage (N,) intensity
    fraction 1/ER into the wrong arm; pulse_amplitude_noise, pulse_phase_noise: relative amplitude
    and phase (rad) RMS of each input pulse, redrawn every step; readout_offset (N,) wl and
    readout_gain_error (N,) of the length readout in the observation.
    Actuators: actuator_gain_error (N,); backlash_wl (play width, wl); lag_steps (first-order time
    constant, steps); dac_bits (0: exact) over actuator_span_wl.
    Detector (P and oscilloscope samples, in units of P_max and the ideal peak): detector_offset,
    detector_gain_error, detector_saturation (full scale), adc_bits (0: exact) over [0, full scale].
    Vibration: vib_rms (wl RMS) of a 1/f^vib_alpha background; resonance_freq (R,) cycles per
    step, resonance_q (R,), resonance_rms (R,) wl RMS.
    p_best: the best P reachable with the static imperfections (set by ``ops_jax.make``: P_max without them).
    randomize: domain randomisation r in [0, 1]: at every reset each error magnitude (``SCALED``)
    is multiplied by 1 + r u, u ~ U[-1, 1) per entry, for that episode (r = 1: 0 to 2x the values).
    randomize_layout: probability in [0, 1] that an episode's signed per-stage error patterns (``LAYOUT``)
    are each permuted over the stages, every entry's sign flipped at random (before ``randomize`` scales them).
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
    """The overrides of preset ``name`` ("none" | "lab") for N stages, error magnitudes x ``scale``."""
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
    """Validated float32 ``Imperfections`` (per-stage leaves broadcast to (..., N)); ValueError names
    a field out of range or of the wrong shape."""
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


@partial(jax.tree_util.register_dataclass)
@dataclasses.dataclass(frozen=True)
class LabState:
    """command, play, position (N,): the actuator chain (wl, since the episode start); fir
    (FIR_TAPS, N), osc (2, R, N): the vibration filters; pulses (2, 2^N): this step's input pulse
    weights (re, im); values: this episode's ``Imperfections`` (randomised at reset)."""

    command: jax.Array
    play: jax.Array
    position: jax.Array
    fir: jax.Array
    osc: jax.Array
    pulses: jax.Array
    values: Imperfections


def _draws(key, stages, fresh):
    """Standard normals of one reset (``fresh``: the filters' stationary start) or one step."""
    n, r = stages, NUM_RESONANCES
    shapes = {"pulse": (2, 2**n)}
    shapes.update(
        {"fir": (vibration.FIR_TAPS, n), "osc": (2, r, n)} if fresh else {"bg": (n,), "res": (r, n)}
    )
    return noise.draws(jax.random.fold_in(key, _TAG), normal=shapes)


def _pulses(z, lab):
    """Input pulse weights (re, im) from standard normals z (2, 2^N)."""
    amp = 1 + lab.pulse_amplitude_noise * z[0]
    phase = lab.pulse_phase_noise * z[1]
    return jnp.stack([amp * jnp.cos(phase), amp * jnp.sin(phase)])


def _layout(key, lab: Imperfections) -> dict:
    """With probability ``randomize_layout``, each ``LAYOUT`` pattern permuted over the stages, signs flipped at random."""
    keys = jax.random.split(jax.random.fold_in(key, _TAG + 2), 2 * len(LAYOUT) + 1)
    drawn = jax.random.uniform(keys[-1]) < lab.randomize_layout
    out = {}
    for i, k in enumerate(LAYOUT):
        v = jnp.asarray(getattr(lab, k))
        signs = jnp.where(jax.random.bernoulli(keys[2 * i], 0.5, v.shape), -1.0, 1.0)
        out[k] = jnp.where(drawn, jax.random.permutation(keys[2 * i + 1], v) * signs, v)
    return out


def episode_values(key, lab: Imperfections) -> Imperfections:
    """This episode's imperfections: the ``LAYOUT`` patterns re-drawn (``randomize_layout``), then each
    ``SCALED`` entry v becomes v (1 + randomize u)."""
    lab = dataclasses.replace(lab, **_layout(key, lab))
    u = noise.draws(
        jax.random.fold_in(key, _TAG + 1), uniform={k: jnp.shape(getattr(lab, k)) for k in SCALED}
    )
    return dataclasses.replace(
        lab, **{k: getattr(lab, k) * (1 + lab.randomize * u[k]) for k in SCALED}
    )


def reset(key, stages, lab: Imperfections) -> LabState:
    """Episode start: actuators at rest, vibration drawn from its stationary law, the episode's
    imperfections drawn (``randomize``)."""
    d = _draws(key, stages, True)
    lab = episode_values(key, lab)
    zero = jnp.zeros((stages,), jnp.float32)
    osc = vibration.stationary_lags(
        d["osc"], jnp.asarray(lab.resonance_freq), jnp.asarray(lab.resonance_q)
    )
    return LabState(zero, zero, zero, d["fir"], osc, _pulses(d["pulse"], lab), lab)


def advance(key, state: LabState, move):
    """One control step for a commanded move (N,) wl. Returns (state, actual length change (N,))."""
    lab = state.values
    d = _draws(key, state.command.shape[-1], False)
    command, play, position = hardware.actuate(
        state.command,
        state.play,
        state.position,
        move,
        lab.actuator_gain_error,
        lab.backlash_wl,
        lab.lag_steps,
        lab.actuator_span_wl,
        lab.dac_bits,
    )
    fir, osc, _ = vibration.step(
        state.fir,
        state.osc,
        d["bg"],
        d["res"],
        lab.vib_alpha,
        lab.vib_rms,
        jnp.asarray(lab.resonance_freq),
        jnp.asarray(lab.resonance_q),
        jnp.asarray(lab.resonance_rms),
    )
    new = LabState(command, play, position, fir, osc, _pulses(d["pulse"], lab), lab)
    return new, position - state.position


def sense(config, deltas, state: LabState, p_max, peak):
    """What happens and what is seen at slow offsets ``deltas`` (N,) wl: (true Measurement,
    detected Measurement, length readout (N,) wl). Vibration adds to the lengths."""
    lab = state.values
    x = deltas + vibration.displacement(
        state.fir, state.osc, lab.vib_alpha, lab.vib_rms, jnp.asarray(lab.resonance_rms)
    )
    m = optics.measure(
        x,
        optics.rotation(lab.waveplate_error_deg),
        lab.pbs_leakage,
        state.pulses,
        stages=config.stages,
        model=config.model,
        detector=config.detector,
    )
    det = lambda v: hardware.detect(
        v, lab.detector_gain_error, lab.detector_offset, lab.detector_saturation, lab.adc_bits
    )
    seen = physics.Measurement(p_max * det(m.power / p_max), peak * det(m.samples / peak), None)
    return m, seen, (1 + lab.readout_gain_error) * x + lab.readout_offset


P_BEST_STARTS = 4  # gradient-ascent starts: the ideal optimum and 3 draws within +-0.1 wl
P_BEST_ITERS = 300


def best_power(config, lab: Imperfections):
    """P_best (shape of lab's batch): max over offsets of P with the static optics imperfections
    (wave plates, leakage; identical pulses, no vibration), by Adam ascent on the differentiable
    model from P_BEST_STARTS starts, never below P at the ideal optimum."""
    batch = np.shape(lab.pbs_leakage)[:-1]
    return np.asarray(_best(config, lab)[0]).reshape(batch)


def best_offsets(config, lab: Imperfections):
    """The offsets (..., N) wl where ``best_power`` reaches P_best (the ideal optimum, zeros, where nothing beats it)."""
    return np.asarray(_best(config, lab)[1]).reshape(*np.shape(lab.pbs_leakage)[:-1], config.stages)


def _best(config, lab: Imperfections):
    """(P_best (B,), its offsets (B, N)) of ``lab``'s instances flattened to a batch B."""
    n = config.stages
    batch = np.shape(lab.pbs_leakage)[:-1]
    rot = jnp.broadcast_to(
        optics.rotation(jnp.asarray(lab.waveplate_error_deg)), (*batch, n)
    ).reshape(-1, n)
    leak = jnp.broadcast_to(jnp.asarray(lab.pbs_leakage), (*batch, n)).reshape(-1, n)
    return _best_power_fn(n, config.model, config.detector)(rot, leak)


def held_power(
    config, lab: Imperfections, key, samples: int = 4096, predict: bool = False
) -> float:
    """Mean P (units of P) with the lines held at the ``best_offsets``, over ``samples`` draws of the vibration
    and the input pulses from their stationary law: the most that a controller can hold which follows the drift
    exactly but not the vibration. ``predict``: the lines held at those offsets less the
    vibration's one-step prediction from its exact past, so that only its new innovation is left: the most
    that a controller can hold which also predicts the vibration perfectly. The lines sit where they are put
    (no actuator errors); the detector plays no part (P is the true stacked power). One bench: an unbatched
    ``lab`` without randomisation."""
    n = config.stages
    if np.shape(lab.pbs_leakage) != (n,):
        raise ValueError(
            f"lab must be one bench (per-stage leaves of shape ({n},)), got {np.shape(lab.pbs_leakage)}"
        )
    if float(lab.randomize) or float(lab.randomize_layout):
        raise ValueError(
            "lab must not be randomised (randomize = randomize_layout = 0), got "
            f"randomize={float(lab.randomize)}, randomize_layout={float(lab.randomize_layout)}"
        )
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    offsets = jnp.asarray(best_offsets(config, lab))
    keys = jax.random.split(key, int(samples))
    return float(jnp.mean(_held_power_fn(config, bool(predict))(keys, lab, offsets)))


@functools.lru_cache(maxsize=None)
def _held_power_fn(config, predict):
    """The jitted P (samples,) of held lines over a batch of keys."""
    n = config.stages
    p_max, peak = physics.p_max(n, config.detector), physics.peak_intensity(n)

    def one(key, lab, offsets):
        state = reset(key, n, lab)
        if predict:
            zero = jnp.zeros((n,), jnp.float32)
            ahead = vibration.step(
                state.fir,
                state.osc,
                zero,
                jnp.zeros_like(state.osc[0]),
                lab.vib_alpha,
                lab.vib_rms,
                jnp.asarray(lab.resonance_freq),
                jnp.asarray(lab.resonance_q),
                jnp.asarray(lab.resonance_rms),
            )[2]
            state, _ = advance(jax.random.fold_in(key, 1), state, zero)
            offsets = offsets - ahead
        return sense(config, offsets, state, p_max, peak)[0].power

    return jax.jit(jax.vmap(one, in_axes=(0, None, None)))


@functools.lru_cache(maxsize=None)
def _best_power_fn(n, model, detector):
    """The jitted P_best search over a batch of (rotation, leakage) (B, N): (P_best (B,), its offsets (B, N))."""
    p_max = physics.p_max(n, detector)

    def one(rot, leak):
        f = lambda x: (
            optics.measure(
                x, rot, leak, optics.ideal_pulses(n), stages=n, model=model, detector=detector
            ).power
            / p_max
        )
        starts = jnp.concatenate(
            [
                jnp.zeros((1, n)),
                jax.random.uniform(
                    jax.random.key(0), (P_BEST_STARTS - 1, n), minval=-0.1, maxval=0.1
                ),
            ]
        )
        grad = jax.vmap(jax.grad(f))

        def body(carry, i):
            x, m, v = carry
            g = grad(x)
            m = 0.9 * m + 0.1 * g
            v = 0.999 * v + 0.001 * g**2
            lr = 3e-3 * jnp.minimum(1.0, 3.0 * (1 - i / P_BEST_ITERS))
            step = lr * (m / (1 - 0.9 ** (i + 1))) / (jnp.sqrt(v / (1 - 0.999 ** (i + 1))) + 1e-8)
            return (x + step, m, v), None

        zeros = jnp.zeros_like(starts)
        x, _, _ = jax.lax.scan(
            body, (starts, zeros, zeros), jnp.arange(P_BEST_ITERS, dtype=jnp.float32)
        )[0]
        ends = jax.vmap(f)(x)
        best = jnp.argmax(ends)
        beats_ideal = ends[best] > f(starts[0])
        return jnp.where(beats_ideal, ends[best], f(starts[0])) * p_max, jnp.where(
            beats_ideal, x[best], starts[0]
        )

    return jax.jit(jax.vmap(one))
