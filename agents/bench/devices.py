"""ophyd devices of an OPS bench (``agents.bench`` drives them), built from its mapping
(``agents.bench.mapping``)."""

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

# the mapping's names, as the runner, benchmarks.lab and the tests import them
from agents.bench.mapping import (  # noqa: F401
    SAFETY_DEFAULTS,
    SETTLE_RANGE_S,
    SETTLE_S,
    MappingError,
    check_mapping,
    load_mapping,
    sim_mapping,
)

log = logging.getLogger("agents.bench")


def monitored(sig):
    """The newest value of a monitored signal as its monitor callback left it (``get()`` without its
    connection checks and metadata handling: a control loop reads a dozen per step)."""
    return sig._readback


class RawMonitor:
    """An ophyd signal's PV followed by caproto's client directly instead of ophyd's monitor: each
    value lands on the signal as that monitor would leave it (``monitored``, ``.timestamp``), then
    ``hook(value=, timestamp=)`` runs, in caproto's receiving thread as the value is read off the
    socket (``hook`` must not block). ophyd's dispatcher thread, its per-value metadata handling and
    caproto's hand-off of each value to its callback thread, most of a Python client's time per
    frame, are skipped; alarm fields are not followed. Numeric PVs only; create after ``connect``,
    once per signal."""

    def __init__(self, sig):
        read_pv = sig._read_pv
        read_pv.clear_auto_monitor()  # ophyd's own monitor stops
        sig._auto_monitor = False  # and does not start again on a reconnection
        self.sig, self.hook = sig, None
        self._sub = read_pv._caproto_pv.subscribe(data_type="time")
        self._sub.add_callback(
            self._on_value
        )  # starts the subscription (and renews it on a reconnection)
        self._sub.process = (
            self._process
        )  # each response handled inline instead of queued to the callback thread

    def _process(self, response):
        self._sub.most_recent_response = response
        self._on_value(self._sub, response)

    @staticmethod
    def serves(sig) -> bool:
        """Whether caproto serves ``sig``'s monitor and its PV is numeric (not another control
        layer, not a fake signal, not a string)."""
        read_pv = getattr(sig, "_read_pv", None)
        pv = getattr(read_pv, "_caproto_pv", None)
        channel = getattr(pv, "channel", None)
        if (
            getattr(sig, "_auto_monitor", False) is not True
            or not hasattr(read_pv, "clear_auto_monitor")
            or channel is None
        ):
            return False
        from caproto import ChannelType

        return channel.native_data_type in (
            ChannelType.INT,
            ChannelType.FLOAT,
            ChannelType.LONG,
            ChannelType.DOUBLE,
        )

    def _on_value(self, sub, response):
        try:
            data = response.data
            value = data[0] if len(data) == 1 else data
            stamp = response.metadata.timestamp
            self.sig._readback, self.sig._metadata["timestamp"] = value, stamp
            if self.hook is not None:
                self.hook(value=value, timestamp=stamp)
        except Exception:  # caproto's executor would drop it unseen
            log.exception("monitor of PV %s failed", self.sig.pvname)


class RawWriter:
    """Setpoints written through caproto's client directly, every line's in one message per circuit:
    ophyd's ``put`` (value checks, connection wait, its own callbacks) and one send per PV are
    skipped. Floating-point PVs served by caproto only (``serves``); nothing waits for the IOC's
    confirmation, as with ``put``. The ophyd signals' setpoint caches are not updated (``Lines``
    keeps the setpoints sent)."""

    def __init__(self, sigs):
        self.pvs = [sig._write_pv._caproto_pv for sig in sigs]
        self.names = [sig.setpoint_pvname for sig in sigs]

    @staticmethod
    def serves(sig) -> bool:
        """Whether ``sig``'s setpoint PV is a floating-point PV that caproto serves (connected)."""
        channel = getattr(
            getattr(getattr(sig, "_write_pv", None), "_caproto_pv", None), "channel", None
        )
        if channel is None:
            return False
        from caproto import ChannelType

        return channel.native_data_type in (ChannelType.FLOAT, ChannelType.DOUBLE)

    def write(self, values) -> None:
        """Write ``values`` (one per PV, the PVs' units); a PV not connected stops the run
        (``SafetyStop``)."""
        circuits: dict = {}
        for pv, name, value in zip(self.pvs, self.names, values):
            channel, manager = pv.channel, pv.circuit_manager
            if channel is None or manager is None or not pv.connected:
                raise SafetyStop(f"lost connection to PV {name}")
            command = channel.write((float(value),), ioid=manager._ioid_counter(), notify=False)
            circuits.setdefault(id(manager), (manager, []))[1].append(command)
        for manager, commands in circuits.values():
            manager.send(*commands, extra={"pv": self.names})


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

    def arm(self, raw: RawMonitor | None = None):
        """Start following the counter (after connection; through ``raw`` when given); the frame
        there now counts as new."""
        self._latest, self._used, self._stamp = self.tick.get(), None, self.tick.timestamp
        self.tick_time = time.perf_counter()
        if raw is not None:
            raw.hook = self._on_tick
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


class SafetyStop(RuntimeError):
    """The watchdog stopped the run; the message is its reason."""


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
        self._lines, self.units_per_wl = lines, units_per_wl
        self.max_step_wl, self.soft_range = max_step_wl, np.asarray(soft_range_wl, float)
        self.wrap_wl = wrap_wl
        self.locked: str | None = None
        self._sent = None
        self.shift = np.zeros(
            len(lines)
        )  # the last move's wrap shift (wl, one per line; 0 where not wrapped)
        self.raw: RawWriter | None = None  # set by ``arm`` where caproto serves every setpoint
        super().__init__(prefix, **kwargs)

    @property
    def position(self) -> np.ndarray:
        """The setpoints (wl): the last ones written, else as read from the PVs."""
        if self._sent is None:
            return (
                np.array([line.setpoint.get() for line in self._lines], float) / self.units_per_wl
            )
        return self._sent.copy()

    def wrap(self, positions) -> np.ndarray:
        """The shift (wl, one per line) that takes ``positions`` within ``wrap_wl`` of a soft limit
        one ``wrap_wl`` back towards the middle (zeros without ``wrap_wl``)."""
        if self.wrap_wl is None:
            return np.zeros(len(self._lines))
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
        if self.raw is not None:
            self.raw.write(out * self.units_per_wl)
        else:
            for line, value in zip(self._lines, out):
                line.setpoint.put(float(value) * self.units_per_wl)
        self._sent, self.shift = out, shift
        return out.copy()


def _device_class(mapping: dict):
    """The bench's ``Device`` subclass: lines ``line1..lineN`` (+ ``length1..``), ``detector``,
    ``evaluation``."""
    comps = {}
    for i, line in enumerate(mapping["lines"], 1):
        comps[f"line{i}"] = Cpt(DelayLine, "", sp_pv=line["setpoint"], rbv_pv=line["readback"])
        if "length" in line:
            comps[f"length{i}"] = Cpt(LengthReadout, "", len_pv=line["length"])
    d = mapping["detector"]
    comps["detector"] = Cpt(
        Detector,
        "",
        power_pv=d["power"],
        trace_pv=d["trace"],
        tick_pv=d["tick"],
        timeout=mapping["safety"]["stale_s"],
    )
    ev = mapping["evaluation"]
    if ev:
        comps["evaluation"] = Cpt(Evaluation, "", pmax_pv=ev["p_pmax"], pbest_pv=ev["p_pbest"])
    if mapping["advance"]:
        comps["advance"] = Cpt(EpicsSignal, mapping["advance"], kind="omitted")
    return type("OPSBenchDevice", (Device,), comps)


def make_bench(mapping: dict, device_class=None, name: str = "bench"):
    """``(bench device, Lines)`` for a validated mapping. ``device_class(mapping) -> class`` may
    wrap the device class (``ophyd.sim.make_fake_device`` in tests). The first bench of a process
    sets ophyd's Channel Access timeouts to the mapping's ``connect_s``."""
    from ophyd.signal import EpicsSignalBase

    try:
        s = mapping["safety"]["connect_s"]
        EpicsSignalBase.set_defaults(timeout=s, connection_timeout=s)
    except RuntimeError:  # signals exist already in this process: their timeouts stay
        pass
    cls = _device_class(mapping)
    if device_class is not None:
        cls = device_class(cls)
    bench = cls("", name=name)
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


def signals(bench) -> dict:
    """Every Channel Access signal of ``bench`` by its PV name."""
    out = {}
    for walk in bench.walk_signals():
        sig = walk.item
        if hasattr(sig, "pvname"):
            out[sig.pvname] = sig
            if getattr(sig, "setpoint_pvname", sig.pvname) != sig.pvname:
                out[sig.setpoint_pvname] = sig
    return out


def arm(bench, lines: Lines | None = None) -> None:
    """Follow ``bench`` (after ``connect``): its monitored PVs through ``RawMonitor`` where caproto
    serves them (ophyd's monitors elsewhere), the detector's frame counter from now on
    (``Detector.arm``); ``lines`` (its ``Lines``) write through ``RawWriter`` where caproto serves
    every setpoint (ophyd's ``put`` elsewhere)."""
    if not hasattr(bench, "raw_monitors"):  # once: a second call keeps the first's monitors
        bench.raw_monitors = {
            w.item.name: RawMonitor(w.item)
            for w in bench.walk_signals()
            if RawMonitor.serves(w.item)
        }
    bench.detector.arm(bench.raw_monitors.get(bench.detector.tick.name))
    setpoints = [line.setpoint for line in lines._lines] if lines is not None else []
    if setpoints and all(RawWriter.serves(sig) for sig in setpoints):
        lines.raw = RawWriter(setpoints)


def connect(bench, timeout: float) -> None:
    """Wait for every PV; a ``MappingError`` names the ones that did not answer within ``timeout``
    s."""
    sigs = signals(bench)
    deadline = time.monotonic() + timeout
    for sig in sigs.values():
        try:
            sig.wait_for_connection(timeout=max(deadline - time.monotonic(), 0.05))
        except TimeoutError:
            pass
    missing = sorted(name for name, sig in sigs.items() if not sig.connected)
    if missing:
        raise MappingError(
            f"no answer from PV(s) {missing} within {timeout:g} s (is the IOC running, "
            f"and EPICS_CA_ADDR_LIST / EPICS_CA_SERVER_PORT set to reach it?)"
        )


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


def disconnect(bench) -> None:
    """Stop following ``bench``'s PVs and close the Channel Access circuits (a clean exit)."""
    import ophyd

    bench.destroy()
    if ophyd.cl.name == "caproto":
        from caproto.threading.pyepics_compat import PV

        previous = threading.excepthook
        threading.excepthook = _closing_socket_hook(previous)
        try:
            PV.default_context().disconnect()  # joins caproto's threads: none outlives the hook
        finally:
            threading.excepthook = previous


def _closing_socket_hook(previous):
    """A ``threading.excepthook`` that drops the network error a caproto thread may raise while its
    socket is being closed under it (its search-retry thread sends between the close and its join);
    others go on to ``previous``."""

    def hook(args) -> None:
        if isinstance(args.exc_value, OSError) and _raised_in_caproto(
            args.exc_traceback
        ):  # CaprotoNetworkError too
            log.debug(
                "closing Channel Access: %s in thread %s",
                args.exc_value,
                args.thread and args.thread.name,
            )
            return
        previous(args)

    return hook


def _raised_in_caproto(tb) -> bool:
    """Whether a frame of traceback ``tb`` is caproto's."""
    while tb is not None:
        if tb.tb_frame.f_globals.get("__name__", "").startswith("caproto."):
            return True
        tb = tb.tb_next
    return False
