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

``python -m agents.bench template --out FILE`` writes a mapping to start from,
``python -m agents.bench check --mapping FILE`` reads every PV it names once
(``agents.bench.template``).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np

from agents import api as base
from agents.bench import defaults, learning as bench_learn, report, template
from agents.bench.devices import (
    SETTLE_RANGE_S,
    MappingError,
    SafetyStop,
    arm,
    check_mapping,
    connect,
    disconnect,
    load_mapping,
    make_bench,
    sim_mapping,
)
from agents.bench.loop import (
    USER_STOP,
    Loop,
    control_plan,
    load_controller,  # noqa: F401
)
from agents.cli import parse_set
from agents.io import dumps_json, write_json_atomic
from ops_jax import lock
from ops_jax.cli import runtime
from ops_jax.cli.progress import exit_interrupted, keep_ctrl_c

# Python's thread switch interval during a run (s; 5 ms by default): a frame's arrival wakes the
# loop, which then waits at most this long for the interpreter lock held by another thread (the
# RunEngine writing out a page)
SWITCH_S = 0.0005
# the watchdog's (safety) stop; the user's: 128 + the signal (130 for Ctrl-C, 143 for SIGTERM)
EXIT_WATCHDOG = 3


def say(line: str) -> None:
    """A line of the runner's on stderr."""
    print(f"agents.bench.runner: {line}", file=sys.stderr, flush=True)


def _stopped_by(loop: Loop) -> str:
    """How the run ended: ``"time"``, ``"steps"``, ``"user"`` (``USER_STOP``) or the watchdog's
    reason."""
    user = USER_STOP if loop.user_stop else None
    return (
        loop.stop_reason
        or user
        or ("steps" if 0 < loop.max_steps <= len(loop.rec["time_s"]) else "time")
    )


def summarize(loop: Loop, controller: str, elapsed: float) -> dict:
    """``summary.json``: the score (the last 80 % of the run: of its time, in lockstep of its
    frames, so that a lockstep score does not depend on the host's pace), achieved rates, latencies,
    how it ended; the lock figures of P / P_best over the whole run at its achieved rate
    (``ops_jax.lock.trace_json``)."""
    rec = {k: np.asarray(v, float) for k, v in loop.rec.items()}
    steps, t = len(rec["time_s"]), rec["time_s"]
    if loop.advance is not None and steps:
        tail = rec["tick"] >= rec["tick"][0] + 0.2 * (rec["tick"][-1] - rec["tick"][0])
    else:
        tail = t >= 0.2 * elapsed
    pct = lambda v, q: float(np.percentile(v, q)) if v.size else float("nan")
    mean = lambda v: float(np.mean(v)) if v.size else float("nan")
    frames = float(rec["tick"][-1] - rec["tick"][0]) if steps > 1 else 0.0
    return {
        "controller": controller,
        "stopped_by": _stopped_by(loop),
        "watchdog_time": loop.stopped_at,
        "steps": steps,
        "seconds": elapsed,
        "rate_hz": steps / elapsed if elapsed > 0 else 0.0,
        "frames_per_step": frames / (steps - 1) if steps > 1 else float("nan"),
        "probes_per_step": loop.agent.probes,
        "latency_ms_p50": pct(rec["latency_ms"], 50),
        "latency_ms_p99": pct(rec["latency_ms"], 99),
        "latency_ms_max": float(rec["latency_ms"].max())
        if rec["latency_ms"].size
        else float("nan"),
        "decide_ms_p50": pct(rec["decide_ms"], 50),
        "decide_ms_p99": pct(rec["decide_ms"], 99),
        "cpu_ms_per_step": 1e3 * (time.process_time() - loop.cpu0) / steps
        if steps
        else float("nan"),
        "p_over_pbest_mean": mean(rec["p_pbest"][tail]),
        "p_over_pmax_mean": mean(rec["p_pmax"][tail]),
        "clipped_moves": int(loop.lines.clipped.get()),
        "wrapped_moves": int(loop.lines.wraps.get()),
        "actions_cut": loop.actions_cut,
        **lock.trace_json(rec["p_pbest"], steps / elapsed if elapsed > 0 and steps else None),
    }


def _pyplot():
    """matplotlib's pyplot on the Agg backend (imported before a run: the end of a run is kept
    short)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot(path: Path, loop: Loop, title: str, ratio=None, rate_hz=None) -> None:
    """P / P_max and P / P_best against time; ``ratio``: (times (s), gradient steps per env step) on
    a second axis; beside it the PSD of P / P_best after lock at ``rate_hz`` (control steps/s;
    ``ops_jax.lock``)."""
    plt = _pyplot()
    t = np.asarray(loop.rec["time_s"])
    fig, (ax, psd_ax) = plt.subplots(1, 2, figsize=(11, 3.5), width_ratios=(3, 2))
    _draw_psd(psd_ax, loop.rec["p_pbest"], rate_hz)
    ax.plot(t, loop.rec["p_pbest"], lw=1, label="P / P_best")
    ax.plot(t, loop.rec["p_pmax"], lw=1, alpha=0.7, label="P / P_max")
    ax.set(xlabel="time (s)", ylabel="stacked power", ylim=(0, 1.05), title=title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    if ratio is not None:
        twin = ax.twinx()
        twin.plot(*ratio, color="C3", lw=1)
        twin.set_ylabel("gradient steps per env step", color="C3")
        twin.set_ylim(bottom=0)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _draw_psd(ax, trace, rate_hz) -> None:
    """The PSD after lock of ``trace`` on ``ax``, or a note that the run is too short to score."""
    if len(trace) < lock.MIN_STEPS:
        ax.text(0.5, 0.5, "too short to score a lock", transform=ax.transAxes, ha="center")
        return
    lock.draw_psd(ax, lock.lock_figures(trace, rate_hz or None), label="P / P_best")


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m agents.bench",
        description=__doc__.split("\n\n")[0],
        epilog="python -m agents.bench template --out FILE: a mapping to start from; python -m "
        "agents.bench check --mapping FILE: read every PV it names once (each with --help)",
    )
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
        default=bench_learn.CHECKPOINT_EVERY,
        metavar="M",
        help="--learn: env steps between checkpoints",
    )
    ap.add_argument(
        "--catch-up-s",
        type=float,
        default=bench_learn.CATCH_UP_S,
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
    return ap


def _setup(args):
    """(mapping, Agent (or ``bench_learn.Learning``), env_config, action scale, window) from the
    arguments; raises what is wrong."""
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
    if args.cpu is not None:  # before JAX and its thread pools start
        pin(args.cpu)
    elif (
        not args.learn
    ):  # a controller's calls are small: XLA's pools one thread each (on one core they are)
        runtime.start_single_threaded()
    checkpoint = bench_learn.check_args(args) if args.learn else None
    saved = args.controller not in ("spgd", "physics", None)
    if saved and not Path(args.controller).is_dir():
        raise ValueError(
            "--controller must be spgd, physics or a folder written by agents.save, got "
            f"{args.controller!r}"
        )
    stages = args.stages or (
        bench_learn.default_stages(args, checkpoint)
        if args.learn
        else base.load(args.controller).env_config.get("stages", 5)
        if saved
        else 5
    )
    mapping = (
        load_mapping(args.mapping)
        if args.mapping
        else sim_mapping(args.prefix, stages, args.lockstep, lengths=not args.no_lengths)
    )
    for key, value in (("stale_s", args.stale_s), ("wrap_wl", args.wrap)):
        if value is not None:
            mapping["safety"] = {**(mapping.get("safety") or {}), key: value}
    if args.settle_s is not None:
        low, high = SETTLE_RANGE_S
        if not low <= args.settle_s <= high:
            raise ValueError(f"--settle-s must be in [{low:g}, {high:g}] s, got {args.settle_s}")
        mapping["detector"] = {**mapping["detector"], "settle_s": args.settle_s}
    args.set, mapping, chosen = defaults.choose(args, check_mapping(mapping), checkpoint)
    # the run's first line: what was chosen by default and why
    then = "the controller's compilation, then the connection to the bench"
    say(f"starting: chosen: {chosen}; now {then}" if chosen else f"starting: {then}")
    if args.learn:
        return (
            mapping,
            *bench_learn.setup(args, mapping, checkpoint, parse_set(args.env), parse_set(args.set)),
        )
    # A controller's calls are small and each waits for its result: run them inline, without the
    # hand-off to XLA's dispatch thread (set before JAX's first computation in the process; a
    # learning run keeps it)
    import jax

    jax.config.update("jax_cpu_enable_async_dispatch", False)
    agent, env_config, scale, window = load_controller(
        args.controller,
        mapping,
        parse_set(args.env),
        parse_set(args.set),
        args.seed,
        None if args.trim is None else parse_set(args.trim),
    )
    return mapping, agent, env_config, scale, window


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


def main(argv=None) -> int:
    keep_ctrl_c()
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    if argv[:1] and argv[0] in template.COMMANDS:  # a template mapping, or a check of one
        return template.main(argv)
    args = parser().parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s: %(message)s"
    )
    out = Path(args.out)
    try:  # a Ctrl-C before the run starts: one line, nothing recorded
        try:
            mapping, agent, env_config, scale, window = _setup(args)
            _pyplot()
            bench, lines = make_bench(mapping)
            connect(bench, mapping["safety"]["connect_s"])
        except (MappingError, ValueError, TypeError, FileNotFoundError) as exc:
            say(str(exc))
            return 2
        out.mkdir(parents=True, exist_ok=True)
        if args.resume:  # a resumed learning run appends its documents
            bench_learn.mend_documents(out / "documents.jsonl")
        else:
            (out / "documents.jsonl").unlink(missing_ok=True)
        arm(bench, lines)
        learning, label = (
            (agent, f"learning {args.learn}") if args.learn else (None, args.controller)
        )
        steps = args.steps - learning.counts.env_steps if learning else args.steps
        loop = Loop(bench, lines, mapping, agent, scale, window, args.seconds, args.rate, steps)
        loop.watch()
        say("running; Ctrl-C stops the run after the current step")
    except KeyboardInterrupt:
        kept = "; its checkpoint as it was" if args.resume else ""
        exit_interrupted(f"stopped while starting; nothing recorded in {out}{kept}")
    md = {
        "controller": label,
        "controller_env": env_config,
        "hyper": parse_set(args.set),
        "trim": None if args.trim is None else parse_set(args.trim),
        "learning": learning and learning.describe(),
        "seed": args.seed,
        "rate_hz": args.rate,
        "mapping": mapping,
        "plan_name": "agents.bench",
    }
    with user_stops(loop):  # from here on nothing recorded is lost to a Ctrl-C
        if learning:
            learning.begin(steps, lambda exc: loop.trip(f"error: the learner failed: {exc!r}"))
        quiet = _QuietStop()
        for name in QUIET_LOGGERS:
            logging.getLogger(name).addFilter(quiet)
        # a controller's progress line (a learner shows its own)
        shown = None if learning else report.RunProgress(label, steps, lines)
        try:
            elapsed = _run(loop, md, out, shown)
            # the learner's steps while the loop ran end here (then its catch-up, its last
            # checkpoint)
            if learning:
                learning.end(args.catch_up_s if _stopped_by(loop) in ("steps", "time") else 0.0)
        finally:
            if shown is not None:
                shown.close()
            disconnect(bench)
            for name in QUIET_LOGGERS:
                logging.getLogger(name).removeFilter(quiet)
        summary = summarize(loop, label, elapsed)
        if learning:
            learning.finish()
            summary.update(learning.report())
        write_json_atomic(out / "summary.json", summary)
        stopped = summary["stopped_by"] not in ("time", "steps", USER_STOP)
        if stopped:
            say(f"stopped by the watchdog: {summary['stopped_by']}")
        plot(
            out / "power.png",
            loop,
            f"{label} on the bench, {summary['rate_hz']:.0f} steps/s",
            learning and learning.ratio_series(loop.t0),
            rate_hz=summary["rate_hz"],
        )
        print(report.readable(summary, out), flush=True)
    if stopped:
        return EXIT_WATCHDOG
    return 128 + (int(loop.user_stop) or signal.SIGINT) if summary["stopped_by"] == USER_STOP else 0


QUIET_LOGGERS = (
    "bluesky",
    "caproto.circ",
    "caproto.ch",
)  # filtered by _QuietStop from connection to disconnection


class _QuietStop(logging.Filter):
    """Drops what an expected stop prints besides the runner's line: the RunEngine's "Run aborted"
    traceback of a watchdog stop, and caproto's notes on a closing circuit or channel (the watchdog
    names the lost PV)."""

    def filter(self, record) -> bool:
        if record.name.startswith("caproto"):
            return False
        return not (record.exc_info and isinstance(record.exc_info[1], SafetyStop))


def _writer(out: Path):
    """The document callback: every document a line of ``out/documents.jsonl`` as it comes
    (bluesky's ``JSONLinesWriter``), an event page as its events."""
    from bluesky.callbacks.json_writer import JSONLinesWriter
    from event_model import sanitize_doc, unpack_event_page

    writer = JSONLinesWriter(str(out), "documents.jsonl")

    def write(name, doc):
        if name != "event_page":
            return writer(name, sanitize_doc(doc))
        with open(
            out / "documents.jsonl", "a"
        ) as f:  # a page (plain types already) at once, one open per page
            f.writelines(
                dumps_json({"name": "event", "doc": e}, indent=None) + "\n"
                for e in unpack_event_page(doc)
            )

    return write


@contextlib.contextmanager
def user_stops(loop: Loop):
    """Ctrl-C and SIGTERM while the run lasts: the first ends it after the current step (a line on
    stderr says so), a second at once (``USER_STOP``, no further move); once the plan has returned,
    while what the run recorded is written, each is answered with a line and otherwise ignored. The
    previous handlers are restored after."""

    def stop(signum, frame):
        if loop.ended:
            os.write(2, b"agents.bench.runner: the run has ended; writing what it recorded\n")
        elif loop.user_stop:
            loop.trip(USER_STOP)
        else:
            loop.user_stop = signum  # (truthy) the signal that ended the run: its exit status
            os.write(2, b"agents.bench.runner: stopping after the current step (again: at once)\n")

    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def _run(loop: Loop, md: dict, out: Path, shown=None) -> float:
    """Run the plan, documents streamed to ``out/documents.jsonl`` (and to ``shown``, a document
    callback, where given), Ctrl-C and SIGTERM as ``user_stops`` says; returns the seconds it
    ran."""
    from bluesky import RunEngine

    RE = RunEngine({}, context_managers=[])  # its own Ctrl-C handling left out: user_stops
    RE.subscribe(_writer(out))
    if shown is not None:
        RE.subscribe(shown)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_S)
    try:
        with user_stops(loop):
            RE(control_plan(loop, md))
    except (
        Exception
    ) as exc:  # the watchdog (SafetyStop) or a failure: no further move, keep what was recorded
        if loop.stop_reason is None:
            loop.trip(f"error: {exc}")
    finally:
        loop.ended = True
        sys.setswitchinterval(switch)
    return time.perf_counter() - loop.t0 if loop.t0 is not None else 0.0


def run() -> None:
    """The ``ops-bench`` command: ``main``, then an exit that skips the interpreter's teardown."""
    status = main()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    # Everything is on disk: skip the teardown of JAX and the Channel Access threads, which takes
    # seconds on a loaded host, so a stopped run ends at once.
    os._exit(status)
