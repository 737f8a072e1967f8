"""The observation layout (``OPSEnv.layout``): slices, scales, stacking, with and without the length
readouts, and the frames-only option ``observe_lengths=False`` through the environment and the
controllers."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agents
import ops_jax
from ops_jax.observation import ObservationLayout


def test_layout_reads_what_the_environment_writes():
    env, params = ops_jax.make(
        stages=3, mode="hard", model="phasor", obs_noise=0.0, frame_stack=2, include_noise=True
    )
    layout = env.layout
    assert (
        layout.frame_size,
        layout.size,
        layout.samples_slice,
        layout.lengths_slice,
        layout.noise_slice,
    ) == (8 + 3 + 3, 28, slice(1, 8), slice(8, 11), slice(11, 14))
    obs, state = env.reset(jax.random.key(0), params)
    m = ops_jax.physics.measure(state.deltas, stages=3, model="phasor")
    assert float(layout.power(obs)) == pytest.approx(float(m.power / env.p_max), abs=1e-6)
    np.testing.assert_allclose(layout.length_readouts(obs, params.window), state.deltas, atol=1e-6)
    batch = jnp.stack([obs, obs])  # (B, D) too
    assert layout.power(batch).shape == (2,) and layout.detector(batch).shape == (2, 8)
    back = layout.decode(layout.latest(obs), params.window)
    np.testing.assert_allclose(back["trace"], np.asarray(m.samples / env.peak), atol=1e-6)
    frame = layout.encode(
        back["power"], back["trace"], back["length"], params.window, np.zeros(3), xp=np
    )
    np.testing.assert_allclose(frame[:11], np.asarray(layout.latest(obs))[:11], atol=1e-6)
    with pytest.raises(
        ValueError, match=r"has 28 entries \(stages=3, frame_stack=2, .*got trailing shape \(27,\)"
    ):
        layout.power(obs[:-1])


def test_frames_only_observation():
    full, params = ops_jax.make(stages=3, mode="hard", model="phasor", obs_noise=0.0)
    env, params_f = ops_jax.make(
        stages=3, mode="hard", model="phasor", obs_noise=0.0, observe_lengths=False
    )
    assert env.observation_size == env.layout.frame_size == 8 and env.layout.lengths_slice is None
    obs_full, state = full.reset(jax.random.key(0), params)
    obs, state_f = env.reset(jax.random.key(0), params_f)
    np.testing.assert_array_equal(state.deltas, state_f.deltas)
    np.testing.assert_allclose(obs, obs_full[:8], atol=1e-7)  # P and the samples, the same draws
    obs2, *_ = env.step(jax.random.key(1), state_f, jnp.zeros(3), params_f)
    assert obs2.shape == (8,)
    with pytest.raises(ValueError, match="no length readouts"):
        env.layout.length_readouts(obs, params_f.window)
    with pytest.raises(ValueError, match="give lengths and window"):
        ObservationLayout(3).encode(0.5, np.zeros(7), xp=np)
    with pytest.raises(TypeError, match="observe_lengths must be a bool"):
        ops_jax.make(stages=3, observe_lengths=1)


def test_controllers_on_frames_only():
    """SPGD reads P through the layout; the physics controller reads the frames (traced here, not
    run), and refuses to read lengths that the observation does not hold."""
    env = {"stages": 2, "mode": "easy", "model": "phasor", "observe_lengths": False}
    module = agents.api.algo_module
    ev = agents.evaluate((module("spgd").make_policy(env), None), env, episodes=4, seed=1, steps=40)
    assert ev.summary["final_mean"] > 0.9 > ev.normalized_power[:, 0].mean()
    physics = module("physics").make_policy(
        env, agents.PhysicsConfig.from_hyper({"config": "frames", "iters": 2, "starts": 2})
    )
    obs = jnp.zeros((3, 4), jnp.float32)
    action, _ = jax.eval_shape(
        lambda: physics.act(
            None, physics.init(jax.random.key(0), obs), obs, jax.random.key(1), None
        )
    )
    assert action.shape == (3, 2)
    with pytest.raises(ValueError, match=r"observe_lengths=False\): use config=\"frames\""):
        module("physics").make_policy(env, None)
