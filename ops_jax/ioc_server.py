"""How ``ops_jax.ioc`` serves its PVs: caproto's asyncio server, its monitor batches sent as soon as
the queue is drained and within ``batch_window`` under load, its replies sent without Nagle's delay
(subclasses of caproto's public ``Context`` and ``VirtualCircuit``), on a Channel Access port clear
of the kernel's range for auto-bound ports."""

from __future__ import annotations

import asyncio
import functools
import os
import socket

BATCH_WINDOW_ENV = "CAPROTO_SERVER_HIGH_LOAD_TIMEOUT_SEC"


def batch_window(rate: float) -> float:
    """The longest caproto holds a batch of monitor updates while more keep coming (s): a tenth of
    the tick period, at most caproto's default 10 ms, unless
    ``CAPROTO_SERVER_HIGH_LOAD_TIMEOUT_SEC`` sets it. With a window as long as the period every
    update finds the next one coming, and caproto, taking the server for overloaded, lets the
    batches grow to 1 s of latency."""
    if os.environ.get(BATCH_WINDOW_ENV):
        return float(os.environ[BATCH_WINDOW_ENV])
    return min(0.01, 0.1 / rate)


def set_batch_window(rate: float) -> None:
    """``batch_window(rate)`` in caproto's ``CAPROTO_SERVER_HIGH_LOAD_TIMEOUT_SEC``, which caproto's
    server reads when it is first imported (call before)."""
    os.environ[BATCH_WINDOW_ENV] = repr(batch_window(rate))


async def drained_get(queue: asyncio.Queue, timeout=None):
    """The next queued monitor update of ``queue``; None at once when none is queued (``timeout``
    given), so that a batch goes out as soon as the queue is drained; with ``timeout`` None, waits
    for one. caproto's own waits up to ``timeout`` (the batch window) for more after the last update
    of a tick, delaying every frame by it."""
    try:
        return queue.get_nowait()
    except asyncio.QueueEmpty:
        return None if timeout is not None else await queue.get()


@functools.lru_cache(maxsize=None)
def context_class():
    """caproto's asyncio server ``Context`` with drained batches (``drained_get``) and TCP_NODELAY
    on its listening sockets, which the connections it accepts inherit (built on first use:
    ``import ops_jax`` needs no caproto). caproto binds with protocol 0, so asyncio leaves Nagle's
    algorithm on; small replies then wait for the client's delayed acknowledgement (~40 ms a write
    round trip while monitors flow, where 1.3 ms is the wire's)."""
    from caproto.asyncio.server import Context, VirtualCircuit

    class DrainedCircuit(VirtualCircuit):
        async def get_from_sub_queue(self, timeout=None):
            return await drained_get(self.subscription_queue, timeout)

    class TunedContext(Context):
        CircuitClass = DrainedCircuit

        async def server_accept_loop(self, sock):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            await super().server_accept_loop(sock)

    return TunedContext


def serve(pvdb: dict, interface: str, startup_hook) -> None:
    """Serve ``pvdb`` on ``interface`` (``context_class``) until Ctrl-C; ``startup_hook(async_lib)``
    runs once the server is up."""

    async def run():  # caproto's queues belong to the loop they are made in
        await context_class()(pvdb, [interface]).run(startup_hook=startup_hook)

    try:
        asyncio.run(run())
    except KeyboardInterrupt:
        pass


def ephemeral_ports() -> tuple[int, int]:
    """The kernel's range for auto-bound ports (first, last); Linux's default where it cannot be
    read (other systems: their own, e.g. macOS 49152-65535)."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            first, last = map(int, f.read().split())
        return first, last
    except (OSError, ValueError):
        return 32768, 60999


def port_warning(port: int) -> str | None:
    """A line for a Channel Access port inside the kernel's range for auto-bound ports (None:
    outside it): caproto binds the IOC's UDP port with SO_REUSEADDR and SO_REUSEPORT, as it does its
    client sockets, so a client socket the kernel auto-binds to the same port takes the IOC's search
    replies for itself, and that client's search times out."""
    first, last = ephemeral_ports()
    if first <= port <= last:
        return (
            f"ops_jax.ioc: warning: port {port} lies in the kernel's range for auto-bound ports "
            f"({first}-{last}); a client given the same port misses the IOC's search replies: set "
            f"EPICS_CA_SERVER_PORT below {first}"
        )
    return None
