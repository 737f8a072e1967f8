"""PPO: ``brax.training.agents.ppo.train`` on the Brax adapter
(``ops_jax.adapters.brax.OPSBraxEnv``), unchanged; this module only chooses hyperparameters, records
the curve and wraps the result.

Presets of ``PPOConfig`` (below) (``config="paper" | "fast"``; any field may be overridden):
- "paper": the paper's SB3 PPO (Table 5): 2 x 256 tanh networks, lr 3e-4, gamma 0.99, GAE lambda
  0.95, clip 0.2, entropy 0.001, vf coefficient 0.5, max grad norm 0.5, 10 epochs over a 512-step
  rollout in minibatches of 64. In brax terms: 8 envs x unroll 64 (= 512 steps per update),
  batch_size 1 x num_minibatches 8 (minibatches of one 64-step segment = 64 transitions),
  num_updates_per_batch 10. (SB3 ran one env and shuffled single transitions; brax shuffles
  segments, whose GAE bootstraps at the segment end.)
- "fast": for wall clock on a 2-core CPU: 256 parallel envs, unroll 16, 2 x 128 tanh networks,
  32 minibatches of 32 x 16 transitions and 8 epochs per 16,384 env steps (256 gradient steps),
  8M env steps, observation normalisation, time-outs bootstrapped, lr 3e-4, gamma 0.99, no entropy
  bonus, initial policy std 0.3 (brax's default 1.0 on a tanh-Gaussian makes the first policies
  random walks of +-1 action units that wipe out the start). Measured results: docs/results.md.

Both train on ``model="phasor"`` (unless env_config names a model) with ``episode_length =
max_steps``; brax evaluates (``num_evals`` times, ``num_eval_envs`` episodes, deterministic
actions) on the adapter with ``first_episode = 10`` (hard mode's drift fully on, as
``agents.evaluate``). Curve: 'step' (env steps), 'normalized_power' (evaluation's final P/Pmax,
mean over episodes), 'reward' (evaluation episode return), 'wall' (s since training started).

Wall time: 'total' is the whole brax ``train`` call (compilation included); 'simulation' is
estimated as (training + evaluation env steps) x (seconds per env step), the latter measured by
timing a jitted scan of the wrapped batched env alone (uniform random actions, same num_envs,
after compilation); 'optimisation' = total - simulation (network inference while acting,
gradient steps, compilation, host overhead).
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
class PPOConfig(AlgoConfig):
    """PPO (``agents.learners.brax.ppo``, brax's trainer): presets "paper" (the paper's Table 5) and
    "fast"."""

    NAME: ClassVar[str] = "PPO"
    PRESETS: ClassVar[dict] = {
        "paper": dict(
            num_envs=8,
            unroll_length=64,
            batch_size=1,
            num_minibatches=8,
            num_updates_per_batch=10,
            learning_rate=3e-4,
            entropy_cost=1e-3,
            discounting=0.99,
            gae_lambda=0.95,
            clipping_epsilon=0.2,
            vf_loss_coefficient=0.5,
            max_grad_norm=0.5,
            reward_scaling=1.0,
            normalize_observations=False,
            hidden=(256, 256),
            activation="tanh",
            init_noise_std=1.0,
            bootstrap_on_timeout=True,
            total_steps=300_000,
            num_evals=10,
            num_eval_envs=64,
        ),
        "fast": dict(
            num_envs=256,
            unroll_length=16,
            batch_size=32,
            num_minibatches=32,
            num_updates_per_batch=8,
            learning_rate=3e-4,
            entropy_cost=0.0,
            discounting=0.99,
            gae_lambda=0.95,
            clipping_epsilon=0.2,
            vf_loss_coefficient=0.5,
            max_grad_norm=0.5,
            reward_scaling=1.0,
            normalize_observations=True,
            hidden=(128, 128),
            activation="tanh",
            init_noise_std=0.3,
            bootstrap_on_timeout=True,
            total_steps=8_000_000,
            num_evals=10,
            num_eval_envs=64,
        ),
    }

    config: str = field(choice("paper", "fast"))
    num_envs: int = field(COUNT)
    unroll_length: int = field(COUNT)
    batch_size: int = field(COUNT)
    num_minibatches: int = field(COUNT)
    num_updates_per_batch: int = field(COUNT)
    learning_rate: float = field(POSITIVE)
    entropy_cost: float = field(NONNEG)
    discounting: float = field(UNIT)
    gae_lambda: float = field(UNIT)
    clipping_epsilon: float = field(NONNEG)
    vf_loss_coefficient: float = field(NONNEG)
    max_grad_norm: float = field(NONNEG)
    reward_scaling: float = field(NONNEG)
    normalize_observations: bool = field(flag)
    hidden: tuple = field(widths)
    activation: str = field(ACTIVATION)
    init_noise_std: float = field(POSITIVE)
    bootstrap_on_timeout: bool = field(flag)
    total_steps: int = field(COUNT0)
    num_evals: int = field(COUNT)
    num_eval_envs: int = field(COUNT)

    def budget_layout(self) -> tuple[int, int, str]:
        """No warm-up; updates of ``batch_size * unroll_length * num_minibatches`` env steps."""
        return 0, self.batch_size * self.unroll_length * self.num_minibatches, ""

    def trained_units(self, units: int) -> int:
        """brax's whole epochs."""
        return budgets.brax_units(self.num_evals, units)

    def updates_per_step(self) -> float:
        """Per training step brax collects ``batch_size * num_minibatches * unroll_length`` env
        steps and takes ``num_updates_per_batch * num_minibatches`` gradient steps."""
        return self.num_updates_per_batch / (self.batch_size * self.unroll_length)

    def check(self):
        if (self.batch_size * self.num_minibatches) % self.num_envs:
            raise ValueError(
                f"batch_size * num_minibatches must be divisible by num_envs, got "
                f"{self.batch_size} * {self.num_minibatches} and {self.num_envs}"
            )


ALGO = Algo("ppo", __name__, PPOConfig, "PPO", needs="agents.learners.brax.compat")


def _network_factory(c: PPOConfig):
    from brax.training.agents.ppo import networks as ppo_networks

    return functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=c.hidden,
        value_hidden_layer_sizes=c.hidden,
        activation=brax_training.activation(c.activation),
        init_noise_std=c.init_noise_std,
    )


def _networks(env_spec: EnvSpec, c: PPOConfig):
    return brax_training.networks(env_spec, _network_factory(c), c.normalize_observations)


def params_template(env_spec: EnvSpec, config: PPOConfig):
    """brax's PPO params tuple (normalizer state, policy params, value params), freshly
    initialised."""
    net, d = _networks(env_spec, PPOConfig.of(config))
    key = jax.random.PRNGKey(0)
    return (
        brax_training.normalizer_template(d),
        net.policy_network.init(key),
        net.value_network.init(key),
    )


# brax's inference function; deterministic actions: the mode of the tanh-Gaussian; carry and probe
# ignored
make_policy = brax_training.policy_maker("brax.training.agents.ppo.networks", _networks, PPOConfig)


def train(
    env_config: EnvSpec | dict,
    *,
    seed: int = 0,
    total_steps: int | None = None,
    progress_fn=None,
    config: PPOConfig | str | None = None,
    **hyper,
) -> base.TrainResult:
    """Train PPO with ``brax.training.agents.ppo.train`` (arguments and progress metrics:
    ``agents.train``)."""
    env_spec, c = brax_training.training_config(PPOConfig, env_config, config, total_steps, hyper)
    from brax.training.agents.ppo import train as ppo_train

    per_iteration = c.batch_size * c.unroll_length * c.num_minibatches  # env steps
    num_timesteps, num_evals = brax_training.fit_budget(
        "ppo", c.total_steps, 0, per_iteration, c.num_evals
    )
    return brax_training.trained(
        "ppo",
        ppo_train.train,
        env_spec,
        c,
        seed,
        progress_fn,
        num_timesteps,
        num_evals,
        unroll_length=c.unroll_length,
        batch_size=c.batch_size,
        num_minibatches=c.num_minibatches,
        num_updates_per_batch=c.num_updates_per_batch,
        learning_rate=c.learning_rate,
        entropy_cost=c.entropy_cost,
        discounting=c.discounting,
        gae_lambda=c.gae_lambda,
        clipping_epsilon=c.clipping_epsilon,
        vf_loss_coefficient=c.vf_loss_coefficient,
        max_grad_norm=c.max_grad_norm,
        reward_scaling=c.reward_scaling,
        normalize_observations=c.normalize_observations,
        bootstrap_on_timeout=c.bootstrap_on_timeout,
        network_factory=_network_factory(c),
        use_pmap_on_reset=False,
    )
