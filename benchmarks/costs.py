"""Estimated seconds of the benchmarks' cells per algorithm (the sweep's units, the lab-budget
section's cells), by which the sweep orders and shares out its work.

The cost models are fitted to two measured runs on an idle 2-core host: the sweep's default preset
(docs/results.md: medians of its table-1 cells, PPO 94.7 s for 1,916,928 env steps, SAC 69.3 s for
99,968, TD3 38.5 s per seed for 59,776, physics-informed 5.5 s; its stage scan, physics-informed at
N = 6 and 7: 14-107 s; its evaluations, physics-informed 5.4-6.1 s, the others 0.1-0.2 s of rollout)
and its lab-budget section of 2026-11-26 (one core per cell: DroQ 114-161 s, adapt cells 83-133 s,
SPGD 4-8 s; TD3 58-102 s, SAC 240-384 s for five runs, PPO 20-153 s). Per env step and per gradient
step together: the two runs' configs differ in their update-to-data ratio (SAC 0.25 and 10, TD3
0.125 and 10, PPO 0.016 and 0.08 gradient steps per env step).
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class CostModel:
    """Estimated seconds of an algorithm's cells on one worker of a 2-core CPU: a training run of
    ``steps`` env steps, ``updates`` gradient steps, on N stages costs (``fixed_s`` + ``s_per_step``
    x steps + ``s_per_update`` x updates) x ``stage_growth`` ** (N - 5) for N > 5; an evaluation of
    32 episodes ``eval_s``."""

    fixed_s: float = 5.0
    s_per_step: float = 0.0
    s_per_update: float = 0.0
    stage_growth: float = 1.0
    eval_s: float = 1.0

    def train_s(self, steps: int, updates: float = 0.0, stages: int = 5) -> float:
        """Seconds of one training run of ``steps`` env steps and ``updates`` gradient steps on
        ``stages`` stages."""
        return (
            self.fixed_s + self.s_per_step * steps + self.s_per_update * updates
        ) * self.stage_growth ** max(0, stages - 5)


# algorithm (``agents.registry`` name) -> its cost model; one not named here costs ``CostModel()``
COSTS = {
    "spgd": CostModel(fixed_s=3.0),
    "physics": CostModel(fixed_s=6.0, stage_growth=3.5, eval_s=6.0),
    "ppo": CostModel(s_per_step=9.9e-6, s_per_update=2.38e-3),
    "sac": CostModel(fixed_s=10.0, s_per_step=5.4e-4, s_per_update=4.0e-4),
    "td3": CostModel(fixed_s=3.0, s_per_step=5.7e-4, s_per_update=1.43e-4),
    "droq": CostModel(fixed_s=25.0, s_per_update=4.5e-4),
}


def cost_model(algo: str) -> CostModel:
    """The cost model of ``algo`` (``CostModel()`` for one that ``COSTS`` does not name)."""
    return COSTS.get(algo, CostModel())


def train_s(algo: str, hyper: dict, steps: int, stages: int = 5) -> float:
    """Seconds of a training run of ``algo`` with ``hyper`` for ``steps`` env steps on ``stages``
    stages (its gradient steps from the config's ``updates_per_step``)."""
    from agents.registry import get

    updates = steps * get(algo).config.from_hyper(hyper).updates_per_step()
    return cost_model(algo).train_s(steps, updates, stages)
