"""A bench's life over Channel Access: ``connect`` (every PV answers), ``arm`` (its transport
follows the PVs a step reads and writes the setpoints, ``agents.bench.transport``), ``disconnect``
(a clean exit)."""

from __future__ import annotations

import contextlib
import logging
import threading
import time

from ophyd import Kind

from agents.bench.mapping import MappingError

log = logging.getLogger("agents.bench")


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


def followed_pvs(bench) -> list:
    """The PVs of ``bench``'s signals a step reads (its hinted and normal ones: each event's)."""
    return [
        walk.item.pvname
        for walk in bench.walk_signals()
        if hasattr(walk.item, "pvname") and walk.item.kind & Kind.normal
    ]


def described(bench) -> tuple[dict, list]:
    """(the event descriptor's data keys of ``bench``'s readings, [(event key, PV)]): each from the
    transport's newest value and the signal's metadata as ophyd holds it since the connection (the
    keys ``describe`` gives, without reading every PV again)."""
    from ophyd.utils.epics_pvs import data_shape, data_type

    keys, reads = {}, []
    for walk in bench.walk_signals():
        sig = walk.item
        if not (hasattr(sig, "pvname") and sig.kind & Kind.normal):
            continue
        value, meta = bench.transport.value(sig.pvname), sig.metadata
        key = {
            "source": f"PV:{sig.pvname}",
            "dtype": data_type(value),
            "shape": list(data_shape(value)),
        }
        key["units"] = meta.get("units") or ""
        key["lower_ctrl_limit"], key["upper_ctrl_limit"] = sig.limits
        if sig.precision is not None:
            key["precision"] = sig.precision
        keys[sig.name] = key
        reads.append((sig.name, sig.pvname))
    return keys, reads


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


def arm(bench, lines=None) -> None:
    """Follow ``bench`` (after ``connect``) through its transport (opened once: a second call keeps
    the first's), the detector's frame counter from now on (``Detector.arm``); ``lines`` (its
    ``Lines``) write through the transport."""
    transport = bench.transport
    setpoints = [line.setpoint.setpoint_pvname for line in lines.delay_lines] if lines else []
    if not transport.opened:
        transport.open(signals(bench), followed_pvs(bench), setpoints)
    bench.detector.arm(transport)
    if lines is not None:
        lines.writer = transport


def disconnect(bench) -> None:
    """Stop following ``bench``'s PVs and close the Channel Access circuits (a clean exit)."""
    import ophyd

    if bench.transport.opened:
        bench.transport.close()
    bench.destroy()
    if ophyd.cl.name == "caproto":
        from caproto.threading.pyepics_compat import PV

        with closing_channel_access():
            PV.default_context().disconnect()  # joins caproto's threads: none outlives the hook


@contextlib.contextmanager
def closing_channel_access():
    """Within: the network error a caproto thread may raise while its socket closes under it is
    dropped (``closing_socket_hook``); the previous ``threading.excepthook`` is back after."""
    previous = threading.excepthook
    threading.excepthook = closing_socket_hook(previous)
    try:
        yield
    finally:
        threading.excepthook = previous


def closing_socket_hook(previous):
    """A ``threading.excepthook`` that drops the network error a caproto thread may raise while its
    socket is being closed under it (its search-retry thread sends between the close and its join);
    others go on to ``previous``."""

    def hook(args) -> None:
        if isinstance(args.exc_value, OSError) and _raised_in_caproto(args.exc_traceback):
            log.debug(  # CaprotoNetworkError too
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
