import json
import os
from pathlib import Path

import numpy as np
import pytest

REFERENCE_DIR = Path(__file__).resolve().parents[1] / "benchmarks" / "reference"


@pytest.fixture(scope="session")
def reference():
    """The paper implementation's numbers (benchmarks/reference, or OPS_REFERENCE_DIR): physics
    arrays and constants."""
    ref = Path(os.environ.get("OPS_REFERENCE_DIR") or REFERENCE_DIR)
    assert (ref / "ops_reference_physics.npz").exists(), f"reference data not found in {ref}"
    physics = dict(np.load(ref / "ops_reference_physics.npz"))
    constants = json.loads((ref / "ops_reference_constants.json").read_text())["stages"]
    return physics, constants
