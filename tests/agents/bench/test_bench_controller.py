"""``agents.bench.controller.Controller``: the protocol the control loop drives; a frozen controller
(``agents.bench.frozen.Agent``) implements it (the learner's actor:
tests/system/test_bench_learn.py), an object that lacks one of its members does not."""

import numpy as np
import pytest

pytest.importorskip("ophyd")

import agents.api  # noqa: E402
import ops_jax  # noqa: E402
from agents.bench.controller import Controller  # noqa: E402
from agents.bench.frozen import Agent


def test_a_frozen_controller_is_a_controller_and_an_object_without_tell_is_not():
    env_config = {"stages": 2, "model": "phasor"}
    policy = agents.api.algo_module("spgd").make_policy(env_config, None)
    env, _ = ops_jax.make(**env_config)
    agent = Agent(policy, None, env, seed=0)
    assert isinstance(agent, Controller) and agent.probes == 1

    class Untold:
        probes = 0

        def __init__(self, env):
            self.env = env

        def start(self, obs):
            return None

        def offsets(self, obs, results, i):
            return None

        def act(self, obs, results):
            return np.zeros(2)

    assert not isinstance(Untold(env), Controller)
