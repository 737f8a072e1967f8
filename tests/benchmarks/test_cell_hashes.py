"""Stored sweep cells are found by their label and ``config_hash``: these are keys of stored
results, so the configurations a preset declares must hash as they did when those results were
stored."""

import json
from pathlib import Path

import pytest

from benchmarks.sweep import plan as sweep_plan, presets, units as sweep_units
from benchmarks.cells import config_hash

STORED = {  # preset -> {cell label: config_hash}
    "quick": {
        "table1-easy-spgd-s0": "5e9c4c45d84d9345",
        "table1-hard-td3-s1": "8200c13a81e35703",
        "table1-medium-sac-s0": "2cb30b6b0ff75368",
        "stages-N2-easy-spgd-s0": "393adbda8b27d4ee",
        "feedback-k1-ppo-s0": "971bd89d9a6c0380",
        "transfer-easy-hard-sac-s0": "1c00201af6bb2b8d",
        "budget-0": "7a3b4cd7229749a6",
        "budget-3": "f599550f364a1f65",
    },
    "default": {
        "table1-medium-ppo-s1": "6af4fb26a339fac9",
        "stages-N6-hard-physics-s0": "dcbce6c4dc121b44",
    },
    "paper": {
        "table1-hard-td3-s7": "ce67d5ecfa0e5101",
        "budget-0": "81224b2d02dd7421",
        "budget-17": "4006d0f7c3f06c92",
    },
}


@pytest.mark.parametrize("name", sorted(STORED))
def test_stored_cells_keep_their_keys(name, tmp_path: Path):
    preset = json.loads(json.dumps(presets.preset(name)))
    sweep = sweep_units.Sweep(preset, tmp_path, lambda *a: None)
    cells = {
        c.label: c for unit in sweep.units(list(sweep_plan.default_sections())) for c in unit.cells
    }
    assert {label: cells[label].key for label in STORED[name]} == STORED[name]
    assert all(c.key == config_hash(c.config) for c in cells.values())


def test_units_are_frozen_picklable_records_of_the_stored_form(tmp_path: Path):
    """A unit crosses to a Ray worker by pickle and comes back equal; a cell's key is the hash of
    its configuration as stored (JSON); a misspelt field or environment option fails where the
    record is built."""
    import dataclasses
    import pickle

    from benchmarks.sweep.records import Controller, EvalUnit, Evaluation, TrainUnit

    preset = json.loads(json.dumps(presets.preset("quick")))
    units = sweep_units.Sweep(preset, tmp_path, lambda *a: None).units(list(sweep_plan.PLAN))
    assert {type(u).__name__ for u in units} == {"TrainUnit", "EvalUnit", "SectionUnit"}
    for unit in units:
        assert pickle.loads(pickle.dumps(unit)) == unit
        assert all(c.key == config_hash(json.loads(json.dumps(c.config))) for c in unit.cells)
    train = next(u for u in units if isinstance(u, TrainUnit))
    assert [c.label for c in train.cells] == [train.controller.label(s) for s in train.seeds]
    evals = next(u for u in units if isinstance(u, EvalUnit))
    assert [c.label for c in evals.cells] == [e.label for e in evals.evals]
    with pytest.raises(dataclasses.FrozenInstanceError):
        train.cost = 0.0
    with pytest.raises(TypeError, match="extra"):
        Controller(prefix="p", algo="spgd", env={"stages": 5}, extra={})
    with pytest.raises(TypeError, match="stage"):
        Evaluation(label="e", env={"stage": 5}, seed=0)
    with pytest.raises(TypeError):
        TrainUnit(key="k", algo="spgd", cells=(), cost=1.0)  # no controller
