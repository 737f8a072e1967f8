"""Learning on a bench: an off-policy learner of ``agents.learners.offpolicy.driver`` (DroQ, TD3)
acting in the control loop of ``agents.bench`` and learning from the bench's own transitions.

    python -m agents.bench --prefix OPS: --learn droq [--from DIR] --steps 20000 --out DIR \\
        [--resume]

The actor (the loop's thread, ``agents.bench.learning.actor.Actor``, an
``agents.bench.controller.Controller``) hands each step's observation (``Loop.observe``: the
simulator's layout) with the previous observation and action to the learner, and sends the
exploration action of the newest actor network it was handed. The learner (a thread of its own,
``agents.bench.learning.thread``) stores the transitions in the replay buffer, their reward the
configuration's (``OPSEnv.reward``) at the detector's reading, and takes gradient steps one at a
time as the wall clock allows, at most the config's ratio (``utd_ratio``) per env step after the
warm-up; every ``PUBLISH_STEPS`` env steps it hands the actor a copy of the actor network (a swap
under a lock). Its parts: ``start`` (the arguments, settings, the learner built or restored),
``programs`` (what it is built of, its jitted programs), ``state`` (its state and checkpoints),
``actor``, ``thread``; ``Learning`` holds them for the runner.

A free-running bench has no reset and no terminal state: the task is continuing, every transition's
discount 1 (every target bootstrapped). The warm-up is ``learning_starts`` transitions of uniform
random actions, the observation statistics then frozen from them; from ``--from`` (a policy of
``agents.save``) it is the policy's own exploration and its statistics are kept, as
``agents.learners.offpolicy.driver`` continues a run.

``DIR/checkpoint``, written every ``--checkpoint-every`` env steps and at the end
(``agents.io.replace_dir``): an ``agents.save`` folder of the current policy
(``--controller DIR/checkpoint`` runs it), ``learner.msgpack`` (networks, targets, optimiser states,
replay buffer, gradient step count, PRNG key) and ``learner.json`` (``Counts``). ``--resume``
continues from it; the actor's draws are keyed by the run's seed and env step.
"""

from agents.bench.learning.start import (
    CATCH_UP_S,
    CHECKPOINT_EVERY,
    Learning,
    check_args,
    default_stages,
    off_policy_learner,
    settings,
    setup,
)

__all__ = [
    "CATCH_UP_S",
    "CHECKPOINT_EVERY",
    "Learning",
    "check_args",
    "default_stages",
    "off_policy_learner",
    "settings",
    "setup",
]
