"""ophyd devices of an OPS bench (``agents.bench`` drives them), built from its mapping
(``agents.bench.mapping``) on ophyd's public API. The PVs a step reads are followed by the bench's
transport (``bench.transport``, ``agents.bench.transport``), not by ophyd's monitors, unless that
transport is ophyd's own."""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np

from ophyd import Component as Cpt
from ophyd import Device, EpicsSignal, EpicsSignalRO, Signal
from ophyd import FormattedComponent as FCpt
from ophyd.status import Status

from agents.bench import transport as transports

from agents.bench.transport import SafetyStop

log = logging.getLogger("agents.bench")


class DelayLine(Device):
    """One delay line: a setpoint (written) and its readback. Neither is monitored nor read at every
    step (the setpoints sent are recorded by the runner): a bench's monitor traffic is what a
    Python client pays for most."""

    setpoint = FCpt(EpicsSignal, "{sp_pv}", kind="config")
    readback = FCpt(EpicsSignalRO, "{rbv_pv}", kind="config")

    def __init__(self, prefix="", *, sp_pv, rbv_pv, **kwargs):
        self.sp_pv, self.rbv_pv = sp_pv, rbv_pv
        super().__init__(prefix, **kwargs)


class LengthReadout(Device):
    """A delay line's length sensor (offset from the optimum, the PV's units)."""

    value = FCpt(EpicsSignalRO, "{len_pv}", kind="hinted", auto_monitor=True)

    def __init__(self, prefix="", *, len_pv, **kwargs):
        self.len_pv = len_pv
        super().__init__(prefix, **kwargs)


class Detector(Device):
    """The detector's power, the oscilloscope trace and the frame counter (a new value: a complete
    new frame). ``trigger()`` completes with a frame not used before and stamped no earlier than the
    last ``after``, or fails after ``timeout`` s."""

    power = FCpt(EpicsSignalRO, "{power_pv}", kind="hinted", auto_monitor=True)
    trace = FCpt(EpicsSignalRO, "{trace_pv}", kind="normal", auto_monitor=True)
    tick = FCpt(EpicsSignalRO, "{tick_pv}", kind="normal", auto_monitor=True)

    def __init__(self, prefix="", *, power_pv, trace_pv, tick_pv, timeout=0.5, **kwargs):
        self.power_pv, self.trace_pv, self.tick_pv = power_pv, trace_pv, tick_pv
        self.timeout = timeout
        self._pending: Status | None = None
        self._lock = (
            threading.Condition()
        )  # guards the counters; notified on every frame and on a failure
        self._failure: Exception | None = None
        self._latest = self._used = None  # the newest counter value seen, the last one used
        self._stamp, self._not_before = (
            0.0,
            -math.inf,
        )  # the newest frame's time stamp, the earliest one usable
        self.tick_time = 0.0  # time.perf_counter() when the newest frame arrived
        super().__init__(prefix, **kwargs)

    def arm(self, feed=None):
        """Start following the counter (after connection; through ``feed``, a transport, when
        given, else the signal's own monitor); the frame there now counts as new."""
        if feed is not None:
            self._latest, self._stamp = feed.value(self.tick_pv), feed.stamp(self.tick_pv)
        else:
            self._latest, self._stamp = self.tick.get(), self.tick.timestamp
        self._used, self.tick_time = None, time.perf_counter()
        if feed is not None:
            feed.on_update(self.tick_pv, self._on_tick)
        else:
            self.tick.subscribe(self._on_tick, run=False)

    def _usable(self) -> bool:
        return self._latest != self._used and self._stamp >= self._not_before

    def _on_tick(self, value=None, timestamp=None, **kwargs):
        with self._lock:
            self._latest, self.tick_time = value, time.perf_counter()
            self._stamp = time.time() if timestamp is None else timestamp
            pending = None
            if self._pending is not None and self._usable():
                pending, self._pending, self._used = self._pending, None, value
            self._lock.notify_all()
        if pending is not None and not pending.done:
            pending.set_finished()

    def use(self):
        """Count the newest frame as used: the next ``trigger`` waits for a newer one."""
        with self._lock:
            self._used = self._latest

    def after(self, stamp: float):
        """Frames stamped before ``stamp`` (time.time(), s) no longer count: the next ``trigger``
        waits for one acquired at or after it (a frame that shows a move written before
        ``stamp``)."""
        with self._lock:
            self._used, self._not_before = self._latest, stamp

    def trigger(self):
        """Completes with the newest usable frame (at once if it has arrived)."""
        status = Status(obj=self, timeout=self.timeout)
        with self._lock:
            fresh = self._usable()
            if fresh:
                self._used = self._latest
            else:
                self._pending = status
        if fresh:
            status.set_finished()
        return status

    def wait(self, timeout: float) -> bool:
        """Block until a usable frame has arrived and count it as used (``trigger`` without a
        status, for a loop in its own thread); False after ``timeout`` s without one; raises the
        failure of ``fail``."""
        deadline = time.monotonic() + timeout
        with self._lock:
            while not self._usable():
                left = deadline - time.monotonic()
                if self._failure is not None:
                    raise self._failure
                if left <= 0:
                    return False
                self._lock.wait(left)
            if self._failure is not None:
                raise self._failure
            self._used = self._latest
            return True

    def fail(self, exc: Exception):
        """Fail the acquisition being waited for and every later ``wait`` (the watchdog's stop)."""
        with self._lock:
            pending, self._pending, self._failure = self._pending, None, exc
            self._lock.notify_all()
        if pending is not None and not pending.done:
            pending.set_exception(exc)


class Evaluation(Device):
    """The simulator's true P / P_max and P / P_best (recorded, never shown to a controller)."""

    p_pmax = FCpt(EpicsSignalRO, "{pmax_pv}", kind="hinted", auto_monitor=True)
    p_pbest = FCpt(EpicsSignalRO, "{pbest_pv}", kind="hinted", auto_monitor=True)

    def __init__(self, prefix="", *, pmax_pv, pbest_pv, **kwargs):
        self.pmax_pv, self.pbest_pv = pmax_pv, pbest_pv
        super().__init__(prefix, **kwargs)


class Lines(Device):
    """The delay lines moved together: ``set(targets)`` (wl, one per line) clips each move to
    ``max_step_wl``, takes a line that would come within ``wrap_wl`` of a soft limit one ``wrap_wl``
    back (when given), clips the result to the soft range, then writes every setpoint without
    waiting; clipped moves and wraps are counted, clipped moves logged. After ``lock()`` (the
    watchdog) nothing is written."""

    clipped = Cpt(Signal, value=0, kind="normal")
    wraps = Cpt(Signal, value=0, kind="normal")

    def __init__(
        self,
        prefix="",
        *,
        lines: list,
        units_per_wl: float,
        max_step_wl: float,
        soft_range_wl,
        wrap_wl: float | None = None,
        **kwargs,
    ):
        self.delay_lines, self.units_per_wl = lines, units_per_wl
        self.max_step_wl, self.soft_range = max_step_wl, np.asarray(soft_range_wl, float)
        self.wrap_wl = wrap_wl
        self.locked: str | None = None
        self._sent = None
        self.shift = np.zeros(
            len(lines)
        )  # the last move's wrap shift (wl, one per line; 0 where not wrapped)
        self.writer = None  # the transport that writes the setpoints (``arm``); else ``put``
        super().__init__(prefix, **kwargs)

    @property
    def position(self) -> np.ndarray:
        """The setpoints (wl): the last ones written, else as read from the PVs."""
        if self._sent is None:
            return (
                np.array([line.setpoint.get() for line in self.delay_lines], float)
                / self.units_per_wl
            )
        return self._sent.copy()

    def wrap(self, positions) -> np.ndarray:
        """The shift (wl, one per line) that takes ``positions`` within ``wrap_wl`` of a soft limit
        one ``wrap_wl`` back towards the middle (zeros without ``wrap_wl``)."""
        if self.wrap_wl is None:
            return np.zeros(len(self.delay_lines))
        low, high = self.soft_range[:, 0], self.soft_range[:, 1]
        return self.wrap_wl * (
            (positions < low + self.wrap_wl).astype(float) - (positions > high - self.wrap_wl)
        )

    def safe(self, targets) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(targets within the limits (wl), which lines were clipped, the wrap shift (wl, 0 where
        not wrapped))."""
        targets = np.asarray(targets, float)
        here = self.position
        step = np.clip(targets - here, -self.max_step_wl, self.max_step_wl)
        shift = self.wrap(here + step)
        out = np.clip(here + step + shift, self.soft_range[:, 0], self.soft_range[:, 1])
        return out, ~np.isclose(out, targets + shift, rtol=0, atol=1e-12), shift

    def lock(self, reason: str):
        self.locked = reason

    def set(self, targets):
        self.move(targets)
        status = Status(obj=self)
        status.set_finished()
        return status

    def move(self, targets) -> np.ndarray:
        """``set`` without a status: the setpoints sent (wl)."""
        if self.locked:
            raise SafetyStop(f"no move after the watchdog's stop ({self.locked})")
        out, clipped, shift = self.safe(targets)
        if shift.any():
            self.wraps.put(self.wraps.get() + int(np.count_nonzero(shift)))
        if clipped.any():
            self.clipped.put(self.clipped.get() + int(clipped.sum()))
            log.warning(
                "move clipped to the safety limits: lines %s, asked %s wl, sent %s wl",
                (np.flatnonzero(clipped) + 1).tolist(),
                np.round(targets, 6).tolist(),
                np.round(out, 6).tolist(),
            )
        if self.writer is not None:
            self.writer.write(out * self.units_per_wl)
        else:
            for line, value in zip(self.delay_lines, out):
                line.setpoint.put(float(value) * self.units_per_wl)
        self._sent, self.shift = out, shift
        return out.copy()


def _on_demand(cls):
    """``cls`` with its monitored signals read on demand instead (no monitor of ophyd's: the
    transport follows their PVs)."""
    comps = {}
    for attr in cls.component_names:
        cpt = getattr(cls, attr)
        if cpt.kwargs.get("auto_monitor"):
            kwargs = {**cpt.kwargs, "auto_monitor": False}
            comps[attr] = FCpt(cpt.cls, cpt.suffix, kind=cpt.kind, **kwargs)
    return type(cls.__name__, (cls,), comps)


def _device_class(mapping: dict, monitor: bool = True):
    """The bench's ``Device`` subclass: lines ``line1..lineN`` (+ ``length1..``), ``detector``,
    ``evaluation``; ``monitor`` False: their readings without ophyd's monitors (``_on_demand``)."""
    kinds = [LengthReadout, Detector, Evaluation]
    length, detector, evaluation = kinds if monitor else map(_on_demand, kinds)
    comps = {}
    for i, line in enumerate(mapping["lines"], 1):
        comps[f"line{i}"] = Cpt(DelayLine, "", sp_pv=line["setpoint"], rbv_pv=line["readback"])
        if "length" in line:
            comps[f"length{i}"] = Cpt(length, "", len_pv=line["length"])
    d = mapping["detector"]
    comps["detector"] = Cpt(
        detector,
        "",
        power_pv=d["power"],
        trace_pv=d["trace"],
        tick_pv=d["tick"],
        timeout=mapping["safety"]["stale_s"],
    )
    ev = mapping["evaluation"]
    if ev:
        comps["evaluation"] = Cpt(evaluation, "", pmax_pv=ev["p_pmax"], pbest_pv=ev["p_pbest"])
    if mapping["advance"]:
        comps["advance"] = Cpt(EpicsSignal, mapping["advance"], kind="omitted")
    return type("OPSBenchDevice", (Device,), comps)


def make_bench(mapping: dict, device_class=None, name: str = "bench", transport: str | None = None):
    """``(bench device, Lines)`` for a validated mapping, its transport (``transport``, else the
    default: ``agents.bench.transport.chosen``) in ``bench.transport``, to be opened by ``arm``.
    ``device_class(mapping) -> class`` may wrap the device class (``ophyd.sim.make_fake_device`` in
    tests). ophyd's control layer follows the transport; the first bench of a process sets ophyd's
    Channel Access timeouts to the mapping's ``connect_s``."""
    from ophyd.signal import EpicsSignalBase

    kind, s = transports.chosen(transport), mapping["safety"]["connect_s"]
    transports.use_control_layer(kind)
    try:
        EpicsSignalBase.set_defaults(timeout=s, connection_timeout=s)
    except RuntimeError:  # signals exist already in this process: their timeouts stay
        pass
    feed = transports.make(kind, s)
    cls = _device_class(mapping, monitor=not feed.follows_itself)
    if device_class is not None:
        cls = device_class(cls)
    with transports.repeater_start_quiet():  # the signals' channels: libca's first
        bench = cls("", name=name)
    bench.transport = feed
    lines = [getattr(bench, f"line{i}") for i in range(1, len(mapping["lines"]) + 1)]
    s = mapping["safety"]
    mover = Lines(
        "",
        name="lines",
        lines=lines,
        units_per_wl=mapping["units_per_wl"],
        max_step_wl=s["max_step_wl"],
        soft_range_wl=s["soft_range_wl"],
        wrap_wl=s["wrap_wl"],
    )
    return bench, mover


class Control(Device):
    """What the controller did in a step (software signals, recorded in the step's event)."""

    action = Cpt(Signal, value=np.zeros(1), kind="normal")
    setpoint_wl = Cpt(Signal, value=np.zeros(1), kind="normal")
    probe_power = Cpt(Signal, value=np.zeros(0), kind="normal")
    latency_ms = Cpt(Signal, value=0.0, kind="hinted")

    def put(self, action, setpoint_wl, probe_power, latency_ms):
        self.action.put(np.asarray(action, float))
        self.setpoint_wl.put(np.asarray(setpoint_wl, float))
        self.probe_power.put(np.asarray(probe_power, float))
        self.latency_ms.put(float(latency_ms))
