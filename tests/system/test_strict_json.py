"""Every JSON file the package writes is strict JSON (no NaN, Infinity): a tiny training through the
command line (its summary and checkpoint), ``agents.save``, a sweep cell; each parsed with
``parse_constant`` refusing the constants Python's ``json`` would otherwise accept. Numbers that
were not finite read back as NaN."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import agents
from agents.io import dumps_json, read_json, write_json_atomic
from benchmarks.cells import CellStore
from ops_jax import EnvSpec

REPO = Path(__file__).resolve().parents[2]


def reject(constant: str):
    raise ValueError(f"not strict JSON: {constant}")


def strict(path: Path):
    return json.loads(path.read_text(), parse_constant=reject)


def test_nan_and_inf_become_null_with_a_reason_and_read_back():
    data = {"a": float("nan"), "b": [1.0, np.float32("inf")], "c": {"d": -math.inf}, "e": None}
    text = dumps_json(data, reasons={"a": "no episode reached it"})
    parsed = json.loads(text, parse_constant=reject)
    assert parsed == {
        "a": None,
        "a_reason": "no episode reached it",
        "b": [1.0, None],
        "b_reason": "its nulls: +infinite",
        "c": {"d": None, "d_reason": "-infinite"},
        "e": None,
    }
    with pytest.raises(ValueError):
        json.dumps({"x": float("nan")}, allow_nan=False)  # what the writers rely on


def test_a_tiny_training_on_the_command_line_writes_strict_json(tmp_path):
    """TD3 past its warm-up by one evaluation chunk: its first curve point has no loss yet (NaN),
    and few evaluation episodes reach 0.9 (the median steps NaN). The budget's warning comes before
    any work."""
    sets = ["eval_every=100", "eval_episodes=2", "hidden=(16,16)", "batch_size=32"]
    argv = [
        "--algo",
        "td3",
        "--config",
        "budget",
        "--stages",
        "2",
        "--steps",
        "1100",
        "--episodes",
        "2",
    ]
    res = subprocess.run(
        [sys.executable, "-m", "agents", *argv, "--out", "run", "--set", *sets],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(REPO), "OPS_JAX_PROGRESS_INTERVAL": "0"},
    )
    assert res.returncode == 0, res.stderr[-3000:]
    first = res.stderr.splitlines()[0]
    assert first.startswith("python -m agents: warning: --steps 1100 trains 100 env steps (9%)"), (
        first
    )
    assert "compile" in res.stdout and "other" in res.stdout, res.stdout  # the wall time's parts
    run = tmp_path / "run"
    summary, meta = strict(run / "summary.json"), strict(run / "checkpoint" / "meta.json")
    assert meta["curve"]["critic_loss"][0] is None and "critic_loss_reason" in meta["curve"]
    assert summary["wall_time"]["compile"] > 0 and summary["train_steps"] == 1100
    median = summary["evaluation"]["steps_to_0p9_median"]
    assert median is not None or summary["evaluation"]["steps_to_0p9_median_reason"] == (
        "no episode reached P/Pmax 0.9"
    )
    loaded = agents.load(run / "checkpoint")
    assert math.isnan(loaded.curve["critic_loss"][0]) and set(loaded.curve) == {
        "step",
        "normalized_power",
        "final_normalized_power",
        "critic_loss",
        "actor_loss",
    }


def test_agents_save_and_a_sweep_cell_write_strict_json(tmp_path):
    result = agents.api.TrainResult(
        "spgd",
        EnvSpec(stages=2),
        agents.SPGDConfig.make(),
        {"w": np.zeros(2, np.float32)},
        {"step": np.arange(2), "normalized_power": np.array([np.nan, 0.5])},
        {"total": 1.0},
        0,
    )
    agents.save(tmp_path / "ckpt", result)
    assert strict(tmp_path / "ckpt" / "meta.json")["curve"]["normalized_power"] == [None, 0.5]
    store = CellStore(tmp_path / "cells", log=lambda line: None)
    config = {"algo": "spgd", "seed": 0}
    got = store.get("cell", config, lambda: {"final": float("nan"), "curve": [0.1, float("inf")]})
    assert math.isnan(got["final"])
    (path,) = (tmp_path / "cells").glob("*.json")
    assert strict(path)["result"] == {
        "final": None,
        "final_reason": "not a number (NaN)",
        "curve": [0.1, None],
        "curve_reason": "its nulls: +infinite",
    }
    again = store.load("cell", config)
    assert math.isnan(again["final"]) and again["curve"] == [0.1, math.inf]
    write_json_atomic(tmp_path / "x.json", {"v": np.float64("-inf")})
    assert read_json(tmp_path / "x.json") == {"v": -math.inf}
