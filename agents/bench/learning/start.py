"""How a learning run on the bench starts (``agents.bench.learning``): its arguments checked, its
settings (``settings``: from scratch, ``--from`` a policy or resumed), the learner built, restored
or started from the policy (``setup``); ``Learning``: its parts for the runner."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np

from agents import api as base, registry
from agents.bench.learning.actor import Actor, Handover
from agents.bench.learning.programs import Built, build, compile_programs
from agents.bench.learning.state import Checkpoints, State, fresh, restore, start_from
from agents.bench.learning.thread import GradientThread
from agents.bench.frozen import check_lengths
from agents.io import kept_dir
from agents.learners.offpolicy.learner import Learner

CHECKPOINT_EVERY = 1000  # env steps between two checkpoints (default)
# most seconds of gradient steps taken after the loop to make up the ratio (default: none)
CATCH_UP_S = 0.0


def off_policy_learner(name: str) -> Learner:
    """The ``Learner`` of ``--learn name`` (ValueError naming the off-policy learners otherwise)."""
    names = [a.name for a in registry.REGISTRY.values() if a.off_policy]
    if name not in names:
        raise ValueError(
            f"--learn must be an off-policy learner ({', '.join(names)}), got {name!r}"
        )
    return registry.get(name).load().LEARNER


def check_args(args) -> Path | None:
    """The learning arguments checked (ValueError, one line naming the parameter); the checkpoint to
    resume."""
    off_policy_learner(args.learn)
    if args.controller or args.trim is not None:
        raise ValueError("--learn replaces --controller and --trim: give --learn alone")
    if args.steps < 1:
        raise ValueError(
            "--steps must be >= 1 with --learn (env steps in all, resumes included), got "
            f"{args.steps}"
        )
    if not args.catch_up_s >= 0:
        raise ValueError(f"--catch-up-s must be >= 0 s, got {args.catch_up_s}")
    if args.checkpoint_every < 1:
        raise ValueError(f"--checkpoint-every must be >= 1 env step, got {args.checkpoint_every}")
    if args.from_ is not None and not Path(args.from_).is_dir():
        raise ValueError(f"--from must be a folder written by agents.save, got {args.from_!r}")
    checkpoint = kept_dir(Path(args.out) / "checkpoint")
    if args.resume:
        if args.from_ or args.set or args.env:
            raise ValueError(
                "--resume continues the run in --out with its own settings: drop --from, --set "
                "and --env"
            )
        if checkpoint is None or not (checkpoint / "learner.json").exists():
            raise ValueError(
                f"--resume needs a checkpoint of a learning run in --out, none in {args.out}"
            )
        try:
            done = json.loads((checkpoint / "learner.json").read_text())["counts"]["env_steps"]
        except (OSError, ValueError, KeyError, TypeError):
            done = None  # unreadable: restoring it says why
        if done is not None and done >= args.steps:
            raise ValueError(
                f"--steps must be > the {done} env steps of the checkpoint, got {args.steps}"
            )
    elif checkpoint is not None:
        raise ValueError(
            f"--out {args.out} holds a learning run's checkpoint: continue it with --resume, or "
            "give another --out"
        )
    return checkpoint if args.resume else None


def default_stages(args, checkpoint: Path | None) -> int:
    """The simulated bench's stages: the resumed run's, the ``--from`` policy's, else 5."""
    source = checkpoint or args.from_
    return base.load(source).env_spec.stages if source else 5


def settings(args, learner, mapping: dict, checkpoint: Path | None, env_options: dict, hyper: dict):
    """(env_config, the learner's config, seed, start: the ``--from`` or resumed TrainResult or
    None)."""
    stages, lengths = len(mapping["lines"]), all("length" in line for line in mapping["lines"])
    start = base.load(checkpoint or args.from_) if (checkpoint or args.from_) else None
    if start is None:  # one instance, few env steps: the budget preset where there is one
        presets = learner.config_type.PRESETS
        config = learner.config_type.make(
            hyper.pop("config", "budget" if "budget" in presets else None), **hyper
        )
        return (
            {"stages": stages, "observe_lengths": lengths, **env_options},
            config,
            args.seed,
            None,
        )
    what = "--from" if checkpoint is None else f"the checkpoint in {args.out}"
    if start.algo != learner.name:
        raise ValueError(f"--learn {learner.name}: {what} holds a {start.algo} policy")
    config = learner.config_type.from_hyper({**start.config.to_hyper(), **hyper})
    seed = start.seed if checkpoint else args.seed
    return {**start.env_spec.as_dict(), **env_options}, config, seed, start


def _check_env(args, parts: Built, mapping: dict) -> None:
    """The learner's environment fits the bench of ``mapping`` (ValueError, MappingError)."""
    stages, env = len(mapping["lines"]), parts.env
    if env.num_actions != stages:
        raise ValueError(
            f"--learn: the policy's env_config drives {env.num_actions} lines, the bench has "
            f"{stages}"
        )
    if env.config.include_noise:
        raise ValueError(
            "--env include_noise=True: the noise state is the simulator's, no bench measures it"
        )
    check_lengths(
        f"--from {args.from_}" if args.from_ else f"--learn {args.learn}", True, env, mapping
    )


def setup(args, mapping: dict, checkpoint: Path | None, env_options: dict, hyper: dict):
    """(Learning, env_config, action scale (wl per unit), window (wl)) of the arguments on the bench
    of ``mapping``."""
    learner = off_policy_learner(args.learn)
    env_config, config, seed, start = settings(
        args, learner, mapping, checkpoint, env_options, hyper
    )
    parts, env_params = build(learner, base.check_env_config(env_config), config, seed)
    _check_env(args, parts, mapping)
    out = Path(args.out)
    for stale in out.glob("checkpoint.*.tmp"):  # a checkpoint's folder a kill left half-written
        shutil.rmtree(stale, ignore_errors=True)
    state = fresh(parts, env_params)
    if checkpoint is not None:
        restore(state, checkpoint, config.learning_starts)
    elif start is not None:
        start_from(state, start, args.from_)
    c = state.counts
    if c.transitions + args.steps - c.env_steps <= config.learning_starts:
        print(
            f"agents.bench.runner: warning: --steps {args.steps} ends within the learner's "
            f"warm-up (learning_starts={config.learning_starts} transitions of random actions): "
            "it takes no gradient step",
            file=sys.stderr,
        )
    learning = Learning(parts, state, Checkpoints(parts, out, args.checkpoint_every))
    return learning, parts.env_config, float(env_params.action_scale), float(env_params.window)


class Learning:
    """A learner on a bench: its ``actor`` (the loop's controller), its gradient ``thread``, the
    start document's entry (``describe``), the plot's ratio series and the summary's entries
    (``report``). Its programs are compiled when it is made."""

    def __init__(self, parts: Built, state: State, checkpoints: Checkpoints):
        self.parts, self.state = parts, state
        programs, handover = compile_programs(parts, state.ts), Handover()
        self.actor = Actor(parts, programs, handover)
        self.thread = GradientThread(parts, programs, handover, state, checkpoints)
        self.thread.publish()

    def begin(self, steps: int, on_error) -> None:
        """An invocation of ``steps`` env steps starts: the actor's draws from the env steps so
        far, the learning thread started (``on_error(exc)`` if it fails)."""
        self.actor.begin(self.state.counts.env_steps)
        self.thread.begin(steps, on_error)

    def describe(self) -> dict:
        """The start document's ``learning`` entry."""
        p = self.parts
        return {
            "learner": p.learner.name,
            "hyper": p.hyper,
            "from": self.state.from_policy,
            "seed": p.seed,
            "env_steps_resumed_from": self.state.counts.env_steps,
            "update_ratio_target": p.ratio,
        }

    def ratio_series(self, t0: float | None, window: int = 10):
        """(seconds since ``t0`` (perf_counter), gradient steps per env step over the last
        ``window`` hand-overs, NaN in the warm-up) for the plot, or None."""
        rec = self.thread.invocation.ratio_rec
        if t0 is None or len(rec) <= window:
            return None
        t, learn, env = np.asarray(rec, float).T
        d_env = env[window:] - env[:-window]
        ratio = np.divide(
            learn[window:] - learn[:-window],
            d_env,
            out=np.full_like(d_env, np.nan),
            where=d_env > 0,
        )
        return t[window:] - t0, ratio

    def report(self) -> dict:
        """The summary's learning entries: totals over the run's invocations and this invocation's
        update ratio."""
        c, done, error = self.state.counts, self.thread.invocation, self.thread.error
        return {
            "learner": self.parts.learner.name,
            "env_steps_total": c.env_steps,
            "learn_steps_total": c.learn_steps,
            "env_steps_resumed_from": done.first.env_steps,
            "learn_steps_resumed_from": done.first.learn_steps,
            "transitions_total": c.transitions,
            "learning_env_steps_total": c.learning_env_steps,
            "update_ratio": done.update_ratio(done.in_loop_steps),
            "update_ratio_target": self.parts.ratio,
            "catch_up_steps": done.since("learn_steps") - done.in_loop_steps,
            "update_ratio_with_catch_up": done.update_ratio(),
            "update_ratio_total": c.learn_steps / c.learning_env_steps
            if c.learning_env_steps
            else 0.0,
            "sessions": c.sessions,
            "learner_error": None if error is None else repr(error),
        }
