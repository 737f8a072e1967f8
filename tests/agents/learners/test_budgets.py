"""Budgets that cannot learn, the training progress bar, and results that print as their numbers."""

import dataclasses
import io
import random
import warnings

import numpy as np
import pytest

import agents
from agents.learners import budgets
from agents.api import EvalResult, TrainResult
from agents import DroQConfig, PPOConfig, SACConfig, TD3Config
from agents.learners.offpolicy.driver import schedule
from ops_jax import EnvSpec
from ops_jax.cli import progress as progress_module
from ops_jax.cli.progress import StepProgress

OFF_POLICY = [
    TD3Config.make("fast"),
    TD3Config.make("budget"),
    TD3Config.make("paper"),
    DroQConfig.make("budget"),
    TD3Config.make("fast", learning_starts=1024, eval_every=1000),
]


@pytest.mark.parametrize("config", OFF_POLICY, ids=lambda c: f"{type(c).__name__}-{c.config}")
def test_trained_steps_are_the_drivers_schedule(config):
    """What ``budgets`` says trains is what the off-policy driver runs past its warm-up."""
    rng = random.Random(0)
    for total in [0, 999, 1000, 1001, 4096, 4128, 5000, 20_000] + [
        rng.randrange(60_000) for _ in range(100)
    ]:
        try:
            warm_iters, chunks, chunk = schedule(dataclasses.replace(config, total_steps=total))
            expected = chunks * chunk * config.num_envs * config.unroll
        except ValueError:  # under the warm-up
            expected = 0
        assert budgets.trained_steps(config, total) == expected, total


def test_a_budget_that_takes_no_gradient_step_is_refused_naming_what_to_type():
    td3 = TD3Config.make("fast")  # 32 envs, learning_starts 4096
    with pytest.raises(ValueError) as refused:
        budgets.check(td3, 4096, "--steps", " ")
    assert str(refused.value).startswith("--steps 4096 takes no gradient step: its first 4,096")
    assert str(refused.value).endswith("try --steps 8192 (--steps 4128 takes one)")
    assert budgets.trained_steps(td3, 4128) == 32 and budgets.trained_steps(td3, 8192) == 4096
    with pytest.raises(ValueError, match="one training step takes 16,384 env steps"):
        budgets.check(PPOConfig.make("fast"), 16_383)
    assert budgets.check(PPOConfig.make("fast"), 16_384) is None


def test_a_budget_its_warm_up_takes_most_of_is_warned_and_a_fair_one_is_not():
    line = budgets.check(TD3Config.make("fast"), 5000, "--steps", " ")
    assert line.startswith("--steps 5000 trains 896 env steps (18%): 4,096 are the random warm-up")
    assert "8 are not run" in line and "--steps 8192 trains half" in line
    sac = SACConfig.make("fast")
    assert "replay prefill" in budgets.check(sac, 9000)
    for config in [*OFF_POLICY, sac, PPOConfig.make("fast")]:
        useful = budgets.useful_steps(config)
        assert budgets.check(config, useful) is None
        assert budgets.trained_steps(config, useful) >= useful / 2
    assert budgets.check(TD3Config.make("fast"), 300_000) is None


def test_agents_train_warns_before_it_trains(monkeypatch):
    """The warning comes from ``agents.train`` before the trainer runs (here: a stand-in that
    records)."""
    calls = []
    module = agents.api.algo_module("td3")
    monkeypatch.setattr(module, "train", lambda *a, **k: calls.append(len(caught)) or "trained")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert agents.train("td3", {"stages": 2}, total_steps=5000, progress=False) == "trained"
    assert [w.category for w in caught] == [budgets.BudgetWarning] and calls == [1]
    assert "trains 896 env steps" in str(caught[0].message)


def test_step_progress_says_compiling_then_a_rate_from_the_second_report(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(progress_module.time, "monotonic", lambda: now[0])
    out = io.StringIO()
    bar = StepProgress(3000, "td3", file=out)  # plain lines: not a terminal
    assert bar.bar.postfix == "compiling" and bar.bar.remaining is False
    now[0] = 40.0
    bar(1000, {"normalized_power": 0.25})  # 40 s after the start: compiling and warm-up
    assert bar.bar.postfix == "P/Pmax 0.250, 0:40 compiling and warming up"
    now[0] = 70.0
    bar(2000, {"normalized_power": 0.5})  # the training step compiled since the first report
    assert bar.bar.postfix == "P/Pmax 0.500" and bar.n == 2000
    now[0] = 75.0
    bar(2500, {"normalized_power": 0.6})  # 500 steps in 5 s since the second report
    assert bar.bar.postfix == "P/Pmax 0.600, 100 step/s, ~0:05 remaining" and bar.n == 2500


def test_agents_train_shows_a_bar_on_a_terminal_and_progress_false_silences_it(monkeypatch):
    seen = []
    monkeypatch.setattr(progress_module, "is_terminal", lambda stream: True)
    monkeypatch.setattr(progress_module, "StepProgress", _Recorder)
    module = agents.api.algo_module("spgd")

    def fake_train(env_config, *, progress_fn, **kw):
        progress_fn(0, {"normalized_power": 0.5})
        return "trained"

    monkeypatch.setattr(module, "train", fake_train)
    agents.train("spgd", {"stages": 2}, progress_fn=lambda s, m: seen.append(s))
    assert _Recorder.made[-1].steps == [0] and _Recorder.made[-1].closed and seen == [0]
    agents.train("spgd", {"stages": 2}, progress=False, progress_fn=lambda s, m: seen.append(s))
    assert len(_Recorder.made) == 1 and seen == [0, 0]  # no second bar; the given progress_fn ran


class _Recorder:
    made = []

    def __init__(self, total, desc):
        self.steps, self.closed = [], False
        _Recorder.made.append(self)

    def __call__(self, step, metrics):
        self.steps.append(step)

    def close(self):
        self.closed = True


def test_results_print_their_numbers_not_their_arrays():
    npow = np.full((50, 200), 0.5, np.float32)
    ev = EvalResult(npow, np.zeros((50, 200), bool), {"final_mean": 0.123456, "episodes": 50}, npow)
    assert repr(ev) == (
        "EvalResult(summary={'final_mean': 0.1235, 'episodes': 50}, "
        "normalized_power: 50 episodes x 200 steps)"
    )
    curve = {"step": np.array([4096, 8192]), "normalized_power": np.array([0.2, 0.61])}
    wall = {"total": 13.33, "compile": 9.71}
    result = TrainResult("td3", EnvSpec(stages=2), TD3Config.make("fast"), {}, curve, wall, 0)
    assert repr(result) == (
        "TrainResult(algo='td3', seed=0, env_steps=8192, curve=2 points, last "
        "normalized_power=0.61, wall_time={'total': 13.33, 'compile': 9.71}, config='fast')"
    )
