"""The Brax adapter: contract, registration, fresh random starts under brax's training wrappers,
the evaluation metric. (brax's PPO / SAC trainers on it: tests/agents/learners/test_ppo_sac.py.)"""

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brax import envs
from brax.envs.wrappers import training as wrappers

import ops_jax
from ops_jax.adapters.brax import OPSBraxEnv


def _wrapped(max_steps, num_envs=2, **kw):
    env = envs.get_environment("ops", stages=3, max_steps=max_steps, **kw)
    return env, wrappers.wrap(env, episode_length=max_steps)


def _run(wrapped, steps, num_envs=2, seed=0, action=0.0):
    """Step zero (or constant) actions; return per step (deltas before the step's reset, done,
    the state after the wrapper's reset)."""
    n = wrapped.action_size

    @jax.jit
    def run(key):
        state = wrapped.reset(jax.random.split(key, num_envs))

        def body(s, _):
            s = wrapped.step(s, jnp.full((num_envs, n), action, jnp.float32))
            return s, (
                s.pipeline_state.deltas,
                s.pipeline_state.episode,
                s.pipeline_state.mu_episode,
                s.done,
            )

        return state, jax.lax.scan(body, state, None, length=steps)[1]

    return run(jax.random.PRNGKey(seed))


def test_contract_and_registration():
    env = envs.get_environment("ops", stages=4, mode="medium", frame_stack=2)
    assert isinstance(env, OPSBraxEnv)
    ops_env, _ = ops_jax.make(4, "medium", frame_stack=2)
    assert env.observation_size == ops_env.observation_size == 2 * (16 + 4)
    assert env.action_size == 4 and env.backend == "ops_jax"
    s = jax.jit(env.reset)(jax.random.PRNGKey(1))
    s2 = jax.jit(env.step)(s, jnp.zeros(4))
    assert s.obs.shape == (env.observation_size,) and s.obs.dtype == jnp.float32
    for st in (s, s2):
        assert st.reward.dtype == jnp.float32 and st.done.dtype == jnp.float32
        assert st.reward.shape == () and st.done.shape == ()
    assert -1.0 <= float(s2.reward) <= 0.0
    assert 0 < float(s2.metrics["normalized_power"]) <= 1
    # registering again is harmless; options reach ops_jax.make
    import ops_jax.adapters.brax as be

    be.register()
    assert envs.get_environment("ops", stages=2).ops_env.config.model == "phasor"
    assert (
        envs.get_environment("ops", stages=2, observe_lengths=False).observation_size == 4
    )  # frames only
    assert envs.get_environment("ops", stages=2, model="field").ops_env.config.model == "field"
    with pytest.raises(TypeError, match="unknown option"):
        OPSBraxEnv(stages=2, nonsense=1)
    with pytest.raises(ValueError, match="first_episode"):
        OPSBraxEnv(stages=2, first_episode=-1)
    with pytest.raises(ValueError, match="action"):
        env.step(s, jnp.zeros(3))


def test_import_ops_jax_does_not_import_brax():
    code = "import sys, ops_jax; assert 'brax' not in sys.modules, 'brax imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_successive_episodes_start_fresh_and_noise_differs():
    steps = 6
    _, wrapped = _wrapped(steps, mode="easy")
    first, (deltas, episode, _, done) = _run(wrapped, 3 * steps)
    deltas, episode, done = np.asarray(deltas), np.asarray(episode), np.asarray(done)
    # done exactly at the end of each episode; the state after it is the next episode's start
    np.testing.assert_array_equal(done[:, 0], np.tile(np.arange(1, steps + 1) == steps, 3))
    starts = [np.asarray(first.pipeline_state.deltas)] + [deltas[k * steps - 1] for k in (1, 2)]
    np.testing.assert_array_equal(episode[steps - 1], [1, 1])
    np.testing.assert_array_equal(episode[2 * steps - 1], [2, 2])
    for a in range(3):
        for b in range(a + 1, 3):
            # every slot's episodes start from different random delays (not the cached first state)
            assert np.all(np.abs(starts[a] - starts[b]).max(-1) > 1e-3), (a, b)
    # per-step randomness: with zero actions, the free-running increments of episode 2 differ from
    # episode 1's (the key is not restored with the cached state)
    inc1 = np.diff(deltas[0 : steps - 1], axis=0)
    inc2 = np.diff(deltas[steps : 2 * steps - 1], axis=0)
    assert np.abs(inc1).max() > 0 and not np.allclose(inc1, inc2)


def test_hard_mode_drift_is_redrawn_each_episode():
    steps = 4
    _, wrapped = _wrapped(steps, mode="hard", num_envs=1)
    first, (_, episode, mu, _) = _run(wrapped, 4 * steps, num_envs=1)
    mu = np.asarray(mu)[:, 0, 0]
    per_episode = [float(np.asarray(first.pipeline_state.mu_episode)[0, 0])] + [
        mu[k * steps - 1] for k in (1, 2, 3)
    ]
    assert per_episode[0] == 0.0  # first episode: drift ramp at 0
    assert len(set(per_episode[1:])) == 3 and all(m != 0.0 for m in per_episode[1:])
    np.testing.assert_array_equal(
        np.asarray(episode)[[steps - 1, 2 * steps - 1, 3 * steps - 1], 0], [1, 2, 3]
    )


def test_eval_metric_is_final_power():
    env = OPSBraxEnv(stages=3, mode="easy", max_steps=5)
    ev = wrappers.EvalWrapper(wrappers.wrap(env, episode_length=5))

    @jax.jit
    def run(key):
        s = ev.reset(jax.random.split(key, 4))
        return jax.lax.fori_loop(0, 5, lambda i, s: ev.step(s, jnp.zeros((4, 3))), s)

    s = run(jax.random.PRNGKey(0))
    total = s.info["eval_metrics"].episode_metrics["final_normalized_power"]
    # the episode sum of final_normalized_power is the last step's P/Pmax
    np.testing.assert_allclose(total, s.metrics["normalized_power"], rtol=1e-6)


def test_slots_under_vmap_match_single_slots_bitwise():
    # Early terminations at different steps: the batched step computes the fresh starts only on
    # steps where some slot ends, and every slot's trajectory equals its own single-slot run.
    b, t, steps = 4, 16, 6
    env, wrapped = _wrapped(steps, mode="hard", window=0.5, action_scale=0.3)
    keys = jax.random.split(jax.random.PRNGKey(3), b)
    actions = jax.random.uniform(jax.random.PRNGKey(4), (t, b, 3), minval=-1, maxval=1)

    @jax.jit
    def run(keys, actions):
        def body(s, a):
            s = wrapped.step(s, a)
            return s, (s.obs, s.reward, s.done, s.pipeline_state, s.info["first_obs"])

        return jax.lax.scan(body, wrapped.reset(keys), actions)[1]

    out = run(keys, actions)
    done = np.asarray(out[2])
    assert (
        done.any() and not done[done.any(axis=1)].all(axis=1).all()
    )  # slots end at different steps
    assert np.asarray(out[3].episode)[-1].min() >= 1
    for i in range(b):
        one = run(keys[i : i + 1], actions[:, i : i + 1])
        for x, y in zip(jax.tree.leaves(one), jax.tree.leaves(out)):
            np.testing.assert_array_equal(np.asarray(x)[:, 0], np.asarray(y)[:, i])
    state = jax.jit(wrapped.reset)(keys)
    text = str(jax.make_jaxpr(wrapped.step)(state, actions[0]))
    assert text.count("cond[") == 1  # one batch-wide branch, not a per-slot select
