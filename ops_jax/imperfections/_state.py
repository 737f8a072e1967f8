"""The lab state of an episode (``LabState``: actuator chain, vibration filters, input pulses, the
episode's imperfections), its reset, its control step and what is sensed from it."""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp

from ops_jax import hardware, noise, optics, physics, vibration
from ops_jax.imperfections._parameters import LAYOUT, NUM_RESONANCES, SCALED, Imperfections

# Folded into a step's key for the imperfection draws (the ideal draws stay as they were).
_KEY_TAG = 0x1AB


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
    return noise.draws(jax.random.fold_in(key, _KEY_TAG), normal=shapes)


def _pulses(z, lab):
    """Input pulse weights (re, im) from standard normals z (2, 2^N)."""
    amp = 1 + lab.pulse_amplitude_noise * z[0]
    phase = lab.pulse_phase_noise * z[1]
    return jnp.stack([amp * jnp.cos(phase), amp * jnp.sin(phase)])


def _layout(key, lab: Imperfections) -> dict:
    """With probability ``randomize_layout``, each ``LAYOUT`` pattern permuted over the stages,
    signs flipped at random."""
    keys = jax.random.split(jax.random.fold_in(key, _KEY_TAG + 2), 2 * len(LAYOUT) + 1)
    drawn = jax.random.uniform(keys[-1]) < lab.randomize_layout
    out = {}
    for i, k in enumerate(LAYOUT):
        v = jnp.asarray(getattr(lab, k))
        signs = jnp.where(jax.random.bernoulli(keys[2 * i], 0.5, v.shape), -1.0, 1.0)
        out[k] = jnp.where(drawn, jax.random.permutation(keys[2 * i + 1], v) * signs, v)
    return out


def episode_values(key, lab: Imperfections) -> Imperfections:
    """This episode's imperfections: the ``LAYOUT`` patterns re-drawn (``randomize_layout``), then
    each ``SCALED`` entry v becomes v (1 + randomize u)."""
    lab = dataclasses.replace(lab, **_layout(key, lab))
    u = noise.draws(
        jax.random.fold_in(key, _KEY_TAG + 1),
        uniform={k: jnp.shape(getattr(lab, k)) for k in SCALED},
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
