"""The PV group ``ops_jax.ioc`` serves: one PV per reading, setpoint and control of a simulated
bench (``ops_jax.ioc.Bench``), its names from ``ops_jax.pvs``, and the tick that advances the bench
and publishes its frame."""

from __future__ import annotations

import asyncio
import functools
import json
import math
import time

import numpy as np

from ops_jax import pvs

STATUS_OK, STATUS_OUTSIDE = "running", "outside window"
TICK_REPORT = 1000  # ticks per line of the tick-time report on stdout


def pv_group(bench, prefix: str, rate: float, lockstep: bool, tick_log=None):
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
            name=pvs.line_pv(pvs.LINE_SETPOINT, i),
            lower_ctrl_limit=-lim,
            upper_ctrl_limit=lim,
            units="wl",
            precision=6,
            doc=f"line {i} setpoint (wl)",
        )
        ns[f"rbv{i}"] = pvproperty(
            value=0.0,
            name=pvs.line_pv(pvs.LINE_READBACK, i),
            read_only=True,
            units="wl",
            precision=6,
        )
        if (
            bench.env.layout.lengths
        ):  # a bench without length readouts (observe_lengths=False) serves none
            ns[f"len{i}"] = pvproperty(
                value=0.0,
                name=pvs.line_pv(pvs.LINE_LENGTH, i),
                read_only=True,
                units="wl",
                precision=6,
            )
    ns["power"] = pvproperty(value=0.0, name=pvs.DETECTOR_POWER, read_only=True, precision=6)
    ns["trace"] = pvproperty(value=[0.0] * m, name=pvs.SCOPE_TRACE, read_only=True, max_length=m)
    ns["p_pmax"] = pvproperty(value=0.0, name=pvs.EVAL_P_PMAX, read_only=True, precision=6)
    ns["p_pbest"] = pvproperty(value=0.0, name=pvs.EVAL_P_PBEST, read_only=True, precision=6)
    ns["tick"] = pvproperty(value=0, name=pvs.TICK, read_only=True, dtype=ChannelType.LONG)
    ns["overruns"] = pvproperty(value=0, name=pvs.OVERRUNS, read_only=True, dtype=ChannelType.LONG)
    ns["rate"] = pvproperty(
        value=0.0 if lockstep else float(rate), name=pvs.RATE, read_only=True, units="Hz"
    )
    ns["status"] = pvproperty(
        value="starting", name=pvs.STATUS, read_only=True, dtype=ChannelType.STRING
    )
    ns["advance"] = pvproperty(
        value=0, name=pvs.ADVANCE, dtype=ChannelType.LONG, doc="lockstep: a write advances one tick"
    ).putter(_advance)
    ns["reset"] = pvproperty(
        value=0,
        name=pvs.RESET,
        dtype=ChannelType.LONG,
        doc="a non-zero write starts the bench again",
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
