"""The command line of ``python -m agents.bench`` (``parser``; the command: ``agents.bench.runner``,
its arguments checked where they are used: ``agents.bench.prepare``, ``agents.bench.learning``)."""

from __future__ import annotations

import argparse

from agents.bench.learning import CATCH_UP_S, CHECKPOINT_EVERY

DESCRIPTION = (
    "Drive a controller through a lab's control stack: ophyd devices over EPICS Channel Access, "
    "the control loop a Bluesky plan run by a ``RunEngine``."
)


def _bench_args(ap: argparse.ArgumentParser) -> None:
    """The arguments of the bench: the simulated one or a mapping's."""
    ap.add_argument(
        "--prefix", default="OPS:", help="PV prefix of the simulated bench (without --mapping)"
    )
    ap.add_argument(
        "--stages",
        type=int,
        default=None,
        help="delay lines of the simulated bench (default: the saved controller's, else 5)",
    )
    ap.add_argument(
        "--mapping", help="a mapping file (JSON) naming the bench's PVs, units and safety limits"
    )
    ap.add_argument(
        "--no-lengths",
        action="store_true",
        help="the simulated bench without its length readouts (LINEi:LEN not mapped; without "
        "--mapping)",
    )


def _controller_args(ap: argparse.ArgumentParser) -> None:
    """The arguments of what runs: a controller (its settings, the trim) or a learner."""
    ap.add_argument("--controller", help="spgd, physics or a folder written by agents.save")
    ap.add_argument(
        "--learn",
        metavar="NAME",
        help="learn on the bench with this off-policy learner (droq, td3) "
        "instead of running a controller",
    )
    ap.add_argument(
        "--from", dest="from_", metavar="DIR", help="--learn: start from this policy (agents.save)"
    )
    ap.add_argument(
        "--resume", action="store_true", help="--learn: continue the run checkpointed in --out"
    )
    ap.add_argument(
        "--checkpoint-every",
        type=int,
        default=CHECKPOINT_EVERY,
        metavar="M",
        help="--learn: env steps between checkpoints",
    )
    ap.add_argument(
        "--catch-up-s",
        type=float,
        default=CATCH_UP_S,
        metavar="S",
        help="--learn: at the end of a run stopped by its --steps or --seconds, take the gradient "
        "steps the learner fell behind its ratio, for at most S seconds (default 0: none)",
    )
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", help="controller hyperparameter")
    ap.add_argument(
        "--env", action="append", metavar="KEY=VALUE", help="ops_jax.make option of the controller"
    )
    ap.add_argument(
        "--trim",
        nargs="*",
        metavar="KEY=VALUE",
        default=None,
        help="wrap the controller in the extremum-seeking trim (agents.controllers.trim; one more "
        "probe per step), with these TrimConfig settings (none: its default)",
    )


def _run_args(ap: argparse.ArgumentParser) -> None:
    """The arguments of the run's length, pace and draws."""
    ap.add_argument(
        "--lockstep",
        action="store_true",
        help="the simulated bench runs --lockstep: advance it one frame per step and probe",
    )
    ap.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="run length (s; default 60, with --learn no limit)",
    )
    ap.add_argument(
        "--steps",
        type=int,
        default=0,
        help="stop after this many control steps too (0: no limit; "
        "--learn: env steps in all, resumes included)",
    )
    ap.add_argument("--rate", type=float, default=100.0, help="most control steps per second (Hz)")
    ap.add_argument("--seed", type=int, default=0, help="the controller's random draws")


def _limit_args(ap: argparse.ArgumentParser) -> None:
    """The arguments of the safety limits' and the detector's overrides, the core, the output."""
    ap.add_argument(
        "--wrap",
        type=float,
        default=None,
        metavar="WL",
        help="take a line that comes within WL of its soft limit WL back (0: never); "
        "safety.wrap_wl of the mapping (default: the mapping's period_wl, the simulated bench's "
        "0.5, where the controller reads no length readouts)",
    )
    ap.add_argument(
        "--stale-s",
        type=float,
        default=None,
        help="the watchdog's limit on a reading's age and "
        "on the wait for a frame (s; default: the mapping's, 0.5)",
    )
    ap.add_argument(
        "--settle-s",
        type=float,
        default=None,
        metavar="S",
        help="from a setpoint write until a frame acquired S s or more after it shows the move "
        "(s; default: the mapping's detector.settle_s, 0.002)",
    )
    ap.add_argument(
        "--cpu",
        type=int,
        default=None,
        metavar="CORE",
        help="run the runner on this CPU core only (Linux): a controller's step costs less CPU on "
        "a core of its own, with the bench's other processes on the others",
    )
    ap.add_argument(
        "--out", required=True, help="folder for documents.jsonl, power.png, summary.json"
    )


def parser() -> argparse.ArgumentParser:
    """The parser of ``python -m agents.bench`` (a run; ``template`` and ``check``:
    ``agents.bench.template``)."""
    ap = argparse.ArgumentParser(
        prog="python -m agents.bench",
        description=DESCRIPTION,
        epilog="python -m agents.bench template --out FILE: a mapping to start from; python -m "
        "agents.bench check --mapping FILE: read every PV it names once (each with --help)",
    )
    for add in (_bench_args, _controller_args, _run_args, _limit_args):
        add(ap)
    return ap
