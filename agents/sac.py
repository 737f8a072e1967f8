"""SAC: ``brax.training.agents.sac.train`` on the Brax adapter (``ops_jax.brax_env.OPSBraxEnv``),
unchanged; this module only chooses hyperparameters, records the curve and wraps the result
(curve, wall-time split and evaluation as in ``agents.ppo``, whose helpers it shares).

Configurations (``hyper["config"]``; any key below may be overridden):
- "paper": the paper's SB3 SAC (Table 6): 2 x 256 ReLU networks, lr 3e-4, gamma 0.99, tau 0.002,
  replay 1e4, learning starts 1000 (brax ``min_replay_size``), one env, one gradient step per env
  step, batch 256 (SB3's default), automatic entropy tuning. SB3's gSDE exploration has no brax
  counterpart (brax samples a tanh-Gaussian each step).
- "fast": tuned for wall clock on a 2-core CPU: 64 parallel envs, 16 gradient steps per batched
  env step (1 update per 4 env steps), 2 x 128 ReLU networks, batch 256, replay 2e5, observation
  normalisation, gamma 0.95, lr 1e-3, tau 0.005, 400k env steps. Measured on 5-stage hard, seed 0,
  testing P/Pmax (50 episodes) and training wall time on a 2-core CPU, one session: 2 x 256 / batch
  256 / 200k 0.935 in 143 s (partly beside another run); 2 x 128 / batch 256 / 200k 0.930 in 64 s,
  the same with 32 gradient steps 0.926 in 116 s; 2 x 128 / batch 256 / 400k 0.974 in 132 s
  (chosen). The earlier default, 2 x 256 / batch 512 / 200k, gave 0.935 in ~500 s on a slower
  host of the same kind (not timed side by side).

brax's SAC masks the critic loss on time-limit steps (``truncation``), so time-outs are not
treated as terminations.
"""

from __future__ import annotations

import functools
import time

import jax

from agents import base, brax_compat
from agents.ppo import (
    EVAL_FIRST_EPISODE,
    Recorder,
    activation,
    make_brax_env,
    obs_spec,
    resolve,
    seconds_per_env_step,
    train_env_config,
    wall_split,
)

CONFIGS = {
    "paper": dict(
        num_envs=1, batch_size=256, grad_updates_per_step=1, learning_rate=3e-4, discounting=0.99, tau=0.002,
        max_replay_size=10_000, min_replay_size=1000, reward_scaling=1.0, normalize_observations=False,
        hidden=(256, 256), activation="relu", total_steps=300_000, num_evals=10, num_eval_envs=64,
    ),
    "fast": dict(
        num_envs=64, batch_size=256, grad_updates_per_step=16, learning_rate=1e-3, discounting=0.95, tau=0.005,
        max_replay_size=200_000, min_replay_size=8192, reward_scaling=1.0, normalize_observations=True,
        hidden=(128, 128), activation="relu", total_steps=400_000, num_evals=10, num_eval_envs=64,
    ),
}


def resolve_hyper(hyper: dict | None = None) -> dict:
    h = resolve("SAC", CONFIGS, hyper)
    if h["min_replay_size"] > h["max_replay_size"]:
        raise ValueError(f"min_replay_size must be <= max_replay_size, got {h['min_replay_size']} > "
                         f"{h['max_replay_size']}")
    return h


def _network_factory(h: dict):
    from brax.training.agents.sac import networks as sac_networks

    return functools.partial(sac_networks.make_sac_networks, hidden_layer_sizes=tuple(h["hidden"]),
                             activation=activation(h["activation"]))


def _networks(env_config: dict, h: dict):
    from brax.training.acme import running_statistics

    import ops_jax

    env, _ = ops_jax.make(**train_env_config(env_config))
    normalize = running_statistics.normalize if h["normalize_observations"] else (lambda x, y: x)
    net = _network_factory(h)(observation_size=env.observation_size, action_size=env.num_actions,
                              preprocess_observations_fn=normalize)
    return net, env.observation_size


def params_template(env_config: dict, hyper: dict):
    """brax's SAC policy params tuple (normalizer state, policy params), freshly initialised."""
    from brax.training.acme import running_statistics

    h = resolve_hyper(hyper)
    net, d = _networks(env_config, h)
    return (running_statistics.init_state(obs_spec(d)), net.policy_network.init(jax.random.PRNGKey(0)))


def make_policy(env_config: dict, hyper: dict) -> base.Policy:
    """brax's ``make_inference_fn`` with deterministic actions (tanh of the Gaussian mean);
    ignores carry and probe."""
    from brax.training.agents.sac import networks as sac_networks

    h = resolve_hyper(hyper)
    net, _ = _networks(env_config, h)
    make = sac_networks.make_inference_fn(net)

    def act(params, carry, obs, key, probe):
        del probe
        actions, _ = make(params, deterministic=True)(obs, key)
        return actions, carry

    return base.Policy(lambda key, obs: (), act)


def train(env_config: dict, *, seed: int = 0, total_steps: int | None = None, progress=None,
          **hyper) -> base.TrainResult:
    """Train SAC with ``brax.training.agents.sac.train``. ``progress(row)`` (optional) is called
    with each evaluation row (step, normalized_power, reward, wall)."""
    brax_compat.prepare_brax()
    from brax.training.agents.sac import train as sac_train

    env_config = base.check_env_config(env_config)
    h = resolve_hyper(hyper)
    if total_steps is not None:
        h["total_steps"] = int(total_steps)
    if h["min_replay_size"] >= h["total_steps"]:
        raise ValueError(f"total_steps must exceed min_replay_size = {h['min_replay_size']}, got {h['total_steps']}")
    env = make_brax_env(env_config)
    eval_env = make_brax_env(env_config, EVAL_FIRST_EPISODE)
    rec = Recorder(progress)
    t0 = time.perf_counter()
    _, params, _ = sac_train.train(
        environment=env, eval_env=eval_env, num_timesteps=h["total_steps"], episode_length=env.max_steps,
        num_envs=h["num_envs"], batch_size=h["batch_size"], grad_updates_per_step=h["grad_updates_per_step"],
        learning_rate=h["learning_rate"], discounting=h["discounting"], tau=h["tau"],
        max_replay_size=h["max_replay_size"], min_replay_size=h["min_replay_size"],
        reward_scaling=h["reward_scaling"], normalize_observations=h["normalize_observations"],
        network_factory=_network_factory(h), seed=int(seed), num_evals=h["num_evals"],
        num_eval_envs=h["num_eval_envs"], deterministic_eval=True, progress_fn=rec,
    )
    total = time.perf_counter() - t0
    curve = rec.curve()
    steps = int(curve["step"][-1]) if curve["step"].size else 0
    eval_steps = len(rec.rows) * h["num_eval_envs"] * env.max_steps
    sim = seconds_per_env_step(env, h["num_envs"], seed=seed)
    params = jax.device_get(params)
    return base.TrainResult("sac", env_config, h, params, curve, wall_split(total, sim, steps + eval_steps), int(seed))
