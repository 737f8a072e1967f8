"""The examples run without torch: the CleanRL-style loop over ``gymnasium.vector`` for a few
iterations in both autoreset conventions, and the stable-baselines3 example's evaluation helper."""

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import gymnasium
import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("mode, episodes", [("vector_entry_point", [12, 12]), ("sync", [8, 12])])
def test_cleanrl_loop_runs_a_few_iterations(mode, episodes):
    """4 envs x 30 steps per iteration, episodes of 10 steps: same-step autoreset ends 12 per
    iteration; next-step autoreset spends one step per episode on the reset (10, 21 | 32, 43,
    54)."""
    cleanrl = _load("cleanrl_vector")
    history = cleanrl.train(
        mode, num_envs=4, iterations=2, num_steps=30, seed=1, log=None, max_steps=10
    )
    assert [row["episodes"] for row in history] == episodes
    for row in history:
        assert -10.0 <= row["episodic_return"] <= 0.0  # paper reward in [-1, 0] per step
        assert 0.0 <= row["final_normalized_power"] <= 1.0 + 1e-5
        assert row["env_steps_per_s"] > 0


def test_gae_matches_a_direct_sum():
    """With lam = 1 and no episode ends, GAE + V is the discounted return bootstrapped by
    V(next)."""
    gae = _load("cleanrl_vector").gae
    rng = np.random.default_rng(0)
    r, v = rng.normal(size=(5, 2)), rng.normal(size=(5, 2))
    next_v, gamma = rng.normal(size=2), 0.9
    adv = gae(r, v, np.zeros((5, 2)), next_v, np.zeros(2), gamma, 1.0)
    direct = [
        sum(gamma**k * r[t + k] for k in range(5 - t)) + gamma ** (5 - t) * next_v for t in range(5)
    ]
    np.testing.assert_allclose(adv + v, np.array(direct), rtol=1e-12)


def test_sb3_example_evaluation_helper_without_torch():
    sb3 = _load("sb3_td3")
    env = gymnasium.make("ops_jax/OPS-v0", **{**sb3.ENV_KWARGS, "max_steps": 5})
    finals = sb3.final_power(
        env, lambda obs: np.zeros(env.action_space.shape, np.float32), episodes=2, seed=0
    )
    assert finals.shape == (2,) and np.all((finals > 0) & (finals <= 1.0 + 1e-5))


def test_cleanrl_async_default_is_one_process_per_core():
    cleanrl = _load("cleanrl_vector")
    assert cleanrl.default_num_envs("async") == os.cpu_count()
    assert cleanrl.default_num_envs("vector_entry_point") == cleanrl.default_num_envs("sync") == 64


def test_sb3_example_without_torch_names_the_install_command(tmp_path):
    """Run as a program with torch unimportable: one line naming the packages, exit status 1."""
    (tmp_path / "sitecustomize.py").write_text("import sys\nsys.modules['torch'] = None\n")
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / "sb3_td3.py"), "--steps", "10"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(tmp_path)},
    )
    assert out.returncode == 1 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert out.stderr.strip().endswith("pip install torch stable-baselines3")
