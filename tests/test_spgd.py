"""SPGD-PID: raises P on easy against doing nothing, counts its probe, deterministic, validated."""

import jax.numpy as jnp
import numpy as np
import pytest

import agents
from agents import spgd
from agents.base import Policy

ENV = {"stages": 3, "mode": "easy", "model": "phasor"}


def _zero_policy():
    return Policy(lambda key, obs: (), lambda params, carry, obs, key, probe: (jnp.zeros((obs.shape[0], 3)), carry))


def test_spgd_raises_power_and_counts_probes():
    policy = spgd.make_policy(ENV, {})
    res = agents.evaluate((policy, spgd.gains({})), ENV, episodes=32, seed=5, steps=60)
    idle = agents.evaluate(_zero_policy(), ENV, episodes=32, seed=5, steps=60)
    assert res.summary["measurements_per_step"] == 2  # observation + one probe
    assert res.summary["final_mean"] > idle.summary["final_mean"] + 0.1
    assert res.normalized_power[:, -1].mean() > res.normalized_power[:, 0].mean()


def test_train_same_seed_same_result_and_params_are_gains():
    a = agents.train("spgd", ENV, seed=3, kp=8.0)
    b = agents.train("spgd", ENV, seed=3, kp=8.0)
    np.testing.assert_array_equal(a.curve["normalized_power"], b.curve["normalized_power"])
    assert set(a.params) == set(spgd.DEFAULTS) and float(a.params["kp"]) == 8.0
    assert a.wall_time["optimisation"] == 0.0 and a.wall_time["total"] > 0
    # the result's policy with its params (and None -> hyper) gives the same actions
    pr = agents.evaluate(a, ENV, episodes=4, seed=9, steps=10).normalized_power
    pn = agents.evaluate(a.policy(), ENV, episodes=4, seed=9, steps=10).normalized_power
    np.testing.assert_allclose(pr, pn, atol=1e-6)
    # the curve is the training-environment evaluation with curve_episodes episodes
    c = agents.train("spgd", ENV, seed=3, curve_episodes=4)
    ev = agents.evaluate(c, ENV, episodes=4, seed=3)
    np.testing.assert_array_equal(c.curve["normalized_power"], ev.normalized_power.mean(0))
    with pytest.raises(ValueError, match="curve_episodes"):
        agents.train("spgd", ENV, seed=3, curve_episodes=0)


@pytest.mark.parametrize("hyper, word", [
    ({"delta": 0.0}, "delta"), ({"kp": -1.0}, "kp"), ({"leak": 2.0}, "leak"), ({"ki": "x"}, "ki"),
    ({"gain": 1.0}, "gain"),
])
def test_bad_hyperparameters_raise(hyper, word):
    with pytest.raises(ValueError, match=word):
        spgd.make_policy(ENV, hyper)
