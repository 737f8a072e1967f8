"""The extremum-seeking trim: removes a policy's static bias, is the policy itself at ki = 0, leaves
the local maxima a hill climber stops on, one compiled program for every gain, gated, holds near the
top, validated."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agents
from agents.controllers import trim
from agents.api import Policy
from agents.envs import built

ENV = {"stages": 3, "mode": "easy", "model": "phasor"}
BIAS = 0.04  # wl, on every line: P/Pmax about 0.6 on 3 stages


def _biased_policy(env_config, bias=BIAS, gain=0.3, traces=None):
    """A proportional controller on the length readouts whose set point is ``bias`` wl off the
    optimum."""
    env, params = built(env_config)

    def act(p, carry, obs, key, probe):
        if traces is not None:
            traces.append(1)
        x = env.layout.length_readouts(obs, params.window)  # the latest frame's
        return jnp.clip(-gain * (x - bias) / params.action_scale, -1.0, 1.0), carry

    return Policy(lambda key, obs: (), act)


def _final(ev):
    return float(ev.normalized_power[:, -10:].mean())


def _final_best(ev):
    return float(ev.normalized_power_best[:, -10:].mean())


def test_trim_removes_a_static_bias():
    policy = _biased_policy(ENV)
    alone = agents.evaluate(policy, ENV, episodes=16, seed=3, steps=200)
    pair = trim.trimmed((policy, None), {"ki": 0.003}, env_config=ENV)
    trimmed = agents.evaluate(pair, ENV, episodes=16, seed=3, steps=200)
    assert _final(alone) < 0.85  # the bias costs P
    assert _final(trimmed) > 0.97  # the trim climbs to the top
    assert trimmed.summary["measurements_per_step"] == 2  # the observation and one probe


def test_ki_zero_is_the_wrapped_policy():
    policy = _biased_policy(ENV)
    alone = agents.evaluate(policy, ENV, episodes=8, seed=4, steps=50)
    off = agents.evaluate(
        trim.trimmed((policy, None), {"ki": 0.0}, env_config=ENV), ENV, episodes=8, seed=4, steps=50
    )
    np.testing.assert_array_equal(alone.normalized_power, off.normalized_power)


def test_escape_lifts_a_hill_climber_off_local_maxima():
    env = {"stages": 5, "mode": "easy", "model": "phasor"}
    plain = agents.train(
        "spgd", env, seed=0, curve_episodes=1, jump=0.0
    )  # SPGD without its own escape
    alone = agents.evaluate(plain, env, episodes=64, seed=7)
    trimmed = agents.evaluate(
        trim.trimmed(plain, {"ki": 0.0, "jump": 0.25, "p_stall": 0.9}), env, episodes=64, seed=7
    )
    assert alone.summary["final_mean"] < 0.95  # some episodes stay on local maxima
    assert trimmed.summary["final_mean"] > alone.summary["final_mean"] + 0.04
    assert (
        trimmed.summary["measurements_per_step"] == 3
    )  # the observation, SPGD's probe and the trim's


def test_gains_are_traced_one_program_for_every_config():
    traces = []
    policy = trim.make_policy(_biased_policy(ENV, traces=traces), ENV)
    scores = [
        _final(
            agents.evaluate(
                (policy, {"policy": None, "trim": trim.gains({"ki": ki})}),
                ENV,
                episodes=8,
                seed=5,
                steps=100,
            )
        )
        for ki in (0.0, 0.003, 0.01)
    ]
    agents.evaluate(
        (policy, {"policy": None, "trim": trim.gains({"ki": 0.0, "hold": 0.85})}),
        ENV,
        episodes=8,
        seed=5,
        steps=100,
    )
    assert len(traces) == 1  # traced once, whatever the gains, with or without the hold
    assert scores[1] > scores[0] + 0.1


def test_gate_holds_the_trim_below_it_and_release_clears_it():
    policy = trim.make_policy(_biased_policy(ENV), ENV)
    env, _ = built(ENV)
    obs = (
        jnp.zeros((2, env.observation_size), jnp.float32)
        .at[:, -env.frame_size]
        .set(jnp.array([0.6, -0.6]))
    )
    carry = policy.init(None, obs)
    carry = dict(carry, c=jnp.full((2, 3), 0.5, jnp.float32))
    made = []

    def probe(offsets, active=None):  # P/Pmax 0.9 at the probe: gradient > 0 along s
        made.append(active)
        return jnp.where(active, 0.9, jnp.nan)

    params = {"policy": None, "trim": trim.gains({"ki": 0.01, "p_gate": 0.5, "release": 0.5})}
    _, out = policy.act(params, carry, obs, jax.random.key(0), probe)
    c = np.asarray(out["c"])
    assert np.asarray(made[0]).tolist() == [
        True,
        False,
    ]  # below the gate the reading would go unused: none is made
    # instance 0 reads P/Pmax 0.8 >= 0.5: integrates (|step| = ki x 0.1 / amp); instance 1 reads
    # 0.2: released
    np.testing.assert_allclose(np.abs(c[0] - 0.5), 0.01 * 0.1 / 0.002, rtol=1e-4)
    np.testing.assert_allclose(c[1], 0.25)


def test_hold_replaces_the_move_at_and_above_it_and_climbs_from_a_biased_policy():
    policy = trim.make_policy(_biased_policy(ENV), ENV)
    env, _ = built(ENV)
    obs = (
        jnp.zeros((2, env.observation_size), jnp.float32)
        .at[:, -env.frame_size]
        .set(jnp.array([0.6, -0.6]))
    )
    probe = lambda offsets, active=None: jnp.array(
        [0.8001, 0.2001], jnp.float32
    )  # a slope of 0.05 / wl along the dither
    key = jax.random.key(0)
    act = lambda hyper: np.asarray(
        policy.act(
            {"policy": None, "trim": trim.gains(hyper)}, policy.init(None, obs), obs, key, probe
        )[0]
    )  # noqa: E731
    plain, held = act({"ki": 0.0}), act({"ki": 0.0, "hold": 0.5})
    # instance 0 reads P/Pmax 0.8 >= 0.5: SPGD's step, Kp(0.8) x 0.05 on every line; instance 1
    # reads 0.2: the policy's
    kp = float(
        agents.controllers.spgd.proportional_gain(
            agents.controllers.spgd.gains({}), jnp.array([0.8])
        )[0, 0]
    )
    np.testing.assert_allclose(np.abs(held[0]), kp * 0.0001 / 0.002, rtol=1e-3)
    np.testing.assert_array_equal(held[1], plain[1])
    assert not np.allclose(held[0], plain[0])
    climbed = agents.evaluate(
        trim.trimmed((_biased_policy(ENV), None), {"ki": 0.0, "hold": 0.5}, env_config=ENV),
        ENV,
        episodes=16,
        seed=3,
        steps=200,
    )
    assert (
        _final(climbed) > 0.97
    )  # the biased policy acquires to about 0.6, the hold climbs from there


@pytest.mark.parametrize("inner", ["physics", "observer"])
def test_the_wrapped_fit_is_told_the_move_the_trim_sent(inner):
    """``Policy.sent``: a wrapped policy that reads its own last move (the fit) records the trim's,
    not its own."""
    from agents.learners.offpolicy import observer
    from agents.controllers import physics_informed

    env_config = {
        "stages": 3,
        "mode": "hard",
        "model": "phasor",
        "imperfections": "lab",
        "observe_lengths": False,
    }
    if inner == "physics":
        wrapped = physics_informed.make_policy(
            env_config, physics_informed.PhysicsConfig.from_hyper({"config": "frames"})
        )
    else:
        wrapped = observer.policy(
            observer.fit_observer(env_config), lambda params, seen: jnp.zeros((seen.shape[0], 3))
        )
    policy = trim.make_policy(wrapped, env_config)
    env, env_params = built(env_config)
    obs, _ = jax.vmap(env.reset, (0, None))(jax.random.split(jax.random.key(1), 2), env_params)
    probe = lambda offsets, active=None: jnp.array([0.9, 0.9], jnp.float32)  # noqa: E731
    params = {
        "policy": None,
        "trim": trim.gains({"ki": 0.0, "hold": 0.0}),
    }  # the hold's step replaces every move
    action, carry = policy.act(
        params, policy.init(jax.random.key(0), obs), obs, jax.random.key(2), probe
    )
    _, own = wrapped.act(None, wrapped.init(jax.random.key(0), obs), obs, jax.random.key(2), probe)
    fit = physics_informed.fitted_stages(env.config)
    sent = np.clip(np.asarray(action)[:, :fit], -1, 1) * float(env_params.action_scale)
    np.testing.assert_allclose(carry["policy"]["dz_prev"], sent, rtol=1e-6)
    assert not np.allclose(own["dz_prev"], sent)  # alone the fit would have recorded its own move
    assert Policy(wrapped.init, wrapped.act).sent is None and policy.sent is not None


def test_the_trims_hold_around_the_fit_is_the_fits_own_hold():
    """Told the moves the trim sent, the frames' fit wrapped in the trim's hold runs the episodes of
    the fit with the same hold inside (``config="frames-hold"``: the same dither stream, the same
    step)."""
    from agents.controllers import physics_informed

    env_config = {
        "stages": 3,
        "mode": "hard",
        "model": "phasor",
        "imperfections": "lab",
        "imperfection_scale": 2.0,
        "observe_lengths": False,
    }
    small = {"starts": 4, "iters": 4}
    own = physics_informed.make_policy(
        env_config, physics_informed.PhysicsConfig.from_hyper({"config": "frames-hold", **small})
    )
    wrapped = trim.trimmed(
        (
            physics_informed.make_policy(
                env_config, physics_informed.PhysicsConfig.from_hyper({"config": "frames", **small})
            ),
            None,
        ),
        {"ki": 0.0, "hold": 0.85},
        env_config,
    )
    run = lambda pair: agents.evaluate(pair, env_config, episodes=8, seed=2, steps=60)  # noqa: E731
    inside, around = run((own, None)), run(wrapped)
    np.testing.assert_allclose(around.normalized_power, inside.normalized_power, atol=1e-5)
    assert (
        inside.normalized_power[:, -10:].mean() > 0.85
    )  # the hold engaged: it held the lines near the top


@pytest.mark.parametrize(
    "hyper, word",
    [
        ({"ki": -0.1}, "ki"),
        ({"ki": 2.0}, "ki"),
        ({"amp": 0.0}, "amp"),
        ({"p_gate": 1.5}, "p_gate"),
        ({"release": -1.0}, "release"),
        ({"ki": "x"}, "ki"),
        ({"jump": 0.6}, "jump"),
        ({"patience": 0.0}, "patience"),
        ({"hold": 1.5}, "hold"),
    ],
)
def test_bad_trim_settings_raise_naming_the_field(hyper, word):
    with pytest.raises(ValueError, match=word):
        trim.gains(hyper)


def test_unknown_setting_and_bad_arguments():
    with pytest.raises(
        TypeError, match=r"unknown trim hyperparameter\(s\) \['kp'\]; accepted: .*'ki'"
    ):
        trim.gains({"kp": 1.0})
    with pytest.raises(ValueError, match="env_config"):
        trim.trimmed((_biased_policy(ENV), None))
    with pytest.raises(TypeError, match="TrainResult or a \\(Policy, params\\) pair"):
        trim.trimmed("droq")
    with pytest.raises(ValueError, match="action_scale"):
        trim.gains({}, action_scale=-1.0)


def test_trimmed_result_keeps_the_learners_params():
    result = agents.train("spgd", ENV, seed=1, curve_episodes=2)
    policy, params = trim.trimmed(result, {"ki": 0.0})
    assert params["policy"] is result.params and float(params["trim"]["ki"]) == 0.0
    a = agents.evaluate(result, ENV, episodes=4, seed=2, steps=30)
    b = agents.evaluate((policy, params), ENV, episodes=4, seed=2, steps=30)
    np.testing.assert_allclose(a.normalized_power, b.normalized_power, atol=1e-6)


def test_trim_loss_pairs_the_same_episodes():
    """benchmarks.trim_loss counts, episode by episode, where the trim ends lower or higher than the
    policy alone."""
    from benchmarks.trim_loss import paired, table

    alone = np.array([0.99, 0.95, 0.20, 0.90])
    trimmed = np.array([0.995, 0.20, 0.97, 0.93])
    row = paired(alone, trimmed, margin=0.05)
    assert row["lost"] == 1 and row["gained"] == 1 and row["episodes"] == 4
    assert row["worst"] == pytest.approx(-0.75) and (row["worst_alone"], row["worst_trimmed"]) == (
        0.95,
        0.20,
    )
    assert "| guarded | 0.7600 | 0.7738 | 4 | 1 | 1 | -0.750 (0.950 -> 0.200) |" in table(
        [{**row, "env": "hard", "seed": 0, "trim": "guarded"}], 0.05
    )


def test_trim_loss_offset_shifts_every_action_of_the_policy_alone():
    """``benchmarks.trim_loss.shifted``: the policy's own action plus the offset, clipped; offset 0
    is the policy."""
    from benchmarks.trim_loss import shifted

    result = agents.train("spgd", ENV, seed=1, curve_episodes=2)
    obs = jnp.zeros((2, built(ENV)[0].observation_size))
    key = jax.random.key(0)
    own = result.policy()
    probe = lambda offsets: jnp.ones(offsets.shape[0])
    base, _ = own.act(result.params, own.init(key, obs), obs, key, probe)
    for offset in (0.0, 0.3, -0.7):
        policy, params = shifted(result, offset)
        action, _ = policy.act(params, policy.init(key, obs), obs, key, probe)
        np.testing.assert_allclose(action, np.clip(np.asarray(base) + offset, -1, 1), atol=1e-6)
    a = agents.evaluate(result, ENV, episodes=4, seed=2, steps=30)
    b = agents.evaluate(shifted(result, 0.0), ENV, episodes=4, seed=2, steps=30)
    c = agents.evaluate(shifted(result, 0.5), ENV, episodes=4, seed=2, steps=30)
    np.testing.assert_allclose(a.normalized_power, b.normalized_power, atol=1e-6)
    assert not np.allclose(a.normalized_power, c.normalized_power)


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--algo", "foo"], "--algo must be one of"),
        (["--algo", "physics"], "--config must be one of physics's presets"),
        (["--offsets", "1.5"], "--offsets must be numbers in (-1, 1)"),
    ],
)
def test_trim_loss_refuses_bad_arguments_naming_them(argv, needle, capsys):
    from benchmarks import trim_loss

    with pytest.raises(SystemExit):
        trim_loss.main(argv)
    assert needle in capsys.readouterr().err


def test_guarded_preset_gates_and_releases():
    """The ``guarded`` preset is the default one with the gate at half of P_max and a decaying
    offset below it."""
    default, guarded = trim.gains(None), trim.gains({"config": "guarded"})
    assert float(guarded["p_gate"]) == 0.5 and float(guarded["release"]) == pytest.approx(0.9)
    assert float(default["p_gate"]) == 0.0 and float(guarded["ki"]) == float(default["ki"])


def test_bench_preset_climbs_with_probes_read_a_frame_later():
    """Read a frame later (``probe="frame"``), the guarded trim's 0.002 wl dither is under the
    frame-to-frame change of P; the ``bench`` preset, the guarded trim with a larger dither, still
    removes the bias."""
    env = {"stages": 3, "mode": "hard", "model": "phasor", "imperfections": "lab", "probe": "frame"}
    bench, guarded = trim.gains({"config": "bench"}), trim.gains({"config": "guarded"})
    assert float(bench["amp"]) > float(guarded["amp"]) and float(bench["p_gate"]) == float(
        guarded["p_gate"]
    )
    policy = _biased_policy(env)
    wrapped = trim.make_policy(policy, env)
    score = lambda pair: _final_best(agents.evaluate(pair, env, episodes=16, seed=3, steps=200))
    alone = score(policy)
    fine, coarse = (score((wrapped, {"policy": None, "trim": gains})) for gains in (guarded, bench))
    assert alone < 0.85 and coarse > 0.95 and coarse > fine + 0.02
