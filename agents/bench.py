"""Drive a controller through a lab's control stack: ophyd devices over EPICS Channel Access, the
control loop a Bluesky plan run by a ``RunEngine``.

    python -m agents.bench --prefix OPS: --controller physics --seconds 60 --rate 100 --out DIR

``--controller``: ``spgd``, ``physics`` or a folder written by ``agents.save``; ``--set key=value``
overrides the controller's hyperparameters, ``--env key=value`` the ``ops_jax.make`` options the
controller is built for (stages come from the bench). The bench is the simulated one of
``python -m ops_jax.ioc`` under ``--prefix`` (``--no-lengths``: without its length readouts) or any bench
described by ``--mapping FILE`` (``agents.bench_devices``). A controller that reads length readouts the
bench lacks fails at start.

One control step: wait for a detector frame that shows the last setpoints written (the newest one
acquired ``settle_s`` or more after the write, by its time stamp), read it, build the observation
exactly as the simulator does (power, oscilloscope samples, length readouts), decide, write the
setpoints (within the safety limits). A probe (SPGD's dither measurement) is a real move: write the
probed setpoints, wait for a frame that shows them, read the power; so each probe costs at least one
frame and the step's action goes out after it. ``--rate`` caps the control steps per second. The loop
runs in its own thread as a Bluesky flyer (``agents.bench_flyer``); the plan collects its events in pages.

The watchdog stops the run at once and writes nothing more when a PV disconnects, no new frame
arrives within ``stale_s``, a reading is older than ``stale_s`` or not finite. Ctrl-C (or SIGTERM)
ends the run after the current step. Written to ``DIR``: ``documents.jsonl`` (the Bluesky documents,
one per line, as they are emitted), ``power.png`` (P / P_max and P / P_best against time) and
``summary.json``. Exit status 0 when the run ended by time or by the user, 3 when the watchdog
stopped it, 2 for bad arguments or a bench that cannot be reached.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import ops_jax
from agents import base, trim
from agents.bench_devices import (Control, MappingError, SafetyStop, check_mapping, connect, disconnect, load_mapping,
                                  make_bench, monitored, signals, sim_mapping)
from agents.bench_flyer import LoopFlyer, fly
from agents.cli import parse_set
from agents.io import write_json_atomic

MAX_PROBES = 16  # probes per control step a controller may ask for
FLUSH_S = 0.2  # the plan collects the loop's events this often (s)
# Python's thread switch interval during a run (s; 5 ms by default): a frame's arrival wakes the loop, which then
# waits at most this long for the interpreter lock held by another thread (the RunEngine's validating a page)
SWITCH_S = 0.0005
EXIT_WATCHDOG = 3
log = logging.getLogger("agents.bench")


class Agent:
    """A controller on one instance (B = 1): ``start(obs)``, then per step the probe ``offsets`` in
    turn and the ``act``ion, with probe results filled in as they are measured. One jitted program;
    a step with K probes calls it K + 1 times (the policy is pure, so each call repeats the same
    draws)."""

    def __init__(self, policy: base.Policy, params, env, seed: int):
        self.policy, self.params, self.env = policy, params, env
        _, self._k_init, self._k_run = jax.random.split(jax.random.key(seed), 3)
        obs = jnp.zeros((1, env.observation_size), jnp.float32)
        calls = []
        jax.eval_shape(lambda: self._act(params, policy.init(self._k_init, obs), obs, self._k_run,
                                         jnp.zeros((MAX_PROBES, 1)), calls))
        self.probes = len(calls)
        self._init = jax.jit(policy.init)
        self._run = jax.jit(self._step)
        # compile before the run (results discarded: the policy is pure); twice, the second time with the
        # carry as act returns it (its dtypes may differ from init's)
        carry = self._init(self._k_init, obs)
        for _ in range(2):
            _, carry, _ = self._run(params, carry, np.zeros(obs.shape[1], np.float32), 0, np.zeros(self.probes, np.float32))
        jax.block_until_ready(carry)
        self.carry, self.t = None, 0

    def _act(self, params, carry, obs, key, results, calls):
        def probe(offsets):
            calls.append(offsets)
            if len(calls) > results.shape[0]:
                raise ValueError(f"the controller asks for more than {MAX_PROBES} probes per step")
            return results[len(calls) - 1].astype(jnp.float32)

        action, carry = self.policy.act(params, carry, obs, key, probe)
        offsets = jnp.stack(calls) if calls else jnp.zeros((0, *action.shape), jnp.float32)
        return action, carry, offsets

    def _step(self, params, carry, obs, t, results):
        """Step ``t``'s (action (N,), carry, probe offsets (K, N)) from obs (D,) and probe results (K,)."""
        key = jax.random.split(jax.random.fold_in(self._k_run, t))[0]
        action, carry, offsets = self._act(params, carry, obs[None], key, results[:, None], [])
        return action[0], carry, offsets[:, 0]

    def start(self, obs):
        """The controller's state from the first observation."""
        self.carry = self._init(self._k_init, jnp.asarray(obs, jnp.float32)[None])

    def _call(self, obs, results):
        return self._run(self.params, self.carry, np.asarray(obs, np.float32), self.t, np.asarray(results, np.float32))

    def offsets(self, obs, results, i: int) -> np.ndarray:
        """Probe i's offsets (N,) wl, given the results of probes 0..i-1."""
        return np.asarray(self._call(obs, results)[2][i], np.float64)

    def act(self, obs, results) -> np.ndarray:
        """The step's action (N,) in [-1, 1]; advances the controller's state."""
        action, self.carry, _ = self._call(obs, results)
        self.t += 1
        return np.asarray(action, np.float64)


def load_controller(spec: str, mapping: dict, env_options: dict, hyper: dict, seed: int,
                    trim_hyper: dict | None = None):
    """(Agent, env_config, action scale (wl per unit), window (wl)) for ``spgd``, ``physics`` or a saved folder
    on the bench of ``mapping``; with ``trim_hyper`` (``TrimConfig`` overrides, ``{}``: the default), wrapped in
    the trim (``agents.trim``). A controller that reads length readouts the mapping lacks fails (``MappingError``)."""
    stages = len(mapping["lines"])
    if spec in ("spgd", "physics"):
        env_config = {"stages": stages, **env_options}
        module = base.algo_module(spec)
        policy, params = module.make_policy(env_config, hyper or None), None
        algo = spec
    else:
        if hyper:
            raise ValueError("--set applies to spgd and physics only; a saved policy keeps its own settings")
        result = base.load(spec)
        env_config = {**result.env_config, **env_options}
        policy, params = result.policy(), result.params
        algo, hyper = result.algo, result.hyper
    if trim_hyper is not None:
        policy, params = trim.trimmed((policy, params), trim_hyper, env_config)
    env, env_params = ops_jax.make(**base.check_env_config(env_config))
    if env.num_actions != stages:
        raise ValueError(f"the controller drives {env.num_actions} lines, the bench has {stages}")
    if env.config.include_noise:
        raise ValueError("controllers built with include_noise=True read the simulator's noise state, "
                         "which no bench can measure")
    check_lengths(spec, reads_lengths(algo, hyper), env, mapping)
    return Agent(policy, params, env, seed), env_config, float(env_params.action_scale), float(env_params.window)


def observes_lengths(env) -> bool:
    """Whether ``env``'s observation frame holds the length readouts (power, 2^N - 1 scope samples, then N
    lengths; frames-only observations stop after the samples)."""
    return env.layout.lengths


def reads_lengths(algo: str, hyper: dict | None) -> bool:
    """Whether a controller of ``algo`` with settings ``hyper`` uses the length readouts: SPGD never,
    the physics-informed controller with ``use_lengths`` (or ``lengths_only``), a learned policy always
    (every input of its networks)."""
    if algo == "spgd":
        return False
    if algo == "physics":
        h = base.ALGOS["physics"].settings(hyper or {})
        return bool(h["use_lengths"] or h["lengths_only"])
    return True


def check_lengths(controller: str, reads: bool, env, mapping: dict) -> None:
    """A controller that uses length readouts on a bench that lacks some fails here, naming the entries."""
    missing = [f"lines[{i}].length" for i, line in enumerate(mapping["lines"]) if "length" not in line]
    if reads and observes_lengths(env) and missing:
        raise MappingError(f"the controller {controller} reads the length readouts and the mapping lacks "
                           f"{', '.join(missing)}; map them, or run a controller that does not read them (spgd, "
                           f"physics with use_lengths=False, a policy trained without them)")


class Loop:
    """The state of one run shared by the plan, the watchdog and the summary."""

    def __init__(self, bench, lines, mapping, agent, scale, window, seconds, rate, steps=0):
        self.bench, self.lines, self.mapping, self.agent = bench, lines, mapping, agent
        self.scale, self.window, self.seconds, self.period = scale, window, seconds, 1.0 / rate
        self.max_steps = steps
        self.det = bench.detector
        self.n = len(mapping["lines"])
        self.frames = None
        self.stop_reason: str | None = None
        self.stopped_at = None  # time.time() of the watchdog's stop
        self.user_stop = False
        self.rec = {k: [] for k in ("time_s", "tick", "p_pmax", "p_pbest", "latency_ms", "decide_ms")}
        self.t0 = self.cpu0 = None  # wall-clock and CPU time at the first step
        self.advance = getattr(bench, "advance", None)
        self.reads = []  # (event key, signal) of the readings recorded at every step

    # -- watchdog --------------------------------------------------------------------------------
    def trip(self, reason: str):
        """Stop at once: no further move; the frame being waited for fails with ``reason``."""
        if self.stop_reason is None:
            self.stop_reason, self.stopped_at = reason, time.time()
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
        elif not self.mapping["advance"] and now - sig.timestamp > self.mapping["safety"]["stale_s"]:
            self.trip(f"stale reading on PV {sig.pvname} ({now - sig.timestamp:.3f} s old)")
        if self.stop_reason:
            raise SafetyStop(self.stop_reason)

    def no_frame(self) -> str:
        lost = sorted(name for name, sig in signals(self.bench).items() if not sig.connected)
        tick = self.mapping["detector"]["tick"]
        return f"lost connection to PV(s) {lost}" if lost else \
            f"no new frame on PV {tick} within {self.mapping['safety']['stale_s']:g} s"

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
            frame = env.layout.encode(power / d["power_full_scale"], trace / d["trace_peak"], lengths, self.window,
                                      xp=np)
        except ValueError as exc:
            self.trip(f"the bench's frame does not fit the controller: {exc}")
            raise SafetyStop(self.stop_reason) from None
        stack = env.config.frame_stack
        self.frames = [frame] * stack if self.frames is None else (self.frames + [frame])[-stack:]
        return np.concatenate(self.frames)

    def moved(self):
        """Setpoints were written: the next frame used must show them (in lockstep: the next tick; else
        a frame acquired ``settle_s`` after now)."""
        if self.mapping["advance"]:
            self.det.use()
        else:
            self.det.after(time.time() + self.mapping["detector"]["settle_s"])

    def probe_power(self) -> float:
        value = monitored(self.det.power)
        self.check(self.det.power, value, time.time())
        return float(value) / self.mapping["detector"]["power_full_scale"]

    def readings(self) -> tuple[dict, dict]:
        """The event's readings of the frame just used (the bench's hinted and normal signals): values and
        IOC time stamps."""
        return {k: monitored(sig) for k, sig in self.reads}, {k: sig.timestamp for k, sig in self.reads}

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
        """One control step (wait for a frame, read, probe, act, write); the event's data and time stamps."""
        next_read = time.perf_counter() + self.period
        self.frame()
        t_frame = self.det.tick_time
        data, stamps = self.readings()
        obs, base_wl = self.observe(), self.lines.position
        results, latency, decide = np.zeros(self.agent.probes), [], 0.0
        for i in range(self.agent.probes):  # a probe: move, wait for the next frame, read (moved back below)
            t = time.perf_counter()
            offsets = self.agent.offsets(obs, results, i)
            decide += time.perf_counter() - t
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
        control = {"control_action": action, "control_setpoint_wl": sent, "control_probe_power": results,
                   "control_latency_ms": latency[-1]}
        data.update(control)
        stamps.update(dict.fromkeys(control, sent_at))
        self.record(latency, decide_ms)
        self.tick()
        if (wait := next_read - time.perf_counter()) > 0:
            time.sleep(wait)
        return data, stamps

    def flyer(self) -> LoopFlyer:
        """The loop as a Bluesky flyer: one event per step in the stream ``primary``."""
        control = Control(name="control")
        control.put(np.zeros(self.n), np.zeros(self.n), np.zeros(self.agent.probes), 0.0)
        keys = {**self.bench.describe(), **control.describe()}
        self.reads = [(k, sig) for k in self.bench.read() for sig in [self._signal(k)]]
        return LoopFlyer("control_loop", keys, self.start, self.step, self.done)

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
        return (self.user_stop or self.stop_reason is not None or time.perf_counter() - self.t0 >= self.seconds
                or 0 < self.max_steps <= steps)


def control_plan(loop: Loop, md: dict, flush_s: float = FLUSH_S):
    """The Bluesky plan: the control loop as a flyer (``agents.bench_flyer``) in its own thread, its events
    (one per control step: the bench's readings, the action, the setpoints sent, the probe readings and the
    step's latency) collected in pages every ``flush_s`` s; ends by time, by the user or by the watchdog."""
    import bluesky.preprocessors as bpp
    from bluesky.utils import FailedStatus

    flyer = loop.flyer()

    @bpp.run_decorator(md=md)
    def run():
        try:
            yield from fly(flyer, flush_s)
        except FailedStatus:  # the loop ended on an exception (its events kept): fail the run
            if not isinstance(flyer.error, SafetyStop):  # a failure, not the watchdog: its traceback
                log.error("the control loop failed", exc_info=flyer.error)
            loop.trip(loop.stop_reason or f"error: {flyer.error!r}")
            raise SafetyStop(loop.stop_reason) from None

    return run()


def summarize(loop: Loop, controller: str, elapsed: float) -> dict:
    """``summary.json``: the score (last 80 % of the run), achieved rates, latencies, how it ended."""
    rec = {k: np.asarray(v, float) for k, v in loop.rec.items()}
    steps, t = len(rec["time_s"]), rec["time_s"]
    tail = t >= 0.2 * elapsed
    pct = lambda v, q: float(np.percentile(v, q)) if v.size else float("nan")
    mean = lambda v: float(np.mean(v)) if v.size else float("nan")
    frames = float(rec["tick"][-1] - rec["tick"][0]) if steps > 1 else 0.0
    stopped_by = loop.stop_reason or ("user" if loop.user_stop else "steps" if 0 < loop.max_steps <= steps else "time")
    return {
        "controller": controller,
        "stopped_by": stopped_by,
        "watchdog_time": loop.stopped_at,
        "steps": steps,
        "seconds": elapsed,
        "rate_hz": steps / elapsed if elapsed > 0 else 0.0,
        "frames_per_step": frames / (steps - 1) if steps > 1 else float("nan"),
        "probes_per_step": loop.agent.probes,
        "latency_ms_p50": pct(rec["latency_ms"], 50),
        "latency_ms_p99": pct(rec["latency_ms"], 99),
        "latency_ms_max": float(rec["latency_ms"].max()) if rec["latency_ms"].size else float("nan"),
        "decide_ms_p50": pct(rec["decide_ms"], 50),
        "decide_ms_p99": pct(rec["decide_ms"], 99),
        "cpu_ms_per_step": 1e3 * (time.process_time() - loop.cpu0) / steps if steps else float("nan"),
        "p_over_pbest_mean": mean(rec["p_pbest"][tail]),
        "p_over_pmax_mean": mean(rec["p_pmax"][tail]),
        "clipped_moves": int(loop.lines.clipped.get()),
    }


def _pyplot():
    """matplotlib's pyplot on the Agg backend (imported before a run: the end of a run is kept short)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot(path: Path, loop: Loop, title: str) -> None:
    """P / P_max and P / P_best against time."""
    plt = _pyplot()
    t = np.asarray(loop.rec["time_s"])
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(t, loop.rec["p_pbest"], lw=1, label="P / P_best")
    ax.plot(t, loop.rec["p_pmax"], lw=1, alpha=0.7, label="P / P_max")
    ax.set(xlabel="time (s)", ylabel="stacked power", ylim=(0, 1.05), title=title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m agents.bench", description=__doc__.split("\n")[0])
    ap.add_argument("--prefix", default="OPS:", help="PV prefix of the simulated bench (without --mapping)")
    ap.add_argument("--stages", type=int, default=None, help="delay lines of the simulated bench "
                    "(default: the saved controller's, else 5)")
    ap.add_argument("--mapping", help="a mapping file (JSON) naming the bench's PVs, units and safety limits")
    ap.add_argument("--no-lengths", action="store_true",
                    help="the simulated bench without its length readouts (LINEi:LEN not mapped; without --mapping)")
    ap.add_argument("--controller", required=True, help="spgd, physics or a folder written by agents.save")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", help="controller hyperparameter")
    ap.add_argument("--env", action="append", metavar="KEY=VALUE", help="ops_jax.make option of the controller")
    ap.add_argument("--trim", nargs="*", metavar="KEY=VALUE", default=None,
                    help="wrap the controller in the extremum-seeking trim (agents.trim; one more probe per step), "
                         "with these TrimConfig settings (none: its default)")
    ap.add_argument("--lockstep", action="store_true",
                    help="the simulated bench runs --lockstep: advance it one frame per step and probe")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--steps", type=int, default=0, help="stop after this many control steps too (0: no limit)")
    ap.add_argument("--rate", type=float, default=100.0, help="most control steps per second (Hz)")
    ap.add_argument("--seed", type=int, default=0, help="the controller's random draws")
    ap.add_argument("--stale-s", type=float, default=None, help="the watchdog's limit on a reading's age and "
                    "on the wait for a frame (s; default: the mapping's, 0.5)")
    ap.add_argument("--out", required=True, help="folder for documents.jsonl, power.png, summary.json")
    return ap


def _setup(args):
    """(mapping, Agent, env_config, action scale, window) from the arguments; raises what is wrong."""
    if not (np.isfinite(args.seconds) and args.seconds > 0):
        raise ValueError(f"--seconds must be > 0, got {args.seconds}")
    if not (np.isfinite(args.rate) and args.rate > 0):
        raise ValueError(f"--rate must be > 0 Hz, got {args.rate}")
    saved = args.controller not in ("spgd", "physics")
    if saved and not Path(args.controller).is_dir():
        raise ValueError(f"--controller must be spgd, physics or a folder written by agents.save, got {args.controller!r}")
    stages = args.stages or (base.load(args.controller).env_config.get("stages", 5) if saved else 5)
    mapping = load_mapping(args.mapping) if args.mapping else sim_mapping(args.prefix, stages, args.lockstep,
                                                                                 lengths=not args.no_lengths)
    if args.stale_s is not None:
        mapping["safety"] = {**(mapping.get("safety") or {}), "stale_s": args.stale_s}
    mapping = check_mapping(mapping)
    agent, env_config, scale, window = load_controller(args.controller, mapping, parse_set(args.env),
                                                       parse_set(args.set), args.seed,
                                                       None if args.trim is None else parse_set(args.trim))
    return mapping, agent, env_config, scale, window


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    out = Path(args.out)
    try:
        mapping, agent, env_config, scale, window = _setup(args)
    except (MappingError, ValueError, TypeError, FileNotFoundError) as exc:
        print(f"agents.bench: {exc}", file=sys.stderr)
        return 2
    _pyplot()
    bench, lines = make_bench(mapping)
    try:
        connect(bench, mapping["safety"]["connect_s"])
    except MappingError as exc:
        print(f"agents.bench: {exc}", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    (out / "documents.jsonl").unlink(missing_ok=True)
    bench.detector.arm()
    loop = Loop(bench, lines, mapping, agent, scale, window, args.seconds, args.rate, args.steps)
    loop.watch()
    md = {"controller": args.controller, "controller_env": env_config, "hyper": parse_set(args.set),
          "trim": None if args.trim is None else parse_set(args.trim),
          "seed": args.seed, "rate_hz": args.rate, "mapping": mapping, "plan_name": "agents.bench"}
    quiet = _QuietStop()
    for name in QUIET_LOGGERS:
        logging.getLogger(name).addFilter(quiet)
    try:
        elapsed = _run(loop, md, out)
    finally:
        disconnect(bench)
        for name in QUIET_LOGGERS:
            logging.getLogger(name).removeFilter(quiet)
    summary = summarize(loop, args.controller, elapsed)
    write_json_atomic(out / "summary.json", summary)
    stopped = summary["stopped_by"] not in ("time", "steps", "user")
    if stopped:
        print(f"agents.bench: stopped by the watchdog: {summary['stopped_by']}", file=sys.stderr, flush=True)
    plot(out / "power.png", loop, f"{args.controller} on the bench, {summary['rate_hz']:.0f} steps/s")
    print(json.dumps(summary, indent=1))
    return EXIT_WATCHDOG if stopped else 0


QUIET_LOGGERS = ("bluesky", "caproto.circ", "caproto.ch")  # filtered by _QuietStop from connection to disconnection


class _QuietStop(logging.Filter):
    """Drops what an expected stop prints besides the runner's line: the RunEngine's "Run aborted" traceback of
    a watchdog stop, and caproto's notes on a closing circuit or channel (the watchdog names the lost PV)."""

    def filter(self, record) -> bool:
        if record.name.startswith("caproto"):
            return False
        return not (record.exc_info and isinstance(record.exc_info[1], SafetyStop))


def _writer(out: Path):
    """The document callback: every document a line of ``out/documents.jsonl`` as it comes (bluesky's
    ``JSONLinesWriter``), an event page as its events."""
    from bluesky.callbacks.json_writer import JSONLinesWriter
    from event_model import sanitize_doc, unpack_event_page

    writer = JSONLinesWriter(str(out), "documents.jsonl")

    def write(name, doc):
        if name != "event_page":
            return writer(name, sanitize_doc(doc))
        with open(out / "documents.jsonl", "a") as f:  # a page (plain types already) at once, one open per page
            f.writelines(json.dumps({"name": "event", "doc": e}) + "\n" for e in unpack_event_page(doc))

    return write


def _run(loop: Loop, md: dict, out: Path) -> float:
    """Run the plan, documents streamed to ``out/documents.jsonl``; returns the seconds it ran."""
    from bluesky import RunEngine

    RE = RunEngine({}, context_managers=[])  # Ctrl-C and SIGTERM end the run after the step (below)
    RE.subscribe(_writer(out))

    def stop(signum, frame):
        if loop.user_stop:  # a second Ctrl-C: stop now, move nothing more
            loop.trip("interrupted by the user")
        loop.user_stop = True

    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    switch = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_S)
    try:
        RE(control_plan(loop, md))
    except Exception as exc:  # the watchdog (SafetyStop) or a failure: no further move, keep what was recorded
        if loop.stop_reason is None:
            loop.trip(f"error: {exc}")
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        sys.setswitchinterval(switch)
    return time.perf_counter() - loop.t0 if loop.t0 is not None else 0.0


if __name__ == "__main__":
    status = main()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    # Everything is on disk: skip the interpreter's teardown of JAX and the Channel Access threads, which
    # takes seconds on a loaded host, so a stopped run ends at once.
    os._exit(status)
