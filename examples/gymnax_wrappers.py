"""The gymnax adapter of ops-jax under gymnax 1.x's own wrappers, each jitted and vmapped where it
is functional.

    pip install -e ".[gymnax]"
    python examples/gymnax_wrappers.py [--num-envs 64] [--steps 100] [--seed 0]

Functional wrappers (``jax.jit(jax.vmap(...))`` over ``--num-envs`` instances, ``--steps`` steps in
one ``lax.scan``): ``LogWrapper`` (episode returns), ``FlattenObservationWrapper``,
``GymnaxToDmEnvWrapper`` (dm_env ``TimeStep``), ``LegacyStepAPIWrapper`` (the five-value step of
gymnax 0.0.x). Object wrappers: ``GymnaxToGymWrapper`` (a Gymnasium env) and
``GymnaxToVectorGymWrapper`` (a Gymnasium vector env). Also ``GymnaxToBraxWrapper`` where brax is
installed. ``StickyActionWrapper`` needs a discrete action space and does not fit OPS. The policy is
random in [-1, 1]^N: the point is the plumbing.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys

import jax
import jax.numpy as jnp
import numpy as np

ENV_KWARGS = dict(stages=3, mode="easy", model="phasor", max_steps=20)


def _gymnax():
    try:
        from gymnax import wrappers

        from ops_jax.adapters import gymnax as gymnax_env
    except ImportError as e:
        sys.exit(
            f'examples/gymnax_wrappers.py needs gymnax >= 1.0 ({e}): pip install -e ".[gymnax]"'
        )
    if not gymnax_env.SIX_VALUE_STEP:
        sys.exit('examples/gymnax_wrappers.py needs gymnax >= 1.0: pip install -e ".[gymnax]"')
    return wrappers, gymnax_env


def scan_steps(
    env, params, num_envs: int, steps: int, seed: int, unpack, carry=lambda reset_out: reset_out[1]
):
    """Run ``steps`` random-action steps of ``num_envs`` instances of a functional env in one jitted
    scan; ``unpack(step_out) -> (carry, dict)``, ``carry(reset_out)`` the first carry; returns the
    dicts stacked (steps, num_envs, ...)."""
    reset, step = env.reset, env.step
    n = env.action_space(params).shape[0]

    @jax.jit
    def run(key):
        k_reset, k_run = jax.random.split(key)
        state = carry(
            jax.vmap(reset, in_axes=(0, None))(jax.random.split(k_reset, num_envs), params)
        )

        def body(state, k):
            k_act, k_env = jax.random.split(k)
            action = jax.random.uniform(k_act, (num_envs, n), minval=-1.0, maxval=1.0)
            out = jax.vmap(step, in_axes=(0, 0, 0, None))(
                jax.random.split(k_env, num_envs), state, action, params
            )
            return unpack(out)

        _, outs = jax.lax.scan(body, state, jax.random.split(k_run, steps))
        return outs

    return jax.device_get(run(jax.random.key(seed)))


def run(num_envs: int = 64, steps: int = 100, seed: int = 0, **env_kwargs) -> dict:
    """Every wrapper that fits a continuous-action env, on
    ``gymnax_env.make(**ENV_KWARGS, **env_kwargs)``; returns per wrapper what it reports (episode
    returns, shapes, done flags)."""
    wrappers, gymnax_env = _gymnax()
    env, params = gymnax_env.make(**{**ENV_KWARGS, **env_kwargs})
    results = {}

    log_env = wrappers.LogWrapper(env)
    out = scan_steps(
        log_env,
        params,
        num_envs,
        steps,
        seed,
        unpack=lambda o: (
            o[1],
            {
                "returned": o[5]["returned_episode"],
                "episode_return": o[5]["returned_episode_returns"],
                "episode_length": o[5]["returned_episode_lengths"],
                "normalized_power": o[5]["normalized_power"],
            },
        ),
    )
    done = out["returned"]
    results["LogWrapper"] = {
        "episodes": int(done.sum()),
        "mean_episode_return": float(out["episode_return"][done].mean()) if done.any() else None,
        "episode_lengths": sorted({int(x) for x in out["episode_length"][done]}),
        "mean_normalized_power": float(out["normalized_power"].mean()),
    }

    flat_env = wrappers.FlattenObservationWrapper(env)
    out = scan_steps(
        flat_env,
        params,
        num_envs,
        steps,
        seed,
        unpack=lambda o: (o[1], {"obs": o[0], "final_obs": o[5]["final_observation"]}),
    )
    results["FlattenObservationWrapper"] = {
        "obs_shape": out["obs"].shape[1:],
        "space": flat_env.observation_space(params).shape,
    }

    dm_env = wrappers.GymnaxToDmEnvWrapper(env)
    out = scan_steps(
        dm_env,
        params,
        num_envs,
        steps,
        seed,
        carry=lambda ts: ts,
        unpack=lambda ts: (ts, {"discount": ts.discount, "reward": ts.reward}),
    )
    results["GymnaxToDmEnvWrapper"] = {
        "min_discount": float(out["discount"].min()),
        "mean_reward": float(out["reward"].mean()),
    }

    legacy = wrappers.LegacyStepAPIWrapper(env)
    out = scan_steps(
        legacy,
        params,
        num_envs,
        steps,
        seed,
        unpack=lambda o: (o[1], {"values": jnp.asarray(len(o)), "done": o[3]}),
    )
    results["LegacyStepAPIWrapper"] = {
        "values_per_step": int(out["values"][0]),
        "episodes": int(out["done"].sum()),
    }

    gym_env = wrappers.GymnaxToGymWrapper(env, params, seed=seed)
    obs, _ = gym_env.reset(seed=seed)
    finished = 0
    for _ in range(steps):
        obs, reward, terminated, truncated, info = gym_env.step(gym_env.action_space.sample())
        finished += bool(terminated) or bool(truncated)
    results["GymnaxToGymWrapper"] = {
        "obs_shape": tuple(np.shape(obs)),
        "episodes": finished,
        "action_space": str(gym_env.action_space),
    }

    vec_env = wrappers.GymnaxToVectorGymWrapper(env, num_envs=num_envs, params=params, seed=seed)
    obs, _ = vec_env.reset(seed=seed)
    finished = 0
    for _ in range(steps):
        obs, reward, terminated, truncated, info = vec_env.step(
            np.asarray(vec_env.action_space.sample())
        )
        finished += int(np.sum(np.asarray(terminated) | np.asarray(truncated)))
    results["GymnaxToVectorGymWrapper"] = {"obs_shape": tuple(np.shape(obs)), "episodes": finished}

    try:
        with contextlib.redirect_stdout(
            io.StringIO()
        ):  # brax.envs prints about mujoco's optional warp backend
            from gymnax.wrappers.brax import GymnaxToBraxWrapper
    except ModuleNotFoundError:
        return results
    brax_env = GymnaxToBraxWrapper(env)
    reset, step = jax.jit(jax.vmap(brax_env.reset)), jax.jit(jax.vmap(brax_env.step))
    state = reset(jax.random.split(jax.random.key(seed), num_envs))
    dones = 0
    for i in range(steps):
        state = step(state, jnp.zeros((num_envs, env.num_actions)))
        dones += int(state.done.sum())
    results["GymnaxToBraxWrapper"] = {"obs_shape": tuple(state.obs.shape), "episodes": dones}
    return results


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--num-envs", type=int, default=64)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    for name, report in run(a.num_envs, a.steps, a.seed).items():
        print(f"{name:28s} {report}")


if __name__ == "__main__":
    main()
