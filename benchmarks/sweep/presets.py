"""The sweep's presets ("quick", "default", "paper"): seeds, episodes and section settings
(``PRESETS``), and each algorithm's part in them (``BUDGETS``, ``HYPER``, ``REALITY_BUDGETS``),
keyed by its ``agents.registry`` name.

An algorithm takes part in a preset where ``BUDGETS`` gives it a training budget there (env steps; 0
for a controller that trains nothing), in the order of ``BUDGETS``; ``HYPER`` overrides its config's
fields there, on top of the preset's ``algo_config`` (the ``config`` of the learners' config types).
A new algorithm joins the sweep with its entry in ``BUDGETS`` (and, where it needs them, ``HYPER``)
and its cost model in ``benchmarks.costs``.
"""

from __future__ import annotations

from benchmarks.sweep.paper import MODES

PRESETS = {
    "quick": dict(  # a first look: tiny budgets, a cheaper physics-informed fit, few episodes
        seeds=2,
        algo_config="fast",
        episodes=8,
        stage_range=(2, 3),
        stage_modes=("easy",),
        stage_algos=("spgd",),
        stage_seeds=1,
        feedback_ks=(1, 100),
        aux_seeds=1,
        reality_seeds=2,
    ),
    "default": dict(  # its wall time: docs/results.md
        seeds=5,
        algo_config="fast",
        episodes=32,
        stage_range=(1, 7),
        stage_modes=("easy", "hard"),
        stage_algos=("spgd", "physics"),
        stage_seeds=1,
        feedback_ks=(1, 20, 40, 60, 80, 100),
        aux_seeds=2,
        reality_seeds=3,
    ),
    "paper": dict(
        seeds=20,
        algo_config="paper",
        episodes=100,
        stage_range=(1, 7),
        stage_modes=MODES,
        stage_algos=("spgd", "physics", "td3", "sac"),
        stage_seeds=5,
        feedback_ks=(1, 20, 40, 60, 80, 100),
        reality_seeds=5,
    ),
}

# algorithm -> {preset: training budget (env steps)}
BUDGETS = {
    "spgd": {"quick": 0, "default": 0, "paper": 0},
    "physics": {"quick": 0, "default": 0, "paper": 0},
    "ppo": {"quick": 32_768, "default": 2_000_000, "paper": 200_000},
    "sac": {"quick": 3_000, "default": 100_000, "paper": 200_000},
    "td3": {"quick": 3_000, "default": 60_000, "paper": 250_000},
}

# algorithm -> {preset: hyperparameters overriding its config's}
HYPER = {
    "physics": {  # half the fit cost of 16 x 8
        "quick": {"starts": 4, "iters": 4},
        "default": {"starts": 8, "iters": 6},
    },
    "ppo": {
        "quick": {
            "num_evals": 2,
            "num_eval_envs": 16,
            "hidden": [64, 64],
            "num_updates_per_batch": 2,
        }
    },
    "sac": {
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
    "td3": {
        "quick": {"learning_starts": 1024, "eval_every": 1000, "eval_episodes": 4},
        "default": {"eval_every": 5000},
    },
}

# algorithm -> {preset: the reality section's own training budget}: randomised training is far from
# done at 100k (docs/imperfections.md)
REALITY_BUDGETS = {"sac": {"default": 300_000}}

# sweep preset -> the lab-budget section's preset (benchmarks/budget/presets.py) that its budget
# section runs
BUDGET_PRESETS = {"quick": "quick", "default": "default", "paper": "full"}


def preset(name: str) -> dict:
    """The preset ``name`` with its algorithms' parts: ``algos``, ``budgets``, ``hyper`` and (where
    any) ``reality_budgets`` (ValueError naming an algorithm that is not registered)."""
    from agents.registry import get

    if name not in PRESETS:
        raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {name!r}")
    algos = [get(algo).name for algo, budgets in BUDGETS.items() if name in budgets]
    out = dict(
        PRESETS[name],
        name=name,
        algos=tuple(algos),
        budgets={algo: BUDGETS[algo][name] for algo in algos},
    )
    hyper = {algo: HYPER[algo][name] for algo in algos if name in HYPER.get(algo, {})}
    budgets = {
        algo: REALITY_BUDGETS[algo][name] for algo in algos if name in REALITY_BUDGETS.get(algo, {})
    }
    return {
        **out,
        **({"hyper": hyper} if hyper else {}),
        **({"reality_budgets": budgets} if budgets else {}),
    }
