"""The lab-budget section's presets (``python -m benchmarks.budget --preset NAME``; the sweep's
budget section runs "quick", "default" and, in its "paper" preset, "full"): each preset's
environments, seeds, checkpoints of env steps, test episodes, protocol (b)'s pretraining and
adapting (``adapt``), and its ``controllers``: algorithm (``agents.registry`` name) -> its
hyperparameters, trained there if a learner, else evaluated as a reference, in the order of the
plan's cells (their labels in the sweep, budget-<index>) and of the tables.

    "quick"    tiny (seconds): 3 stages, DroQ with small networks, the references
    "default"  DroQ at its budget preset, the references and protocol (b) (15 min on 2 cores)
    "full"     every learner at its budget preset (52 min on 2 cores)
    "frames-residual-history"
               the detector's frames only: DroQ correcting the physics-informed fit's move on four
               frames, and the references (docs/results.md, "Frames only")

The presets that docs/learners.md measured and no longer recommends are retired; docs/results.md
("Retired lab-budget presets") names each with its date, its command and the settings it differed
in.
"""

from __future__ import annotations

CHECKPOINTS = (1000, 2000, 5000, 10_000, 20_000)
HARD = dict(stages=5, mode="hard", model="phasor")
ENVS = {"hard": HARD, "hard + lab": dict(HARD, imperfections="lab")}
QUICK_ENV = dict(stages=3, mode="easy", model="phasor")

# DroQ at the quick preset's size: small networks, 2 gradient steps per env step
DROQ_QUICK = {
    "config": "budget",
    "learning_starts": 200,
    "eval_every": 200,
    "utd_ratio": 2.0,
    "hidden": [32, 32],
    "critic_hidden": [32, 32],
    "batch_size": 64,
}
# protocol (b): pretrained on the randomised simulator (each episode's imperfections 0-2x the lab
# preset, its per-stage errors in any layout), 8 envs, 10 gradient steps per 8 env steps; then
# adapted on an unseen bench: 250 steps of the pretrained policy, then 2 gentler gradient steps per
# step; the trim of agents.controllers.trim's default TrimConfig
ADAPT = dict(
    algo="droq",
    pretrain_env=dict(HARD, imperfections="lab", randomize=1.0, randomize_layout=1.0),
    pretrain_steps=100_000,
    pretrain_hyper={
        "config": "budget",
        "num_envs": 8,
        "utd_ratio": 1.25,
        "buffer_size": 100_000,
        "learning_starts": 2000,
        "eval_every": 10_000,
    },
    hyper={
        "config": "budget",
        "learning_starts": 250,
        "eval_every": 250,
        "utd_ratio": 2.0,
        "actor_lr": 1e-4,
        "critic_lr": 1e-4,
    },
    bench_env=HARD,
    scale=2.0,
    bench_seed_offset=1000,
    checkpoints=(1000, 2000, 5000),
    trim={},
)
# the frames alone (``observe_lengths=False``: no length readouts), on the lab's system and in
# protocol (b)
FRAMES = dict(observe_lengths=False)
# DroQ's action a correction of at most a quarter of the action range added to the physics-informed
# fit's move, the fit comparing the newest frame with the three before it
# (``agents.learners.offpolicy.observer``)
RESIDUAL_HISTORY = {"observer": "fit-residual", "residual_scale": 0.25, "fit_history": 3}

PRESETS = {
    "quick": dict(
        envs={"easy 3": QUICK_ENV},
        seeds=(0,),
        checkpoints=(600, 1200),
        episodes=4,
        eval_seed=4242,
        adapt=dict(
            algo="droq",
            pretrain_env=dict(QUICK_ENV, imperfections="lab", randomize=1.0, randomize_layout=1.0),
            pretrain_steps=600,
            pretrain_hyper=DROQ_QUICK,
            hyper=dict(DROQ_QUICK, learning_starts=100, eval_every=100),
            bench_env=QUICK_ENV,
            scale=2.0,
            bench_seed_offset=1000,
            checkpoints=(300, 600),
            trim={},
        ),
        controllers={
            "droq": DROQ_QUICK,
            "spgd": {},
            "physics": {"config": "frames", "starts": 4, "iters": 4},
        },
    ),
    "default": dict(
        envs=ENVS,
        seeds=(11, 12, 13, 14, 15),
        checkpoints=CHECKPOINTS,
        episodes=32,
        eval_seed=4242,
        adapt=ADAPT,
        controllers={"droq": {"config": "budget"}, "spgd": {}, "physics": {}},
    ),
}
PRESETS["full"] = dict(
    PRESETS["default"],
    controllers={
        "droq": {"config": "budget"},
        "td3": {"config": "budget"},
        "sac": {"config": "budget"},
        # 1,000 env steps per iteration
        "ppo": {"config": "paper", "unroll_length": 25, "batch_size": 5, "num_evals": 2},
        "spgd": {},
        "physics": {},
    },
)
PRESETS["frames-residual-history"] = dict(
    PRESETS["default"],
    envs={"hard + lab, frames only": dict(ENVS["hard + lab"], **FRAMES)},
    adapt=dict(
        ADAPT,
        pretrain_env=dict(ADAPT["pretrain_env"], **FRAMES),
        bench_env=dict(HARD, **FRAMES),
        pretrain_steps=20_000,  # the fit's move is sent from the first step
        pretrain_hyper=dict(ADAPT["pretrain_hyper"], **RESIDUAL_HISTORY),
        hyper=dict(ADAPT["hyper"], **RESIDUAL_HISTORY),
    ),
    # the physics-informed reference with ``history=3``: the controller the learner corrects
    controllers={
        "droq": {"config": "budget", **RESIDUAL_HISTORY},
        "spgd": {},
        "physics": {"config": "frames", "history": 3},
    },
)
