"""The environment's records: the static ``EnvConfig``, the dynamic ``EnvParams`` pytree and the
``EnvState`` pytree that ``ops_jax.env.OPSEnv`` reads and returns. Lengths in wavelengths (wl).
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any

import jax
from jax.typing import ArrayLike

from ops_jax import imperfections
from ops_jax.ranges import Range, ranged

INT32_MAX = 2**31 - 1  # step counters are int32


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Static configuration: changing it recompiles.

    stages: N >= 1. model: "field" (exact) | "phasor" (fast). detector: "total" | "polariser".
    reward: "paper" (Eq. 3) | "reference" (the code's) | "linear" (in P). max_steps: truncation
    length. feedback_k: free-running draws per control step (feedback delay). frame_stack:
    observations stacked. observe_lengths: the N length readouts in the observation (False: the
    detector's frames only). include_noise: append the noise state to the observation. imperfect:
    apply ``EnvParams.lab`` (docs/imperfections.md); False is the ideal system whatever ``lab``
    holds. probe: how ``OPSEnv.probe_step`` measures a dither probe: "instant" (P at the probed
    offsets in the same instant as the last frame: nothing moves, no time passes) | "frame" (as on a
    bench: the lines move to the probed offsets through the actuators, one frame passes, the
    detector reads P; the next step's move starts from there).
    """

    stages: int = 5
    model: str = "field"
    detector: str = "total"
    reward: str = "paper"
    max_steps: int = ranged(Range(1, INT32_MAX, integer=True), 200)
    feedback_k: int = ranged(Range(1, INT32_MAX, integer=True), 1)
    frame_stack: int = ranged(Range(1, INT32_MAX, integer=True), 1)
    include_noise: bool = False
    imperfect: bool = False
    observe_lengths: bool = True
    probe: str = "instant"


@partial(jax.tree_util.register_dataclass)
@dataclasses.dataclass(frozen=True)
class EnvParams:
    """Dynamic parameters (a pytree: one batch may hold different values per instance). wl units.

    init_spread: s0 of the reset offsets. step_sigma: std of each free-running draw.
    drift_cap, drift_ramp: the reference's per-episode drift (r ~ U(-s, s), s = min(cap, ramp *
    resets); init_loc = r s0, mu = r sigma); cap 0 disables it. drift_amplitude (wl per step),
    drift_segment (steps): within-episode piecewise-linear mean mu_t with knots every segment
    drawn in +-amplitude; amplitude 0 disables it. action_scale: wl per unit action.
    obs_noise: std of the observation noise. window: termination bound |x_i| > window.
    lab: the lab imperfections (``imperfections.Imperfections``), used when ``imperfect``.

    Each range excludes values that leave no meaningful task: actions without effect (action_scale
    0), a window nothing fits in (and window > init_spread), phases randomised every step (offsets
    repeat every wavelength: spreads, step noise and drifts beyond ~1 wl carry no more information),
    observations drowned in noise (entries live in about [-1, 1]).
    """

    init_spread: ArrayLike = ranged(
        Range(0.0, 1.0, unit="wl"), 0.13
    )  # 0: every episode starts at the optimum
    step_sigma: ArrayLike = ranged(Range(0.0, 0.1, unit="wl"), 5e-4)  # 0: noise-free
    drift_cap: ArrayLike = ranged(Range(0.0, 10.0), 0.0)
    drift_ramp: ArrayLike = ranged(Range(0.0), 0.1)
    drift_amplitude: ArrayLike = ranged(Range(0.0, 0.1, unit="wl per step"), 0.0)
    drift_segment: ArrayLike = ranged(Range(1, INT32_MAX, integer=True, unit="steps"), 50)
    action_scale: ArrayLike = ranged(Range(0.0, 1.0, lo_open=True, unit="wl per unit action"), 0.01)
    obs_noise: ArrayLike = ranged(Range(0.0, 1.0), 1e-4)  # 0: noise-free observations
    window: ArrayLike = ranged(Range(0.0, lo_open=True, unit="wl"), 3.0)
    lab: imperfections.Imperfections = dataclasses.field(
        default_factory=imperfections.Imperfections
    )


@partial(jax.tree_util.register_dataclass)
@dataclasses.dataclass(frozen=True)
class EnvState:
    """deltas: offsets (N,) wl. mu_episode: per-episode free-running mean (N,) wl. knots: the
    current drift segment's start and end knots (2, N). t: step in episode (frames, probes included,
    with ``probe="frame"``). episode: resets so far. p_init: P at the first reset (reference
    reward). frames: stacked observations. probed: the probe offsets (N,) wl the lines hold since
    the last step (zero but between a "frame" probe and the next step). lab: the imperfections'
    state (``imperfections.LabState``; () when the config is ideal)."""

    deltas: jax.Array
    mu_episode: jax.Array
    knots: jax.Array
    t: jax.Array
    episode: jax.Array
    p_init: jax.Array
    frames: jax.Array
    probed: jax.Array
    lab: Any = ()
