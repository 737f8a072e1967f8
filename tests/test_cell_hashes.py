"""Stored sweep cells are found by their label and ``config_hash``: these are keys of stored results, so the
configurations a preset declares must hash as they did when those results were stored."""

import json
from pathlib import Path

import pytest

from benchmarks import sweep_plan, sweep_units
from benchmarks.cells import config_hash

STORED = {  # preset -> {cell label: config_hash}
    "quick": {"table1-easy-spgd-s0": "5e9c4c45d84d9345", "table1-hard-td3-s1": "8200c13a81e35703",
              "table1-medium-sac-s0": "2cb30b6b0ff75368", "stages-N2-easy-spgd-s0": "393adbda8b27d4ee",
              "feedback-k1-ppo-s0": "971bd89d9a6c0380", "transfer-easy-hard-sac-s0": "1c00201af6bb2b8d",
              "budget-0": "7a3b4cd7229749a6", "budget-3": "f599550f364a1f65"},
    "default": {"table1-medium-ppo-s1": "6af4fb26a339fac9", "stages-N6-hard-physics-s0": "dcbce6c4dc121b44"},
    "paper": {"table1-hard-td3-s7": "ce67d5ecfa0e5101", "budget-0": "81224b2d02dd7421", "budget-17": "4006d0f7c3f06c92"},
}


@pytest.mark.parametrize("name", sorted(STORED))
def test_stored_cells_keep_their_keys(name, tmp_path: Path):
    preset = json.loads(json.dumps(sweep_plan.preset(name)))
    sweep = sweep_units.Sweep(preset, tmp_path, lambda *a: None)
    cells = {label: config for unit in sweep.units(list(sweep_plan.default_sections())) for label, config in unit["cells"]}
    assert {label: config_hash(cells[label]) for label in STORED[name]} == STORED[name]
