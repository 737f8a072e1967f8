"""Shared helpers of the benchmark scripts: reference data location and atomic writes."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path


VENDORED_REFERENCE = Path(__file__).resolve().parent / "reference"


def reference_dir() -> Path:
    """The folder of the paper implementation's numbers: ``OPS_REFERENCE_DIR`` if set, else
    ../shared/reference beside the checkout, else the copy vendored in benchmarks/reference (so a
    bare clone, e.g. CI's, still tests against them)."""
    env = os.environ.get("OPS_REFERENCE_DIR")
    if env:
        return Path(env)
    shared = Path(__file__).resolve().parents[2] / "shared" / "reference"
    return shared if shared.exists() else VENDORED_REFERENCE


def load_reference_timing() -> dict:
    """Per-N timing of the reference environment ({} when the reference folder is absent)."""
    path = reference_dir() / "reference_timing.json"
    if not path.exists():
        return {}
    return json.loads(path.read_text())["timing"]


def write_json_atomic(path: Path, data) -> None:
    """Write JSON to a temporary file in the same folder, then rename it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(data, f, indent=1, default=float)
    os.replace(tmp, path)
