"""A run's setup from the command line (``agents.bench.cli``): the arguments checked, the threads
placed, the bench's mapping with its overrides and defaults (``agents.bench.defaults``), the
controller built: a frozen one (``agents.bench.frozen.load_controller``) or a learner's actor
(``agents.bench.learning``); ``Setup`` holds what the run needs of it."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from agents import api as base
from agents.bench import defaults, learning as bench_learn
from agents.bench.controller import Controller
from agents.bench.mapping import SETTLE_RANGE_S, check_mapping, load_mapping, sim_mapping
from agents.bench.frozen import load_controller
from agents.bench.report import say
from agents.cli import parse_set
from ops_jax.cli import runtime

FROZEN = ("spgd", "physics")  # the controllers built by name (else a folder of agents.save)


@dataclasses.dataclass(frozen=True)
class Setup:
    """What a run needs: the checked ``mapping``, the ``controller`` the loop drives, the
    ``env_config`` it is built for, its action ``scale`` (wl per unit) and ``window`` (wl), the
    ``learning`` run it acts for (None: a frozen controller), its ``label`` in the documents and
    summary."""

    mapping: dict
    controller: Controller
    env_config: dict
    scale: float
    window: float
    learning: bench_learn.Learning | None
    label: str

    def loop_args(self) -> tuple:
        """(mapping, controller, scale, window): the ``agents.bench.loop.Loop``'s of the run."""
        return self.mapping, self.controller, self.scale, self.window


def usable_cores(core: int) -> set:
    """The CPU cores this process may run on; ``ValueError`` naming ``--cpu`` unless ``core`` is one
    (Linux)."""
    if not hasattr(os, "sched_setaffinity"):
        raise ValueError("--cpu needs Linux (os.sched_setaffinity); leave it out here")
    allowed = os.sched_getaffinity(0)
    if core not in allowed:
        raise ValueError(
            f"--cpu must be one of the cores this process may run on, {sorted(allowed)}, got {core}"
        )
    return allowed


def pin(core: int) -> None:
    """Run this process's threads, and the threads they start, on CPU core ``core`` only (Linux)."""
    usable_cores(core)
    runtime.set_cores({core})


def _check_run(args) -> None:
    """The run's length, pace and what runs (ValueError naming the parameter); ``--seconds``'s
    default set (60 s, a learning run none)."""
    if args.seconds is None:
        args.seconds = np.inf if args.learn else 60.0
    if not args.seconds > 0:
        raise ValueError(f"--seconds must be > 0, got {args.seconds}")
    if not (np.isfinite(args.rate) and args.rate > 0):
        raise ValueError(f"--rate must be > 0 Hz, got {args.rate}")
    if (args.controller is None) == (args.learn is None):
        raise ValueError(
            "give one of --controller (run a controller) and --learn (learn on the bench)"
        )
    if args.controller not in (*FROZEN, None) and not Path(args.controller).is_dir():
        raise ValueError(
            "--controller must be spgd, physics or a folder written by agents.save, got "
            f"{args.controller!r}"
        )


def _place_threads(args) -> None:
    """``--cpu``: every thread on that core; else a controller's run gives XLA's pools one thread
    each (its calls are small). Before JAX and its thread pools start."""
    if args.cpu is not None:
        pin(args.cpu)
    elif not args.learn:
        runtime.start_single_threaded()


def _stages(args, checkpoint: Path | None) -> int:
    """The simulated bench's stages: ``--stages``, else the learner's or saved controller's, else
    5."""
    if args.stages:
        return args.stages
    if args.learn:
        return bench_learn.default_stages(args, checkpoint)
    saved = args.controller not in FROZEN
    return base.load(args.controller).env_spec.stages if saved else 5


def _mapping(args, checkpoint: Path | None) -> dict:
    """The bench's mapping (``--mapping`` or the simulated bench's) with the command line's
    overrides of its safety limits and settle time, unchecked."""
    mapping = (
        load_mapping(args.mapping)
        if args.mapping
        else sim_mapping(
            args.prefix, _stages(args, checkpoint), args.lockstep, lengths=not args.no_lengths
        )
    )
    for key, value in (("stale_s", args.stale_s), ("wrap_wl", args.wrap)):
        if value is not None:
            mapping["safety"] = {**(mapping.get("safety") or {}), key: value}
    if args.settle_s is not None:
        low, high = SETTLE_RANGE_S
        if not low <= args.settle_s <= high:
            raise ValueError(f"--settle-s must be in [{low:g}, {high:g}] s, got {args.settle_s}")
        mapping["detector"] = {**mapping["detector"], "settle_s": args.settle_s}
    return mapping


def _frozen(args, mapping: dict) -> Setup:
    """The frozen controller's run, its calls inline (without the hand-off to XLA's dispatch
    thread: set before JAX's first computation in the process; a learning run keeps it)."""
    import jax

    jax.config.update("jax_cpu_enable_async_dispatch", False)
    trim = None if args.trim is None else parse_set(args.trim)
    agent, env_config, scale, window = load_controller(
        args.controller, mapping, parse_set(args.env), parse_set(args.set), args.seed, trim
    )
    return Setup(mapping, agent, env_config, scale, window, None, args.controller)


def setup(args) -> Setup:
    """The run's ``Setup`` from the arguments; raises what is wrong (``ValueError``,
    ``MappingError``, ...). The run's first line says what was chosen by default."""
    _check_run(args)
    _place_threads(args)
    checkpoint = bench_learn.check_args(args) if args.learn else None
    mapping = check_mapping(_mapping(args, checkpoint))
    args.set, mapping, chosen = defaults.choose(args, mapping, checkpoint)
    then = "the controller's compilation, then the connection to the bench"
    say(f"starting: chosen: {chosen}; now {then}" if chosen else f"starting: {then}")
    if not args.learn:
        return _frozen(args, mapping)
    learning, env_config, scale, window = bench_learn.setup(
        args, mapping, checkpoint, parse_set(args.env), parse_set(args.set)
    )
    label = f"learning {args.learn}"
    return Setup(mapping, learning.actor, env_config, scale, window, learning, label)
