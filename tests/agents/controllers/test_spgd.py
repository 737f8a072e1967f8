"""SPGD-PID: raises P on easy against doing nothing, counts its probe, escapes local maxima,
deterministic, validated."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agents
from agents.controllers import spgd
from agents.api import Policy

ENV = {"stages": 3, "mode": "easy", "model": "phasor"}


def _zero_policy():
    return Policy(
        lambda key, obs: (),
        lambda params, carry, obs, key, probe: (jnp.zeros((obs.shape[0], 3)), carry),
    )


def test_spgd_raises_power_and_counts_probes():
    policy = spgd.make_policy(ENV, spgd.SPGDConfig.from_hyper({}))
    res = agents.evaluate((policy, spgd.gains({})), ENV, episodes=32, seed=5, steps=60)
    idle = agents.evaluate(_zero_policy(), ENV, episodes=32, seed=5, steps=60)
    assert res.summary["measurements_per_step"] == 2  # observation + one probe
    assert res.summary["final_mean"] > idle.summary["final_mean"] + 0.1
    assert res.normalized_power[:, -1].mean() > res.normalized_power[:, 0].mean()


def test_train_same_seed_same_result_and_params_are_gains():
    a = agents.train("spgd", ENV, seed=3, kp=8.0)
    b = agents.train("spgd", ENV, seed=3, kp=8.0)
    np.testing.assert_array_equal(a.curve["normalized_power"], b.curve["normalized_power"])
    assert (
        set(a.params) == set(spgd.SPGDConfig.names()) | {"action_scale"}
        and float(a.params["kp"]) == 8.0
    )
    assert a.params["action_scale"] == np.float32(0.01)  # the environment's default
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


@pytest.mark.parametrize(
    "hyper, word",
    [
        ({"delta": 0.0}, "delta"),
        ({"kp": -1.0}, "kp"),
        ({"leak": 2.0}, "leak"),
        ({"ki": "x"}, "ki"),
        ({"jump": 0.6}, "jump"),
        ({"patience": 0.0}, "patience"),
        ({"kp_pow": -1.0}, "kp_pow"),
    ],
)
def test_bad_hyperparameters_raise(hyper, word):
    with pytest.raises(ValueError, match=word):
        spgd.make_policy(ENV, spgd.SPGDConfig.from_hyper(hyper))


def test_unknown_hyperparameter_lists_the_accepted_ones():
    with pytest.raises(
        TypeError, match=r"unknown SPGD hyperparameter\(s\) \['gain'\]; accepted: .*'kp'"
    ):
        agents.train("spgd", ENV, gain=1.0)


def test_bad_action_scale_raises():
    with pytest.raises(ValueError, match="action_scale"):
        spgd.gains({}, action_scale=0.0)


def test_stalled_instance_tests_each_line_then_commits_a_jump():
    """Below p_stall for `patience` steps, the probe tests line k at +jump (instead of the dither);
    a line that beats P by `margin` is moved by `jump` at full action, one probe per step
    throughout."""
    n, hyper = 3, {"patience": 2.0, "jump": 0.05, "p_stall": 0.9, "margin": 0.02}
    policy = spgd.make_policy(ENV, spgd.SPGDConfig.from_hyper(hyper))
    obs = jnp.zeros((1, 2**n + n)).at[0, 0].set(2 * 0.4 - 1)  # P/Pmax = 0.4
    carry = policy.init(jax.random.key(0), obs)
    seen = []

    def probe(offsets):
        seen.append(np.asarray(offsets)[0])
        return jnp.where(
            (offsets[:, 1] > 0.04) & (offsets[:, 0] == 0), 0.8, 0.4
        )  # only line 1 at +jump

    key = jax.random.key(1)
    for _ in range(2):  # stalling: dither probes
        _, carry = policy.act(None, carry, obs, key, probe)
    assert all(np.all(np.abs(s) > 0) for s in seen)  # dither: every line perturbed
    a0, carry = policy.act(None, carry, obs, key, probe)  # tests line 0: no better
    np.testing.assert_array_equal(np.asarray(a0), 0.0)  # a test step does not move the lines
    np.testing.assert_allclose(seen[-1], [0.05, 0, 0])
    a1, carry = policy.act(None, carry, obs, key, probe)  # tests line 1: commit
    np.testing.assert_allclose(seen[-1], [0, 0.05, 0])
    assert float(a1[0, 1]) == 1.0  # 0.01 wl of the 0.05 wl jump
    pushes = [float(a1[0, 1])]
    for _ in range(6):
        a, carry = policy.act(None, carry, obs, key, probe)
        pushes.append(float(a[0, 1]))
    np.testing.assert_allclose(pushes[:5], 1.0, atol=1e-5)  # 5 x 0.01 wl, then the dither resumes
    assert float(np.abs(np.asarray(carry["move"])).max()) == 0.0
    assert len(seen) == 2 + 2 + 6  # one probe per control step


def test_escape_beats_plain_spgd_on_five_stage_easy():
    env = {"stages": 5, "mode": "easy", "model": "phasor"}
    plain = agents.evaluate(
        agents.train("spgd", env, seed=0, curve_episodes=1, jump=0.0), env, episodes=64, seed=7
    )
    escape = agents.evaluate(
        agents.train("spgd", env, seed=0, curve_episodes=1), env, episodes=64, seed=7
    )
    assert plain.summary["final_mean"] < 0.95  # some episodes stay on local maxima
    assert escape.summary["final_mean"] > plain.summary["final_mean"] + 0.04
    assert escape.summary["measurements_per_step"] == 2
