"""The fit observer (``observer="fit"`` or ``"fit-residual"`` of TD3 and DroQ,
``agents.learners.offpolicy.observer``): what it appends, its resets, the move a residual learner
sends, the stored form of the field, and a learner trained and evaluated with it on frames alone."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agents
from agents.learners.offpolicy import droq, observer
from agents import DroQConfig, TD3Config
from agents.envs import built
from agents.controllers.physics_informed import wrap

FRAMES = dict(stages=5, mode="hard", model="phasor", observe_lengths=False)


def _rollout(env_config, steps: int, actions_fn, residual: bool = False, power: bool = False):
    """(appended entries (steps, B, fit), true offsets (steps, B, N) wl, done flags[, P / P_max
    (steps, B)]) of ``Observed`` under ``actions_fn(key) -> (B, N)``."""
    env, params = built(env_config)
    seen_env = observer.Observed(env, observer.fit_observer(env_config, residual=residual))
    step = jax.jit(seen_env.step_batch)
    key = jax.random.key(0)
    obs, state = seen_env.reset_batch(jax.random.split(key, 16), params)
    assert obs.shape == (16, env.observation_size + seen_env.observer.size)
    out = []
    for _ in range(steps):
        key, k_act, k_env = jax.random.split(key, 3)
        obs, state, _, term, trunc, info = step(
            jax.random.split(k_env, 16), state, actions_fn(k_act), params
        )
        out.append(
            (
                np.asarray(info["final_observation"][:, env.observation_size :]),
                np.asarray(info["deltas_wl"]),
                np.asarray(term | trunc),
            )
            + ((np.asarray(info["normalized_power"]),) if power else ())
        )
    return [np.stack(x) for x in zip(*out)]


def test_fit_reads_the_offsets_from_frames_under_random_moves():
    """Ideal hard mode, frames only, uniform random actions: the appended offsets are the true ones
    (modulo the period) within 0.005 wl in >= 90 % of the steps after the first five."""
    z, deltas, _ = _rollout(
        FRAMES, 40, lambda k: jax.random.uniform(k, (16, 5), minval=-1, maxval=1)
    )
    fit = z.shape[-1]
    err = np.abs(np.asarray(wrap(z - deltas[..., :fit])))[5:]
    assert fit == 4 and np.mean(err < 0.005) >= 0.9, np.quantile(err, [0.5, 0.9])


def test_a_residual_learner_sends_its_correction_added_to_the_fits_move():
    """With ``fit-residual`` a zero correction sends the fit's own move (the physics-informed
    controller's frames preset), which stacks ideal hard from its random starts; with ``fit`` the
    same zero action leaves the lines where they start. A correction is added to that move, then
    clipped to [-1, 1]."""
    zeros = lambda k: jnp.zeros((16, 5))  # noqa: E731
    *_, p_residual = _rollout(FRAMES, 60, zeros, residual=True, power=True)
    *_, p_fit = _rollout(FRAMES, 60, zeros, power=True)
    assert np.mean(p_residual[-10:]) >= 0.95 and np.mean(p_fit[-10:]) < 0.6, (
        p_residual[-1],
        p_fit[-1],
    )
    env, params = built(FRAMES)
    obs, _ = env.reset_batch(jax.random.split(jax.random.key(3), 4), params)
    correction = jax.random.uniform(jax.random.key(5), (4, 5), minval=-1, maxval=1)
    for scale in (1.0, 0.25):  # ``residual_scale``: the correction per unit of the learner's action
        ob = observer.of_learner(
            FRAMES, DroQConfig.make(observer="fit-residual", residual_scale=scale)
        )
        _, carry = ob.observe(None, ob.init(None, obs), obs, jax.random.key(4))
        np.testing.assert_allclose(
            np.asarray(ob.command(carry, correction)),
            np.clip(np.asarray(carry["prior"]) + scale * np.asarray(correction), -1, 1),
            atol=1e-6,
        )
        assert np.any(np.asarray(carry["prior"]) != 0)


def test_episode_ends_restart_the_fit():
    """At a truncation the final observation keeps the episode's fit, and the next episode's first
    observation is the fit of a fresh carry at its first frame."""
    config = dict(FRAMES, max_steps=3)
    env, params = built(config)
    ob = observer.fit_observer(config)
    seen_env = observer.Observed(env, ob)
    key = jax.random.key(1)
    obs, state = jax.jit(seen_env.reset_batch)(jax.random.split(key, 4), params)
    step = jax.jit(seen_env.step_batch)
    for t in range(3):
        keys = jax.random.split(jax.random.fold_in(key, t), 4)
        obs, state, _, term, trunc, info = step(keys, state, jnp.zeros((4, 5)), params)
    assert bool(jnp.all(trunc)) and not bool(jnp.allclose(obs, info["final_observation"]))
    carry = state[1]
    assert float(carry["valid"].min()) == 1.0  # one fit done on the new episode's frame
    raw = obs[:, : env.observation_size]
    k_reset = jax.random.split(jax.random.fold_in(keys[0], 1))[1]
    fresh, _ = jax.jit(ob.observe)(
        {"action_scale": params.action_scale, "window": params.window},
        ob.init(k_reset, raw),
        raw,
        k_reset,
    )
    np.testing.assert_allclose(np.asarray(obs), np.asarray(fresh), atol=1e-6)


def test_observer_field_is_checked_and_stored_only_when_set():
    assert (
        "observer" not in DroQConfig.make().to_hyper()
        and "observer" not in TD3Config.make("budget").to_hyper()
    )
    assert DroQConfig.make(observer="fit").to_hyper()["observer"] == "fit"
    assert TD3Config.make(observer="fit-residual").to_hyper()["observer"] == "fit-residual"
    assert DroQConfig.from_hyper(DroQConfig.make().to_hyper()).observer == "none"
    with pytest.raises(ValueError, match="observer must be one of"):
        DroQConfig.make(observer="kalman")
    assert "residual_scale" not in DroQConfig.make(observer="fit-residual").to_hyper()
    assert (
        TD3Config.make(observer="fit-residual", residual_scale=0.25).to_hyper()["residual_scale"]
        == 0.25
    )
    with pytest.raises(ValueError, match="residual_scale must be"):
        DroQConfig.make(residual_scale=0.0)
    assert "fit_starts" not in DroQConfig.make(observer="fit").to_hyper()
    assert "fit_history" not in DroQConfig.make(observer="fit").to_hyper()
    assert TD3Config.make(observer="fit", fit_starts=4, fit_iters=3).to_hyper()["fit_iters"] == 3
    assert DroQConfig.make(observer="fit", fit_history=3).to_hyper()["fit_history"] == 3
    with pytest.raises(ValueError, match="fit_starts must be"):
        DroQConfig.make(fit_starts=0)
    for bad in (0, 17, 2.5):
        with pytest.raises(ValueError, match="fit_history must be"):
            TD3Config.make(fit_history=bad)


def test_the_fits_history_holds_the_frames_and_the_moves_really_sent():
    """``fit_history=3``: the fit's carry keeps the frames it compares the next one with (the newest
    and the two before it) and the moves the residual learner really sent after each (the fit's move
    plus its correction, clipped), newest first."""
    env, params = built(FRAMES)
    ob = observer.of_learner(FRAMES, DroQConfig.make(observer="fit-residual", fit_history=3))
    key = jax.random.key(11)
    obs, state = env.reset_batch(jax.random.split(key, 4), params)
    carry, frames, sent, observe = ob.init(key, obs), [], [], jax.jit(ob.observe)
    for t in range(4):
        _, carry = observe(None, carry, obs, jax.random.fold_in(key, t))
        frames.append(np.asarray(env.layout.detector(obs)))
        sent.append(
            np.asarray(
                ob.command(
                    carry,
                    jax.random.uniform(
                        jax.random.fold_in(key, 10 + t), (4, 5), minval=-1, maxval=1
                    ),
                )
            )
        )
        carry = ob.moved(None, carry, jnp.asarray(sent[-1]))
        obs, state, *_ = env.step_batch(
            jax.random.split(jax.random.fold_in(key, 20 + t), 4),
            state,
            jnp.asarray(sent[-1]),
            params,
        )
    fit, scale = ob.size, float(params.action_scale)
    np.testing.assert_allclose(np.asarray(carry["y_prev"]), frames[3], atol=1e-6)
    np.testing.assert_allclose(
        np.asarray(carry["y_older"]), np.stack([frames[2], frames[1]], axis=1), atol=1e-6
    )
    np.testing.assert_allclose(np.asarray(carry["dz_prev"]), sent[3][:, :fit] * scale, atol=1e-6)
    np.testing.assert_allclose(
        np.asarray(carry["dz_older"]),
        np.stack([sent[2], sent[1]], axis=1)[..., :fit] * scale,
        atol=1e-6,
    )
    assert "y_older" not in observer.of_learner(FRAMES, DroQConfig.make(observer="fit")).init(
        key, obs
    )


def test_the_fits_size_reaches_the_observer():
    """``fit_starts`` / ``fit_iters``: one Levenberg-Marquardt iteration from one random start reads
    a fresh frame's offsets (up to their sign: one frame does not tell it) worse than the frames
    preset's 16 starts x 8 iterations."""
    env, params = built(FRAMES)
    obs, state = env.reset_batch(jax.random.split(jax.random.key(7), 32), params)
    truth = np.asarray(state.deltas)[:, :4]

    def error(h):
        ob = observer.of_learner(FRAMES, DroQConfig.make(observer="fit", **h))
        seen, _ = ob.observe(None, ob.init(None, obs), obs, jax.random.key(8))
        z = np.asarray(seen[:, env.observation_size :])
        return np.minimum(np.abs(np.asarray(wrap(z - truth))), np.abs(np.asarray(wrap(z + truth))))

    small, preset = error({"fit_starts": 1, "fit_iters": 1}), error({})
    assert np.median(small) > 2 * np.median(preset) + 1e-3, (np.median(small), np.median(preset))


def test_droq_with_the_fit_trains_saves_and_acts_on_raw_frames(tmp_path):
    """A short DroQ run with the fit: its policy params are sized for frames + offsets, the saved
    policy evaluates on the frames-only env (the fit runs inside the policy), and the same seed
    gives the same params."""
    config = dict(
        FRAMES, imperfections="none", max_steps=50
    )  # short episodes: the fit is costly to run unoptimised
    kw = dict(
        seed=2,
        total_steps=200,
        observer="fit",
        learning_starts=100,
        eval_every=100,
        hidden=(16, 16),
        critic_hidden=(16, 16),
        batch_size=32,
        utd_ratio=1.0,
        eval_episodes=2,
    )
    result = agents.train("droq", config, **kw)
    env, _ = built(config)
    assert result.config.observer == "fit"
    assert result.params["obs_norm"]["mean"].shape == (env.observation_size + 4,)
    agents.save(tmp_path / "p", result)
    loaded = agents.load(tmp_path / "p")
    ev = agents.evaluate(loaded, config, episodes=3, seed=0)
    assert np.all(np.isfinite(ev.normalized_power)) and ev.normalized_power.shape[0] == 3
    again = agents.train("droq", config, **kw)
    assert all(
        np.array_equal(a, b)
        for a, b in zip(jax.tree.leaves(result.params), jax.tree.leaves(again.params))
    )
    assert droq.LEARNER.make_policy(result.env_spec, result.config).init(
        None, jnp.zeros((1, env.observation_size))
    )["z"].shape == (1, 4)
