"""A new learner is its module plus one registry entry: this test module is one (a proportional
controller on the length readout whose "training" picks its gain), registered from inside the test
and run through agents.train / evaluate and the command line's choices; joined to the benchmarks by
their own presets and cost models (benchmarks/), a one-cell sweep plan and the lab-budget
section."""

import dataclasses
import json
from typing import ClassVar

import jax.numpy as jnp
import numpy as np
import pytest

import agents
import ops_jax
from agents import api as base, cli, registry
from agents.config import AlgoConfig, Range, field

ENV = {"stages": 2, "mode": "easy"}


@dataclasses.dataclass(frozen=True)
class TinyConfig(AlgoConfig):
    """The test learner: candidate gains tried in training."""

    NAME: ClassVar[str] = "tiny"
    PRESETS: ClassVar[dict] = {
        "fast": dict(max_gain=1.0, total_steps=400),
        "paper": dict(max_gain=0.5, total_steps=400),
    }

    config: str = field(lambda name, v: v)
    max_gain: float = field(Range(0, 1, lo_open=True))
    total_steps: int = field(Range(0, integer=True))


def params_template(env_spec, config):
    return {"gain": jnp.zeros(())}


def make_policy(env_spec, config):
    assert isinstance(env_spec, ops_jax.EnvSpec) and isinstance(config, TinyConfig)
    env, _ = env_spec.make()
    n = env.num_actions

    def act(params, carry, obs, key, probe):
        lengths = obs[:, -n:] * 3.0  # the length readout (window 3 wl), wl
        return jnp.clip(-params["gain"] * lengths / 0.01, -1.0, 1.0), carry

    return base.Policy(lambda key, obs: (), act)


def train(env_config, *, seed=0, total_steps=None, progress_fn=None, config=None, **hyper):
    c = TinyConfig.make(config, **hyper)
    steps = c.total_steps if total_steps is None else total_steps
    gains = np.linspace(0.1, c.max_gain, 3)
    result = base.TrainResult("tiny", env_config, c, None, {}, {}, seed)
    scores = []
    for g in gains:
        result.params = {"gain": jnp.float32(g)}
        scores.append(
            agents.evaluate(result, env_config, episodes=4, seed=seed, steps=steps // 12).summary[
                "final_mean"
            ]
        )
        if progress_fn:
            progress_fn(len(scores) * steps // len(gains), {"normalized_power": scores[-1]})
    result.params = {"gain": jnp.float32(gains[int(np.argmax(scores))])}
    result.curve = {"step": np.arange(1, 4) * (steps // 3), "normalized_power": np.asarray(scores)}
    result.wall_time = {"simulation": 0.0, "optimisation": 0.0, "total": 0.0}
    return result


@pytest.fixture
def tiny(monkeypatch):
    """The tiny learner registered, and joined to the benchmarks: a budget and overrides in the
    sweep's quick preset, its hyperparameters in the lab-budget section's quick preset and its cost
    model."""
    from benchmarks import costs
    from benchmarks.budget import presets as budget_presets
    from benchmarks.sweep import presets as sweep_presets

    entry = registry.register(registry.Algo("tiny", __name__, TinyConfig, "Tiny"))
    monkeypatch.setitem(sweep_presets.BUDGETS, "tiny", {"quick": 120})
    monkeypatch.setitem(sweep_presets.HYPER, "tiny", {"quick": {"max_gain": 0.8}})
    quick = budget_presets.PRESETS["quick"]
    monkeypatch.setitem(
        budget_presets.PRESETS,
        "quick",
        dict(quick, controllers=dict(quick["controllers"], tiny={"max_gain": 0.6})),
    )
    monkeypatch.setitem(costs.COSTS, "tiny", costs.CostModel(fixed_s=1.0, s_per_step=1e-3))
    yield entry
    registry.unregister("tiny")


def test_registered_learner_trains_evaluates_and_loads(tiny, tmp_path):
    assert "tiny" in agents.ALGOS and registry.CONFIG_TYPES["tiny"] is TinyConfig and tiny.learner
    result = agents.train("tiny", ENV, seed=0, total_steps=120)
    assert float(result.params["gain"]) in np.linspace(0.1, 1.0, 3)
    ev = agents.evaluate(result, ENV, episodes=8, seed=3)
    assert ev.normalized_power.shape == (8, 200) and 0.5 < ev.summary["final_mean"] <= 1.0
    agents.save(tmp_path / "ckpt", result)
    assert float(agents.load(tmp_path / "ckpt").params["gain"]) == float(result.params["gain"])
    with pytest.raises(TypeError, match="unknown tiny hyperparameter"):
        agents.train("tiny", ENV, nope=1)


def test_registered_learner_on_the_command_line(tiny, tmp_path, capsys):
    summary = cli.main(
        [
            "--algo",
            "tiny",
            "--stages",
            "2",
            "--mode",
            "easy",
            "--steps",
            "120",
            "--episodes",
            "4",
            "--out",
            str(tmp_path),
        ]
    )
    assert (
        summary["algo"] == "tiny"
        and json.loads((tmp_path / "summary.json").read_text())["evaluation"]["episodes"] == 4
    )
    registry.unregister("tiny")
    try:
        with pytest.raises(SystemExit):
            cli.main(["--algo", "tiny", "--out", str(tmp_path)])
        assert "invalid choice: 'tiny'" in capsys.readouterr().err
    finally:
        registry.register(tiny)


def test_registered_learner_in_a_sweep_plan(tiny, tmp_path):
    from benchmarks.sweep import presets, units as sweep_units

    assert presets.preset("quick")["algos"][-1] == "tiny"
    preset = dict(presets.preset("quick"), algos=["tiny"], seeds=1)
    assert preset["budgets"]["tiny"] == 120 and preset["hyper"]["tiny"] == {"max_gain": 0.8}
    plan = sweep_units.Sweep(preset, tmp_path, print)
    units = [u for u in plan.units(["table1"]) if u.key == "table1-easy-tiny"]
    assert len(units) == 1 and len(units[0].cells) == 1
    cell = units[0].cells[0]
    assert (
        cell.config["hyper"] == {"config": "fast", "max_gain": 0.8} and cell.config["steps"] == 120
    )
    plan.compute_unit(units[0])
    record = plan.store.load(cell.label, cell.config)
    assert 0.5 < np.mean(record["test_env"]["final"]) <= 1.0
    assert agents.load(tmp_path / record["checkpoint"]).algo == "tiny"


def test_registered_learner_in_the_budget_section(tiny):
    from benchmarks.budget import plan as budget

    cells = budget.cells("quick", only=["tiny"], seeds=[0])
    assert [(c.kind, c.algo) for c in cells] == [("learner", "tiny")] * len(
        budget.PRESETS["quick"]["envs"]
    )
    cell = cells[0]
    assert cell.hyper == {"max_gain": 0.6} and cell.settings["max_gain"] == 0.6
    # a run per checkpoint (not off-policy): (fixed + per env step) + one evaluation each
    assert budget.cost(cell) == pytest.approx(sum(1.0 + 1e-3 * k + 1.0 for k in cell.checkpoints))
    rec = budget.compute(cell)
    assert set(rec["scores"]) == {str(k) for k in cell.checkpoints} and not rec["errors"]
    assert all(0.5 < v <= 1.0 for v in rec["scores"].values())


def test_an_entry_declares_what_its_module_provides(tiny):
    """The tiny module trains one seed per call: an entry declaring more is refused when it is
    loaded."""
    assert tiny.load() is base.algo_module("tiny")
    for declared in ({"vmaps_seeds": True}, {"off_policy": True}):
        with pytest.raises(TypeError, match="lacks .*train_seeds"):
            dataclasses.replace(tiny, **declared).load()


def test_each_algorithm_is_registered_from_the_module_that_declares_it():
    """``agents.algos`` registers each module's ``ALGO``, whose config type is declared beside it
    and exported by ``agents``; a module that declares none is refused."""
    import importlib

    for entry in registry.REGISTRY.values():
        module = importlib.import_module(entry.module)
        assert module.ALGO is entry and entry.config.__module__ == entry.module
        assert getattr(agents, entry.config.__name__) is entry.config
    with pytest.raises(TypeError, match="module agents.envs must declare ALGO"):
        registry.register_module("agents.envs")
