"""The gymnax adapter on gymnax 0.0.x (five-value step) and rejax 0.1.3's PPO and SAC on it, at tiny
budgets. Runs in a venv of its own (.ci/run: gymnax 0.0.9, rejax 0.1.3); skipped where gymnax >= 1.0
is installed."""

import importlib.util
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ops_jax

gymnax_env = pytest.importorskip("ops_jax.adapters.gymnax", reason="needs gymnax 0.0.x")
if gymnax_env.SIX_VALUE_STEP:
    pytest.skip(
        "gymnax >= 1.0 installed: tests/ops_jax/adapters/test_gymnax.py covers it",
        allow_module_level=True,
    )

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
KW = dict(stages=3, mode="easy", model="phasor", max_steps=4)


def test_five_value_step_is_ops_step_with_done_and_truncation_in_info():
    env, params = gymnax_env.make(**KW)
    ops_env, ops_params = ops_jax.make(**KW)
    _, state = env.reset(jax.random.key(0), params)
    _, state_o = ops_env.reset(jax.random.key(0), ops_params)
    ops_step = jax.jit(ops_env.step)
    dones = []
    for i in range(5):
        key = jax.random.key(10 + i)
        out = env.step(key, state, jnp.full(3, 0.2), params)
        ref = ops_step(key, state_o, jnp.full(3, 0.2), ops_params)
        assert len(out) == 5
        obs, state, reward, done, info = out
        state_o = ref[1]
        np.testing.assert_allclose(obs, ref[0], atol=1e-6)
        np.testing.assert_allclose(reward, ref[2], atol=1e-6)
        assert bool(done) == bool(ref[3] | ref[4]) and bool(info["truncated"]) == bool(ref[4])
        dones.append(bool(done))
    assert dones == [False, False, False, True, False]


def _rejax_example():
    pytest.importorskip("rejax", reason="needs rejax 0.1.3")
    spec = importlib.util.spec_from_file_location("rejax_train", EXAMPLES / "rejax_train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    "algo, config",
    [
        (
            "ppo",
            dict(
                num_envs=4,
                num_steps=10,
                num_epochs=1,
                num_minibatches=2,
                agent_kwargs={"hidden_layer_sizes": (8,)},
            ),
        ),
        (
            "sac",
            dict(
                num_envs=2,
                buffer_size=200,
                fill_buffer=20,
                batch_size=16,
                agent_kwargs={"hidden_layer_sizes": (8,)},
            ),
        ),
    ],
)
def test_rejax_trains_on_the_adapter_unchanged(algo, config):
    out = _rejax_example().train(
        algo, timesteps=80, seed=0, eval_freq=40, eval_envs=2, config=config, max_steps=10
    )
    assert out["env_steps"] == [0, 40, 80]  # the initial evaluation, then one every 40 env steps
    assert out["global_step"] >= 80
    assert all(
        -10.0 <= r <= 0.0 for r in out["episode_return"]
    )  # paper reward in [-1, 0], 10 steps
    assert all(0.0 < p <= 1.0 + 1e-5 for p in out["final_normalized_power"])
