"""The algorithms of ``agents``, registered in ``agents.registry``: their modules are imported on first use
(``Algo.load``)."""

from agents.config import DroQConfig, PhysicsConfig, PPOConfig, SACConfig, SPGDConfig, TD3Config
from agents.registry import Algo, CostModel, SweepPresets, register

# Cost models fitted to two measured runs on an idle 2-core host: the sweep's default preset (docs/results.md:
# medians of its table-1 cells, PPO 94.7 s for 1,916,928 env steps, SAC 69.3 s for 99,968, TD3 38.5 s per seed
# for 59,776, physics-informed 5.5 s; its stage scan, physics-informed at N = 6 and 7: 14-107 s; its evaluations,
# physics-informed 5.4-6.1 s, the others 0.1-0.2 s of rollout) and its lab-budget section of 2026-11-26 (one core
# per cell: DroQ 114-161 s, adapt cells 83-133 s, SPGD 4-8 s; TD3 58-102 s, SAC 240-384 s for five runs, PPO
# 20-153 s). Per env step and per gradient step together: the two runs' configs differ in their
# update-to-data ratio (SAC 0.25 and 10, TD3 0.125 and 10, PPO 0.016 and 0.08 gradient steps per env step).
register(
    Algo(
        "spgd",
        "agents.controllers.spgd",
        SPGDConfig,
        "SPGD",
        cost=CostModel(fixed_s=3.0),
        sweep=SweepPresets(
            budgets={"quick": 0, "default": 0, "paper": 0},
            lab_budget={
                "quick": {},
                "default": {},
                "full": {},
                "frames": {},
                "frames-fit": {},
                "frames-residual": {},
                "frames-residual-bounded": {},
                "frames-residual-history": {},
                "frames-residual-hold": {},
            },
        ),
    )
)
register(
    Algo(
        "physics",
        "agents.controllers.physics_informed",
        PhysicsConfig,
        "Physics",
        cost=CostModel(fixed_s=6.0, stage_growth=3.5, eval_s=6.0),
        sweep=SweepPresets(
            budgets={"quick": 0, "default": 0, "paper": 0},
            hyper={
                "quick": {"starts": 4, "iters": 4},
                "default": {"starts": 8, "iters": 6},
            },  # half the fit cost of 16 x 8
            lab_budget={
                "quick": {"config": "frames", "starts": 4, "iters": 4},
                "default": {},
                "frames": {"config": "frames"},
                "frames-fit": {"config": "frames"},
                "frames-residual": {"config": "frames"},
                "frames-residual-bounded": {"config": "frames"},
                "frames-residual-history": {"config": "frames", "history": 3},
                "frames-residual-hold": {"config": "frames-hold"},
                "full": {},
            },
        ),
    )
)
register(
    Algo(
        "ppo",
        "agents.learners.brax.ppo",
        PPOConfig,
        "PPO",
        cost=CostModel(s_per_step=9.9e-6, s_per_update=2.38e-3),
        sweep=SweepPresets(
            budgets={"quick": 32_768, "default": 2_000_000, "paper": 200_000},
            hyper={
                "quick": {
                    "num_evals": 2,
                    "num_eval_envs": 16,
                    "hidden": [64, 64],
                    "num_updates_per_batch": 2,
                }
            },
            # 1,000 env steps per iteration
            lab_budget={
                "full": {"config": "paper", "unroll_length": 25, "batch_size": 5, "num_evals": 2}
            },
        ),
    )
)
register(
    Algo(
        "sac",
        "agents.learners.brax.sac",
        SACConfig,
        "SAC",
        cost=CostModel(fixed_s=10.0, s_per_step=5.4e-4, s_per_update=4.0e-4),
        sweep=SweepPresets(
            budgets={"quick": 3_000, "default": 100_000, "paper": 200_000},
            hyper={
                "quick": {
                    "min_replay_size": 1024,
                    "num_evals": 2,
                    "num_eval_envs": 16,
                    "hidden": [64, 64],
                    "grad_updates_per_step": 4,
                    "batch_size": 256,
                },
                "default": {"min_replay_size": 2048},
            },
            # randomised training is far from done at 100k (docs/imperfections.md)
            reality_budgets={"default": 300_000},
            lab_budget={"full": {"config": "budget"}},
        ),
    )
)
register(
    Algo(
        "td3",
        "agents.learners.offpolicy.td3",
        TD3Config,
        "TD3",
        vmaps_seeds=True,
        off_policy=True,
        cost=CostModel(fixed_s=3.0, s_per_step=5.7e-4, s_per_update=1.43e-4),
        sweep=SweepPresets(
            budgets={"quick": 3_000, "default": 60_000, "paper": 250_000},
            hyper={
                "quick": {"learning_starts": 1024, "eval_every": 1000, "eval_episodes": 4},
                "default": {"eval_every": 5000},
            },
            lab_budget={"full": {"config": "budget"}},
        ),
    )
)
# DroQ's bounded residual on a fit comparing four frames (the budget presets "frames-residual-history" and
# "frames-residual-hold", which differ in the trim only)
_RESIDUAL_HISTORY = {
    "config": "budget",
    "observer": "fit-residual",
    "residual_scale": 0.25,
    "fit_history": 3,
}
register(
    Algo(
        "droq",
        "agents.learners.offpolicy.droq",
        DroQConfig,
        "DroQ",
        vmaps_seeds=True,
        off_policy=True,
        cost=CostModel(fixed_s=25.0, s_per_update=4.5e-4),
        sweep=SweepPresets(
            budgets={},  # in the sweep's lab-budget section only
            lab_budget={
                "quick": {
                    "config": "budget",
                    "learning_starts": 200,
                    "eval_every": 200,
                    "utd_ratio": 2.0,
                    "hidden": [32, 32],
                    "critic_hidden": [32, 32],
                    "batch_size": 64,
                },
                "default": {"config": "budget"},
                "full": {"config": "budget"},
                "frames": {"config": "budget"},
                "frames-fit": {"config": "budget", "observer": "fit"},
                "frames-residual": {"config": "budget", "observer": "fit-residual"},
                "frames-residual-bounded": {
                    "config": "budget",
                    "observer": "fit-residual",
                    "residual_scale": 0.25,
                },
                "frames-residual-history": _RESIDUAL_HISTORY,
                "frames-residual-hold": _RESIDUAL_HISTORY,
            },
        ),
    )
)
