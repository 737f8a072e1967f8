"""Lab imperfections of the OPS loop as batched parameters, their state, presets and the best
reachable P. Lengths in wavelengths (wl), time in control steps; docs/imperfections.md has the
model, the preset values and their sources.

``Imperfections`` is the ``lab`` field of ``EnvParams``: a pytree whose leaves may differ per batch
instance (domain randomisation). Per-stage / per-line leaves have shape (N,) (or (B, N) batched),
resonance leaves (R,) (or (B, R)), the others are scalars (or (B,)). The environment applies them
only when its static ``EnvConfig.imperfect`` is set; otherwise the step is the ideal one.
"""

from ops_jax.imperfections._ceilings import (
    CEILING_SAMPLES,
    CEILING_SEED,
    P_BEST_ITERS,
    P_BEST_STARTS,
    Ceilings,
    best_offsets,
    best_power,
    ceilings,
    held_power,
)
from ops_jax.imperfections._parameters import (
    FIELDS,
    LAYOUT,
    NUM_RESONANCES,
    OPTIONS,
    PER_RESONANCE,
    PER_STAGE,
    PRESETS,
    RANGES,
    SCALED,
    Imperfections,
    batch_axes,
    build,
    from_options,
    observation_bounds,
    preset,
)
from ops_jax.imperfections._state import LabState, advance, episode_values, reset, sense

__all__ = [
    "CEILING_SAMPLES",
    "CEILING_SEED",
    "Ceilings",
    "FIELDS",
    "LAYOUT",
    "NUM_RESONANCES",
    "OPTIONS",
    "PER_RESONANCE",
    "PER_STAGE",
    "PRESETS",
    "P_BEST_ITERS",
    "P_BEST_STARTS",
    "RANGES",
    "SCALED",
    "Imperfections",
    "LabState",
    "advance",
    "batch_axes",
    "best_offsets",
    "best_power",
    "build",
    "ceilings",
    "episode_values",
    "from_options",
    "held_power",
    "observation_bounds",
    "preset",
    "reset",
    "sense",
]
