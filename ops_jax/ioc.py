"""The simulator served as an EPICS Channel Access IOC (caproto): one OPS instance in wall-clock
time.

    python -m ops_jax.ioc --prefix OPS: --stages 5 --mode hard --imperfections lab --rate 100

Every ``ops_jax.make`` option is accepted as ``--option value`` (underscores or dashes; tuples as
Python literals, e.g. ``--waveplate-error-deg "(0.3, -0.2, 0.4, -0.3, 0.2)"``). At every tick of
``--rate`` Hz the simulation advances one control step whether or not a setpoint changed: vibration,
drift and pulse noise go on, so a slow controller pays for its latency as on a bench. A tick applies
the setpoints present at its start; a line moves at most ``--action-scale`` wl per tick towards its
setpoint (default here 1 wl: a piezo settles within a tick; the option is the lines' slew limit). A
tick that starts late is counted in ``OVERRUNS``; ticks missed by a stall are run back to back, so
the simulated time stays the wall-clock time. ``--lockstep`` instead
advances one tick per write to ``ADVANCE`` (reproducible runs, tests).

PVs (prefix first; lengths in wavelengths, wl):

- ``LINE{i}:SP`` (i = 1..N, writable): the commanded position of delay line i since start-up, within
  the actuator's span (writes outside it or non-finite are refused).
- ``LINE{i}:RBV``: where the line is, through the actuator model (gain, backlash, lag, DAC).
- ``LINE{i}:LEN``: the length readout: the line's offset from the optimum as its calibrated sensor
  reports it (the environment's observed length); not served with ``--observe-lengths False``.
- ``DET:POWER``: the detector reading in units of P_max; ``SCOPE:TRACE``: the 2^N - 1 oscilloscope
  samples in units of the ideal pulse peak (both as the detector reads them, with observation
  noise).
- ``EVAL:P_PMAX``, ``EVAL:P_PBEST``: the true P / P_max and P / P_best, for evaluation only.
- ``TICK`` (published last in a tick: a new value means a complete new frame), ``STATUS``,
  ``OVERRUNS``, ``RATE`` (Hz; 0 in lockstep), ``ADVANCE`` (lockstep only).
- ``RESET``: a non-zero write starts again: setpoints to 0, the lines' offsets from the optimum
  drawn afresh as at start-up (the k-th reset's key folded by k, the same ``--drift-episode``); the
  tick count goes on.

Every PV of a tick carries the tick's start as its time stamp: the moment its setpoints were read,
so a frame stamped after a setpoint write shows that write once the write has reached the IOC.
``--tick-log FILE`` appends one JSON line per tick, ``{"tick": t, "stamp": s, "setpoints": [...]}``
(the time stamp, time.time() s, and the setpoints the tick applied, wl): what a client's frames can
be checked against. Every 1,000 ticks the IOC prints one line of their host time (the simulator
step, then the PV writes: median and 99th percentile, ms) and the overruns so far.

Random draws follow ``agents.evaluate``'s episode 0 for ``--seed``: ``reset`` as the
``--drift-episode``-th episode (hard mode's drift fully on by default), step t with the key folded
by t. The IOC listens on 127.0.0.1 unless ``--interface`` is given; port and search settings follow
the standard ``EPICS_CA_*`` environment variables.
"""

from __future__ import annotations

import argparse
import ast
import asyncio
import functools
import json
import math
import os
import socket
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import ops_jax
from ops_jax.cli import runtime
from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import exit_interrupted, keep_ctrl_c
from ops_jax.env import option_names
from ops_jax.adapters.gymnasium.codec import FlatCodec

STATUS_OK, STATUS_OUTSIDE = "running", "outside window"
TICK_REPORT = 1000  # ticks per line of the tick-time report on stdout


def _literal(text: str):
    """A command-line value as a Python literal (numbers, booleans, tuples), else the string."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def parser() -> argparse.ArgumentParser:
    """The IOC's options: its own, then ``stages``, ``mode`` and every ``ops_jax.make`` option."""
    ap = ArgumentParser(prog="python -m ops_jax.ioc", description=__doc__.split("\n")[0])
    ap.add_argument("--prefix", default="OPS:", help="PV name prefix (default OPS:)")
    ap.add_argument("--rate", type=float, default=100.0, help="ticks per second (Hz, default 100)")
    ap.add_argument(
        "--lockstep", action="store_true", help="advance one tick per write to ADVANCE instead"
    )
    ap.add_argument("--seed", type=int, default=0, help="seed of the simulated run")
    ap.add_argument(
        "--drift-episode", type=int, default=10, help="the reset's episode count (hard-mode drift)"
    )
    ap.add_argument(
        "--interface", default="127.0.0.1", help="address to serve on (default localhost only)"
    )
    ap.add_argument(
        "--tick-log",
        metavar="FILE",
        help="append each tick's time stamp and applied setpoints to FILE (JSON lines)",
    )
    env = ap.add_argument_group("simulator (ops_jax.make options)")
    env.add_argument("--stages", type=int, default=5)
    env.add_argument("--mode", default="hard")
    for name in option_names():
        env.add_argument(
            f"--{name.replace('_', '-')}", dest=name, type=_literal, default=None, metavar="VALUE"
        )
    return ap


def make_options(args: argparse.Namespace) -> dict:
    """The ``ops_jax.make`` keyword options given on the command line (``action_scale``, the largest
    move per tick, 1 wl unless given)."""
    return {
        "action_scale": 1.0,
        **{k: getattr(args, k) for k in option_names() if getattr(args, k) is not None},
    }


class Bench:
    """One simulated instance: the jitted single-instance step and its wall-clock state (host side).
    The state is kept as one float32 vector and a tick's outputs come back as another
    (``gym_codec``): one argument in and one copy out per tick instead of one per leaf."""

    def __init__(
        self, stages: int, mode: str, options: dict, seed: int = 0, drift_episode: int = 10
    ):
        self.env, self.params = ops_jax.make(stages, mode, **options)
        self.n = self.env.num_actions
        self.scale = float(self.params.action_scale)
        self.span = (
            float(np.max(self.params.lab.actuator_span_wl))
            if self.env.config.imperfect
            else math.inf
        )
        self._k_reset, _, self._k_run = jax.random.split(jax.random.key(seed), 3)
        reset = jax.jit(self.env.reset, static_argnums=2)
        self._reset = lambda key: reset(key, self.params, drift_episode)
        self._codec = FlatCodec(jax.eval_shape(self._reset, self._k_reset)[1])
        self._pack = jax.jit(self._codec.flatten)
        self._step = jax.jit(self._advance)
        self.t, self.resets = 0, -1
        self.reset()
        # compile once, before serving (the result is discarded: the step is pure)
        jax.block_until_ready(self._step(self._packed, np.zeros(self.n, np.float32), 1))

    def reset(self) -> dict:
        """Start again: the lines drawn afresh as at start-up (the k-th reset folds its key by k),
        the setpoints applied back to 0; the tick count goes on. Returns the new PV values."""
        self.resets += 1
        obs, state = self._reset(jax.random.fold_in(self._k_reset, self.resets))
        self._packed = self._pack(state)
        self.command = np.zeros(self.n)  # what has been applied of the setpoints (wl)
        self.frame = self._decode(
            self.env.layout.latest(np.asarray(obs)),
            np.zeros(self.n),
            *self._true_power(state),
            False,
        )
        return self.frame

    def _true_power(self, state):
        """(P / P_max, P / P_best) of ``state`` as it truly is (the reset's evaluation values)."""
        power = self.env._sense(state.deltas, state.lab)[0].power
        best = float(np.max(self.params.lab.p_best)) if self.env.config.imperfect else 0.0
        return float(power / self.env.p_max), float(power / (best if best > 0 else self.env.p_max))

    def _advance(self, packed, action, t):
        """(packed state, [frame, position (N,) wl, P / P_max, P / P_best, outside]) after step
        ``t``."""
        k_env = jax.random.split(jax.random.fold_in(self._k_run, t - 1))[1]
        state = self._codec.unflatten(packed)
        obs, state, _, terminated, _, info = self.env.step_env(
            jax.random.fold_in(k_env, 0), state, action, self.params
        )
        position = state.lab.position if self.env.config.imperfect else jnp.zeros(self.n)
        out = [
            self.env.layout.latest(obs),
            position,
            info["normalized_power"],
            info["normalized_power_best"],
            terminated,
        ]
        return self._codec.flatten(state), jnp.concatenate(
            [jnp.ravel(jnp.asarray(x, jnp.float32)) for x in out]
        )

    def _decode(self, frame, position, npow, npow_best, outside) -> dict:
        """PV values of one observation frame (float64: the client re-encodes it exactly)."""
        return {
            **self.env.layout.decode(frame, self.params.window),
            "position": np.asarray(position, np.float64),
            "p_pmax": float(npow),
            "p_pbest": float(npow_best),
            "outside": bool(outside),
        }

    def tick(self, setpoints) -> dict:
        """Advance one control step towards ``setpoints`` (N,) wl; returns the new PV values."""
        action = np.clip((np.asarray(setpoints, np.float64) - self.command) / self.scale, -1.0, 1.0)
        action = np.where(np.isfinite(action), action, 0.0)
        self.command = self.command + action * self.scale
        self.t += 1
        self._packed, out = self._step(self._packed, action.astype(np.float32), self.t)
        out = np.asarray(out)
        frame, position, (npow, best, outside) = out[: -self.n - 3], out[-self.n - 3 : -3], out[-3:]
        if not self.env.config.imperfect:
            position = self.command
        self.frame = self._decode(frame, position, npow, best, outside != 0)
        return self.frame


def pv_group(bench: Bench, prefix: str, rate: float, lockstep: bool, tick_log=None):
    """The caproto ``PVGroup`` instance serving ``bench``; ``tick_log``: a text file each tick
    appends its line to (``--tick-log``; None: none)."""
    from caproto import ChannelType
    from caproto.server import pvproperty

    n, m = bench.n, 2**bench.n - 1
    lim = bench.span / 2 if math.isfinite(bench.span) else 1e6
    ns = {}
    for i in range(1, n + 1):
        ns[f"sp{i}"] = pvproperty(
            value=0.0,
            name=f"LINE{i}:SP",
            lower_ctrl_limit=-lim,
            upper_ctrl_limit=lim,
            units="wl",
            precision=6,
            doc=f"line {i} setpoint (wl)",
        )
        ns[f"rbv{i}"] = pvproperty(
            value=0.0, name=f"LINE{i}:RBV", read_only=True, units="wl", precision=6
        )
        if (
            bench.env.layout.lengths
        ):  # a bench without length readouts (observe_lengths=False) serves none
            ns[f"len{i}"] = pvproperty(
                value=0.0, name=f"LINE{i}:LEN", read_only=True, units="wl", precision=6
            )
    ns["power"] = pvproperty(value=0.0, name="DET:POWER", read_only=True, precision=6)
    ns["trace"] = pvproperty(value=[0.0] * m, name="SCOPE:TRACE", read_only=True, max_length=m)
    ns["p_pmax"] = pvproperty(value=0.0, name="EVAL:P_PMAX", read_only=True, precision=6)
    ns["p_pbest"] = pvproperty(value=0.0, name="EVAL:P_PBEST", read_only=True, precision=6)
    ns["tick"] = pvproperty(value=0, name="TICK", read_only=True, dtype=ChannelType.LONG)
    ns["overruns"] = pvproperty(value=0, name="OVERRUNS", read_only=True, dtype=ChannelType.LONG)
    ns["rate"] = pvproperty(
        value=0.0 if lockstep else float(rate), name="RATE", read_only=True, units="Hz"
    )
    ns["status"] = pvproperty(
        value="starting", name="STATUS", read_only=True, dtype=ChannelType.STRING
    )
    ns["advance"] = pvproperty(
        value=0, name="ADVANCE", dtype=ChannelType.LONG, doc="lockstep: a write advances one tick"
    ).putter(_advance)
    ns["reset"] = pvproperty(
        value=0, name="RESET", dtype=ChannelType.LONG, doc="a non-zero write starts the bench again"
    ).putter(_reset)
    group_type = type("OPSBench", (_group_class(),), ns)
    return group_type(prefix=prefix, bench=bench, rate=rate, lockstep=lockstep, tick_log=tick_log)


class _BenchGroupBase:
    """Tick logic shared by the generated PV group (mixed into a caproto ``PVGroup``)."""

    async def publish(self, values: dict, stamp: float | None = None):
        """Write one tick's values, each stamped ``stamp`` (the tick's start, time.time() s; now if
        None)."""
        at = {} if stamp is None else {"timestamp": stamp}
        for i in range(1, self.bench.n + 1):
            await getattr(self, f"rbv{i}").write(values["position"][i - 1], **at)
            if values["length"] is not None:
                await getattr(self, f"len{i}").write(values["length"][i - 1], **at)
        await self.power.write(values["power"], **at)
        await self.trace.write(values["trace"], **at)
        await self.p_pmax.write(values["p_pmax"], **at)
        await self.p_pbest.write(values["p_pbest"], **at)
        status = STATUS_OUTSIDE if values["outside"] else STATUS_OK
        if status != self.status.value:
            await self.status.write(status, **at)
        await self.tick.write(self.bench.t, **at)  # last: a new tick means a complete frame

    async def step(self):
        """One tick: the setpoints as they are now, one simulator step, its frame stamped with this
        moment."""
        stamp, t0 = time.time(), time.perf_counter()
        setpoints = [getattr(self, f"sp{i}").value for i in range(1, self.bench.n + 1)]
        if self.tick_log is not None:
            self.tick_log.write(
                json.dumps(
                    {"tick": self.bench.t + 1, "stamp": stamp, "setpoints": setpoints},
                    allow_nan=False,  # strict JSON: setpoints are finite (the PVs refuse others)
                )
                + "\n"
            )
        values = self.bench.tick(setpoints)
        t1 = time.perf_counter()
        await self.publish(values, stamp)
        self.tick_ms.append((1e3 * (t1 - t0), 1e3 * (time.perf_counter() - t1)))
        if len(self.tick_ms) == TICK_REPORT:
            self.report_ticks()

    def report_ticks(self):
        """One line on the last ``TICK_REPORT`` ticks' host time: the simulator step, then the PV
        writes (ms)."""
        step, write = np.percentile(np.asarray(self.tick_ms), [50, 99], axis=0).T
        print(
            f"ops_jax.ioc: ticks {self.bench.t - len(self.tick_ms) + 1}-{self.bench.t}: step p50 "
            f"/ p99 {step[0]:.2f} / {step[1]:.2f} ms, publish {write[0]:.2f} / {write[1]:.2f} "
            f"ms, overruns {self.overruns.value}",
            flush=True,
        )
        self.tick_ms = []

    async def clock(self):
        """Tick at ``rate`` Hz on the wall clock; late ticks are counted and caught up."""
        period, t0, k, late = 1.0 / self.tick_rate, time.monotonic(), 0, 0
        while True:
            k += 1
            delay = t0 + k * period - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            elif delay < -period / 2:
                late += 1
                await self.overruns.write(late)
            await self.step()

    async def start(self, async_lib):
        await self.publish(self.bench.frame)
        print(
            f"ops_jax.ioc: serving {len(self.pvdb)} PVs under {self.prefix!r}, {self.bench.n} "
            f"lines, {'lockstep' if self.lockstep else f'{self.tick_rate:g} Hz'}",
            flush=True,
        )
        if not self.lockstep:
            asyncio.get_running_loop().create_task(self.clock())


async def _advance(group, instance, value):
    if group.lockstep:
        await group.step()
    return value


async def _reset(group, instance, value):
    """Setpoints to 0, then the bench's ``reset`` (a tick in between moves towards 0), its frame
    published."""
    if value:
        for i in range(1, group.bench.n + 1):
            await getattr(group, f"sp{i}").write(0.0)
        await group.publish(group.bench.reset())
    return 0


@functools.lru_cache(maxsize=None)
def _group_class():
    """``_BenchGroupBase`` mixed into caproto's ``PVGroup`` (built on first use: ``import ops_jax``
    needs no caproto)."""
    from caproto.server import PVGroup

    class BenchGroup(_BenchGroupBase, PVGroup):
        def __init__(self, *args, bench, rate, lockstep, tick_log=None, **kwargs):
            self.bench, self.tick_rate, self.lockstep, self.tick_ms = bench, rate, lockstep, []
            self.tick_log = tick_log
            super().__init__(*args, **kwargs)

    return BenchGroup


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


async def _tcp_socket(addr: str, port: int) -> socket.socket:
    """The server's listening socket, made with the TCP protocol number so that asyncio sets
    TCP_NODELAY on every accepted connection."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.setblocking(False)
    sock.bind((addr, port))
    return sock


async def _drained_get(circuit, timeout=None):
    """A circuit's next queued monitor update; None at once when none is queued (``timeout`` given),
    so that a batch goes out as soon as the queue is drained; with ``timeout`` None, waits for one.
    caproto's own waits up to ``timeout`` (the batch window) for more after the last update of a
    tick, delaying every frame by it."""
    queue = circuit.subscription_queue
    try:
        return queue.get_nowait()
    except asyncio.QueueEmpty:
        return None if timeout is not None else await queue.get()


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


def tune_server(rate: float) -> None:
    """caproto's server set for a tick-paced IOC: monitor batches sent once the queue is drained
    (``_drained_get``) and within ``batch_window(rate)`` under load, and replies sent without
    Nagle's delay. caproto binds with protocol 0, so asyncio leaves Nagle's algorithm on; small
    replies then wait for the client's delayed acknowledgement (~40 ms a write round trip while
    monitors flow, where 1.3 ms is the wire's)."""
    import caproto.asyncio.server
    import caproto.server.common

    caproto.server.common.HIGH_LOAD_TIMEOUT = batch_window(rate)
    if hasattr(caproto.asyncio.server, "_create_bound_tcp_socket"):
        caproto.asyncio.server._create_bound_tcp_socket = _tcp_socket
    if hasattr(caproto.asyncio.server.VirtualCircuit, "get_from_sub_queue"):
        caproto.asyncio.server.VirtualCircuit.get_from_sub_queue = _drained_get


def main(argv=None) -> None:
    """Serve the IOC until Ctrl-C (or SIGINT): then one line, exit status 130, while starting as
    well."""
    keep_ctrl_c()
    ap = parser()
    args = ap.parse_args(argv)
    if not (args.lockstep or (math.isfinite(args.rate) and 0 < args.rate <= 10_000)):
        ap.error(f"--rate must be a number in (0, 10000] Hz, got {args.rate}")
    try:
        group = _start(ap, args)
    except KeyboardInterrupt:
        exit_interrupted("stopped while starting; it served nothing")
    from caproto.server import run

    run(group.pvdb, interfaces=[args.interface], startup_hook=group.start)  # returns on Ctrl-C
    exit_interrupted(f"the IOC {args.prefix} stopped; its PVs are gone")


def _start(ap, args):
    """The PV group of the IOC ``args`` describe: its simulator built and compiled, the server
    tuned."""
    runtime.start_single_threaded()  # a tick is one small call
    try:
        bench = Bench(
            args.stages,
            args.mode,
            make_options(args),
            seed=args.seed,
            drift_episode=args.drift_episode,
        )
    except (TypeError, ValueError) as exc:
        ap.error(str(exc))
    try:
        tick_log = (
            None if args.tick_log is None else open(args.tick_log, "a", buffering=1)
        )  # a line per write
    except OSError as exc:
        raise SystemExit(f"ops_jax.ioc: --tick-log: {exc}")
    tune_server(args.rate)
    from caproto import get_environment_variables

    warning = port_warning(int(get_environment_variables()["EPICS_CA_SERVER_PORT"]))
    if warning:
        print(warning, file=sys.stderr, flush=True)
    return pv_group(bench, args.prefix, args.rate, args.lockstep, tick_log)


if __name__ == "__main__":
    main()
