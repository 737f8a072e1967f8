"""A dither probe, read in the same instant or a frame later (``EnvConfig.probe``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agents
import ops_jax
from agents import api as base
from agents.controllers import spgd
from ops_jax import physics


def _lab(probe, **options):
    return ops_jax.make(
        3, "hard", imperfections="lab", observe_lengths=False, probe=probe, **options
    )


def test_an_instant_probe_reads_the_offsets_and_moves_nothing():
    env, params = _lab("instant")
    _, state = env.reset(jax.random.key(0), params)
    offsets = jnp.array([0.01, -0.02, 0.03])
    p, after = env.probe_step(jax.random.key(1), state, offsets, params)
    assert float(p) == float(env.probe(state, offsets, params))
    assert jax.tree.all(jax.tree.map(lambda a, b: bool(jnp.all(a == b)), after, state))


def test_a_frame_probe_moves_the_lines_for_one_frame_and_the_next_step_moves_them_back():
    env, params = ops_jax.make(3, "medium", step_sigma=0.0, obs_noise=0.0, probe="frame")
    _, state = env.reset(jax.random.key(0), params)
    x0, scale = np.asarray(state.deltas), float(params.action_scale)
    first, second = jnp.array([0.05, 0.0, -0.03]), jnp.array([0.0, 0.02, 0.0])
    p, state = env.probe_step(jax.random.key(1), state, first, params)
    np.testing.assert_allclose(state.deltas, x0 + first, atol=1e-6)
    assert float(p) == pytest.approx(
        float(physics.measure(x0 + first, stages=3).power / env.p_max), rel=1e-5
    )
    p, state = env.probe_step(
        jax.random.key(2), state, second, params
    )  # the second probe starts from the first
    np.testing.assert_allclose(state.deltas, x0 + second, atol=1e-6)
    assert int(state.t) == 2
    action = jnp.array([0.5, -1.0, 0.25])
    _, state, *_ = env.step_env(jax.random.key(3), state, action, params)
    np.testing.assert_allclose(state.deltas, x0 + scale * np.asarray(action), atol=1e-6)
    assert int(state.t) == 3 and not np.any(np.asarray(state.probed))


def test_a_frame_probe_is_the_frame_a_still_step_shows_through_the_vibration():
    env, params = _lab("frame", obs_noise=0.0)
    _, state = env.reset(jax.random.key(0), params)
    still = jnp.zeros(3)
    p, _ = env.probe_step(jax.random.key(5), state, still, params)
    obs, *_ = env.step_env(jax.random.key(5), state, still, params)
    assert float(p) == pytest.approx(float(env.layout.power(obs[None])[0]), abs=1e-6)
    instant = float(env.probe(state, still, params))
    assert abs(float(p) - instant) > 1e-4  # a frame later the vibration has moved the lines


def test_frame_probes_are_deterministic_spgds_fine_dither_drowns_in_frame_noise_its_bench_one_not():
    policy = base.algo_module("spgd").make_policy(_config("frame"), None)
    small = agents.evaluate((policy, None), _config("frame"), episodes=2, seed=7)
    large = agents.evaluate((policy, None), _config("frame"), episodes=6, seed=7)
    assert small.summary["measurements_per_step"] == 2
    # the same episodes whatever the batch (to float32 rounding: the batch size changes the compiled
    # program)
    np.testing.assert_allclose(small.normalized_power, large.normalized_power[:2], atol=1e-5)
    instant = agents.evaluate((policy, None), _config("instant"), episodes=6, seed=7)
    # the preset's dither (delta) is under the frame-to-frame change of P: its slope estimate is
    # noise there
    assert spgd.HOLD["delta"] == pytest.approx(0.002)
    assert large.summary["final_mean_best"] < instant.summary["final_mean_best"] - 0.2
    # the bench preset's dither is above it
    bench = base.algo_module("spgd").make_policy(
        _config("frame"), spgd.SPGDConfig.from_hyper({"config": "bench"})
    )
    above = agents.evaluate((bench, None), _config("frame"), episodes=6, seed=7)
    assert above.summary["final_mean_best"] > large.summary["final_mean_best"] + 0.2


def test_a_probe_left_out_moves_nothing_and_reads_nan():
    """``probe(offsets, active)``: where ``active`` is False no frame passes and nothing moves, and
    the reading is NaN: a policy that moves only on a finite reading runs there the episode of a
    policy that never probes."""
    from agents.api import Policy

    def policy(active):
        def act(params, carry, obs, key, probe):
            still = jnp.zeros((obs.shape[0], 5))
            if active is None:
                return still, carry
            p = probe(jnp.full((obs.shape[0], 5), 0.05), jnp.asarray(active))
            return jnp.where(jnp.isnan(p)[:, None], still, 0.5), carry

        return Policy(lambda key, obs: (), act)

    run = lambda active: agents.evaluate(
        (policy(active), None), _config("frame"), episodes=2, seed=3, steps=20
    )
    none, mixed = run(None), run([True, False])
    np.testing.assert_array_equal(mixed.normalized_power[1], none.normalized_power[1])
    assert not np.allclose(mixed.normalized_power[0], none.normalized_power[0])
    # the readings made: every frame, plus the probe in one episode of two
    assert (none.summary["measurements_per_step"], mixed.summary["measurements_per_step"]) == (
        1,
        1.5,
    )
    assert run([True, True]).summary["measurements_per_step"] == 2


def _config(probe):
    return {
        "stages": 5,
        "mode": "hard",
        "imperfections": "lab",
        "observe_lengths": False,
        "probe": probe,
    }


def test_an_unknown_probe_fails_naming_the_choices():
    with pytest.raises(ValueError, match=r"probe must be one of \('instant', 'frame'\)"):
        ops_jax.make(3, "hard", probe="later")
