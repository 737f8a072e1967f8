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
