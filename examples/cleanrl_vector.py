"""A CleanRL-style single-file training loop over ``gymnasium.vector`` on ops-jax, NumPy only.

The structure of CleanRL's on-policy scripts (``ppo_continuous_action.py``): a vector env with
``RecordEpisodeStatistics``, fixed-size rollout storage (num_steps, num_envs), ``next_obs`` /
``next_done`` bookkeeping, GAE, an update per iteration, episodic returns read from ``infos``. The
agent is a linear Gaussian policy with a linear value baseline, trained by a plain policy
gradient, so that the loop runs without torch; swap in a torch agent to get CleanRL's PPO.

    python examples/cleanrl_vector.py [--mode vector_entry_point|sync|async] [--num-envs N]
                                      [--iterations 30] [--num-steps 100] [--seed 0]

``--num-envs`` defaults to 64 instances in one process for "vector_entry_point" and "sync", and to
the number of CPU cores for "async": async runs one Python process per instance, each importing JAX
and compiling its own step, so more processes than cores only compete for the same cores.

Both autoreset conventions are handled: "vector_entry_point" resets in the same step (the returned
observation already starts the next episode); "sync" / "async" reset on the next step, whose
transition (reward 0, action ignored) is left out of the update.
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers.vector import RecordEpisodeStatistics

import ops_jax  # noqa: F401  (registers "ops_jax/OPS-v0")

ENV_KWARGS = dict(stages=3, mode="easy", model="phasor", max_steps=50)


def make_envs(mode: str, num_envs: int, **env_kwargs):
    """``gymnasium.make_vec`` in ``mode`` ("vector_entry_point", "sync" or "async"), with episode
    statistics."""
    vector_kwargs = {"context": "forkserver"} if mode == "async" else {}
    envs = gymnasium.make_vec(
        "ops_jax/OPS-v0",
        num_envs=num_envs,
        vectorization_mode=mode,
        vector_kwargs=vector_kwargs,
        **{**ENV_KWARGS, **env_kwargs},
    )
    return RecordEpisodeStatistics(envs)


class LinearGaussianAgent:
    """Action mean W obs + b (clipped to [-1, 1] by the caller), std exp(log_std); value v . [obs,
    1]."""

    def __init__(self, obs_dim: int, act_dim: int, rng: np.random.Generator):
        self.w = 0.01 * rng.standard_normal((act_dim, obs_dim))
        self.b = np.zeros(act_dim)
        self.log_std = np.full(act_dim, -0.5)
        self.v = np.zeros(obs_dim + 1)

    def act(self, obs, rng):
        mean = obs @ self.w.T + self.b
        return mean + np.exp(self.log_std) * rng.standard_normal(mean.shape)

    def value(self, obs):
        return obs @ self.v[:-1] + self.v[-1]

    def update(self, obs, actions, advantages, returns, lr: float):
        """One policy-gradient step on mean(A log pi(a|s)); the value baseline refit by ridge
        regression."""
        std = np.exp(self.log_std)
        z = (actions - (obs @ self.w.T + self.b)) / std  # (T, A)
        a = advantages[:, None]
        self.w += lr * (a * z / std).T @ obs / len(obs)
        self.b += lr * (a * z / std).mean(0)
        self.log_std += lr * (a * (z**2 - 1)).mean(0)
        x = np.concatenate([obs, np.ones((len(obs), 1))], axis=1)
        self.v = np.linalg.solve(x.T @ x + 1e-3 * np.eye(x.shape[1]), x.T @ returns)


def gae(rewards, values, dones, next_value, next_done, gamma: float, lam: float):
    """CleanRL's generalised advantage estimate over (num_steps, num_envs) storage."""
    advantages = np.zeros_like(rewards)
    last = 0.0
    for t in reversed(range(len(rewards))):
        nonterminal = 1.0 - (next_done if t == len(rewards) - 1 else dones[t + 1])
        next_v = next_value if t == len(rewards) - 1 else values[t + 1]
        delta = rewards[t] + gamma * next_v * nonterminal - values[t]
        advantages[t] = last = delta + gamma * lam * nonterminal * last
    return advantages


def train(
    mode: str = "vector_entry_point",
    num_envs: int = 64,
    iterations: int = 30,
    num_steps: int = 100,
    seed: int = 0,
    lr: float = 0.05,
    gamma: float = 0.99,
    lam: float = 0.95,
    log=print,
    **env_kwargs,
):
    """Run the loop; returns one dict per iteration (mean episodic return and final P/Pmax of the
    episodes that ended in it, env-steps/s)."""
    envs = make_envs(mode, num_envs, **env_kwargs)
    rng = np.random.default_rng(seed)
    obs_dim, act_dim = envs.single_observation_space.shape[0], envs.single_action_space.shape[0]
    agent = LinearGaussianAgent(obs_dim, act_dim, rng)
    next_step_reset = envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP

    obs = np.zeros((num_steps, num_envs, obs_dim), np.float32)
    actions = np.zeros((num_steps, num_envs, act_dim))
    rewards = np.zeros((num_steps, num_envs))
    dones = np.zeros((num_steps, num_envs))
    valid = np.ones((num_steps, num_envs), bool)
    next_obs, _ = envs.reset(seed=seed)
    next_done = np.zeros(num_envs)
    history = []
    for iteration in range(iterations):
        t0 = time.perf_counter()
        returns, finals = [], []
        for step in range(num_steps):
            obs[step], dones[step] = next_obs, next_done
            valid[step] = ~(next_step_reset & (next_done > 0))  # NEXT_STEP: this step only resets
            actions[step] = agent.act(next_obs, rng)
            next_obs, reward, terminations, truncations, infos = envs.step(
                np.clip(actions[step], -1, 1)
            )
            rewards[step] = reward
            next_done = np.logical_or(terminations, truncations).astype(float)
            if "episode" in infos:
                ended = infos["_episode"]
                returns += list(infos["episode"]["r"][ended])
                finals += list(infos["normalized_power"][ended])
        values = agent.value(obs)
        advantages = gae(rewards, values, dones, agent.value(next_obs), next_done, gamma, lam)
        ret = advantages + values
        m = valid.reshape(-1)
        adv = advantages.reshape(-1)[m]
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        agent.update(
            obs.reshape(-1, obs_dim)[m],
            actions.reshape(-1, act_dim)[m],
            adv,
            ret.reshape(-1)[m],
            lr,
        )
        row = dict(
            iteration=iteration,
            episodes=len(returns),
            episodic_return=float(np.mean(returns)) if returns else None,
            final_normalized_power=float(np.mean(finals)) if finals else None,
            env_steps_per_s=num_steps * num_envs / (time.perf_counter() - t0),
        )
        history.append(row)
        if log is not None and returns:
            log(
                f"iteration {iteration:3d}: {len(returns):4d} episodes, return "
                f"{row['episodic_return']:8.3f}, final P/Pmax "
                f"{row['final_normalized_power']:.3f}, {row['env_steps_per_s']:,.0f} env-steps/s"
            )
    envs.close()
    return history


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--mode", default="vector_entry_point", choices=["vector_entry_point", "sync", "async"]
    )
    ap.add_argument(
        "--num-envs",
        type=int,
        default=None,
        help="instances (default 64; async: one process each, default the CPU core count)",
    )
    ap.add_argument("--iterations", type=int, default=30)
    ap.add_argument("--num-steps", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    return train(
        args.mode,
        args.num_envs or default_num_envs(args.mode),
        args.iterations,
        args.num_steps,
        args.seed,
    )


def default_num_envs(mode: str) -> int:
    """64 instances in one process; for async (a process per instance) one per CPU core."""
    return (os.cpu_count() or 1) if mode == "async" else 64


if __name__ == "__main__":
    main()
