"""The controller and the control loop that ``agents.bench`` runs on a bench, and the Bluesky plan
around it."""

from __future__ import annotations

import logging
import time

import jax
import jax.numpy as jnp
import numpy as np

import ops_jax
from agents import api as base
from agents.controllers import trim
from agents.bench.controller import Controller
from agents.bench.devices import Control, MappingError, SafetyStop, monitored, signals
from agents.bench.flyer import LoopFlyer, fly
from agents.bench.mapping import missing_lengths

MAX_PROBES = 16  # probes per control step a controller may ask for
FLUSH_S = (
    0.2  # a page of the loop's events is due this often (s), collected after the step that ends it
)
USER_STOP = "user"  # the stop reason of a run the user ended at once (a second Ctrl-C or SIGTERM)
log = logging.getLogger("agents.bench")


class Agent(Controller):
    """A controller on one instance (B = 1): ``start(obs)``, then per step the probe ``offsets`` in
    turn and the ``act``ion, with probe results filled in as they are measured. One jitted program;
    a step with K probes calls it K + 1 times (the policy is pure, so each call repeats the same
    draws)."""

    def __init__(self, policy: base.Policy, params, env, seed: int):
        self.policy, self.params, self.env = policy, params, env
        _, self._k_init, self._k_run = jax.random.split(jax.random.key(seed), 3)
        obs = jnp.zeros((1, env.observation_size), jnp.float32)
        calls = []
        jax.eval_shape(
            lambda: self._act(
                params,
                policy.init(self._k_init, obs),
                obs,
                self._k_run,
                jnp.zeros((MAX_PROBES, 1)),
                calls,
            )
        )
        self.probes = len(calls)
        self._init = jax.jit(policy.init)
        self._run = jax.jit(self._step)
        self._sent = (
            None if policy.sent is None else jax.jit(lambda p, c, a: policy.sent(p, c, a[None]))
        )
        # compile before the run (results discarded: the policy is pure); twice, the second time
        # with the carry as act returns it (its dtypes may differ from init's)
        carry = self._init(self._k_init, obs)
        for _ in range(2):
            _, carry, _ = self._run(
                params,
                carry,
                np.zeros(obs.shape[1], np.float32),
                0,
                np.zeros(self.probes, np.float32),
            )
            if self._sent is not None:
                carry = self._sent(params, carry, np.zeros(env.num_actions, np.float32))
        jax.block_until_ready(carry)
        self.carry, self.t = None, 0

    def _act(self, params, carry, obs, key, results, calls):
        def probe(offsets, active=None):
            calls.append((offsets, jnp.ones(offsets.shape[:1], bool) if active is None else active))
            if len(calls) > results.shape[0]:
                raise ValueError(f"the controller asks for more than {MAX_PROBES} probes per step")
            return results[len(calls) - 1].astype(jnp.float32)

        action, carry = self.policy.act(params, carry, obs, key, probe)
        offsets = (
            jnp.stack([c[0] for c in calls])
            if calls
            else jnp.zeros((0, *action.shape), jnp.float32)
        )
        active = (
            jnp.stack([c[1] for c in calls]) if calls else jnp.zeros((0, action.shape[0]), bool)
        )
        return action, carry, (offsets, active)

    def _step(self, params, carry, obs, t, results):
        """Step ``t``'s (action (N,), carry, (probe offsets (K, N), probes made (K,))) from obs (D,)
        and probe results (K,)."""
        key = jax.random.split(jax.random.fold_in(self._k_run, t))[0]
        action, carry, (offsets, active) = self._act(
            params, carry, obs[None], key, results[:, None], []
        )
        return action[0], carry, (offsets[:, 0], active[:, 0])

    def start(self, obs):
        """The controller's state from the first observation."""
        self.carry = self._init(self._k_init, jnp.asarray(obs, jnp.float32)[None])

    def _call(self, obs, results):
        return self._run(
            self.params,
            self.carry,
            np.asarray(obs, np.float32),
            self.t,
            np.asarray(results, np.float32),
        )

    def offsets(self, obs, results, i: int) -> np.ndarray | None:
        """Probe i's offsets (N,) wl, given the results of probes 0..i-1; None where the controller
        leaves it out."""
        offsets, active = self._call(obs, results)[2]
        return np.asarray(offsets[i], np.float64) if bool(active[i]) else None

    def act(self, obs, results) -> np.ndarray:
        """The step's action (N,) in [-1, 1]; advances the controller's state."""
        action, self.carry, _ = self._call(obs, results)
        self.t += 1
        return np.asarray(action, np.float64)

    def tell(self, action) -> bool:
        """Tell a controller that reads its own last move (``Policy.sent``) the action (N,) really
        sent, where the bench's safety limits cut the one it asked for; False for one that does not
        read it."""
        if self._sent is None:
            return False
        self.carry = self._sent(self.params, self.carry, np.asarray(action, np.float32))
        return True


def load_controller(
    spec: str,
    mapping: dict,
    env_options: dict,
    hyper: dict,
    seed: int,
    trim_hyper: dict | None = None,
):
    """(Agent, env_config, action scale (wl per unit), window (wl)) for ``spgd``, ``physics`` or a
    saved folder on the bench of ``mapping``; with ``trim_hyper`` (``TrimConfig`` overrides, ``{}``:
    the default), wrapped in the trim (``agents.controllers.trim``). A controller that reads length
    readouts the mapping lacks fails (``MappingError``)."""
    stages = len(mapping["lines"])
    if spec in ("spgd", "physics"):
        env_config = {"stages": stages, **env_options}
        module = base.algo_module(spec)
        config = base.ALGOS[spec].config.from_hyper(hyper)
        policy, params = module.make_policy(env_config, config), None
        algo = spec
    else:
        if hyper:
            raise ValueError(
                "--set applies to spgd and physics only; a saved policy keeps its own settings"
            )
        result = base.load(spec)
        env_config = {**result.env_spec.as_dict(), **env_options}
        policy, params = result.policy(), result.params
        algo, hyper = result.algo, result.config.to_hyper()
    if trim_hyper is not None:
        policy, params = trim.trimmed((policy, params), trim_hyper, env_config)
    env, env_params = ops_jax.make(**base.check_env_config(env_config))
    if env.num_actions != stages:
        raise ValueError(f"the controller drives {env.num_actions} lines, the bench has {stages}")
    if env.config.include_noise:
        raise ValueError(
            "controllers built with include_noise=True read the simulator's noise state, "
            "which no bench can measure"
        )
    check_lengths(spec, reads_lengths(algo, hyper), env, mapping)
    return (
        Agent(policy, params, env, seed),
        env_config,
        float(env_params.action_scale),
        float(env_params.window),
    )


def observes_lengths(env) -> bool:
    """Whether ``env``'s observation frame holds the length readouts (power, 2^N - 1 scope samples,
    then N lengths; frames-only observations stop after the samples)."""
    return env.layout.lengths


def reads_lengths(algo: str, hyper: dict | None) -> bool:
    """Whether a controller of ``algo`` with settings ``hyper`` uses the length readouts: SPGD
    never, the physics-informed controller with ``use_lengths`` (or ``lengths_only``), a learned
    policy always (every input of its networks)."""
    if algo == "spgd":
        return False
    if algo == "physics":
        config = base.ALGOS["physics"].config.from_hyper(hyper or {})
        return bool(config.use_lengths or config.lengths_only)
    return True


def check_lengths(controller: str, reads: bool, env, mapping: dict) -> None:
    """A controller that uses length readouts on a bench that lacks some, or that wraps its lines (a
    readout jumps by the period), fails here, naming the entries."""
    if reads and observes_lengths(env) and mapping["safety"]["wrap_wl"] is not None:
        raise MappingError(
            f"the controller {controller} reads the length readouts, which jump by a period when "
            "a line wraps (safety.wrap_wl, --wrap); run it without wrapping, or run a controller "
            "that does not read them (spgd, physics with use_lengths=False, a policy trained "
            "without them)"
        )
    missing = missing_lengths(mapping)
    if reads and observes_lengths(env) and missing:
        raise MappingError(
            f"the controller {controller} reads the length readouts and the mapping lacks "
            f"{', '.join(missing)}; map them, or run a controller that does not read them (spgd, "
            f"physics with use_lengths=False, a policy trained without them)"
        )


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
        self.reads = []  # (event key, signal) of the readings recorded at every step
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

    def check(self, sig, value, now: float):
        """Trip on a non-finite or stale reading of ``sig`` (in lockstep a frame waits for the
        controller: its age is not checked)."""
        if not np.all(np.isfinite(value)):
            self.trip(f"non-finite reading on PV {sig.pvname}")
        elif (
            not self.mapping["advance"] and now - sig.timestamp > self.mapping["safety"]["stale_s"]
        ):
            self.trip(f"stale reading on PV {sig.pvname} ({now - sig.timestamp:.3f} s old)")
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
        power, trace = monitored(self.det.power), np.asarray(monitored(self.det.trace), np.float64)
        self.check(self.det.power, power, now)
        self.check(self.det.trace, trace, now)
        env = self.agent.env
        lengths = np.zeros(self.n)
        if env.layout.lengths:  # the length readouts (0 where the bench has no sensor)
            for i in range(self.n):
                sensor = getattr(self.bench, f"length{i + 1}", None)
                if sensor is not None:
                    lengths[i] = monitored(sensor.value)
                    self.check(sensor.value, lengths[i], now)
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
        value = monitored(self.det.power)
        self.check(self.det.power, value, time.time())
        return float(value) / self.mapping["detector"]["power_full_scale"]

    def readings(self) -> tuple[dict, dict]:
        """The event's readings of the frame just used (the bench's hinted and normal signals):
        values and IOC time stamps."""
        return {k: monitored(sig) for k, sig in self.reads}, {
            k: sig.timestamp for k, sig in self.reads
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
        keys = {**self.bench.describe(), **control.describe()}
        self.reads = [(k, sig) for k in self.bench.read() for sig in [self._signal(k)]]
        return LoopFlyer("control_loop", keys, self.start, self.step, self.done, page_s=page_s)

    def _signal(self, name: str):
        return next(w.item for w in self.bench.walk_signals() if w.item.name == name)

    def record(self, latency_ms: list, decide_ms: float):
        ev = getattr(self.bench, "evaluation", None)
        self.rec["time_s"].append(time.perf_counter() - self.t0)
        self.rec["tick"].append(int(monitored(self.det.tick)))
        self.rec["p_pmax"].append(float(monitored(ev.p_pmax)) if ev is not None else np.nan)
        self.rec["p_pbest"].append(float(monitored(ev.p_pbest)) if ev is not None else np.nan)
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
