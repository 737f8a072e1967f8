"""The learners' tests' yardstick: a policy that does nothing, evaluated beside a trained one."""

import jax.numpy as jnp

import agents
from agents.api import Policy


def learned_and_idle(result, env_config: dict, episodes: int, seed: int = 1) -> tuple[dict, float]:
    """(the evaluation summary of ``result`` on ``env_config``, the final P/Pmax there of zero
    actions)."""
    n = env_config["stages"]
    zero = Policy(
        lambda key, obs: (), lambda p, c, obs, key, probe: (jnp.zeros((obs.shape[0], n)), c)
    )
    baseline = agents.evaluate(zero, env_config, episodes=episodes, seed=seed).summary["final_mean"]
    return agents.evaluate(result, env_config, episodes=episodes, seed=seed).summary, baseline
