"""``ops_jax.EnvSpec``: every ``make`` option, validated when built, frozen and hashable, a stable
key, and taken by ``agents.train`` / ``evaluate`` beside a dict."""

import dataclasses
import inspect
import pickle

import jax.numpy as jnp
import numpy as np
import pytest

import agents
import ops_jax
from benchmarks.cells import config_hash
from ops_jax import EnvSpec
from ops_jax.env import option_names


def test_fields_are_make_options_with_its_defaults():
    assert [f.name for f in dataclasses.fields(EnvSpec)] == ["stages", "mode", *option_names()]
    spec, make = EnvSpec(), inspect.signature(ops_jax.make).parameters
    assert (spec.stages, spec.mode) == (make["stages"].default, make["mode"].default)
    assert (
        spec.as_dict() == {"stages": 5, "mode": "hard"}
        and repr(spec) == "EnvSpec(stages=5, mode='hard')"
    )
    env, _ = EnvSpec(stages=3, model="phasor", observe_lengths=False).make()
    assert env.config == ops_jax.make(3, model="phasor", observe_lengths=False)[0].config


def test_frozen_hashable_with_a_stable_key():
    options = {"stages": 5, "mode": "hard", "model": "phasor"}
    spec = EnvSpec.from_options(options)
    assert EnvSpec.from_options(spec) is spec and spec == EnvSpec(**options)
    assert {spec: 1}[EnvSpec(**options)] == 1 and pickle.loads(pickle.dumps(spec)) == spec
    assert (
        spec.key == "660a7b9f096a595c"
    )  # the same in every process and version: a stored key stays found
    assert EnvSpec(stages=5, model="field").key != EnvSpec(stages=5, model="phasor").key
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.stages = 3
    waveplates = EnvSpec(
        stages=3, imperfections="lab", waveplate_error_deg=np.array([0.3, -0.2, 0.4])
    )
    assert waveplates.waveplate_error_deg == (0.3, -0.2, 0.4) and hash(waveplates)
    # the sweep's cells hash the dict form: a configuration given as a dict or a spec has one cell
    for d in (
        options,
        {
            "stages": 3,
            "mode": "easy",
            "waveplate_error_deg": [0.3, -0.2, 0.4],
            "imperfections": "lab",
        },
    ):
        assert config_hash({"env": EnvSpec.from_options(d).as_dict()}) == config_hash({"env": d})


@pytest.mark.parametrize(
    "options, exc, words",
    [
        ({"stages": 0}, ValueError, r"^stages must be an integer >= 1, got 0$"),
        (
            {"obs_noise": -1.0},
            ValueError,
            r"^obs_noise must be a finite number in \[0, 1\], got -1",
        ),
        ({"observe_lengths": "no"}, TypeError, r"^observe_lengths must be a bool"),
        ({"nope": 1}, TypeError, r"^unknown option\(s\) \['nope'\]; accepted: stages, mode, \["),
        ("stages=5", TypeError, r"^env_config must be an ops_jax.EnvSpec or a dict"),
        ({"model": object()}, TypeError, r"^model must be a number, a string"),
    ],
)
def test_bad_options_fail_when_built(options, exc, words):
    with pytest.raises(exc, match=words):
        EnvSpec.from_options(options)


def test_agents_take_a_spec_or_a_dict():
    spec = EnvSpec(stages=2, mode="easy", model="phasor", max_steps=5)
    result = agents.train("spgd", spec, curve_episodes=1)
    of_dict = agents.train("spgd", spec.as_dict(), curve_episodes=1)
    assert isinstance(of_dict.env_spec, EnvSpec) and result.env_spec == of_dict.env_spec == spec
    zero = (
        agents.Policy(
            lambda key, obs: (), lambda p, c, obs, key, probe: (jnp.zeros((obs.shape[0], 2)), c)
        ),
        None,
    )
    a = agents.evaluate(zero, spec, episodes=2, seed=1)
    b = agents.evaluate(zero, spec.as_dict(), episodes=2, seed=1)
    np.testing.assert_array_equal(a.normalized_power, b.normalized_power)
    assert a.normalized_power.shape == (2, 5)
