"""SAC: ``brax.training.agents.sac.train`` on the Brax adapter (``ops_jax.adapters.brax.OPSBraxEnv``),
unchanged; this module only chooses hyperparameters, records the curve and wraps the result
(curve, wall-time split and evaluation as in ``agents.learners.brax.ppo``; shared helpers: ``agents.learners.brax.training``).

Presets of ``agents.config.SACConfig`` (``config="paper" | "fast"``; any field may be overridden):
- "paper": the paper's SB3 SAC (Table 6): 2 x 256 ReLU networks, lr 3e-4, gamma 0.99, tau 0.002,
  replay 1e4, learning starts 1000 (brax ``min_replay_size``), one env, one gradient step per env
  step, batch 256 (SB3's default), automatic entropy tuning. SB3's gSDE exploration has no brax
  counterpart (brax samples a tanh-Gaussian each step).
- "fast": tuned for wall clock on a 2-core CPU: 64 parallel envs, 16 gradient steps per batched
  env step (1 update per 4 env steps), 2 x 128 ReLU networks, batch 256, replay 2e5, observation
  normalisation, gamma 0.95, lr 1e-3, tau 0.005, 400k env steps (measured: docs/results.md).
- "budget": <= 20k env steps of the target: one env, 10 gradient steps per env step (brax's
  ``grad_updates_per_step`` is the update-to-data ratio times ``num_envs``), 2 x 64 networks,
  batch 128, gamma 0.9, learning from 500 steps (docs/learners.md).

brax's SAC masks the critic loss on time-limit steps (``truncation``), so time-outs are not
treated as terminations.
"""

from __future__ import annotations

import functools

import jax

from agents import api as base  # noqa: F401  (brax_compat: quiet brax import)
from agents.learners.brax import compat  # noqa: F401  (brax quietly; without the agents extra: stops here)
from agents.learners.brax import training as brax_training
from agents.config import SACConfig


def _network_factory(c: SACConfig):
    from brax.training.agents.sac import networks as sac_networks

    return functools.partial(
        sac_networks.make_sac_networks,
        hidden_layer_sizes=c.hidden,
        activation=brax_training.activation(c.activation),
    )


def _networks(env_config: dict, c: SACConfig):
    return brax_training.networks(env_config, _network_factory(c), c.normalize_observations)


def params_template(env_config: dict, hyper: dict):
    """brax's SAC policy params tuple (normalizer state, policy params), freshly initialised."""
    net, d = _networks(env_config, SACConfig.from_hyper(hyper))
    return (brax_training.normalizer_template(d), net.policy_network.init(jax.random.PRNGKey(0)))


# brax's inference function; deterministic actions: tanh of the Gaussian mean; carry and probe ignored
make_policy = brax_training.policy_maker("brax.training.agents.sac.networks", _networks, SACConfig)


def train(
    env_config: dict,
    *,
    seed: int = 0,
    total_steps: int | None = None,
    progress_fn=None,
    config: SACConfig | str | None = None,
    **hyper,
) -> base.TrainResult:
    """Train SAC with ``brax.training.agents.sac.train`` (arguments and progress metrics: ``agents.train``)."""
    env_config, c = brax_training.training_config(SACConfig, env_config, config, total_steps, hyper)
    from brax.training.agents.sac import train as sac_train

    if c.min_replay_size >= c.total_steps:
        raise ValueError(
            f"total_steps must exceed min_replay_size = {c.min_replay_size}, got {c.total_steps}"
        )
    prefill = -(-c.min_replay_size // c.num_envs) * c.num_envs
    num_timesteps, num_evals = brax_training.fit_budget(
        "sac", c.total_steps, prefill, c.num_envs, c.num_evals
    )
    return brax_training.trained(
        "sac",
        sac_train.train,
        env_config,
        c,
        seed,
        progress_fn,
        num_timesteps,
        num_evals,
        batch_size=c.batch_size,
        grad_updates_per_step=c.grad_updates_per_step,
        learning_rate=c.learning_rate,
        discounting=c.discounting,
        tau=c.tau,
        max_replay_size=c.max_replay_size,
        min_replay_size=c.min_replay_size,
        reward_scaling=c.reward_scaling,
        normalize_observations=c.normalize_observations,
        network_factory=_network_factory(c),
    )
