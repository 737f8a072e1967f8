"""PPO and SAC (brax.training's trainers on the Brax adapter, through agents.train): each beats the
zero-action baseline on a small configuration (2 stages, easy, 50-step episodes) within seconds of
training; the policy comes from brax's make_inference_fn; checkpoints restore identical actions;
bad hyperparameters are rejected."""

import jax
import numpy as np
import pytest

import agents
from agents import PPOConfig, SACConfig
from agents.learners.brax.training import fit_budget
from agents.api import Policy

ENV = {"stages": 2, "mode": "easy", "max_steps": 50}
SMALL = dict(hidden=(64, 64), num_evals=1, num_eval_envs=16)


@pytest.fixture(scope="module")
def baseline():
    zero = Policy(lambda key, obs: (), lambda p, c, obs, key, probe: (obs[:, :2] * 0, c))
    return agents.evaluate((zero, None), ENV, episodes=64, seed=5).summary["final_mean"]


def _check(result, baseline, margin, tmp_path, reported):
    assert [step for step, _ in reported] == result.curve[
        "step"
    ].tolist()  # progress_fn(step, metrics)
    np.testing.assert_array_equal(
        [m["normalized_power"] for _, m in reported], result.curve["normalized_power"]
    )
    assert (
        0.9 * result.config.total_steps < result.env_steps <= result.config.total_steps
    )  # the budget is kept
    assert np.isfinite(result.curve["normalized_power"]).all()
    assert set(result.wall_time) == {"simulation", "optimisation", "total"}
    assert 0 < result.wall_time["simulation"] < result.wall_time["total"]
    ev = agents.evaluate(result, ENV, episodes=64, seed=5)
    assert ev.summary["final_mean"] > baseline + margin, (ev.summary["final_mean"], baseline)
    # brax's make_inference_fn -> deterministic, bounded actions; save / load gives identical ones
    obs = jax.random.normal(jax.random.PRNGKey(0), (8, 6))
    policy = result.policy()
    a, _ = policy.act(result.params, (), obs, jax.random.PRNGKey(1), None)
    a2, _ = policy.act(result.params, (), obs, jax.random.PRNGKey(2), None)
    assert a.shape == (8, 2) and np.all(np.abs(np.asarray(a)) <= 1)
    np.testing.assert_array_equal(a, a2)
    loaded = agents.load(agents.save(tmp_path / result.algo, result))
    b, _ = loaded.policy().act(loaded.params, (), obs, jax.random.PRNGKey(1), None)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert (
        ev.summary["final_mean"]
        == agents.evaluate(loaded, ENV, episodes=64, seed=5).summary["final_mean"]
    )


def test_ppo_learns_small(baseline, tmp_path):
    reported = []
    r = agents.train(
        "ppo",
        ENV,
        seed=0,
        total_steps=20_000,
        progress_fn=lambda *a: reported.append(a),
        num_envs=64,
        batch_size=64,
        num_minibatches=4,
        unroll_length=8,
        num_updates_per_batch=2,
        learning_rate=1e-3,
        discounting=0.95,
        entropy_cost=1e-3,
        init_noise_std=1.0,
        **SMALL,
    )
    _check(r, baseline, 0.1, tmp_path, reported)


def test_sac_learns_small(baseline, tmp_path):
    reported = []
    r = agents.train(
        "sac",
        ENV,
        seed=0,
        total_steps=8_000,
        progress_fn=lambda *a: reported.append(a),
        num_envs=32,
        grad_updates_per_step=4,
        batch_size=256,
        min_replay_size=1024,
        **SMALL,
    )
    _check(r, baseline, 0.06, tmp_path, reported)


def test_configs_and_bad_hyper():
    assert PPOConfig.preset("paper").learning_rate == 3e-4
    assert SACConfig.preset("paper").tau == 0.002
    assert SACConfig.preset("paper", max_replay_size=20_000).max_replay_size == 20_000
    assert (
        PPOConfig.from_hyper(PPOConfig.preset("fast", learning_rate=1e-3).to_hyper()).learning_rate
        == 1e-3
    )
    with pytest.raises(ValueError, match="config"):
        PPOConfig.preset("slow")
    with pytest.raises(TypeError, match="unknown PPO.*accepted: config, .*learning_rate"):
        PPOConfig.preset("fast", lr=1.0)
    with pytest.raises(ValueError, match=r"discounting must be a finite number in \(0, 1\]"):
        SACConfig.preset("fast", discounting=1.5)
    with pytest.raises(ValueError, match="num_envs"):
        PPOConfig.preset("fast", num_envs=0)
    with pytest.raises(ValueError, match="divisible"):
        PPOConfig.preset("fast", num_envs=3)
    with pytest.raises(ValueError, match="hidden"):
        SACConfig.preset("fast", hidden=())
    with pytest.raises(ValueError, match="min_replay_size"):
        agents.train("sac", ENV, total_steps=100, min_replay_size=1000)


@pytest.mark.parametrize(
    "total,fixed,unit,evals",
    [
        (20_000, 0, 16_384, 10),
        (2_000_000, 0, 16_384, 10),
        (100_000, 2_048, 64, 10),
        (147_456, 0, 16_384, 10),
        (30_000, 2_048, 64, 1),
        (5_000, 0, 2_048, 40),
    ],
)
def test_fit_budget_never_exceeds_total(total, fixed, unit, evals):
    num_timesteps, num_evals = fit_budget("ppo", total, fixed, unit, evals)
    assert num_timesteps <= total and 1 <= num_evals <= evals
    epochs = max(
        num_evals - 1, 1
    )  # what brax's trainers then run: whole epochs of whole training steps
    per_epoch = -(-(num_timesteps - fixed) // (epochs * unit))
    assert fixed + epochs * per_epoch * unit == num_timesteps
    assert (
        total - num_timesteps < epochs * unit
    )  # rounded down by less than one training step per epoch


def test_fit_budget_too_small_warns_once_and_runs_one_step():
    with pytest.warns(
        UserWarning, match="total_steps = 1,000 holds no whole training step of 16,384"
    ):
        assert fit_budget("ppo", 1_000, 0, 16_384, 10) == (16_384, 2)
