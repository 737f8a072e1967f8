"""The control loop that ``agents.bench`` runs on a bench (``Loop``: the watchdog, one step's reads,
probes and writes, the records) and the Bluesky plan around it; the controller is any
``agents.bench.controller.Controller`` (a frozen one: ``agents.bench.frozen``)."""

from __future__ import annotations

import logging
import time

import numpy as np

from agents.bench.controller import Controller
from agents.bench.devices import Control
from agents.bench.transport import SafetyStop
from agents.bench.lifecycle import signals
from agents.bench.flyer import LoopFlyer, fly
from agents.bench.lifecycle import described

FLUSH_S = (
    0.2  # a page of the loop's events is due this often (s), collected after the step that ends it
)
USER_STOP = "user"  # the stop reason of a run the user ended at once (a second Ctrl-C or SIGTERM)
log = logging.getLogger("agents.bench")


class Loop:
    """The state of one run shared by the plan, the watchdog and the summary."""

    def __init__(
        self, bench, lines, mapping, agent: Controller, scale, window, seconds, rate, steps=0
    ):
        self.bench, self.lines, self.mapping, self.agent = bench, lines, mapping, agent
        self.scale, self.window, self.seconds, self.period = scale, window, seconds, 1.0 / rate
        self.max_steps = steps
        self.det = bench.detector
        self.n = len(mapping["lines"])
        self.frames = None
        self.deadline = (
            None  # time.perf_counter() before which the next step does not read (the rate cap)
        )
        self.stop_reason: str | None = None
        self.stopped_at = None  # time.time() of a stop at once (the watchdog's or the user's)
        self.user_stop = False
        self.ended = False  # the plan has returned: what is left is writing what the run recorded
        self.rec = {
            k: [] for k in ("time_s", "tick", "p_pmax", "p_pbest", "latency_ms", "decide_ms")
        }
        self.t0 = self.cpu0 = None  # wall-clock and CPU time at the first step
        self.advance = getattr(bench, "advance", None)
        self.feed = bench.transport  # the newest readings (``arm``: agents.bench.transport)
        self.reads = []  # (event key, PV) of the readings recorded at every step
        self.actions_cut = 0  # steps whose action the safety limits cut

    # -- watchdog --------------------------------------------------------------------------------
    def trip(self, reason: str):
        """Stop at once: no further move; the frame being waited for fails with ``reason`` (logged
        as the watchdog's, unless it is the user's ``USER_STOP``)."""
        if self.stop_reason is None:
            self.stop_reason, self.stopped_at = reason, time.time()
            if reason != USER_STOP:
                log.error("watchdog: %s", reason)
        self.lines.lock(self.stop_reason)
        self.det.fail(SafetyStop(self.stop_reason))

    def watch(self):
        """Trip on any PV disconnecting."""
        for name, sig in signals(self.bench).items():

            def on_meta(*args, connected=True, _name=name, **kwargs):
                if not connected and self.t0 is not None:
                    self.trip(f"lost connection to PV {_name}")

            sig.subscribe(on_meta, event_type=sig.SUB_META, run=False)

    def read(self, sig, now: float):
        """The newest value of ``sig``'s PV, checked (``check``) at ``now`` (time.time() s)."""
        value = self.feed.value(sig.pvname)
        self.check(sig.pvname, value, now)
        return value

    def check(self, pv: str, value, now: float):
        """Trip on a non-finite or stale reading of PV ``pv`` (in lockstep a frame waits for the
        controller: its age is not checked)."""
        age = now - self.feed.stamp(pv)
        if not np.all(np.isfinite(value)):
            self.trip(f"non-finite reading on PV {pv}")
        elif not self.mapping["advance"] and age > self.mapping["safety"]["stale_s"]:
            self.trip(f"stale reading on PV {pv} ({age:.3f} s old)")
        if self.stop_reason:
            raise SafetyStop(self.stop_reason)

    def no_frame(self) -> str:
        lost = sorted(name for name, sig in signals(self.bench).items() if not sig.connected)
        tick = self.mapping["detector"]["tick"]
        return (
            f"lost connection to PV(s) {lost}"
            if lost
            else f"no new frame on PV {tick} within {self.mapping['safety']['stale_s']:g} s"
        )

    # -- observation -----------------------------------------------------------------------------
    def observe(self) -> np.ndarray:
        """The controller's observation (the simulator's encoding) from the current readings."""
        d, now = self.mapping["detector"], time.time()
        power = self.read(self.det.power, now)
        trace = np.asarray(self.read(self.det.trace, now), np.float64)
        env = self.agent.env
        lengths = np.zeros(self.n)
        if env.layout.lengths:  # the length readouts (0 where the bench has no sensor)
            for i in range(self.n):
                sensor = getattr(self.bench, f"length{i + 1}", None)
                if sensor is not None:
                    lengths[i] = self.read(sensor.value, now)
        lengths /= self.mapping["units_per_wl"]
        try:
            frame = env.layout.encode(
                power / d["power_full_scale"], trace / d["trace_peak"], lengths, self.window, xp=np
            )
        except ValueError as exc:
            self.trip(f"the bench's frame does not fit the controller: {exc}")
            raise SafetyStop(self.stop_reason) from None
        stack = env.config.frame_stack
        self.frames = [frame] * stack if self.frames is None else (self.frames + [frame])[-stack:]
        return np.concatenate(self.frames)

    def moved(self):
        """Setpoints were written: the next frame used must show them (in lockstep: the next tick;
        else a frame acquired ``settle_s`` after now)."""
        if self.mapping["advance"]:
            self.det.use()
        else:
            self.det.after(time.time() + self.mapping["detector"]["settle_s"])

    def probe_power(self) -> float:
        return (
            float(self.read(self.det.power, time.time()))
            / self.mapping["detector"]["power_full_scale"]
        )

    def readings(self) -> tuple[dict, dict]:
        """The event's readings of the frame just used (the bench's hinted and normal signals):
        values and IOC time stamps."""
        feed = self.feed
        return {k: feed.value(pv) for k, pv in self.reads}, {
            k: feed.stamp(pv) for k, pv in self.reads
        }

    def frame(self):
        """Wait for a frame not used before (``stale_s`` at most)."""
        if not self.det.wait(self.mapping["safety"]["stale_s"]):
            self.trip(self.stop_reason or self.no_frame())
        if self.stop_reason:
            raise SafetyStop(self.stop_reason)

    def tick(self):
        """In lockstep, advance the simulator one frame (a free-running bench needs nothing)."""
        if self.advance is not None:
            self.advance.set(1).wait(self.mapping["safety"]["stale_s"])

    def start(self):
        """The controller's state from the current frame; the clocks start."""
        self.agent.start(self.observe())
        self.frames = None
        self.t0, self.cpu0 = time.perf_counter(), time.process_time()

    def step(self) -> tuple[dict, dict]:
        """One control step (wait for a frame, read, probe, act, write); the event's data and time
        stamps."""
        started = time.perf_counter()
        self.frame()
        t_frame = self.det.tick_time
        data, stamps = self.readings()
        obs, base_wl = self.observe(), self.lines.position
        results, latency, decide = np.zeros(self.agent.probes), [], 0.0
        for i in range(
            self.agent.probes
        ):  # a probe: move, wait for the next frame, read (moved back below)
            t = time.perf_counter()
            offsets = self.agent.offsets(obs, results, i)
            decide += time.perf_counter() - t
            if offsets is None:  # left out: no move, no frame
                results[i] = np.nan
                continue
            self.lines.move(base_wl + offsets)
            latency.append(1e3 * (time.perf_counter() - t_frame))
            self.moved()
            self.tick()
            self.frame()
            t_frame, results[i] = self.det.tick_time, self.probe_power()
        t = time.perf_counter()
        action = self.agent.act(obs, results)
        decide_ms = 1e3 * (decide + time.perf_counter() - t)
        sent = self.lines.move(base_wl + action * self.scale)
        sent_at = time.time()
        latency.append(1e3 * (time.perf_counter() - t_frame))
        self.moved()
        self.cut(action, (sent - self.lines.shift - base_wl) / self.scale)
        control = {
            "control_action": action,
            "control_setpoint_wl": sent,
            "control_probe_power": results,
            "control_latency_ms": latency[-1],
        }
        data.update(control)
        stamps.update(dict.fromkeys(control, sent_at))
        self.record(latency, decide_ms)
        self.tick()
        self.pace(started)
        return data, stamps

    def cut(self, action: np.ndarray, done: np.ndarray):
        """Where the safety limits cut the step's ``action``: counted, and the controller told the
        action ``done`` (N,), the move sent less its wrap (a whole period: the same optics)."""
        if not np.allclose(done, action, rtol=0, atol=1e-9):
            self.actions_cut += 1
            self.agent.tell(done)

    def pace(self, started: float):
        """Sleep to the rate cap's next deadline, a period after the last (the first: a period after
        the step ``started``). Deadlines are one period apart whatever each step took: a late
        wake-up does not shift the next, so a cap equal to the bench's frame rate does not drift
        into skipping frames. After a step that started more than a period past its deadline they
        start again from that step."""
        late = self.deadline is None or started - self.deadline > self.period
        self.deadline = (started if late else self.deadline) + self.period
        now = time.perf_counter()
        if (wait := self.deadline - now) > 0:
            time.sleep(wait)

    def flyer(self, page_s: float = FLUSH_S) -> LoopFlyer:
        """The loop as a Bluesky flyer: one event per step in the stream ``primary``, a page due
        every ``page_s``."""
        control = Control(name="control")
        control.put(np.zeros(self.n), np.zeros(self.n), np.zeros(self.agent.probes), 0.0)
        readings, self.reads = described(self.bench)
        keys = {**readings, **control.describe()}
        return LoopFlyer("control_loop", keys, self.start, self.step, self.done, page_s=page_s)

    def record(self, latency_ms: list, decide_ms: float):
        ev = getattr(self.bench, "evaluation", None)
        self.rec["time_s"].append(time.perf_counter() - self.t0)
        value = self.feed.value
        self.rec["tick"].append(int(value(self.det.tick.pvname)))
        self.rec["p_pmax"].append(float(value(ev.p_pmax.pvname)) if ev is not None else np.nan)
        self.rec["p_pbest"].append(float(value(ev.p_pbest.pvname)) if ev is not None else np.nan)
        self.rec["latency_ms"].extend(latency_ms)
        self.rec["decide_ms"].append(decide_ms)

    def done(self) -> bool:
        steps = len(self.rec["time_s"])
        return (
            self.user_stop
            or self.stop_reason is not None
            or time.perf_counter() - self.t0 >= self.seconds
            or 0 < self.max_steps <= steps
        )


def control_plan(loop: Loop, md: dict, flush_s: float = FLUSH_S):
    """The Bluesky plan: the control loop as a flyer (``agents.bench.flyer``) in its own thread, its
    events (one per control step: the bench's readings, the action, the setpoints sent, the probe
    readings and the step's latency) collected in pages, one due every ``flush_s`` s; ends by time,
    by the user or by the watchdog."""
    import bluesky.preprocessors as bpp
    from bluesky.utils import FailedStatus

    flyer = loop.flyer(flush_s)

    @bpp.run_decorator(md=md)
    def run():
        try:
            yield from fly(flyer)
        except FailedStatus:  # the loop ended on an exception (its events kept): fail the run
            stop = isinstance(
                flyer.error, SafetyStop
            )  # the watchdog, or a setpoint write that found its PV gone
            if not stop:  # a failure: its traceback
                log.error("the control loop failed", exc_info=flyer.error)
            loop.trip(loop.stop_reason or (str(flyer.error) if stop else f"error: {flyer.error!r}"))
            raise SafetyStop(loop.stop_reason) from None

    return run()
