"""PPO: ``brax.training.agents.ppo.train`` on the Brax adapter (``ops_jax.brax_env.OPSBraxEnv``),
unchanged; this module only chooses hyperparameters, records the curve and wraps the result.

Presets of ``agents.config.PPOConfig`` (``config="paper" | "fast"``; any field may be overridden):
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
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from agents import base, brax_compat
from agents.config import PPOConfig

EVAL_FIRST_EPISODE = 10


# -- shared with agents.sac ----------------------------------------------------------------------

def train_env_config(env_config: dict) -> dict:
    """The env_config used for training: ``model="phasor"`` unless one is given."""
    return {"model": "phasor", **env_config}


def activation(name: str):
    import flax.linen as nn

    return {"tanh": nn.tanh, "relu": nn.relu, "swish": nn.swish, "elu": nn.elu}[name]


def make_brax_env(env_config: dict, first_episode: int = 0):
    from ops_jax.brax_env import OPSBraxEnv

    return OPSBraxEnv(first_episode=first_episode, **train_env_config(env_config))


def obs_spec(size: int):
    from brax.training.acme import specs

    return specs.Array((size,), jnp.dtype("float32"))


_SIM_SECONDS: dict = {}


def seconds_per_env_step(env, num_envs: int, steps: int = 64, seed: int = 0) -> float:
    """Wall seconds per single-instance env step of brax's training-wrapped ``env`` (``num_envs``
    instances, a jitted scan of ``steps`` batched steps with uniform random actions, timed after
    compilation). Measured once per process and (static configuration, ``num_envs``, ``steps``):
    the step program is the same for every mode (its parameters are state) and seed, so later
    trainings reuse the number instead of compiling a mode's reset and timing again. Noisy on a
    shared machine."""
    memo = (env.ops_env.config, int(num_envs), int(steps))
    if memo not in _SIM_SECONDS:
        _SIM_SECONDS[memo] = _time_env_steps(env, num_envs, steps, seed)
    return _SIM_SECONDS[memo]


def _time_env_steps(env, num_envs: int, steps: int, seed: int) -> float:
    from brax.envs.wrappers import training as wrappers

    wrapped = wrappers.wrap(env, episode_length=env.max_steps)
    n = env.action_size

    @jax.jit
    def run(state, key):
        def body(s, k):
            a = jax.random.uniform(k, (num_envs, n), minval=-1.0, maxval=1.0)
            s = wrapped.step(s, a)
            return s, s.reward.mean()

        return jax.lax.scan(body, state, jax.random.split(key, steps))[1]

    key = jax.random.PRNGKey(seed)
    state = jax.jit(wrapped.reset)(jax.random.split(key, num_envs))
    jax.block_until_ready(run(state, key))
    t0 = time.perf_counter()
    jax.block_until_ready(run(state, jax.random.fold_in(key, 1)))
    return max(time.perf_counter() - t0, 1e-9) / (steps * num_envs)


class Recorder:
    """brax ``progress_fn``: collects the evaluation curve and passes each evaluation on to
    ``progress_fn(step, metrics)`` (metrics normalized_power, reward, elapsed_s)."""

    def __init__(self, progress_fn=None):
        self.t0 = time.perf_counter()
        self.rows = []
        self.progress_fn = progress_fn

    def __call__(self, step, metrics):
        row = dict(
            step=int(step),
            normalized_power=float(metrics.get("eval/episode_final_normalized_power", np.nan)),
            reward=float(metrics.get("eval/episode_reward", np.nan)),
            wall=time.perf_counter() - self.t0,
        )
        self.rows.append(row)
        if self.progress_fn is not None:
            self.progress_fn(row["step"], dict(normalized_power=row["normalized_power"], reward=row["reward"],
                                               elapsed_s=row["wall"]))

    def curve(self) -> dict:
        keys = ("step", "normalized_power", "reward", "wall")
        return {k: np.asarray([r[k] for r in self.rows], np.int64 if k == "step" else np.float64) for k in keys}

    def result(self, algo: str, env, env_config: dict, c, params, total: float, seed: int) -> base.TrainResult:
        """The TrainResult of a brax training call of ``total`` seconds (wall time split as above)."""
        curve = self.curve()
        steps = int(curve["step"][-1]) if curve["step"].size else 0
        eval_steps = len(self.rows) * c.num_eval_envs * env.max_steps
        sim = seconds_per_env_step(env, c.num_envs, seed=seed)
        return base.TrainResult(algo, env_config, c.to_hyper(), jax.device_get(params), curve,
                                wall_split(total, sim, steps + eval_steps), int(seed))


def fit_budget(algo: str, total: int, fixed: int, unit: int, num_evals: int) -> tuple[int, int]:
    """``(num_timesteps, num_evals)`` for a brax trainer that runs ``fixed`` env steps first (SAC's
    replay prefill) and then ``num_evals - 1`` epochs of a whole number of ``unit``-step training steps:
    the most env steps <= ``total`` it can run, with at most the requested evaluations. brax rounds
    ``num_timesteps`` up to whole epochs; given these numbers it runs exactly ``num_timesteps``. When
    ``total`` cannot hold one training step, one step is run and a warning says so."""
    units = (total - fixed) // unit
    if units < 1:
        warnings.warn(f"{algo}: total_steps = {total:,} holds no whole training step of {unit:,} env steps"
                      f"{f' after the {fixed:,} of the replay prefill' if fixed else ''}; training "
                      f"{fixed + unit:,} env steps", stacklevel=3)
        units = 1
    epochs = min(max(num_evals - 1, 1), units)
    return fixed + epochs * (units // epochs) * unit, (epochs + 1 if num_evals > 1 else 1)


def wall_split(total: float, sim_per_step: float, env_steps: int) -> dict:
    sim = min(sim_per_step * env_steps, total)
    return {"simulation": sim, "optimisation": total - sim, "total": total}


# -- PPO -----------------------------------------------------------------------------------------

def _network_factory(c: PPOConfig):
    from brax.training.agents.ppo import networks as ppo_networks

    return functools.partial(ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=c.hidden,
                             value_hidden_layer_sizes=c.hidden, activation=activation(c.activation),
                             init_noise_std=c.init_noise_std)


def _networks(env_config: dict, c: PPOConfig):
    from brax.training.acme import running_statistics

    import ops_jax

    env, _ = ops_jax.make(**train_env_config(env_config))
    normalize = running_statistics.normalize if c.normalize_observations else (lambda x, y: x)
    net = _network_factory(c)(env.observation_size, env.num_actions, preprocess_observations_fn=normalize)
    return net, env.observation_size


def params_template(env_config: dict, hyper: dict):
    """brax's PPO params tuple (normalizer state, policy params, value params), freshly initialised."""
    from brax.training.acme import running_statistics

    net, d = _networks(env_config, PPOConfig.from_hyper(hyper))
    key = jax.random.PRNGKey(0)
    return (running_statistics.init_state(obs_spec(d)), net.policy_network.init(key), net.value_network.init(key))


def make_policy(env_config: dict, hyper: dict) -> base.Policy:
    """brax's ``make_inference_fn`` with deterministic actions (the mode of the tanh-Gaussian);
    ignores carry and probe."""
    from brax.training.agents.ppo import networks as ppo_networks

    net, _ = _networks(env_config, PPOConfig.from_hyper(hyper))
    make = ppo_networks.make_inference_fn(net)

    def act(params, carry, obs, key, probe):
        del probe
        actions, _ = make(params, deterministic=True)(obs, key)
        return actions, carry

    return base.Policy(lambda key, obs: (), act)


def train(env_config: dict, *, seed: int = 0, total_steps: int | None = None, progress_fn=None,
          config: PPOConfig | str | None = None, **hyper) -> base.TrainResult:
    """Train PPO with ``brax.training.agents.ppo.train``; ``config``: a preset name or a
    ``PPOConfig``, ``hyper``: overrides of its fields. ``progress_fn(step, metrics)`` (optional)
    is called after each evaluation (metrics normalized_power, reward, elapsed_s)."""
    brax_compat.prepare_brax()
    from brax.training.agents.ppo import train as ppo_train

    env_config = base.check_env_config(env_config)
    c = PPOConfig.make(config, **hyper)
    if total_steps is not None:
        c = dataclasses.replace(c, total_steps=total_steps)
    env = make_brax_env(env_config)
    eval_env = make_brax_env(env_config, EVAL_FIRST_EPISODE)
    num_timesteps, num_evals = fit_budget("ppo", c.total_steps, 0, c.batch_size * c.unroll_length * c.num_minibatches,
                                          c.num_evals)
    rec = Recorder(progress_fn)
    t0 = time.perf_counter()
    _, params, _ = ppo_train.train(
        environment=env, eval_env=eval_env, num_timesteps=num_timesteps, episode_length=env.max_steps,
        num_envs=c.num_envs, unroll_length=c.unroll_length, batch_size=c.batch_size,
        num_minibatches=c.num_minibatches, num_updates_per_batch=c.num_updates_per_batch,
        learning_rate=c.learning_rate, entropy_cost=c.entropy_cost, discounting=c.discounting,
        gae_lambda=c.gae_lambda, clipping_epsilon=c.clipping_epsilon,
        vf_loss_coefficient=c.vf_loss_coefficient, max_grad_norm=c.max_grad_norm,
        reward_scaling=c.reward_scaling, normalize_observations=c.normalize_observations,
        bootstrap_on_timeout=c.bootstrap_on_timeout, network_factory=_network_factory(c), seed=int(seed),
        num_evals=num_evals, num_eval_envs=c.num_eval_envs, deterministic_eval=True, progress_fn=rec,
        use_pmap_on_reset=False,
    )
    return rec.result("ppo", env, env_config, c, params, time.perf_counter() - t0, seed)
