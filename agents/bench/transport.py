"""How the bench's PVs reach the control loop: a transport follows the PVs a step reads (the newest
value and IOC time stamp of each, a hook per PV run on every update) and writes the setpoints, each
through one public Channel Access client API:

- ``caproto`` (the default): caproto's threading client (``caproto.threading.client.Context``).
- ``pyepics``: libca through pyepics' ``epics.ca`` module: channels, ``create_subscription`` with
  time stamps, ``put(..., wait=False)``.
- ``pyepics-pv``: the same library through ``epics.PV`` objects (their callbacks and ``put``).
- ``ophyd``: the ophyd signals' own monitors (``subscribe``) and ``put``.

``OPS_BENCH_TRANSPORT`` names the one a run uses; ophyd's control layer follows it
(``ophyd.set_cl``: pyepics for the pyepics transports, caproto for caproto), so that one Channel
Access client serves a process. Hooks run in the client's receiving thread, as each value arrives:
they must not block.
"""

from __future__ import annotations

import abc
import contextlib
import logging
import os
import threading
import time

from agents.bench.mapping import MappingError

log = logging.getLogger("agents.bench")

TRANSPORT_ENV = "OPS_BENCH_TRANSPORT"
TRANSPORTS = ("pyepics", "pyepics-pv", "caproto", "ophyd")


class SafetyStop(RuntimeError):
    """The watchdog stopped the run, or a setpoint write found its PV gone; the message is the
    reason."""


def chosen(name: str | None = None) -> str:
    """The transport ``name`` names, else ``OPS_BENCH_TRANSPORT``'s, else ``caproto``;
    ``ValueError`` names the accepted ones."""
    name = name or os.environ.get(TRANSPORT_ENV) or "caproto"
    if name not in TRANSPORTS:
        raise ValueError(f"{TRANSPORT_ENV} must be one of {list(TRANSPORTS)}, got {name!r}")
    return name


def use_control_layer(name: str) -> None:
    """Set ophyd's control layer to the client transport ``name`` uses (``ophyd`` leaves ophyd's
    own choice); signals made before keep theirs."""
    import ophyd

    layer = {"pyepics": "pyepics", "pyepics-pv": "pyepics", "caproto": "caproto"}.get(name)
    if layer is not None and ophyd.cl.name != layer:
        ophyd.set_cl(layer)


@contextlib.contextmanager
def repeater_start_quiet():
    """Within: the standard error of a process forked here goes to /dev/null. libca forks one to
    start a CA repeater when it creates its first channel; pyepics ships no ``caRepeater``, and that
    process's note that none was found would land in the runner's output (searches and monitors
    need no repeater)."""
    saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def make(name: str, timeout: float) -> Transport:
    """A new transport of kind ``name`` (``TRANSPORTS``), not yet open; it connects within
    ``timeout`` s."""
    kinds = {
        "pyepics": PyepicsTransport,
        "pyepics-pv": PyepicsPVTransport,
        "caproto": CaprotoTransport,
        "ophyd": OphydTransport,
    }
    return kinds[chosen(name)](timeout)


class Transport(abc.ABC):
    """The newest value and time stamp (the IOC's, time.time() s) of each followed PV, and the
    setpoints written in one call. ``open(signals, followed, setpoints, timeout)`` connects (every
    followed PV's first value within ``timeout`` s, else ``MappingError``); ``close()`` ends it."""

    name = ""
    follows_itself = True  # False: the ophyd signals' own monitors feed it (``ophyd``)

    def __init__(self, timeout: float):
        self.timeout, self.opened = timeout, False
        self.values: dict = {}
        self.stamps: dict = {}
        self.hooks: dict = {}
        self._arrived = threading.Condition()

    def value(self, pv: str):
        """The newest value of followed PV ``pv``."""
        return self.values[pv]

    def stamp(self, pv: str) -> float:
        """The IOC's time stamp of ``pv``'s newest value (time.time() s)."""
        return self.stamps[pv]

    def on_update(self, pv: str, hook) -> None:
        """Run ``hook(value=, timestamp=)`` on every new value of ``pv`` from now on."""
        self.hooks[pv] = hook

    def update(self, pv: str, value, stamp: float) -> None:
        """A new value of ``pv``: kept, then its hook run (errors logged: the client drops them)."""
        try:
            first = pv not in self.values
            self.values[pv], self.stamps[pv] = value, stamp
            hook = self.hooks.get(pv)
            if hook is not None:
                hook(value=value, timestamp=stamp)
            if first:
                with self._arrived:
                    self._arrived.notify_all()
        except Exception:
            log.exception("monitor of PV %s failed", pv)

    def wait_for_values(self, followed, timeout: float) -> None:
        """Block until every PV of ``followed`` has sent a value; ``MappingError`` names those
        that did not within ``timeout`` s."""
        deadline = time.monotonic() + timeout
        with self._arrived:
            while (missing := [pv for pv in followed if pv not in self.values]) and (
                left := deadline - time.monotonic()
            ) > 0:
                self._arrived.wait(left)
        if missing:
            raise MappingError(f"no value from PV(s) {sorted(missing)} within {timeout:g} s")

    def open(self, signals: dict, followed: list, setpoints: list) -> None:
        """Follow the PVs ``followed`` and write the PVs ``setpoints`` (in this order);
        ``signals``: the bench's ophyd signals by PV name."""
        self._open(signals, followed, setpoints, self.timeout)
        self.opened = True

    @abc.abstractmethod
    def _open(self, signals: dict, followed: list, setpoints: list, timeout: float) -> None:
        """Connect, follow ``followed`` and make ``setpoints`` writable within ``timeout`` s."""

    @abc.abstractmethod
    def write(self, values) -> None:
        """Send ``values`` (wl, one per setpoint PV in ``open``'s order) without waiting."""

    @abc.abstractmethod
    def close(self) -> None:
        """Stop following and release the channels."""


def _lost(name: str) -> SafetyStop:
    return SafetyStop(f"lost connection to PV {name}")


class PyepicsTransport(Transport):
    """libca through ``epics.ca``: a channel per PV, a time-stamped subscription per followed PV,
    setpoints by ``put(wait=False)`` (nothing waits for the IOC's confirmation)."""

    name = "pyepics"

    def _open(self, signals, followed, setpoints, timeout):
        from epics import ca

        self._ca, self._subs = ca, []
        self._chids = {pv: ca.create_channel(pv, connect=False) for pv in {*followed, *setpoints}}
        deadline = time.monotonic() + timeout
        lost = [
            pv
            for pv, chid in self._chids.items()
            if not ca.connect_channel(chid, timeout=max(deadline - time.monotonic(), 0.05))
        ]
        if lost:
            raise MappingError(f"no answer from PV(s) {sorted(lost)} within {timeout:g} s")
        for pv in followed:  # the references kept: libca calls back through them
            self._subs.append(
                ca.create_subscription(self._chids[pv], use_time=True, callback=self._on_value)
            )
        self._setpoints = [(pv, self._chids[pv]) for pv in setpoints]
        self.wait_for_values(followed, max(deadline - time.monotonic(), 0.05))

    def _on_value(self, value=None, pvname=None, timestamp=None, **kwargs):
        self.update(pvname, value, time.time() if timestamp is None else timestamp)

    def write(self, values):
        ca = self._ca
        for (pv, chid), value in zip(self._setpoints, values):
            if not ca.isConnected(chid):
                raise _lost(pv)
            ca.put(chid, float(value), wait=False)

    def close(self):
        """The subscriptions cleared; the channels stay (pyepics shares one per PV name in a
        process: ophyd's signals' too)."""
        for sub in self._subs:
            self._ca.clear_subscription(sub[2])
        self._subs, self._chids = [], {}


class PyepicsPVTransport(Transport):
    """libca through ``epics.PV`` objects: a monitored PV per followed name (its callback), a PV per
    setpoint written by ``put(wait=False)``."""

    name = "pyepics-pv"

    def _open(self, signals, followed, setpoints, timeout):
        import epics

        self._pvs = {  # the callback given at once: the first value (a monitor's) reaches it
            pv: epics.PV(
                pv,
                form="time",
                auto_monitor=pv in followed,
                callback=self._on_value if pv in followed else None,
            )
            for pv in {*followed, *setpoints}
        }
        deadline = time.monotonic() + timeout
        lost = [
            pv
            for pv, chan in self._pvs.items()
            if not chan.wait_for_connection(timeout=max(deadline - time.monotonic(), 0.05))
        ]
        if lost:
            raise MappingError(f"no answer from PV(s) {sorted(lost)} within {timeout:g} s")
        self._setpoints = [(pv, self._pvs[pv]) for pv in setpoints]
        self.wait_for_values(followed, max(deadline - time.monotonic(), 0.05))

    def _on_value(self, pvname=None, value=None, timestamp=None, **kwargs):
        self.update(pvname, value, time.time() if timestamp is None else timestamp)

    def write(self, values):
        for (pv, chan), value in zip(self._setpoints, values):
            if not chan.connected:
                raise _lost(pv)
            chan.put(float(value), wait=False)

    def close(self):
        for chan in self._pvs.values():
            chan.clear_callbacks()
            chan.disconnect(deepclean=False)  # the channel stays: ophyd's signals share it
        self._pvs = {}


class CaprotoTransport(Transport):
    """caproto's threading client: a context of its own, a time-stamped subscription per followed
    PV, setpoints by ``write(wait=False)``."""

    name = "caproto"

    def _open(self, signals, followed, setpoints, timeout):
        from caproto.threading.client import Context

        self._context = Context()
        names = sorted({*followed, *setpoints})
        self._pvs = dict(zip(names, self._context.get_pvs(*names, timeout=timeout)))
        deadline = time.monotonic() + timeout
        lost = []
        for pv, chan in self._pvs.items():
            try:
                chan.wait_for_connection(timeout=max(deadline - time.monotonic(), 0.05))
            except TimeoutError:
                lost.append(pv)
        if lost:
            raise MappingError(f"no answer from PV(s) {sorted(lost)} within {timeout:g} s")
        self._callbacks = []  # caproto keeps weak references to its callbacks
        for pv in followed:
            callback = self._callback(pv)
            self._callbacks.append(callback)
            self._pvs[pv].subscribe(data_type="time").add_callback(callback)
        self._setpoints = [(pv, self._pvs[pv]) for pv in setpoints]
        self.wait_for_values(followed, max(deadline - time.monotonic(), 0.05))

    def _callback(self, pv: str):
        def on_value(sub, response):
            data = response.data
            self.update(pv, data[0] if len(data) == 1 else data, response.metadata.timestamp)

        return on_value

    def write(self, values):
        for (pv, chan), value in zip(self._setpoints, values):
            if not chan.connected:
                raise _lost(pv)
            chan.write((float(value),), wait=False, notify=False)

    def close(self):
        from agents.bench.lifecycle import closing_channel_access

        with closing_channel_access():
            self._context.disconnect()


class OphydTransport(Transport):
    """The ophyd signals' own monitors (``subscribe``: ophyd's dispatcher thread runs the hooks)
    and ``put``."""

    name = "ophyd"
    follows_itself = False

    def _open(self, signals, followed, setpoints, timeout):
        self._tokens = []
        for pv in followed:
            sig = signals[pv]

            def on_value(value=None, timestamp=None, _pv=pv, **kwargs):
                self.update(_pv, value, time.time() if timestamp is None else timestamp)

            self._tokens.append((sig, sig.subscribe(on_value, run=True)))
        self._setpoints = [(pv, signals[pv]) for pv in setpoints]
        self.wait_for_values(followed, timeout)

    def write(self, values):
        for (pv, sig), value in zip(self._setpoints, values):
            if not sig.connected:
                raise _lost(pv)
            sig.put(float(value))

    def close(self):
        for sig, token in self._tokens:
            sig.unsubscribe(token)
        self._tokens = []
