"""Real actuators and detectors: pure maps from what is commanded to what moves, and from what
arrives to what is read. Lengths in wavelengths (wl), time in control steps.

Actuator chain per delay line (positions relative to the episode start):
DAC (the commanded position quantised to ``span / 2^bits``) -> gain (1 + gain_error) ->
backlash (a play operator of total width ``backlash``: the output follows the input only once the
input has moved more than half the width away from it) -> first-order lag (time constant ``tau``
steps: x += (target - x) (1 - exp(-1 / tau)); tau = 0 is instant).

Detector: reading = quantise(clip((1 + gain_error) v + offset, 0, saturation)), v in units of the
ideal full signal (P / P_max or I / I_peak); ``bits`` > 0 quantises [0, saturation] into 2^bits
levels (needs a finite saturation); bits = 0 reads exactly.
"""

from __future__ import annotations

import jax.numpy as jnp


def quantise(v, lsb):
    """``v`` rounded to a multiple of ``lsb``; lsb = 0 leaves it unchanged."""
    safe = jnp.where(lsb > 0, lsb, 1.0)
    return jnp.where(lsb > 0, jnp.round(v / safe) * safe, v)


def backlash(previous, target, width):
    """Play operator: the output stays at ``previous`` until ``target`` is more than width / 2
    away, then trails it by width / 2."""
    return jnp.clip(previous, target - width / 2, target + width / 2)


def lag(previous, target, tau):
    """First-order response over one step, time constant ``tau`` steps (0: instant)."""
    gain = jnp.where(tau > 0, -jnp.expm1(-1.0 / jnp.maximum(tau, 1e-30)), 1.0)
    return previous + (target - previous) * gain


def actuate(command, play, position, move, gain_error, backlash_width, tau, span, bits):
    """One step of the actuator chain for a commanded move ``move`` (N,) wl. ``command``: the
    commanded position so far; ``play``: the backlash output; ``position``: where the line is.
    Returns (command, play, position) after the step; the length change is the new position
    minus the old one."""
    command = command + move
    lsb = jnp.where(bits > 0, span / 2.0 ** jnp.maximum(bits, 0), 0.0)
    target = (1 + gain_error) * quantise(command, lsb)
    play = backlash(play, target, backlash_width)
    return command, play, lag(position, play, tau)


def detect(v, gain_error, offset, saturation, bits):
    """What a detector channel reads for the ideal-units signal ``v``."""
    v = jnp.clip((1 + gain_error) * v + offset, 0.0, saturation)
    finite = jnp.isfinite(saturation) & (bits > 0)
    lsb = jnp.where(finite, jnp.where(finite, saturation, 1.0) / 2.0 ** jnp.maximum(bits, 0), 0.0)
    return quantise(v, lsb)
