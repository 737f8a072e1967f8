"""Drive a controller through a lab's control stack: ophyd devices over EPICS Channel Access, the
control loop a Bluesky plan run by a ``RunEngine``.

    python -m agents.bench --prefix OPS: --controller physics --seconds 60 --rate 100 --out DIR

``--controller``: ``spgd``, ``physics`` or a folder written by ``agents.save``; ``--set key=value``
overrides the controller's hyperparameters, ``--env key=value`` the ``ops_jax.make`` options the
controller is built for (stages come from the bench). The bench is the simulated one of
``python -m ops_jax.ioc`` under ``--prefix`` (``--no-lengths``: without its length readouts) or any
bench described by ``--mapping FILE`` (``agents.bench.devices``). A controller that reads length
readouts the bench lacks fails at start.

One control step: wait for a detector frame that shows the last setpoints written (the newest one
acquired ``settle_s`` or more after the write, by its time stamp), read it, build the observation
exactly as the simulator does (power, oscilloscope samples, length readouts), decide, write the
setpoints (within the safety limits). A probe (SPGD's dither measurement) is a real move: write the
probed setpoints, wait for a frame that shows them, read the power; so each probe costs at least one
frame and the step's action goes out after it. A probe the controller leaves out (``active``,
``agents.api``) is not made: no move, no frame, NaN in the event. ``--rate`` caps the control steps
per second; ``--cpu CORE`` runs the runner on that core only. The loop runs in its own thread as a
Bluesky flyer (``agents.bench.flyer``); the plan collects its events in pages.

``--learn NAME`` (an off-policy learner: droq, td3) learns on the bench instead
(``agents.bench.learning``): it acts in the loop and learns from the bench's transitions for
``--steps`` env steps in all, from scratch or ``--from`` a saved policy, checkpointing to
``DIR/checkpoint`` every ``--checkpoint-every`` steps; ``--resume`` continues it.

The watchdog stops the run at once and writes nothing more when a PV disconnects, no new frame
arrives within ``stale_s``, a reading is older than ``stale_s`` or not finite. Ctrl-C (or SIGTERM)
ends the run after the current step, a second one at once (``user_stops``). Written to ``DIR``:
``documents.jsonl`` (the Bluesky documents, one per line, as they are emitted), ``power.png`` (P /
P_max and P / P_best against time, the PSD after lock beside it; learning: the update ratio too),
``summary.json`` (the lock figures of ``ops_jax.lock`` too; learning: the step counts and update
ratio) and, learning, ``checkpoint/``. Exit status 0 when the run ended by time or steps, 130 when
the user ended it with Ctrl-C (143 with SIGTERM; everything recorded is written first), 3 when the
watchdog stopped it, 2 for bad arguments or a bench that cannot be reached, 130 for a Ctrl-C before
the run started (nothing recorded).

The runner's parts: ``agents.bench.cli`` (the command line), ``agents.bench.prepare`` (the run's
setup), ``agents.bench.execute`` (the plan's run, Ctrl-C and SIGTERM), ``agents.bench.documents``
(``documents.jsonl``), ``agents.bench.report`` (the summary, the plot, the lines shown); the loop
drives an ``agents.bench.controller.Controller``: a frozen controller or a learner's actor.

``python -m agents.bench template --out FILE`` writes a mapping to start from,
``python -m agents.bench check --mapping FILE`` reads every PV it names once
(``agents.bench.template``).
"""

from __future__ import annotations

import logging
import os
import signal
import sys
from pathlib import Path

from agents.bench import cli, documents, prepare, report, template
from agents.bench.mapping import MappingError
from agents.bench.lifecycle import arm, connect, disconnect
from agents.bench.devices import make_bench
from agents.bench.execute import quiet, run_plan, user_stops
from agents.bench.loop import USER_STOP, Loop
from agents.bench.report import say
from agents.cli import parse_set
from agents.io import write_json_atomic
from ops_jax.cli.progress import exit_interrupted, keep_ctrl_c

# the watchdog's (safety) stop; the user's: 128 + the signal (130 for Ctrl-C, 143 for SIGTERM)
EXIT_WATCHDOG = 3
ENDED = ("time", "steps")  # how a run ends by itself


def _start(args) -> tuple[prepare.Setup, Loop] | int:
    """The run's setup, the bench connected and armed, the loop watching it; 2 (a line on stderr)
    for bad arguments or a bench that cannot be reached. A Ctrl-C meanwhile: one line, nothing
    recorded."""
    out = Path(args.out)
    try:
        try:
            run = prepare.setup(args)
            report.pyplot()  # imported before a run: the end of a run is kept short
            bench, lines = make_bench(run.mapping)
            connect(bench, run.mapping["safety"]["connect_s"])
        except (MappingError, ValueError, TypeError, FileNotFoundError) as exc:
            say(str(exc))
            return 2
        out.mkdir(parents=True, exist_ok=True)
        documents.begin(out, args.resume)
        arm(bench, lines)
        done = run.learning.state.counts.env_steps if run.learning else 0
        loop = Loop(bench, lines, *run.loop_args(), args.seconds, args.rate, args.steps - done)
        loop.watch()
        say("running; Ctrl-C stops the run after the current step")
    except KeyboardInterrupt:
        kept = "; its checkpoint as it was" if args.resume else ""
        exit_interrupted(f"stopped while starting; nothing recorded in {out}{kept}")
    return run, loop


def _metadata(args, run: prepare.Setup) -> dict:
    """The start document's metadata."""
    return {
        "controller": run.label,
        "controller_env": run.env_config,
        "hyper": parse_set(args.set),
        "trim": None if args.trim is None else parse_set(args.trim),
        "learning": run.learning and run.learning.describe(),
        "seed": args.seed,
        "rate_hz": args.rate,
        "mapping": run.mapping,
        "plan_name": "agents.bench",
    }


def _fly(args, run: prepare.Setup, loop: Loop) -> dict:
    """Run the plan (a learner's thread beside it), then disconnect; the run's summary."""
    learning = run.learning
    if learning:
        learning.begin(loop.max_steps, lambda exc: loop.trip(f"error: the learner failed: {exc!r}"))
    # a controller's progress line (a learner shows its own)
    shown = None if learning else report.RunProgress(run.label, loop.max_steps, loop.lines)
    with quiet():
        try:
            elapsed = run_plan(loop, _metadata(args, run), Path(args.out), shown)
            # the learner's steps while the loop ran end here (then its catch-up, its last
            # checkpoint)
            if learning:
                ended = report.stopped_by(loop) in ENDED
                learning.thread.end(args.catch_up_s if ended else 0.0)
        finally:
            if shown is not None:
                shown.close()
            disconnect(loop.bench)
    summary = report.summarize(loop, run.label, elapsed)
    summary.update(report.ceilings(summary))  # unknown here: benchmarks.lab adds them
    if learning:
        learning.thread.finish()
        summary.update(learning.report())
    return summary


def _write(out: Path, run: prepare.Setup, loop: Loop, summary: dict) -> None:
    """``summary.json``, ``power.png`` and the summary's lines on stdout."""
    write_json_atomic(out / "summary.json", summary)
    if summary["stopped_by"] not in (*ENDED, USER_STOP):
        say(f"stopped by the watchdog: {summary['stopped_by']}")
    report.plot(
        out / "power.png",
        loop,
        f"{run.label} on the bench, {summary['rate_hz']:.0f} steps/s",
        run.learning and run.learning.ratio_series(loop.t0),
        rate_hz=summary["rate_hz"],
    )
    print(report.readable(summary, out), flush=True)


def exit_status(stopped_by: str, user_stop) -> int:
    """0 for a run that ended by itself, ``EXIT_WATCHDOG`` for the watchdog's stop, 128 + the
    signal for the user's (``user_stop``: the signal, or True: Ctrl-C)."""
    if stopped_by in ENDED:
        return 0
    if stopped_by != USER_STOP:
        return EXIT_WATCHDOG
    return 128 + (int(user_stop) or signal.SIGINT)


def main(argv=None) -> int:
    """``python -m agents.bench`` (module docstring): its exit status."""
    keep_ctrl_c()
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    if argv[:1] and argv[0] in template.COMMANDS:  # a template mapping, or a check of one
        return template.main(argv)
    args = cli.parser().parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s: %(message)s"
    )
    started = _start(args)
    if isinstance(started, int):
        return started
    setup, loop = started
    with user_stops(loop):  # from here on nothing recorded is lost to a Ctrl-C
        summary = _fly(args, setup, loop)
        _write(Path(args.out), setup, loop, summary)
    return exit_status(summary["stopped_by"], loop.user_stop)


def run() -> None:
    """The ``ops-bench`` command: ``main``, then an exit that skips the interpreter's teardown."""
    status = main()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    # Everything is on disk: skip the teardown of JAX and the Channel Access threads, which takes
    # seconds on a loaded host, so a stopped run ends at once.
    os._exit(status)
