"""The environment: determinism, batching, compile-once, auto-reset, noise statistics, bad input."""

import dataclasses

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import ops_jax
from ops_jax import batching, noise, physics


def _zero_policy(n):
    return lambda key, obs: jnp.zeros((obs.shape[0], n))


def _random_policy(n):
    return lambda key, obs: jax.random.uniform(key, (obs.shape[0], n), minval=-1, maxval=1)


def test_reset_and_step_shapes_and_info():
    env, params = ops_jax.make(stages=3, mode="hard")
    obs, state = env.reset(jax.random.key(0), params)
    assert obs.shape == (env.observation_size,) == (2**3 + 3,)
    assert obs.dtype == jnp.float32
    obs2, state2, r, term, trunc, info = env.step(jax.random.key(1), state, jnp.zeros(3), params)
    assert obs2.shape == obs.shape and r.dtype == jnp.float32
    assert set(info) >= {
        "power",
        "normalized_power",
        "deltas_wl",
        "final_observation",
        "action_nonfinite",
    }
    assert float(info["normalized_power"]) == pytest.approx(
        float(info["power"]) / physics.p_max(3), rel=1e-6
    )
    assert np.all(np.abs(obs2) < 1.5)


def test_observation_layout_maps_to_unit_range():
    env, params = ops_jax.make(stages=4, mode="easy", obs_noise=0.0, include_noise=True)
    obs, state = env.reset(jax.random.key(3), params)
    m = physics.measure(state.deltas, stages=4)
    np.testing.assert_allclose(obs[0], 2 * m.power / physics.p_max(4) - 1, rtol=1e-5)
    np.testing.assert_allclose(
        obs[1:16], 2 * m.samples / physics.peak_intensity(4) - 1, rtol=1e-5, atol=1e-6
    )
    np.testing.assert_allclose(obs[16:20], state.deltas / 3.0, rtol=1e-6)
    np.testing.assert_allclose(obs[20:24], 0.0)  # easy: no drift in the noise state
    assert env.observation_size == 24


def test_same_key_same_trajectory_and_batch_independence():
    env, params = ops_jax.make(stages=5, mode="hard", max_steps=30)
    pol = _random_policy(5)
    a = ops_jax.rollout(env, params, pol, jax.random.key(7), 1, 70)
    b = ops_jax.rollout(env, params, pol, jax.random.key(7), 1, 70)
    np.testing.assert_array_equal(a.obs, b.obs)
    # The policy draws batch-shaped noise; use a per-instance deterministic policy for batches.
    pol_det = lambda key, obs: jnp.tanh(obs[:, -5:] * -3.0)
    alone = ops_jax.rollout(env, params, pol_det, jax.random.key(7), 1, 70)
    batch = ops_jax.rollout(env, params, pol_det, jax.random.key(7), 1024, 70)
    np.testing.assert_allclose(alone.obs[:, 0], batch.obs[:, 0], atol=1e-6)
    np.testing.assert_allclose(
        alone.normalized_power[:, 0], batch.normalized_power[:, 0], atol=1e-6
    )
    assert not np.allclose(batch.obs[:, 0], batch.obs[:, 1])


def test_step_and_step_batch_agree():
    env, params = ops_jax.make(stages=3, mode="hard", max_steps=4)
    keys = jax.random.split(jax.random.key(0), 8)
    obs, states = env.reset_batch(keys, params)
    step_one = jax.jit(env.step)
    step_many = jax.jit(env.step_batch)
    for t in range(6):  # crosses an auto-reset at t = 3
        k = jax.random.split(jax.random.key(100 + t), 8)
        a = jax.random.uniform(jax.random.key(t), (8, 3), minval=-1, maxval=1)
        many = step_many(k, states, a, params)
        for i in range(8):
            one = step_one(k[i], jax.tree.map(lambda x: x[i], states), a[i], params)
            np.testing.assert_allclose(
                one[0], many[0][i], rtol=1e-5, atol=1e-6
            )  # two programs: to rounding
            np.testing.assert_allclose(one[2], many[2][i], rtol=1e-5)
        states = many[1]


def test_compiles_once():
    env, params = ops_jax.make(stages=3, mode="medium")
    chex.clear_trace_counter()
    step = jax.jit(chex.assert_max_traces(env.step_batch, n=1))
    keys = jax.random.split(jax.random.key(0), 4)
    obs, states = env.reset_batch(keys, params)
    for t in range(3):
        obs, states, *_ = step(keys, states, jnp.full((4, 3), 0.1 * t, jnp.float32), params)
    # New parameter values (same structure) do not retrace either.
    step(keys, states, jnp.zeros((4, 3)), dataclasses.replace(params, step_sigma=np.float32(1e-3)))


def _scan_fn(step):
    """Jitted ``lax.scan`` of ``step`` over (keys, actions) (time first); returns per step
    (obs, state, reward, terminated, truncated, final_observation)."""

    def run(params, state, keys, actions):
        def body(s, ka):
            obs, s, r, term, trunc, info = step(ka[0], s, ka[1], params)
            return s, (obs, s, r, term, trunc, info["final_observation"])

        return jax.lax.scan(body, state, (keys, actions))[1]

    return run


# One instance alone and a batch are different programs; from JAX 0.10 XLA rounds them alike (tested
# bitwise), older XLA may fuse them differently and round the last bit of a float32 apart.
SINGLE_EQUALS_BATCH_BITWISE = tuple(int(p) for p in jax.__version__.split(".")[:2]) >= (0, 10)


def _assert_bitwise_equal(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _uneven_ends(model, b):
    """Hard mode, max_steps 5, window 0.5 wl, per-instance action_scale up to 0.5 wl: episodes end
    at different steps."""
    env, params = ops_jax.make(stages=3, mode="hard", max_steps=5, model=model, window=0.5)
    return env, dataclasses.replace(
        params, action_scale=jnp.linspace(0.0, 0.5, b, dtype=jnp.float32)
    )


@pytest.mark.parametrize("model", ["phasor", "field"])
def test_vmapped_step_equals_step_batch_and_single_instance_bitwise(model):
    b, t = 6, 12
    env, params = _uneven_ends(model, b)
    axes = batching.params_axes(params)
    _, state = env.reset_batch(jax.random.split(jax.random.key(0), b), params)
    keys = jax.random.split(jax.random.key(1), (t, b))
    actions = jax.random.uniform(jax.random.key(2), (t, b, 3), minval=-1, maxval=1)
    vmapped = jax.jit(_scan_fn(jax.vmap(env.step, in_axes=(0, 0, 0, axes))))(
        params, state, keys, actions
    )
    batch = jax.jit(_scan_fn(env.step_batch))(params, state, keys, actions)
    scan_inside = jax.jit(jax.vmap(_scan_fn(env.step), in_axes=(axes, 0, 1, 1), out_axes=1))(
        params, state, keys, actions
    )
    done = np.asarray(vmapped[3] | vmapped[4])
    some = done.any(axis=1)
    assert some[:-1].any() and not done[some].all(axis=1).all()  # ends mid-scan, not all at once
    _assert_bitwise_equal(vmapped, batch)
    _assert_bitwise_equal(vmapped, scan_inside)
    single = jax.jit(_scan_fn(env.step))
    for i in range(b):
        p_i = jax.tree.map(
            lambda a, x: x if a is None else x[i], axes, params, is_leaf=lambda a: a is None
        )
        one = single(p_i, jax.tree.map(lambda x: x[i], state), keys[:, i], actions[:, i])
        if SINGLE_EQUALS_BATCH_BITWISE:
            _assert_bitwise_equal(one, jax.tree.map(lambda x: x[:, i], vmapped))
        else:
            jax.tree.map(
                lambda x, y: np.testing.assert_allclose(x, y, rtol=0, atol=1e-6),
                one,
                jax.tree.map(lambda x: x[:, i], vmapped),
            )


def test_nested_vmap_seeds_by_instances_with_per_instance_params():
    s_, b, t = 2, 4, 12
    env, params = _uneven_ends("phasor", b)
    axes = batching.params_axes(params)
    _, state = jax.vmap(env.reset_batch, in_axes=(0, None))(
        jax.random.split(jax.random.key(0), (s_, b)), params
    )
    keys = jax.random.split(jax.random.key(1), (t, s_, b))
    actions = jax.random.uniform(jax.random.key(2), (t, s_, b, 3), minval=-1, maxval=1)
    nested = jax.vmap(jax.vmap(env.step, in_axes=(0, 0, 0, axes)), in_axes=(0, 0, 0, None))
    out = jax.jit(_scan_fn(nested))(params, state, keys, actions)
    assert np.asarray(out[3] | out[4]).any()
    per_seed = jax.jit(_scan_fn(env.step_batch))
    for k in range(s_):
        ref = per_seed(params, jax.tree.map(lambda x: x[k], state), keys[:, k], actions[:, k])
        _assert_bitwise_equal(ref, jax.tree.map(lambda x: x[:, k], out))


def test_vmapped_reset_is_one_batch_wide_branch():
    # Under vmap (nested too) the auto-reset stays a lax.cond on "any instance done" rather than
    # a per-instance select, which would compute a reset for every instance on every step.
    env, params = _uneven_ends("phasor", 4)
    axes = batching.params_axes(params)
    _, state = env.reset_batch(jax.random.split(jax.random.key(0), 4), params)
    one = jax.vmap(env.step, in_axes=(0, 0, 0, axes))
    two = jax.vmap(one, in_axes=(0, 0, 0, None))
    keys = jax.random.split(jax.random.key(1), 4)
    state2 = jax.tree.map(lambda x: jnp.stack([x, x]), state)
    for fn, args in (
        (one, (keys, state, jnp.zeros((4, 3)), params)),
        (two, (jnp.stack([keys, keys]), state2, jnp.zeros((2, 4, 3)), params)),
    ):
        text = str(jax.make_jaxpr(fn)(*args))
        assert text.count("cond[") == 1
        assert "reduce_or[axes=(0,)]" in text or "reduce_or[axes=(0, 1)]" in text


def test_gradients_through_vmapped_auto_reset():
    # Half the instances end on this step: d(obs)/d(init_spread) is the next episode's start's
    # derivative there and zero elsewhere; reverse mode works through the batched reset.
    env, params = ops_jax.make(stages=3, mode="medium", max_steps=2, model="phasor")
    spread = jnp.full(4, 0.13, jnp.float32)
    keys = jax.random.split(jax.random.key(0), 4)
    _, state = env.reset_batch(keys, params)
    state = dataclasses.replace(state, t=jnp.array([0, 1, 0, 1], jnp.int32))
    axes = batching.params_axes(dataclasses.replace(params, init_spread=spread))

    def total_obs(spread):
        p = dataclasses.replace(params, init_spread=spread)
        obs, _, _, term, trunc, _ = jax.vmap(env.step, in_axes=(0, 0, 0, axes))(
            keys, state, jnp.zeros((4, 3)), p
        )
        return obs.sum(), term | trunc

    grad, done = jax.grad(total_obs, has_aux=True)(spread)
    np.testing.assert_array_equal(done, [False, True, False, True])
    for i in range(4):
        k_reset = jax.random.split(keys[i])[1]
        s_i = jax.tree.map(lambda x: x[i], state)
        start = jax.grad(
            lambda v: env.next_episode(k_reset, s_i, dataclasses.replace(params, init_spread=v))[
                0
            ].sum()
        )
        expected = float(start(spread[i])) if done[i] else 0.0
        assert float(grad[i]) == pytest.approx(expected, rel=1e-5, abs=1e-6)
    assert np.abs(np.asarray(grad)[[1, 3]]).min() > 0


def test_vmapped_step_compiles_once():
    env, params = ops_jax.make(stages=3, mode="medium", max_steps=2)
    chex.clear_trace_counter()

    def vstep(keys, states, actions, params):
        return jax.vmap(jax.vmap(env.step, in_axes=(0, 0, 0, None)), in_axes=(0, 0, 0, None))(
            keys, states, actions, params
        )

    step = jax.jit(chex.assert_max_traces(vstep, n=1))
    keys = jax.random.split(jax.random.key(0), (2, 3))
    _, states = jax.vmap(env.reset_batch, in_axes=(0, None))(keys, params)
    for t in range(3):  # crosses an auto-reset
        _, states, *_ = step(keys, states, jnp.full((2, 3, 3), 0.1 * t, jnp.float32), params)
    step(
        keys, states, jnp.zeros((2, 3, 3)), dataclasses.replace(params, step_sigma=np.float32(1e-3))
    )


def test_auto_reset_keeps_final_observation_and_counts_episodes():
    env, params = ops_jax.make(stages=2, mode="hard", max_steps=3)
    obs, state = env.reset(jax.random.key(0), params)
    step = jax.jit(env.step)
    for t in range(3):
        obs, state, r, term, trunc, info = step(jax.random.key(t), state, jnp.zeros(2), params)
    assert bool(trunc) and not bool(term)
    assert int(state.t) == 0 and int(state.episode) == 1
    assert not np.allclose(obs, info["final_observation"])
    np.testing.assert_allclose(info["final_observation"][-2:], info["deltas_wl"] / 3.0, atol=1e-3)


def test_termination_outside_window():
    env, params = ops_jax.make(stages=2, mode="easy", action_scale=1.0, window=0.5)
    obs, state = env.reset(jax.random.key(0), params)
    _, _, _, term, trunc, _ = env.step_env(jax.random.key(1), state, jnp.ones(2), params)
    assert bool(term) and not bool(trunc)


def test_nonfinite_action_is_zero_and_flagged():
    env, params = ops_jax.make(stages=3, mode="easy", step_sigma=0.0)
    obs, state = env.reset(jax.random.key(0), params)
    bad = jnp.array([jnp.nan, jnp.inf, 0.5])
    _, s2, r, *_, info = env.step(jax.random.key(1), state, bad, params)
    assert bool(info["action_nonfinite"])
    np.testing.assert_allclose(s2.deltas, state.deltas + jnp.array([0, 0, 0.005]), atol=1e-7)
    assert np.isfinite(r)


def test_actions_are_clipped():
    env, params = ops_jax.make(stages=2, mode="easy", step_sigma=0.0)
    obs, state = env.reset(jax.random.key(0), params)
    _, s2, *_ = env.step(jax.random.key(1), state, jnp.array([5.0, -5.0]), params)
    np.testing.assert_allclose(s2.deltas - state.deltas, [0.01, -0.01], atol=1e-7)


@pytest.mark.parametrize("mode", ["easy", "medium", "hard"])
def test_initial_spread_matches_mode(mode):
    env, params = ops_jax.make(stages=5, mode=mode, model="phasor")  # statistics: any model
    _, states = jax.jit(env.reset_batch)(jax.random.split(jax.random.key(1), 20000), params)
    x = np.asarray(states.deltas).ravel()
    s0 = ops_jax.env.MODE_PARAMS[mode]["init_spread"]
    expected_std = s0 * stats.truncnorm(-2, 2).std()  # clip at 2 s0: the tails land on the bound
    clipped = stats.norm.sf(2) * 2
    expected_std = s0 * np.sqrt(stats.truncnorm(-2, 2).var() * (1 - clipped) + 4 * clipped)
    assert np.std(x) == pytest.approx(expected_std, rel=0.02)
    assert np.abs(x).max() <= 2 * s0 + 1e-6
    assert abs(np.mean(x)) < 4 * expected_std / np.sqrt(x.size)  # first episode: no drift


def test_step_noise_statistics():
    env, params = ops_jax.make(stages=4, mode="medium", model="phasor")
    _, states = jax.jit(env.reset_batch)(jax.random.split(jax.random.key(2), 20000), params)
    keys = jax.random.split(jax.random.key(3), 20000)
    _, s2, *_ = jax.jit(jax.vmap(env.step_env, in_axes=(0, 0, None, None)))(
        keys, states, jnp.zeros(4), params
    )
    inc = np.asarray(s2.deltas - states.deltas).ravel()
    clipped = stats.norm.sf(3) * 2
    expected = 5e-4 * np.sqrt(stats.truncnorm(-3, 3).var() * (1 - clipped) + 9 * clipped)
    assert np.std(inc) == pytest.approx(expected, rel=0.02)
    assert np.abs(inc).max() <= 3 * 5e-4 * 1.0001


def test_feedback_delay_sums_k_draws():
    env, params = ops_jax.make(stages=3, mode="easy", feedback_k=25, model="phasor")
    _, states = jax.jit(env.reset_batch)(jax.random.split(jax.random.key(2), 8000), params)
    keys = jax.random.split(jax.random.key(3), 8000)
    _, s2, *_ = jax.jit(jax.vmap(env.step_env, in_axes=(0, 0, None, None)))(
        keys, states, jnp.zeros(3), params
    )
    inc = np.asarray(s2.deltas - states.deltas).ravel()
    assert np.std(inc) == pytest.approx(5e-4 * 5 * 0.9866, rel=0.03)  # sqrt(25) draws


def test_hard_drift_grows_with_episodes_and_shifts_mean():
    u = noise.draws(jax.random.key(0), uniform={"u": (20000,)})["u"]
    r = noise.episode_drift(u, 5, 1.0, 0.1)
    assert np.abs(r).max() <= 0.5
    assert np.std(r) == pytest.approx(0.5 / np.sqrt(3), rel=0.03)
    r20 = noise.episode_drift(u, 20, 1.0, 0.1)
    assert np.abs(r20).max() <= 1.0 and np.abs(r20).max() > 0.95  # capped at 1
    # In the environment: mean increment per episode equals mu = r * sigma.
    env, params = ops_jax.make(stages=2, mode="hard", max_steps=1)
    ro = ops_jax.rollout(env, params, _zero_policy(2), jax.random.key(1), 4000, 12)
    assert np.abs(np.asarray(ro.obs)).max() < 2


def test_piecewise_linear_drift():
    env, params = ops_jax.make(
        stages=2,
        mode="custom",
        step_sigma=0.0,
        drift_amplitude=1e-3,
        drift_segment=10,
        obs_noise=0.0,
        include_noise=True,
        max_steps=100,
    )
    ro = ops_jax.rollout(env, params, _zero_policy(2), jax.random.key(4), 1, 40)
    mu = np.asarray(ro.obs[:, 0, -2:]) * noise.REFERENCE_SIGMA_WL  # mu_t seen at each step
    d2 = np.diff(mu[1:], 2, axis=0)  # zero inside segments, kinks at the knots
    kinks = np.abs(d2).max(axis=1) > 1e-7
    assert kinks.sum() <= 4 and np.abs(mu).max() > 1e-5
    assert np.abs(mu).max() <= 1e-3 + 1e-9


def test_params_can_differ_per_instance():
    env, params = ops_jax.make(stages=3, mode="custom", model="phasor")
    spreads = jnp.linspace(0.0, 0.2, 64)
    batched = ops_jax.EnvParams(**{**vars(params), "init_spread": spreads})
    _, states = jax.jit(env.reset_batch)(jax.random.split(jax.random.key(0), 64), batched)
    assert np.abs(np.asarray(states.deltas[0])).max() == 0.0
    assert np.abs(np.asarray(states.deltas[-1])).max() > 0.0
    ro = ops_jax.rollout(env, batched, _zero_policy(3), jax.random.key(1), 64, 5)
    assert ro.obs.shape == (5, 64, env.observation_size)


def test_rewards():
    for reward in ops_jax.REWARDS:
        env, params = ops_jax.make(
            stages=3, mode="easy", reward=reward, init_spread=0.0, step_sigma=0.0
        )
        obs, state = env.reset(jax.random.key(0), params)
        _, _, r, *_ = env.step(jax.random.key(1), state, jnp.zeros(3), params)
        expected = 1.0 if reward == "reference" else 0.0
        assert float(r) == pytest.approx(expected, abs=1e-5)
    env, params = ops_jax.make(stages=3, mode="easy", init_spread=0.1)
    ro = ops_jax.rollout(env, params, _zero_policy(3), jax.random.key(1), 16, 3)
    assert np.all(np.asarray(ro.reward) <= 0.0) and np.all(np.asarray(ro.reward) >= -1.0)
    env_l, params_l = ops_jax.make(stages=3, mode="easy", init_spread=0.1, reward="linear")
    ro_l = ops_jax.rollout(env_l, params_l, _zero_policy(3), jax.random.key(1), 16, 3)
    # the same trajectories: the linear reward is minus the square root of the paper's
    np.testing.assert_allclose(
        np.asarray(ro_l.reward), -np.sqrt(-np.asarray(ro.reward)), rtol=1e-4, atol=1e-6
    )
    assert float(np.asarray(ro_l.reward).min()) < -0.05


def test_frame_stack():
    env, params = ops_jax.make(stages=2, mode="easy", frame_stack=3, obs_noise=0.0)
    obs, state = env.reset(jax.random.key(0), params)
    f = env.frame_size
    assert obs.shape == (3 * f,)
    np.testing.assert_allclose(obs[:f], obs[2 * f :])
    obs2, *_ = env.step(jax.random.key(1), state, jnp.ones(2), params)
    np.testing.assert_allclose(obs2[:f], obs[f : 2 * f])
    assert not np.allclose(obs2[2 * f :], obs[2 * f :])


def test_rollout_metrics():
    env, params = ops_jax.make(stages=3, mode="easy", max_steps=10)
    ro = ops_jax.rollout(env, params, _zero_policy(3), jax.random.key(0), 8, 25)
    assert int(ro.metrics["num_episodes"]) == 16
    final = np.asarray(ro.normalized_power)[[9, 19]].mean()
    assert float(ro.metrics["final_normalized_power"]) == pytest.approx(final, rel=1e-5)


@pytest.mark.parametrize(
    "kwargs, exc, words",
    [
        (dict(stages=0), ValueError, "stages"),
        (dict(stages=1.5), TypeError, "stages"),
        (dict(mode="insane"), ValueError, "mode"),
        (dict(model="ray"), ValueError, "model"),
        (dict(detector="eye"), ValueError, "detector"),
        (dict(reward="money"), ValueError, "reward"),
        (dict(step_sigma=-1e-4), ValueError, "step_sigma"),
        (dict(init_spread=-0.1), ValueError, "init_spread"),
        (dict(obs_noise=float("nan")), ValueError, "obs_noise"),
        (dict(max_steps=0), ValueError, "max_steps"),
        (dict(feedback_k=0), ValueError, "feedback_k"),
        (dict(colour="red"), TypeError, "colour"),
    ],
)
def test_bad_configuration(kwargs, exc, words):
    with pytest.raises(exc, match=words):
        ops_jax.make(**{"stages": 3, **kwargs})


def test_bad_action_shape():
    env, params = ops_jax.make(stages=3)
    obs, state = env.reset(jax.random.key(0), params)
    with pytest.raises(ValueError, match=r"action must have shape \(3,\)"):
        env.step(jax.random.key(1), state, jnp.zeros(4), params)


def test_import_does_not_pull_heavy_dependencies():
    import subprocess
    import sys

    code = (
        "import sys, ops_jax; print(any(m.split('.')[0] in ('brax', 'matplotlib') for m in "
        "sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_draws_are_standard_and_separate():
    d = noise.draws(
        jax.random.key(5), normal={"z": (200, 100)}, uniform={"u": (20000,), "v": (20000,)}
    )
    z, u, v = (np.asarray(d[k]).ravel() for k in "zuv")
    assert (
        z.dtype == np.float32 and abs(z.mean()) < 0.02 and z.std() == pytest.approx(1.0, rel=0.02)
    )
    assert (
        stats.kstest(z, "norm").pvalue > 1e-3
        and stats.kstest(u, "uniform", args=(-1, 2)).pvalue > 1e-3
    )
    assert u.min() >= -1 and u.max() < 1 and abs(np.corrcoef(u, v)[0, 1]) < 0.03  # disjoint bits
