"""What brax's trainers (``agents.learners.brax.ppo``, ``agents.learners.brax.sac``) share: the Brax
adapter of a training configuration, activations, the observation spec, the deterministic inference
policy, the recorded curve and the wall-time split (simulation estimated by timing the wrapped env
alone; see ``agents.learners.brax.ppo``)."""

from __future__ import annotations

import dataclasses
import importlib
import time
from typing import Callable
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from agents import api as base
from agents.envs import check_env_spec, train_env_config
from ops_jax import EnvSpec

EVAL_FIRST_EPISODE = 10


def activation(name: str):
    import flax.linen as nn

    return {"tanh": nn.tanh, "relu": nn.relu, "swish": nn.swish, "elu": nn.elu}[name]


def make_brax_env(env_spec: EnvSpec, first_episode: int = 0):
    from ops_jax.adapters.brax import OPSBraxEnv

    return OPSBraxEnv(first_episode=first_episode, **train_env_config(env_spec).as_dict())


def obs_spec(size: int):
    from brax.training.acme import specs

    return specs.Array((size,), jnp.dtype("float32"))


def networks(env_spec: EnvSpec, factory, normalize_observations: bool):
    """(brax's networks of ``factory`` for the training environment of ``env_spec``, observation
    size)."""
    from brax.training.acme import running_statistics

    from agents.envs import built

    env, _ = built(train_env_config(env_spec))
    normalize = running_statistics.normalize if normalize_observations else (lambda x, y: x)
    net = factory(
        observation_size=env.observation_size,
        action_size=env.num_actions,
        preprocess_observations_fn=normalize,
    )
    return net, env.observation_size


def normalizer_template(size: int):
    """brax's running observation statistics of ``size`` entries, freshly initialised."""
    from brax.training.acme import running_statistics

    return running_statistics.init_state(obs_spec(size))


def trained(
    algo: str,
    train_fn,
    env_spec: EnvSpec,
    c,
    seed: int,
    progress_fn,
    num_timesteps: int,
    num_evals: int,
    **options,
) -> base.TrainResult:
    """The TrainResult of brax's ``train_fn`` (its own ``options``) with config ``c`` on the Brax
    adapter of ``env_spec``, evaluated deterministically from ``EVAL_FIRST_EPISODE``, its curve
    recorded."""
    env = make_brax_env(env_spec)
    eval_env = make_brax_env(env_spec, EVAL_FIRST_EPISODE)
    rec = Recorder(progress_fn)
    t0 = time.perf_counter()
    _, params, _ = train_fn(
        environment=env,
        eval_env=eval_env,
        num_timesteps=num_timesteps,
        episode_length=env.max_steps,
        num_envs=c.num_envs,
        seed=int(seed),
        num_evals=num_evals,
        num_eval_envs=c.num_eval_envs,
        deterministic_eval=True,
        progress_fn=rec,
        **options,
    )
    return rec.result(algo, env, env_spec, c, params, time.perf_counter() - t0, seed)


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
    ``progress_fn(step, metrics)`` (metrics normalized_power, reward, elapsed_s and brax's training
    losses, e.g. policy_loss, v_loss for PPO; actor_loss, critic_loss for SAC)."""

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
            losses = {
                k.split("/", 1)[1]: float(v)
                for k, v in metrics.items()
                if k.startswith("training/") and "loss" in k and np.ndim(v) == 0
            }
            self.progress_fn(
                row["step"],
                dict(
                    normalized_power=row["normalized_power"],
                    reward=row["reward"],
                    elapsed_s=row["wall"],
                    **losses,
                ),
            )

    def curve(self) -> dict:
        keys = ("step", "normalized_power", "reward", "wall")
        return {
            k: np.asarray([r[k] for r in self.rows], np.int64 if k == "step" else np.float64)
            for k in keys
        }

    def result(
        self, algo: str, env, env_spec: EnvSpec, c, params, total: float, seed: int
    ) -> base.TrainResult:
        """The TrainResult of a brax training call of ``total`` seconds (wall time split as
        above)."""
        curve = self.curve()
        steps = int(curve["step"][-1]) if curve["step"].size else 0
        eval_steps = len(self.rows) * c.num_eval_envs * env.max_steps
        sim = seconds_per_env_step(env, c.num_envs, seed=seed)
        return base.TrainResult(
            algo,
            env_spec,
            c,
            jax.device_get(params),
            curve,
            wall_split(total, sim, steps + eval_steps),
            int(seed),
        )


def fit_budget(algo: str, total: int, fixed: int, unit: int, num_evals: int) -> tuple[int, int]:
    """``(num_timesteps, num_evals)`` for a brax trainer that runs ``fixed`` env steps first (SAC's
    replay prefill) and then ``num_evals - 1`` epochs of a whole number of ``unit``-step training
    steps: the most env steps <= ``total`` it can run, with at most the requested evaluations. brax
    rounds ``num_timesteps`` up to whole epochs; given these numbers it runs exactly
    ``num_timesteps``. When ``total`` cannot hold one training step, one step is run and a warning
    says so."""
    units = (total - fixed) // unit
    if units < 1:
        warnings.warn(
            f"{algo}: total_steps = {total:,} holds no whole training step of {unit:,} env steps"
            f"{f' after the {fixed:,} of the replay prefill' if fixed else ''}; training "
            f"{fixed + unit:,} env steps",
            stacklevel=3,
        )
        units = 1
    epochs = min(max(num_evals - 1, 1), units)
    return fixed + epochs * (units // epochs) * unit, (epochs + 1 if num_evals > 1 else 1)


def wall_split(total: float, sim_per_step: float, env_steps: int) -> dict:
    sim = min(sim_per_step * env_steps, total)
    return {"simulation": sim, "optimisation": total - sim, "total": total}


def training_config(
    config_type, env_config: EnvSpec | dict, config, total_steps: int | None, hyper: dict
):
    """``(its EnvSpec checked, config)`` of a brax training: ``config`` (a preset name or a
    ``config_type``) with the ``hyper`` overrides and ``total_steps`` (None: the config's); brax
    made runnable on this JAX."""
    from agents.learners.brax import compat as brax_compat

    brax_compat.prepare_brax()
    c = config_type.make(config, **hyper)
    if total_steps is not None:
        c = dataclasses.replace(c, total_steps=total_steps)
    return check_env_spec(env_config), c


def policy_maker(networks_module: str, networks_of: Callable, config_type) -> Callable:
    """A brax trainer's ``make_policy(env_spec, config)``: ``make_inference_fn`` of the module
    ``networks_module`` at the networks ``networks_of(env_spec, config)``, with deterministic
    actions."""

    def make_policy(env_spec: EnvSpec, config) -> base.Policy:
        module = importlib.import_module(networks_module)
        net, _ = networks_of(env_spec, config_type.of(config))
        return deterministic_policy(module.make_inference_fn, net)

    return make_policy


def deterministic_policy(make_inference_fn, net) -> base.Policy:
    """brax's ``make_inference_fn(net)`` with deterministic actions; ignores carry and probe."""
    make = make_inference_fn(net)

    def act(params, carry, obs, key, probe):
        del probe
        actions, _ = make(params, deterministic=True)(obs, key)
        return actions, carry

    return base.Policy(lambda key, obs: (), act)
