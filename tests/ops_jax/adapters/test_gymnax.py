"""The gymnax adapter on gymnax >= 1.0: a gymnax Environment whose six-value step is OPSEnv.step's,
its truncation, transition gradients, vmap, the wrappers and the purejaxrl-style example at tiny
budgets."""

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ops_jax

gymnax_env = pytest.importorskip(
    "ops_jax.adapters.gymnax", reason="needs gymnax: pip install -e '.[gymnax]'"
)
if not gymnax_env.SIX_VALUE_STEP:
    pytest.skip(
        "gymnax 0.0.x installed: tests/ops_jax/adapters/test_gymnax_legacy.py covers it",
        allow_module_level=True,
    )
from gymnax.environments import environment, spaces  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
KW = dict(stages=3, mode="hard", model="phasor", max_steps=6)


@pytest.fixture(scope="module")
def made():
    """One adapter for the step tests: its jitted step compiles once."""
    return gymnax_env.make(**KW)


def _load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_make_returns_a_gymnax_environment_params_and_box_spaces():
    env, params = gymnax_env.make(**KW, obs_noise=0.0, action_scale=0.02, frame_stack=2)
    assert isinstance(env, environment.Environment) and isinstance(params, environment.EnvParams)
    assert params.max_steps_in_episode == 6 and float(params.ops.action_scale) == pytest.approx(
        0.02
    )
    obs_space, act_space = env.observation_space(params), env.action_space(params)
    assert isinstance(obs_space, spaces.Box) and isinstance(act_space, spaces.Box)
    assert obs_space.shape == (2 * (2**3 + 3),) and act_space.shape == (3,)
    obs, _ = env.reset(jax.random.key(0), params)
    assert obs.shape == obs_space.shape and bool(obs_space.contains(obs))


def test_bad_option_names_the_parameter():
    with pytest.raises(ValueError, match="action_scale"):
        gymnax_env.make(stages=3, action_scale=0.0)
    with pytest.raises(TypeError, match="unknown option"):
        gymnax_env.make(stages=3, no_such_option=1)


def test_step_is_ops_step_six_values_with_truncation_and_reset(made):
    env, params = made
    ops_env, ops_params = ops_jax.make(**KW)
    obs, state = env.reset(jax.random.key(0), params)
    obs_o, state_o = ops_env.reset(jax.random.key(0), ops_params)
    action = jnp.array([0.3, -0.2, 0.1])
    ops_step = jax.jit(ops_env.step)
    ends = []
    for i in range(8):
        key = jax.random.key(100 + i)
        out = env.step(key, state, action, params)
        ref = ops_step(key, state_o, action, ops_params)
        assert len(out) == 6
        obs, state, reward, terminated, truncated, info = out
        obs_o, state_o = ref[0], ref[1]
        np.testing.assert_allclose(obs, obs_o, atol=1e-6)  # jitted vs op-by-op: float32 rounding
        np.testing.assert_allclose(reward, ref[2], atol=1e-6)
        assert bool(terminated) == bool(ref[3]) and bool(truncated) == bool(ref[4])
        np.testing.assert_allclose(
            info["final_observation"], ref[5]["final_observation"], atol=1e-6
        )
        ends.append(bool(truncated))
    assert ends == [False] * 5 + [True, False, False]  # max_steps 6; the counter starts again
    assert int(state.episode) == 1  # the next episode carries the count (hard mode's drift ramp)


def test_max_steps_in_episode_is_a_dynamic_parameter(made):
    env, params = made
    params = params.replace(max_steps_in_episode=3)
    step = env.step
    _, state = env.reset(jax.random.key(1), params)
    flags = []
    for i in range(4):
        _, state, _, _, truncated, _ = step(jax.random.key(i), state, jnp.zeros(3), params)
        flags.append(bool(truncated))
    assert flags == [False, False, True, False]


def test_vmap_of_step_is_step_batch(made):
    env, params = made
    b = 5
    keys = jax.random.split(jax.random.key(2), b)
    _, states = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    actions = jax.random.uniform(jax.random.key(3), (b, 3), minval=-1, maxval=1)
    states = states.__class__(**{**vars(states), "t": jnp.array([0, 5, 5, 0, 1], jnp.int32)})
    out = jax.vmap(env.step, in_axes=(0, 0, 0, None))(keys, states, actions, params)
    ref = env.ops_env.step_batch(keys, states, actions, params.ops)
    for i in (0, 2, 3, 4):
        np.testing.assert_allclose(out[i], ref[i], atol=1e-6)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, atol=1e-6), out[1], ref[1])
    assert out[4].tolist() == [False, True, True, False, False]


def test_transition_gradients_on_request():
    env, params = gymnax_env.make(stages=3, mode="easy", model="phasor", obs_noise=0.0)
    _, state = env.reset(jax.random.key(4), params)

    def outputs(e, a):
        obs, s, reward, *_ = e.step(jax.random.key(5), state, a, params)
        return obs[0], s.deltas.sum(), reward

    a = jnp.array([0.1, -0.3, 0.2])
    grad_on = jax.jacrev(lambda a: outputs(env.with_transition_gradients(), a))(a)
    grad_off = jax.jacrev(lambda a: outputs(env, a))(a)
    assert env.supports_transition_gradients and not env.transition_gradients_enabled
    # P's observation entry and the offsets move with the action (0.01 wl per unit on each offset).
    assert np.all(np.isfinite(grad_on[0])) and np.abs(np.asarray(grad_on[0])).max() > 0
    np.testing.assert_allclose(grad_on[1], np.full(3, float(params.ops.action_scale)), rtol=1e-5)
    np.testing.assert_array_equal(grad_off[0], 0.0)
    np.testing.assert_array_equal(grad_off[1], 0.0)
    np.testing.assert_allclose(grad_off[2], grad_on[2], rtol=1e-6)
    assert np.abs(np.asarray(grad_on[2])).max() > 0  # the reward is differentiable either way


def test_every_gymnax_wrapper_that_fits_runs_the_adapter():
    out = _load("gymnax_wrappers").run(num_envs=2, steps=7, seed=0, max_steps=3)
    log = out["LogWrapper"]
    assert log["episodes"] == 4 and log["episode_lengths"] == [3]  # 2 instances x steps 3 and 6
    assert -3.0 <= log["mean_episode_return"] <= 0.0 and 0.0 < log["mean_normalized_power"] <= 1.0
    assert out["FlattenObservationWrapper"]["obs_shape"] == (2, 11)
    assert out["GymnaxToDmEnvWrapper"]["min_discount"] == 1.0  # truncations only: discount stays 1
    assert out["LegacyStepAPIWrapper"] == {"values_per_step": 5, "episodes": 4}
    assert (
        out["GymnaxToGymWrapper"]["obs_shape"] == (11,)
        and out["GymnaxToGymWrapper"]["episodes"] == 2
    )
    assert out["GymnaxToVectorGymWrapper"] == {"obs_shape": (2, 11), "episodes": 4}
    if "GymnaxToBraxWrapper" in out:
        assert out["GymnaxToBraxWrapper"] == {"obs_shape": (2, 11), "episodes": 4}


def test_purejaxrl_style_ppo_example_trains_at_a_tiny_budget():
    out = _load("purejaxrl_ppo").train(
        timesteps=160,
        seed=0,
        config={
            "num_envs": 4,
            "num_steps": 20,
            "hidden": 8,
            "update_epochs": 1,
            "num_minibatches": 2,
        },
        max_steps=10,
    )
    assert out["env_steps"] == [80, 160]
    assert out["episodes"] == [8, 8]  # 4 instances x 20 steps, episodes of 10
    assert all(-10.0 <= r <= 0.0 for r in out["episode_return"])
    assert all(0.0 < p <= 1.0 + 1e-5 for p in out["final_normalized_power"])
    assert all(np.isfinite(out["loss"]))


def test_missing_gymnax_names_the_extra():
    code = """
import importlib.abc, sys
class NoGymnax(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "gymnax" or name.startswith("gymnax."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, NoGymnax())
try:
    import ops_jax.adapters.gymnax
except ImportError as e:
    print("ImportError:", e)
"""
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=os.environ
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith('pip install -e ".[gymnax]"'), out.stdout
