"""An off-policy learner of ``agents.learners.offpolicy.driver`` as one record (``Learner``): its
name, config type, build, networks and greedy action, and what they give: the stored policy, its
params template and the environment it trains on, each of an ``ops_jax.EnvSpec`` and its config (a
``agents.learners.offpolicy.replay.ReplayConfig``)."""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from agents import api as base
from agents.learners.offpolicy import observer, replay
from agents.envs import built, train_env_config
from ops_jax import EnvSpec


class Learner(NamedTuple):
    """An off-policy learner: ``build(env, config) -> replay.Loop``, its
    ``networks(config, num_actions) -> (actor, critic)`` (flax modules) and
    ``greedy(actor, params, obs) -> action`` (its deterministic action at standardised
    observations); ``config``: its ``config_type``, a ``replay.ReplayConfig``."""

    name: str
    config_type: type
    build: Callable
    networks: Callable
    greedy: Callable

    def _actor(self, env_spec: EnvSpec, config):
        """(the actor module, its observation size, the observer or None)."""
        env, _ = built(train_env_config(env_spec, config.train_reward))
        seen = self._observer(env_spec, config)
        return (
            self.networks(config, env.num_actions)[0],
            env.observation_size + (seen.size if seen else 0),
            seen,
        )

    def params_template(self, env_spec: EnvSpec, config):
        """Pytree with the structure of the policy params: {"actor": flax params, "obs_norm": {mean,
        std}}."""
        actor, d, _ = self._actor(env_spec, self.config_type.of(config))
        return {
            "actor": actor.init(jax.random.key(0), jnp.zeros((1, d))),
            "obs_norm": replay.identity_norm(d),
        }

    def make_policy(self, env_spec: EnvSpec, config) -> base.Policy:
        """The deterministic actor at observations standardised by the params' ``obs_norm``; ignores
        key, carry and probe. With an observer (``agents.learners.offpolicy.observer``), the
        observer's estimate is appended first (its carry is the policy's)."""
        actor, _, seen = self._actor(env_spec, self.config_type.of(config))

        def greedy(params, obs):
            return self.greedy(actor, params["actor"], replay.normalise(params["obs_norm"], obs))

        if seen is not None:
            return observer.policy(seen, greedy)

        def act(params, carry, obs, key, probe):
            del key, probe
            return greedy(params, obs), carry

        return base.Policy(lambda key, obs: (), act)

    @staticmethod
    def _observer(env_spec: EnvSpec, config):
        """The observer of ``config`` on the learner's training environment, or None."""
        return observer.of_learner(train_env_config(env_spec, config.train_reward), config)

    def training_env(self, env, env_spec: EnvSpec, config):
        """The batched env the learner trains on: ``env`` (of
        ``train_env_config(env_spec, config.train_reward)``), wrapped by
        ``agents.learners.offpolicy.observer.Observed`` with an observer."""
        seen = self._observer(env_spec, config)
        return env if seen is None else observer.Observed(env, seen)
