"""A frozen controller on a bench: one jitted program replayed probe by probe (``Agent``, an
``agents.bench.controller.Controller``), built from a name or a saved folder (``load_controller``),
checked against the bench's length readouts."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import ops_jax
from agents import api as base
from agents.controllers import trim
from agents.bench.controller import Controller
from agents.bench.mapping import MappingError, missing_lengths

MAX_PROBES = 16  # probes per control step a controller may ask for


class Agent(Controller):
    """A controller on one instance (B = 1): ``start(obs)``, then per step the probe ``offsets`` in
    turn and the ``act``ion, with probe results filled in as they are measured. One jitted program;
    a step with K probes calls it K + 1 times (the policy is pure, so each call repeats the same
    draws)."""

    def __init__(self, policy: base.Policy, params, env, seed: int):
        self.policy, self.params, self.env = policy, params, env
        _, self._k_init, self._k_run = jax.random.split(jax.random.key(seed), 3)
        obs = jnp.zeros((1, env.observation_size), jnp.float32)
        calls = []
        jax.eval_shape(
            lambda: self._act(
                params,
                policy.init(self._k_init, obs),
                obs,
                self._k_run,
                jnp.zeros((MAX_PROBES, 1)),
                calls,
            )
        )
        self.probes = len(calls)
        self._init = jax.jit(policy.init)
        self._run = jax.jit(self._step)
        self._sent = (
            None if policy.sent is None else jax.jit(lambda p, c, a: policy.sent(p, c, a[None]))
        )
        # compile before the run (results discarded: the policy is pure); twice, the second time
        # with the carry as act returns it (its dtypes may differ from init's)
        carry = self._init(self._k_init, obs)
        for _ in range(2):
            _, carry, _ = self._run(
                params,
                carry,
                np.zeros(obs.shape[1], np.float32),
                0,
                np.zeros(self.probes, np.float32),
            )
            if self._sent is not None:
                carry = self._sent(params, carry, np.zeros(env.num_actions, np.float32))
        jax.block_until_ready(carry)
        self.carry, self.t = None, 0

    def _act(self, params, carry, obs, key, results, calls):
        def probe(offsets, active=None):
            calls.append((offsets, jnp.ones(offsets.shape[:1], bool) if active is None else active))
            if len(calls) > results.shape[0]:
                raise ValueError(f"the controller asks for more than {MAX_PROBES} probes per step")
            return results[len(calls) - 1].astype(jnp.float32)

        action, carry = self.policy.act(params, carry, obs, key, probe)
        offsets = (
            jnp.stack([c[0] for c in calls])
            if calls
            else jnp.zeros((0, *action.shape), jnp.float32)
        )
        active = (
            jnp.stack([c[1] for c in calls]) if calls else jnp.zeros((0, action.shape[0]), bool)
        )
        return action, carry, (offsets, active)

    def _step(self, params, carry, obs, t, results):
        """Step ``t``'s (action (N,), carry, (probe offsets (K, N), probes made (K,))) from obs (D,)
        and probe results (K,)."""
        key = jax.random.split(jax.random.fold_in(self._k_run, t))[0]
        action, carry, (offsets, active) = self._act(
            params, carry, obs[None], key, results[:, None], []
        )
        return action[0], carry, (offsets[:, 0], active[:, 0])

    def start(self, obs):
        """The controller's state from the first observation."""
        self.carry = self._init(self._k_init, jnp.asarray(obs, jnp.float32)[None])

    def _call(self, obs, results):
        return self._run(
            self.params,
            self.carry,
            np.asarray(obs, np.float32),
            self.t,
            np.asarray(results, np.float32),
        )

    def offsets(self, obs, results, i: int) -> np.ndarray | None:
        """Probe i's offsets (N,) wl, given the results of probes 0..i-1; None where the controller
        leaves it out."""
        offsets, active = self._call(obs, results)[2]
        return np.asarray(offsets[i], np.float64) if bool(active[i]) else None

    def act(self, obs, results) -> np.ndarray:
        """The step's action (N,) in [-1, 1]; advances the controller's state."""
        action, self.carry, _ = self._call(obs, results)
        self.t += 1
        return np.asarray(action, np.float64)

    def tell(self, action) -> bool:
        """Tell a controller that reads its own last move (``Policy.sent``) the action (N,) really
        sent, where the bench's safety limits cut the one it asked for; False for one that does not
        read it."""
        if self._sent is None:
            return False
        self.carry = self._sent(self.params, self.carry, np.asarray(action, np.float32))
        return True


def load_controller(
    spec: str,
    mapping: dict,
    env_options: dict,
    hyper: dict,
    seed: int,
    trim_hyper: dict | None = None,
):
    """(Agent, env_config, action scale (wl per unit), window (wl)) for ``spgd``, ``physics`` or a
    saved folder on the bench of ``mapping``; with ``trim_hyper`` (``TrimConfig`` overrides, ``{}``:
    the default), wrapped in the trim (``agents.controllers.trim``). A controller that reads length
    readouts the mapping lacks fails (``MappingError``)."""
    stages = len(mapping["lines"])
    if spec in ("spgd", "physics"):
        env_config = {"stages": stages, **env_options}
        module = base.algo_module(spec)
        config = base.ALGOS[spec].config.from_hyper(hyper)
        policy, params = module.make_policy(env_config, config), None
        algo = spec
    else:
        if hyper:
            raise ValueError(
                "--set applies to spgd and physics only; a saved policy keeps its own settings"
            )
        result = base.load(spec)
        env_config = {**result.env_spec.as_dict(), **env_options}
        policy, params = result.policy(), result.params
        algo, hyper = result.algo, result.config.to_hyper()
    if trim_hyper is not None:
        policy, params = trim.trimmed((policy, params), trim_hyper, env_config)
    env, env_params = ops_jax.make(**base.check_env_config(env_config))
    if env.num_actions != stages:
        raise ValueError(f"the controller drives {env.num_actions} lines, the bench has {stages}")
    if env.config.include_noise:
        raise ValueError(
            "controllers built with include_noise=True read the simulator's noise state, "
            "which no bench can measure"
        )
    check_lengths(spec, reads_lengths(algo, hyper), env, mapping)
    return (
        Agent(policy, params, env, seed),
        env_config,
        float(env_params.action_scale),
        float(env_params.window),
    )


def observes_lengths(env) -> bool:
    """Whether ``env``'s observation frame holds the length readouts (power, 2^N - 1 scope samples,
    then N lengths; frames-only observations stop after the samples)."""
    return env.layout.lengths


def reads_lengths(algo: str, hyper: dict | None) -> bool:
    """Whether a controller of ``algo`` with settings ``hyper`` uses the length readouts: SPGD
    never, the physics-informed controller with ``use_lengths`` (or ``lengths_only``), a learned
    policy always (every input of its networks)."""
    if algo == "spgd":
        return False
    if algo == "physics":
        config = base.ALGOS["physics"].config.from_hyper(hyper or {})
        return bool(config.use_lengths or config.lengths_only)
    return True


def check_lengths(controller: str, reads: bool, env, mapping: dict) -> None:
    """A controller that uses length readouts on a bench that lacks some, or that wraps its lines (a
    readout jumps by the period), fails here, naming the entries."""
    if reads and observes_lengths(env) and mapping["safety"]["wrap_wl"] is not None:
        raise MappingError(
            f"the controller {controller} reads the length readouts, which jump by a period when "
            "a line wraps (safety.wrap_wl, --wrap); run it without wrapping, or run a controller "
            "that does not read them (spgd, physics with use_lengths=False, a policy trained "
            "without them)"
        )
    missing = missing_lengths(mapping)
    if reads and observes_lengths(env) and missing:
        raise MappingError(
            f"the controller {controller} reads the length readouts and the mapping lacks "
            f"{', '.join(missing)}; map them, or run a controller that does not read them (spgd, "
            f"physics with use_lengths=False, a policy trained without them)"
        )
