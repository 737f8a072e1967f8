import json

import numpy as np
import pytest

from benchmarks.common import reference_dir


@pytest.fixture(scope="session")
def reference():
    """The paper implementation's numbers (../shared/reference): physics arrays and constants."""
    ref = reference_dir()
    assert (ref / "ops_reference_physics.npz").exists(), f"reference data not found in {ref}"
    physics = dict(np.load(ref / "ops_reference_physics.npz"))
    constants = json.loads((ref / "ops_reference_constants.json").read_text())["stages"]
    return physics, constants
