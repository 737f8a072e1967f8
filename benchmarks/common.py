"""Shared helpers of the benchmark scripts: the reference data's location and timing."""

from __future__ import annotations

import json
import os
from pathlib import Path


VENDORED_REFERENCE = Path(__file__).resolve().parent / "reference"


def reference_dir() -> Path:
    """The folder of the paper implementation's numbers: ``OPS_REFERENCE_DIR`` if set, else the copy
    in benchmarks/reference."""
    return Path(os.environ.get("OPS_REFERENCE_DIR") or VENDORED_REFERENCE)


def load_reference_timing() -> dict:
    """Per-N timing of the reference environment ({} when the reference folder is absent)."""
    path = reference_dir() / "reference_timing.json"
    if not path.exists():
        return {}
    return json.loads(path.read_text())["timing"]


def count_compiles() -> list:
    """[XLA compile seconds, compiles] of this process from this call on, kept current by a listener
    on JAX's monitoring events."""
    import jax

    counts = [0.0, 0]

    def listen(name, secs, **_):
        if name == "/jax/core/compile/backend_compile_duration":
            counts[0] += secs
            counts[1] += 1

    jax.monitoring.register_event_duration_secs_listener(listen)
    return counts
