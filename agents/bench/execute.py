"""The plan's run on the bench: a ``RunEngine`` runs ``agents.bench.loop.control_plan``, its
documents streamed to ``documents.jsonl`` (``agents.bench.documents``), Ctrl-C and SIGTERM handled
by ``user_stops``, an expected stop's noise kept off stderr (``quiet``)."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from pathlib import Path

from agents.bench import documents
from agents.bench.transport import SafetyStop
from agents.bench.loop import USER_STOP, Loop, control_plan
from ops_jax.cli.progress import stop_signals

# Python's thread switch interval during a run (s; 5 ms by default): a frame's arrival wakes the
# loop, which then waits at most this long for the interpreter lock held by another thread (the
# RunEngine writing out a page)
SWITCH_S = 0.0005


QUIET_LOGGERS = (
    "bluesky",
    "caproto.circ",
    "caproto.ch",
)  # filtered by _QuietStop (``quiet``) from connection to disconnection


class _QuietStop(logging.Filter):
    """Drops what an expected stop prints besides the runner's line: the RunEngine's "Run aborted"
    traceback of a watchdog stop, and caproto's notes on a closing circuit or channel (the watchdog
    names the lost PV)."""

    def filter(self, record) -> bool:
        if record.name.startswith("caproto"):
            return False
        return not (record.exc_info and isinstance(record.exc_info[1], SafetyStop))


@contextlib.contextmanager
def quiet():
    """``_QuietStop`` on ``QUIET_LOGGERS`` while it lasts (from connection to disconnection)."""
    drop = _QuietStop()
    for name in QUIET_LOGGERS:
        logging.getLogger(name).addFilter(drop)
    try:
        yield
    finally:
        for name in QUIET_LOGGERS:
            logging.getLogger(name).removeFilter(drop)


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

    with stop_signals(stop):
        yield


def run_plan(loop: Loop, md: dict, out: Path, shown=None) -> float:
    """Run the plan, documents streamed to ``out/documents.jsonl`` (and to ``shown``, a document
    callback, where given), Ctrl-C and SIGTERM as ``user_stops`` says; returns the seconds it
    ran."""
    from bluesky import RunEngine

    RE = RunEngine({}, context_managers=[])  # its own Ctrl-C handling left out: user_stops
    RE.subscribe(documents.writer(out))
    if shown is not None:
        RE.subscribe(shown)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_S)
    try:
        with user_stops(loop):
            RE(control_plan(loop, md))
    except Exception as exc:  # the watchdog (SafetyStop) or a failure: no move, keep the record
        if loop.stop_reason is None:
            loop.trip(f"error: {exc}")
    finally:
        loop.ended = True
        sys.setswitchinterval(switch)
    return time.perf_counter() - loop.t0 if loop.t0 is not None else 0.0
