"""The evaluation's compiled programs: a policy's episodes in one jitted scan (``evaluator``),
memoised per policy and static environment configuration (``cached_evaluator``), episodes and seeds
split over the local devices (``split_over_devices``, ``episode_ids``). A policy is an
``agents.api.Policy``."""

from __future__ import annotations

from collections import OrderedDict
import jax
import jax.numpy as jnp
import numpy as np


def split_over_devices(size: int, axis: str):
    """A ``NamedSharding`` splitting a leading axis of length ``size`` over all local devices (a
    multi-GPU host, or XLA_FLAGS=--xla_force_host_platform_device_count=K on CPU) when there are
    several and they divide it; else None (one device)."""
    devices = jax.local_devices()
    if len(devices) < 2 or size % len(devices):
        return None
    mesh = jax.sharding.Mesh(np.array(devices), (axis,))
    return jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(axis))


def episode_ids(episodes: int):
    """Episode indices, sharded with ``split_over_devices``: the jitted evaluation then splits its
    episodes across devices. Results do not depend on the device count."""
    ids = jnp.arange(episodes)
    sharding = split_over_devices(episodes, "episodes")
    return ids if sharding is None else jax.device_put(ids, sharding)


_EVALUATORS: "OrderedDict[tuple, tuple]" = OrderedDict()
_EVALUATORS_MAX = 64


def cached_evaluator(ident, policy, env, steps: int, drift_episode: int):
    """``evaluator`` memoised, so repeated evaluations (seeds, testing environments, other modes
    with the same static configuration) reuse one compiled program. A ``TrainResult`` is keyed by
    ``ident``, what its policy is built from (a ``TrainResult``'s algorithm, training configuration
    and hyperparameters, or a policy's identity); the environment by its static ``EnvConfig`` (its
    parameters are arguments). Returns ``(run, warmed)``: ``warmed`` holds the argument signatures
    already run once."""
    key = (ident, env.config, steps, drift_episode)
    if key not in _EVALUATORS:
        _EVALUATORS[key] = (
            evaluator(env, policy, steps, drift_episode),
            set(),
        )  # + warmed signatures
        if len(_EVALUATORS) > _EVALUATORS_MAX:
            _EVALUATORS.popitem(last=False)
    _EVALUATORS.move_to_end(key)
    return _EVALUATORS[key]


def _step_probe(env, env_params, ids, k_env, probes: list, now: list, made: list):
    """``probe(offsets (B, N), active=None) -> P / P_max (B,)`` within one control step: each probe
    of the step its own key (``probes[0]`` counts them), the state after the step's probes so far in
    ``now[0]`` (``EnvConfig.probe="frame"`` moves it), the readings made per episode in
    ``made[0]``; where ``active`` is False nothing moves and the reading is NaN."""

    def probe(offsets, active=None):
        probes[0] += 1
        keys = jax.vmap(jax.random.fold_in, (None, 0))(jax.random.fold_in(k_env, probes[0]), ids)
        p, probed = jax.vmap(env.probe_step, in_axes=(0, 0, 0, None))(
            keys, now[0], offsets, env_params
        )
        if active is None:
            now[0] = probed
            made[0] = made[0] + 1
            return p
        made[0] = made[0] + active.astype(jnp.int32)
        now[0] = jax.tree.map(
            lambda a, b: jnp.where(active.reshape(active.shape + (1,) * (a.ndim - 1)), a, b),
            probed,
            now[0],
        )
        return jnp.where(active, p, jnp.nan)

    return probe


def evaluator(env, policy, steps: int, drift_episode: int, trajectory: bool = False):
    """``run(params, env_params, key, ids)``: the jitted episode rollout (no auto-reset) returning
    P/Pmax, terminated flags and the readings made per step (the observation's frame and the probes
    left in; steps, episodes), with ``trajectory`` also the delay offsets (steps + 1, episodes, N)
    wl after the reset and after each step. The one rollout of a policy: ``evaluate`` and the
    episode renderer (``agents.episode``) use it."""
    probes = [0]  # probe calls so far in the step being traced (each probe's own key)
    axes_params = None

    @jax.jit
    def run(params, env_params, key, ids):
        k_reset, k_init, k_run = jax.random.split(key, 3)
        keys = jax.vmap(jax.random.fold_in, (None, 0))(k_reset, ids)
        obs, states = jax.vmap(env.reset, in_axes=(0, axes_params, None))(
            keys, env_params, drift_episode
        )
        carry = policy.init(k_init, obs)

        def body(c, t):
            obs, states, carry = c
            k_act, k_env = jax.random.split(jax.random.fold_in(k_run, t))
            now, made = [states], [jnp.ones(ids.shape, jnp.int32)]  # readings this step
            probe = _step_probe(env, env_params, ids, k_env, probes, now, made)
            probes[0] = 0
            action, carry = policy.act(params, carry, obs, k_act, probe)
            keys = jax.vmap(jax.random.fold_in, (None, 0))(k_env, ids)
            obs, states, _, term, _, info = jax.vmap(env.step_env, in_axes=(0, 0, 0, None))(
                keys, now[0], action, env_params
            )
            out = (info["normalized_power"], term, made[0]) + (
                (states.deltas,) if trajectory else ()
            )
            return (obs, states, carry), out

        _, out = jax.lax.scan(body, (obs, states, carry), jnp.arange(steps))
        if trajectory:
            out = (*out[:3], jnp.concatenate([states.deltas[None], out[3]]))
        return out

    return run
