"""Checkpoints written by an earlier version of ``agents.save`` (tests/agents/fixtures/saved: a
TD3, a DroQ with the fit-residual observer and an SPGD controller on 2 stages, and the actions each
gave on a fixed batch when written) load, act as they did, and are written back byte for byte."""

import json
import shutil
from pathlib import Path

import jax
import numpy as np
import pytest

import agents
from ops_jax import EnvSpec

SAVED = Path(__file__).parent / "fixtures" / "saved"
ACTIONS = json.loads((SAVED / "actions.json").read_text())


def _actions(result) -> np.ndarray:
    """The loaded policy's actions (4, 2) on the batch the fixture's were computed on."""
    policy = result.policy()
    obs = jax.random.uniform(jax.random.key(5), (4, 2**2 + 2), minval=0.0, maxval=1.0)
    carry = policy.init(jax.random.key(6), obs)
    probe = lambda offsets, active=None: obs[:, 0]  # noqa: E731
    return np.asarray(policy.act(result.params, carry, obs, jax.random.key(7), probe)[0])


@pytest.mark.parametrize("name", sorted(ACTIONS))
def test_saved_checkpoint_loads_and_acts_as_written(name):
    result = agents.load(SAVED / name)
    assert result.algo == name and result.env_spec == EnvSpec(stages=2, mode="easy", model="phasor")
    np.testing.assert_allclose(_actions(result), ACTIONS[name], atol=1e-5)


@pytest.mark.parametrize("name", sorted(ACTIONS))
def test_saved_checkpoint_written_back_byte_for_byte(name, tmp_path):
    agents.save(tmp_path / name, agents.load(SAVED / name))
    for part in ("meta.json", "params.msgpack"):
        assert (tmp_path / name / part).read_bytes() == (SAVED / name / part).read_bytes(), part
    shutil.rmtree(tmp_path / name)
