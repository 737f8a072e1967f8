"""Gymnasium adapters: registration, env_checker, spaces/types, seeding, and the vector env against
stepping the same instances one by one with ``OPSEnv.step``."""

import copy
import pickle
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium
import jax
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, VectorEnv

import ops_jax
from ops_jax.adapters.gymnasium import env as gym_env
from ops_jax.adapters.gymnasium.env import OPSGymEnv, OPSVectorEnv
from ops_jax.adapters.gymnasium.programs import split_step_keys


def test_registered_on_import_and_idempotent():
    assert gym_env.ENV_ID in gymnasium.registry
    spec = gymnasium.registry[gym_env.ENV_ID]
    gym_env.register()
    assert gymnasium.registry[gym_env.ENV_ID] is spec
    assert spec.vector_entry_point == "ops_jax.adapters.gymnasium.env:OPSVectorEnv"


def test_check_env_passes_with_warnings_as_errors():
    env = gymnasium.make(
        "ops_jax/OPS-v0",
        stages=3,
        mode="hard",
        render_mode="rgb_array",
        model="phasor",
        max_steps=20,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
        human = gymnasium.make("ops_jax/OPS-v0", stages=2, mode="easy", render_mode="human")
        check_env(human.unwrapped)  # headless here: human mode must not warn
        # gymnasium.make's PassiveEnvChecker wrapper sees reset/step/render too.
        env.reset(seed=0)
        for _ in range(3):
            env.step(env.action_space.sample())
        env.render()
        frames_only = gymnasium.make(
            "ops_jax/OPS-v0", stages=3, mode="hard", model="phasor", observe_lengths=False
        )
        check_env(frames_only.unwrapped)  # the option passes through; P and the 7 samples per frame
        assert frames_only.observation_space.shape == (2**3,) == frames_only.reset(seed=0)[0].shape
    with pytest.warns(
        UserWarning, match="unwrapped"
    ):  # the checker warns about any wrapper, as the README says
        check_env(env)
    assert (
        "check_env(env.unwrapped)"
        in (Path(__file__).resolve().parents[3] / "README.md").read_text()
    )


def test_types_spaces_and_truncation():
    env = gymnasium.make(
        "ops_jax/OPS-v0", stages=4, mode="easy", model="phasor", max_steps=7, obs_noise=0.0
    )
    u = env.unwrapped
    assert env.observation_space.dtype == np.float32 and env.action_space.dtype == np.float32
    assert env.observation_space.shape == (2**4 + 4,) and env.action_space.shape == (4,)
    assert np.all(np.isfinite(env.observation_space.high))
    assert u.max_episode_steps == 7
    obs, info = env.reset(seed=3)
    assert isinstance(obs, np.ndarray) and obs.dtype == np.float32
    for t in range(7):
        obs, r, term, trunc, info = env.step(np.zeros(4, np.float32))
        assert type(r) is float and type(term) is bool and type(trunc) is bool
        assert env.observation_space.contains(obs)
        assert 0.0 <= info["normalized_power"] <= 1.0 + 1e-5
        assert r <= 0.0  # paper reward
    assert trunc and not term


def test_step_matches_core_env():
    """The adapter reports what OPSEnv.step_env computes from the same state and key."""
    env = OPSGymEnv(stages=3, mode="medium", model="phasor")
    env.reset(seed=11)
    core, params = ops_jax.make(3, "medium", model="phasor")
    key_data, state = env._codec_state()
    action = np.array([0.3, -0.7, 1.0], np.float32)
    _, sub = jax.random.split(jax.random.wrap_key_data(key_data))
    obs_ref, _, reward_ref, _, _, info_ref = core.step_env(sub, state, action, params)
    obs, reward, _, _, info = env.step(action)
    np.testing.assert_allclose(obs, np.asarray(obs_ref), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(reward, float(reward_ref), rtol=1e-6)
    np.testing.assert_allclose(info["deltas_wl"], np.asarray(info_ref["deltas_wl"]), rtol=1e-6)


def test_seeding_reproducible_and_episodes_differ():
    env = OPSGymEnv(stages=3, mode="hard", model="phasor")
    a, _ = env.reset(seed=5)
    b, _ = env.reset()  # next episode: different start
    c, _ = env.reset(seed=5)
    np.testing.assert_array_equal(a, c)
    assert not np.allclose(a, b)
    with pytest.raises(ValueError, match="episode"):
        env.reset(options={"episode": -1})
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(2))


def test_bad_options_raise():
    with pytest.raises(TypeError, match="unknown option"):
        gymnasium.make("ops_jax/OPS-v0", stages=3, not_an_option=1)
    with pytest.raises(ValueError, match="render_mode"):
        OPSGymEnv(stages=3, render_mode="ascii")
    with pytest.raises(ValueError, match="num_envs"):
        OPSVectorEnv(num_envs=0, stages=3)


def test_make_vec_metadata_and_shapes():
    envs = gymnasium.make_vec(
        "ops_jax/OPS-v0",
        num_envs=16,
        vectorization_mode="vector_entry_point",
        stages=3,
        model="phasor",
    )
    assert isinstance(envs, VectorEnv)
    assert envs.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    obs, infos = envs.reset(seed=0)
    assert obs.shape == (16, 11) and obs.dtype == np.float32
    obs, r, te, tr, infos = envs.step(envs.action_space.sample())
    assert r.shape == (16,) and te.dtype == bool and tr.dtype == bool
    assert infos["normalized_power"].shape == (16,)
    assert envs.observation_space.contains(obs)


def test_vector_env_equals_instances_one_by_one():
    """Each instance of the vector env equals OPSEnv.step (single instance, same-step auto-reset)
    on its own state and key, including the final observation of finished episodes."""
    b, steps = 6, 9
    venv = OPSVectorEnv(num_envs=b, stages=3, mode="hard", model="phasor", max_steps=4, window=0.2)
    core, params = ops_jax.make(3, "hard", model="phasor", max_steps=4, window=0.2)
    step_one = jax.jit(core.step)
    venv.reset(seed=1)
    rng = np.random.default_rng(0)
    saw_done = saw_term = False
    for _ in range(steps):
        key, states = venv._carry
        _, keys = split_step_keys(key, b)
        actions = rng.uniform(-1, 1, (b, 3)).astype(np.float32)
        obs, rew, term, trunc, infos = venv.step(actions)
        for i in range(b):
            state_i = jax.tree.map(lambda x: x[i], states)
            o, s, r, te, tr, info = step_one(keys[i], state_i, actions[i], params)
            np.testing.assert_allclose(obs[i], np.asarray(o), rtol=1e-5, atol=1e-6)
            np.testing.assert_allclose(rew[i], float(r), rtol=1e-5, atol=1e-7)
            assert term[i] == bool(te) and trunc[i] == bool(tr)
            np.testing.assert_allclose(
                infos["normalized_power"][i], float(info["normalized_power"]), rtol=1e-5
            )
            if te or tr:
                assert infos["_final_obs"][i]
                np.testing.assert_allclose(
                    infos["final_obs"][i],
                    np.asarray(info["final_observation"]),
                    rtol=1e-5,
                    atol=1e-6,
                )
            elif "final_obs" in infos:
                assert infos["final_obs"][i] is None
        saw_done |= bool((term | trunc).any())
        saw_term |= bool(term.any())
    assert saw_done and saw_term  # both termination and truncation paths exercised


def test_step_cost_helper():
    from benchmarks.speed.throughput import step_cost

    single = step_cost(3, "phasor", number=20, repeats=1)
    batch = step_cost(3, "phasor", 8, number=5, repeats=1)
    assert 0 < single["seconds_per_call"] < 1.0
    assert batch["env_steps_per_second"] == pytest.approx(8 / batch["seconds_per_call"])


def _rollout(env, actions):
    """Observations, rewards and flags of ``env.step`` over ``actions``, resetting (unseeded) when
    an episode ends, so the continuation also exercises ``np_random`` and the episode counter."""
    out = []
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append((obs, r, term, trunc, info["deltas_wl"]))
        if (np.any(term) or np.any(trunc)) and not isinstance(env.unwrapped, VectorEnv):
            out.append(env.reset())
    return out


def _assert_same(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_copy_and_pickle_continue_the_same_trajectory(how):
    """A copy of a live env (wrapped as gymnasium.make returns it) continues exactly as the original
    under the same actions, independently of it, with the jitted functions looked up again."""
    env = gymnasium.make("ops_jax/OPS-v0", stages=3, mode="hard", model="phasor", max_steps=4)
    env.reset(seed=7)
    actions = np.random.default_rng(0).uniform(-1, 1, (11, 3)).astype(np.float32)
    _rollout(env, actions[:6])  # mid-episode, after one unseeded reset
    twin = copy.deepcopy(env) if how == "deepcopy" else pickle.loads(pickle.dumps(env))
    assert (
        twin.unwrapped is not env.unwrapped and twin.unwrapped._step is None
    )  # nothing compiled travels
    ahead = _rollout(twin, actions[6:])  # stepping the copy leaves the original where it was
    _assert_same(ahead, _rollout(env, actions[6:]))
    assert twin.unwrapped._step is env.unwrapped._step  # the cached jitted step, not a recompile
    assert twin.unwrapped._episode == env.unwrapped._episode > 1
    _assert_same(twin.reset(), env.reset())


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_vector_env_copy_and_pickle(how):
    venv = OPSVectorEnv(num_envs=4, stages=2, mode="hard", model="phasor", max_steps=3)
    venv.reset(seed=3)
    actions = np.random.default_rng(1).uniform(-1, 1, (8, 4, 2)).astype(np.float32)
    _rollout(venv, actions[:2])
    twin = copy.deepcopy(venv) if how == "deepcopy" else pickle.loads(pickle.dumps(venv))
    ahead = _rollout(twin, actions[2:])  # crosses auto-resets
    _assert_same(ahead, _rollout(venv, actions[2:]))
    _assert_same(twin.reset(), venv.reset())


def test_unstarted_env_pickles_without_starting_jax():
    """Construction does not start JAX (so async workers may fork after it); a pickled fresh env
    works."""
    code = (
        "import pickle, ops_jax; from ops_jax.adapters.gymnasium.env import OPSGymEnv; from "
        "ops_jax.adapters.gymnasium.devices import jax_running; e = "
        "pickle.loads(pickle.dumps(OPSGymEnv(stages=2, mode='easy', model='phasor'))); "
        "print(jax_running()); e.reset(seed=0); print(jax_running())"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True
    )
    assert out.stdout.split() == ["False", "True"]


def test_gym_modes_benchmark_rows():
    """benchmarks.speed.gym_modes measures a mode in-process and reports a failing one as its row's
    error."""
    from benchmarks.speed import gym_modes

    for mode, n in [("single", 1), ("vector_entry_point", 4)]:
        row = gym_modes.measure_one(mode, None, n, "phasor", stages=2, repeats=1)
        assert row["num_envs"] == n and row["env_steps_per_s"] > 0 and row["start_s"] > 0
    failed = gym_modes.run_in_subprocess("sync", None, 2, "no-such-model", 2, 1)
    assert "model" in failed["error"] and "env_steps_per_s" not in failed
