"""SAC: ``brax.training.agents.sac.train`` on the Brax adapter
(``ops_jax.adapters.brax.OPSBraxEnv``), unchanged; this module only chooses hyperparameters, records
the curve and wraps the result (curve, wall-time split and evaluation as in
``agents.learners.brax.ppo``; shared helpers: ``agents.learners.brax.training``).

Presets of ``SACConfig`` (below) (``config="paper" | "fast"``; any field may be overridden):
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

import dataclasses
import functools
from typing import ClassVar

import jax

from agents import api as base  # noqa: F401  (brax_compat: quiet brax import)
from agents.learners.brax import training as brax_training
from agents.learners import budgets
from agents.config import ACTIVATION, COUNT, COUNT0, NONNEG, POSITIVE, UNIT, AlgoConfig
from agents.config import choice, field, flag, widths
from agents.registry import Algo
from ops_jax import EnvSpec


@dataclasses.dataclass(frozen=True)
class SACConfig(AlgoConfig):
    """SAC (``agents.learners.brax.sac``, brax's trainer): presets "paper" (the paper's Table 6),
    "fast" and "budget" (<= 20k env steps). Its update-to-data ratio is
    ``grad_updates_per_step / num_envs`` (brax's)."""

    NAME: ClassVar[str] = "SAC"
    PRESETS: ClassVar[dict] = {
        "paper": dict(
            num_envs=1,
            batch_size=256,
            grad_updates_per_step=1,
            learning_rate=3e-4,
            discounting=0.99,
            tau=0.002,
            max_replay_size=10_000,
            min_replay_size=1000,
            reward_scaling=1.0,
            normalize_observations=False,
            hidden=(256, 256),
            activation="relu",
            total_steps=300_000,
            num_evals=10,
            num_eval_envs=64,
        ),
        "fast": dict(
            num_envs=64,
            batch_size=256,
            grad_updates_per_step=16,
            learning_rate=1e-3,
            discounting=0.95,
            tau=0.005,
            max_replay_size=200_000,
            min_replay_size=8192,
            reward_scaling=1.0,
            normalize_observations=True,
            hidden=(128, 128),
            activation="relu",
            total_steps=400_000,
            num_evals=10,
            num_eval_envs=64,
        ),
        "budget": dict(
            num_envs=1,
            batch_size=128,
            grad_updates_per_step=10,
            learning_rate=1e-3,
            discounting=0.9,
            tau=0.005,
            max_replay_size=20_000,
            min_replay_size=500,
            reward_scaling=1.0,
            normalize_observations=True,
            hidden=(64, 64),
            activation="relu",
            total_steps=20_000,
            num_evals=10,
            num_eval_envs=16,
        ),
    }

    config: str = field(choice("paper", "fast", "budget"))
    num_envs: int = field(COUNT)
    batch_size: int = field(COUNT)
    grad_updates_per_step: int = field(
        COUNT
    )  # per batched env step: the update-to-data ratio x num_envs
    learning_rate: float = field(POSITIVE)
    discounting: float = field(UNIT)
    tau: float = field(UNIT)
    max_replay_size: int = field(COUNT)
    min_replay_size: int = field(COUNT0)
    reward_scaling: float = field(NONNEG)
    normalize_observations: bool = field(flag)
    hidden: tuple = field(widths)
    activation: str = field(ACTIVATION)
    total_steps: int = field(COUNT0)
    num_evals: int = field(COUNT)
    num_eval_envs: int = field(COUNT)

    def budget_layout(self) -> tuple[int, int, str]:
        """The replay prefill, then steps of ``num_envs`` env steps
        (``agents.learners.budgets``)."""
        why = f"the replay prefill (min_replay_size = {self.min_replay_size:,})"
        return budgets.ceil_to(self.min_replay_size, self.num_envs), self.num_envs, why

    def trained_units(self, units: int) -> int:
        """brax's whole epochs."""
        return budgets.brax_units(self.num_evals, units)

    def updates_per_step(self) -> float:
        return self.grad_updates_per_step / self.num_envs

    def check(self):
        if self.min_replay_size > self.max_replay_size:
            raise ValueError(
                f"min_replay_size must be <= max_replay_size, got {self.min_replay_size} > "
                f"{self.max_replay_size}"
            )


ALGO = Algo("sac", __name__, SACConfig, "SAC", needs="agents.learners.brax.compat")


def _network_factory(c: SACConfig):
    from brax.training.agents.sac import networks as sac_networks

    return functools.partial(
        sac_networks.make_sac_networks,
        hidden_layer_sizes=c.hidden,
        activation=brax_training.activation(c.activation),
    )


def _networks(env_spec: EnvSpec, c: SACConfig):
    return brax_training.networks(env_spec, _network_factory(c), c.normalize_observations)


def params_template(env_spec: EnvSpec, config: SACConfig):
    """brax's SAC policy params tuple (normalizer state, policy params), freshly initialised."""
    net, d = _networks(env_spec, SACConfig.of(config))
    return (brax_training.normalizer_template(d), net.policy_network.init(jax.random.PRNGKey(0)))


# brax's inference function; deterministic actions: tanh of the Gaussian mean; carry and probe
# ignored
make_policy = brax_training.policy_maker("brax.training.agents.sac.networks", _networks, SACConfig)


def train(
    env_config: EnvSpec | dict,
    *,
    seed: int = 0,
    total_steps: int | None = None,
    progress_fn=None,
    config: SACConfig | str | None = None,
    **hyper,
) -> base.TrainResult:
    """Train SAC with ``brax.training.agents.sac.train`` (arguments and progress metrics:
    ``agents.train``)."""
    env_spec, c = brax_training.training_config(SACConfig, env_config, config, total_steps, hyper)
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
        env_spec,
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
