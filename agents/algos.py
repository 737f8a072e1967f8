"""The algorithms of ``agents``, registered in ``agents.registry``: their modules are imported on first use
(``Algo.load``)."""

from agents.config import DroQConfig, PhysicsConfig, PPOConfig, SACConfig, SPGDConfig, TD3Config
from agents.registry import Algo, SweepPresets, register

# Sweep cost constants fitted to the default preset's measured run (docs/results.md): medians of its
# table-1 cells (PPO 94.7 s for 1,916,928 env steps, SAC 69.3 s for 99,968, TD3 38.5 s per seed for
# 59,776, physics-informed 5.5 s), its stage scan (physics-informed at N = 6 and 7: 14-107 s) and its
# evaluations (physics-informed 5.4-6.1 s, the others 0.1-0.2 s of rollout).
register(Algo("spgd", "agents.spgd", SPGDConfig, "SPGD",
              sweep=SweepPresets(budgets={"quick": 0, "default": 0, "paper": 0}, fixed_s=2.0)))
register(Algo("physics", "agents.physics_informed", PhysicsConfig, "Physics",
              sweep=SweepPresets(budgets={"quick": 0, "default": 0, "paper": 0}, fixed_s=6.0, stage_growth=3.5, eval_s=6.0,
                                 hyper={"quick": {"starts": 4, "iters": 4},
                                        "default": {"starts": 8, "iters": 6}})))  # half the fit cost of 16 x 8
register(Algo("ppo", "agents.ppo", PPOConfig, "PPO",
              sweep=SweepPresets(budgets={"quick": 32_768, "default": 2_000_000, "paper": 200_000},
                                 hyper={"quick": {"num_evals": 2, "num_eval_envs": 16, "hidden": [64, 64],
                                                  "num_updates_per_batch": 2}},
                                 s_per_step=4.7e-5)))
register(Algo("sac", "agents.sac", SACConfig, "SAC",
              sweep=SweepPresets(budgets={"quick": 3_000, "default": 100_000, "paper": 200_000},
                                 hyper={"quick": {"min_replay_size": 1024, "num_evals": 2, "num_eval_envs": 16,
                                                  "hidden": [64, 64], "grad_updates_per_step": 4, "batch_size": 256},
                                        "default": {"min_replay_size": 2048}},
                                 # randomised training is far from done at 100k (docs/imperfections.md)
                                 reality_budgets={"default": 300_000},
                                 s_per_step=6.4e-4)))
register(Algo("td3", "agents.td3", TD3Config, "TD3", vmaps_seeds=True,
              sweep=SweepPresets(budgets={"quick": 3_000, "default": 60_000, "paper": 250_000},
                                 hyper={"quick": {"learning_starts": 1024, "eval_every": 1000, "eval_episodes": 4},
                                        "default": {"eval_every": 5000}},
                                 fixed_s=3.0, s_per_step=5.9e-4)))
register(Algo("droq", "agents.droq", DroQConfig, "DroQ", vmaps_seeds=True))  # in the sweep's budget section only
