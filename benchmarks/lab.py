"""Controllers on the simulated bench over real Channel Access: each run against a fresh IOC
(``python -m ops_jax.ioc``, same seed) on a free localhost port, then the IOC SIGKILLed mid-run.
Prints the table and writes ``lab.json`` (needs the ``lab`` extra).

    python -m benchmarks.lab --seconds 60 --rates 100 50 25 --out results/lab [--policy DIR ...]
    python -m benchmarks.lab --frames-only --wrap 0.5 --idle-s 10 --seeds 1 2 3 \\
        --controllers physics-frames
    python -m benchmarks.lab --lockstep 600 --controllers --policy DIR --trims none guarded bench \\
        --seeds 1 2 3

``--frames-only``: the bench serves no length readouts (``--observe-lengths False``) and the runner maps none;
``--wrap WL``: the runner's ``--wrap``; ``--idle-s``: the bench runs uncontrolled this long before the runner
starts (its own start-up comes on top: the summary's ``first_tick`` is the tick of its first step);
``--seeds``: the benches' seeds (``--seed`` of the IOC), a run per seed; ``--learn ALGO``: learn on each bench, then
run the checkpoint (``--kill-learner-after S``: the learning run SIGKILLed after S seconds and resumed);
``--trims``: each controller run alone ("none") and wrapped in each named preset of the extremum-seeking trim
(``agents.controllers.trim``: the runner's ``--trim config=NAME``).

Columns: the runner's control rate cap, achieved control steps per second, frames (IOC ticks) per
step, step latency (from a frame's arrival to the last setpoint written) p50 / p99, the runner's CPU
time per step (all its threads), mean P / P_best over the last 80 % of the run, and the early frames: steps whose
frame, taken as the bench's answer to the step before, the IOC had computed before that step's move reached it
(``early_frames`` of ``early_frames_checked`` steps, from the IOC's ``--tick-log``): the mapping's
``detector.settle_s`` was too short for them.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from agents.io import dumps_json, read_json, write_json_atomic

ROOT = Path(__file__).resolve().parents[1]
IOC_ARGS = ["--stages", "5", "--mode", "hard", "--imperfections", "lab"]
# name: (controller, settings). The physics-informed controller's best settings at the lab level
# (docs/imperfections.md); SPGD as tuned for the simulator, and with a dither above the bench's noise
# between two frames (docs/lab.md).
CONTROLLERS = {
    "spgd": ("spgd", []),
    "spgd-bench": ("spgd", ["delta=0.01", "kp_min=0.05"]),
    "physics": ("physics", ["identify=True", "use_lengths=True", "starts=8", "iters=6"]),
    # the detector's frames alone: the ideal model's fit (comparing the latest frame with the one before
    # it, or with the three before it), or the fit that identifies the imperfections
    "physics-frames": ("physics", ["config=frames", "starts=8", "iters=6"]),
    # the runner's own choice (on a bench without length readouts: the frames configuration, 16 x 8 fit)
    "physics-defaults": ("physics", []),
    "physics-frames-history": ("physics", ["config=frames", "history=3", "starts=8", "iters=6"]),
    # the fit to acquire, SPGD's dither step to hold near the top (one probe per step)
    "physics-frames-hold": ("physics", ["config=frames-hold", "starts=8", "iters=6"]),
    "physics-frames-identify": (
        "physics",
        ["config=frames", "identify=True", "starts=8", "iters=6"],
    ),
}
FRAMES_ONLY = ["--observe-lengths", "False"]
START_S = 300  # an IOC or runner start-up on a loaded 2-core machine (JAX import and compile)


def free_port(other: int | None = None) -> int:
    """A localhost port free for both TCP and UDP (Channel Access serves both on one port), not ``other``, and
    outside the kernel's range for auto-bound ports (from 20,000 up: clear of the well-known ports and of Ray's
    worker ports, 10002-19999). caproto binds an IOC's UDP port with SO_REUSEADDR and SO_REUSEPORT, as it does its
    client sockets, so a client socket the kernel auto-binds to the IOC's port takes the IOC's search replies for
    itself and the client's search times out."""
    from ops_jax.ioc import ephemeral_ports

    first, last = ephemeral_ports()
    outside = [*range(20_000, first), *range(last + 1, 65_536)] or [*range(1024, first)]
    if not outside:
        raise RuntimeError(
            f"no localhost port for Channel Access outside the kernel's auto-bound range {first}-{last}"
        )
    rng = random.SystemRandom()
    for _ in range(200):
        port = rng.choice(outside)
        with (
            socket.socket(socket.AF_INET, socket.SOCK_STREAM) as tcp,
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp,
        ):
            try:
                tcp.bind(("127.0.0.1", port))
                udp.bind(("127.0.0.1", port))
            except OSError:
                continue
            if port != other:
                return port
    raise RuntimeError(f"no free localhost port for Channel Access outside {first}-{last}")


def ca_env() -> dict:
    """This process's environment with Channel Access confined to a fresh localhost port."""
    server = free_port()
    return {
        **os.environ,
        "EPICS_CA_SERVER_PORT": str(server),
        "EPICS_CA_REPEATER_PORT": str(free_port(server)),
        "EPICS_CA_ADDR_LIST": "127.0.0.1",
        "EPICS_CA_AUTO_ADDR_LIST": "NO",
    }


class Process:
    """A ``python -m MODULE ARGS`` subprocess in its own process group, output to ``log``; ``cpus``: on these CPU
    cores only (Linux; None: any)."""

    def __init__(self, module: str, args, env: dict, log: Path, cpus: set | None = None):
        self.env, self.log = env, Path(log)
        run = (
            ["-m", module]
            if cpus is None
            else [  # the child sets its cores before it starts a thread
                "-c",
                f"import os, runpy; os.sched_setaffinity(0, {sorted(cpus)}); "
                f"runpy.run_module({module!r}, run_name='__main__', alter_sys=True)",
            ]
        )
        with open(self.log, "w") as f:
            self.proc = subprocess.Popen(
                [sys.executable, *run, *map(str, args)],
                stdout=f,
                stderr=subprocess.STDOUT,
                cwd=ROOT,
                env=env,
                start_new_session=True,
            )

    def text(self) -> str:
        return self.log.read_text()

    def wait_for(self, needle: str, timeout: float = START_S) -> "Process":
        """Wait until ``needle`` is in the output; raise (with the output) if it exits or times out."""
        deadline = time.monotonic() + timeout
        while needle not in self.text():
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f"{self.log.name}: exited with {self.proc.returncode}:\n{self.text()}"
                )
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"{self.log.name}: no {needle!r} within {timeout} s:\n{self.text()}"
                )
            time.sleep(0.1)
        return self

    def wait(self, timeout: float = START_S) -> int:
        """The exit status; killed (and TimeoutError) past ``timeout`` s."""
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise TimeoutError(
                f"{self.log.name}: still running after {timeout} s:\n{self.text()}"
            ) from None

    def kill(self) -> None:
        """SIGKILL the whole process group."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(30)


TICK_LOG = "ticks.jsonl"  # the IOC's --tick-log, beside its ioc.log


def start_ioc(out: Path, *args, cpus: set | None = None) -> Process:
    """A simulated bench serving on a fresh port (on CPU cores ``cpus``; None: any), once it serves; its ticks
    logged to ``out/TICK_LOG``."""
    return Process(
        "ops_jax.ioc", [*args, "--tick-log", out / TICK_LOG], ca_env(), out / "ioc.log", cpus
    ).wait_for("serving")


def early_frames(documents: Path, ticks: Path) -> tuple[int, int]:
    """(steps whose frame the IOC computed from other setpoints than the move of the step before, steps checked):
    each event's frame tick looked up in the IOC's tick log (``--tick-log``) and its setpoints compared with the
    previous event's move (within a run; a run resumed into the same documents starts afresh)."""
    applied = {}
    for line in ticks.read_text().split("\n")[:-1]:  # whole lines: the IOC may be writing the last
        tick = json.loads(line)
        applied[tick["tick"]] = tick["setpoints"]
    early = checked = 0
    sent = None
    for line in documents.read_text().splitlines():
        doc = json.loads(line)
        if doc["name"] == "start":
            sent = None
        elif doc["name"] == "event":
            data = doc["doc"]["data"]
            seen = applied.get(data["bench_detector_tick"])
            if sent is not None and seen is not None:
                checked += 1
                early += any(abs(a - b) > 1e-9 for a, b in zip(seen, sent, strict=True))
            sent = data["control_setpoint_wl"]
    return early, checked


def _bench_args(
    stale_s: float,
    rate: float,
    frames_only: bool,
    wrap: float | None,
    settle_s: float | None = None,
) -> list:
    """The runner's arguments shared by every run on the simulated bench (``settle_s`` None: the runner's default)."""
    return (
        ["--prefix", "OPS:", "--rate", rate, "--stale-s", stale_s]
        + (["--no-lengths"] if frames_only else [])
        + (["--wrap", wrap] if wrap is not None else [])
        + (["--settle-s", settle_s] if settle_s is not None else [])
    )


def _sets(values) -> list:
    """``--set V`` for each of ``values`` (the runner takes one setting per ``--set``)."""
    return [x for v in values for x in ("--set", v)]


def _cpu(core: int | None) -> list:
    """The runner's ``--cpu CORE`` (none for None)."""
    return [] if core is None else ["--cpu", core]


def _other_cores(core: int | None) -> set | None:
    """The cores this process may use but ``core``: the simulated bench's when the runner has ``core`` (None: any)."""
    if core is None:
        return None
    from agents.bench.runner import usable_cores

    return (usable_cores(core) - {core}) or None


def _run(out: Path, args: list, env: dict, timeout: float) -> dict:
    """``python -m agents.bench ARGS --out OUT``; its summary.json with ``first_tick``, the bench's tick at the
    run's first step, and ``wall_s``, the process's seconds from its start (imports and compiling included)."""
    t0 = time.monotonic()
    runner = Process("agents.bench", [*args, "--out", out], env, out.parent / f"{out.name}.log")
    rc = runner.wait(timeout)
    wall_s = time.monotonic() - t0
    if rc not in (0, 3):  # 3: the watchdog stopped the run; its summary is reported as such
        raise RuntimeError(f"the run failed ({rc}):\n{runner.text()}")
    first = next(
        json.loads(line)
        for line in (out / "documents.jsonl").read_text().splitlines()
        if '"name": "event"' in line
    )
    early, checked = early_frames(out / "documents.jsonl", out.parent / TICK_LOG)
    return {
        **read_json(out / "summary.json"),
        "first_tick": first["doc"]["data"]["bench_detector_tick"],
        "wall_s": wall_s,
        "early_frames": early,
        "early_frames_checked": checked,
    }


def unseen_args(seed: int, scale: float) -> list:
    """IOC options of protocol (b)'s unseen bench ``seed`` (``benchmarks.budget.plan.unseen_bench``: the lab preset at
    ``scale``, its per-stage error patterns re-drawn from the seed)."""
    from benchmarks.budget.plan import unseen_bench

    drawn = unseen_bench({"stages": 5}, seed, scale)
    return [
        x
        for k, v in drawn.items()
        if isinstance(v, list)
        for x in (f"--{k.replace('_', '-')}", str(tuple(v)))
    ]


def _ioc(
    out: Path,
    lockstep: int,
    frames_only: bool,
    seed: int,
    scale: float = 1.0,
    unseen: bool = False,
    cpus: set | None = None,
) -> Process:
    clock = ["--lockstep"] if lockstep else ["--rate", 100]
    drawn = unseen_args(seed, scale) if unseen else []
    return start_ioc(
        out,
        "--prefix",
        "OPS:",
        *clock,
        *IOC_ARGS,
        "--imperfection-scale",
        scale,
        *drawn,
        "--seed",
        seed,
        *(FRAMES_ONLY if frames_only else []),
        cpus=cpus,
    )


def run_controller(
    out: Path,
    controller: str,
    sets,
    seconds: float,
    rate: float,
    stale_s: float,
    lockstep: int = 0,
    frames_only: bool = False,
    wrap: float | None = None,
    idle_s: float = 0.0,
    seed: int = 0,
    scale: float = 1.0,
    unseen: bool = False,
    cpu: int | None = None,
    trim: str | None = None,
    settle_s: float | None = None,
) -> dict:
    """One run against a fresh IOC (``IOC_ARGS`` at imperfection ``scale``, bench seed ``seed``, 100 Hz, or
    ``lockstep`` > 0 steps in lockstep; ``frames_only``: without length readouts; ``unseen``: as ``run_learning``),
    started ``idle_s`` after the IOC serves, the runner on core ``cpu`` and the IOC on the others (None: any), the
    controller wrapped in the trim's preset ``trim`` (None: alone), the runner's ``--settle-s settle_s`` (None: its
    default); returns its summary.json with ``first_tick``."""
    out.mkdir(parents=True, exist_ok=True)
    ioc = _ioc(out, lockstep, frames_only, seed, scale, unseen, _other_cores(cpu))
    try:
        time.sleep(idle_s)
        args = [
            *_bench_args(stale_s, rate, frames_only, wrap, settle_s),
            "--controller",
            controller,
            "--seconds",
            seconds,
        ]
        args += ["--lockstep", "--steps", lockstep] if lockstep else []
        args += _sets(sets) + _cpu(cpu) + ([] if trim is None else ["--trim", f"config={trim}"])
        return _run(out / "run", args, ioc.env, START_S + 2 * seconds + lockstep)
    finally:
        ioc.kill()


def run_learning(
    out: Path,
    algo: str,
    steps: int,
    seconds: float,
    rate: float,
    stale_s: float,
    frames_only: bool = False,
    wrap: float | None = None,
    idle_s: float = 0.0,
    seed: int = 0,
    start_from: str | None = None,
    sets=(),
    scale: float = 1.0,
    unseen: bool = False,
    kill_after: float | None = None,
    catch_up_s: float | None = None,
    learn_seconds: float | None = None,
    checkpoint_every: int | None = None,
    cpu: int | None = None,
    settle_s: float | None = None,
) -> tuple[dict, dict]:
    """``agents.bench --learn ALGO --steps STEPS`` (from ``start_from``, an ``agents.save`` folder; ``sets``: its
    ``--set`` values) against a fresh IOC (the lab preset at ``scale``; ``unseen``: its per-stage errors re-drawn
    from ``seed``, ``unseen_args``) started ``idle_s`` before, then its
    checkpoint as a controller for ``seconds`` on the same bench: the two summaries. ``kill_after``: the learning
    run is SIGKILLed that many seconds after its start, or once it has written its first checkpoint if later, and
    continued with ``--resume`` (the summary, the resumed run's, adds ``killed_after_s``); ``checkpoint_every``: the
    runner's ``--checkpoint-every`` (None: its default); ``catch_up_s``: the runner's ``--catch-up-s`` (None: its default);
    ``learn_seconds``: the learning run's ``--seconds`` (it stops at ``steps`` or then, whichever comes first);
    ``cpu``: the checkpoint's run on that core (the learning run on any), the IOC on the others; ``settle_s``: the
    runner's ``--settle-s`` in both runs (None: its default)."""
    out.mkdir(parents=True, exist_ok=True)
    ioc = _ioc(out, 0, frames_only, seed, scale, unseen, _other_cores(cpu))
    try:
        time.sleep(idle_s)
        shared = _bench_args(stale_s, rate, frames_only, wrap, settle_s)
        run = [*shared, "--learn", algo, "--steps", steps] + (
            [] if catch_up_s is None else ["--catch-up-s", catch_up_s]
        )
        run += [] if learn_seconds is None else ["--seconds", learn_seconds]
        run += [] if checkpoint_every is None else ["--checkpoint-every", checkpoint_every]
        learn = run + (["--from", start_from] if start_from else []) + _sets(sets)
        if kill_after is not None:
            killed = Process(
                "agents.bench",
                [*learn, "--out", out / "learn"],
                ioc.env,
                out / "learn-killed.log",
            )
            started, limit = time.monotonic(), START_S + kill_after + 10 * steps / rate
            while (
                time.monotonic() - started < kill_after
                or not (out / "learn" / "checkpoint" / "learner.json").exists()
            ):
                if killed.proc.poll() is not None:
                    raise RuntimeError(f"the learning run ended before its kill:\n{killed.text()}")
                if time.monotonic() - started > limit:
                    killed.kill()
                    raise TimeoutError(
                        f"the learning run wrote no checkpoint within {limit:.0f} s:\n{killed.text()}"
                    )
                time.sleep(0.05)
            killed.kill()
            killed_after = time.monotonic() - started
            learn = [*run, "--resume"]  # the run's own settings, from its checkpoint
        learned = _run(out / "learn", learn, ioc.env, START_S + 10 * steps / rate)
        if kill_after is not None:
            learned["killed_after_s"] = killed_after
        ran = _run(
            out / "run",
            [
                *shared,
                "--controller",
                out / "learn" / "checkpoint",
                "--seconds",
                seconds,
                *_cpu(cpu),
            ],
            ioc.env,
            START_S + 2 * seconds,
        )
        return learned, ran
    finally:
        ioc.kill()


def kill_check(
    out: Path, stale_s: float, controller: str = "physics", after_events: int = 100
) -> dict:
    """SIGKILL the IOC after ``after_events`` steps; how the runner ends."""
    out.mkdir(parents=True, exist_ok=True)
    ioc = start_ioc(out, "--prefix", "OPS:", "--rate", 100, *IOC_ARGS)
    runner = Process(
        "agents.bench",
        [
            "--prefix",
            "OPS:",
            "--controller",
            controller,
            "--seconds",
            600,
            "--stale-s",
            stale_s,
            "--out",
            out,
        ],
        ioc.env,
        out / "runner.log",
    )
    docs = out / "documents.jsonl"
    deadline = time.monotonic() + START_S
    while not (docs.exists() and docs.read_text().count('"name": "event"') >= after_events):
        if runner.proc.poll() is not None or time.monotonic() > deadline:
            ioc.kill()
            raise RuntimeError(f"the run ended or stalled before the kill:\n{runner.text()}")
        time.sleep(0.05)
    killed = time.time()
    ioc.kill()
    rc = runner.wait(120)
    exited = time.time()
    summary = read_json(out / "summary.json")
    lines = docs.read_text().splitlines()
    last = json.loads(lines[-1])
    return {
        "exit_status": rc,
        "exit_s": exited - killed,
        "watchdog_s": summary["watchdog_time"] - killed,
        "stopped_by": summary["stopped_by"],
        "events_kept": sum('"name": "event"' in x for x in lines),
        "stop_document": last["name"] == "stop" and last["doc"]["exit_status"] == "fail",
    }


def table(rows: list) -> str:
    head = (
        "| controller | bench seed | first tick | rate cap (Hz) | steps/s | frames/step | latency p50 / p99 (ms) "
        "| CPU ms/step | P / P_best | clipped / wrapped moves | early frames | stopped by |\n"
        + "|---" * 12
        + "|"
    )
    body = [
        f"| {r['controller']} | {r['bench_seed']} | {r['first_tick']} | {r['rate']:g} | {r['rate_hz']:.1f} | "
        f"{r['frames_per_step']:.2f} | {r['latency_ms_p50']:.2f} / {r['latency_ms_p99']:.2f} | "
        f"{r['cpu_ms_per_step']:.2f} | {r['p_over_pbest_mean']:.4f} | {r['clipped_moves']} / "
        f"{r['wrapped_moves']} | {r['early_frames']} / {r['early_frames_checked']} | {r['stopped_by']} |"
        for r in rows
    ]
    return "\n".join([head, *body])


def main(argv=None) -> dict:
    from agents import TrimConfig

    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.lab", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument(
        "--rates",
        type=float,
        nargs="+",
        default=[100.0],
        help="the runner's control rate caps (Hz)",
    )
    ap.add_argument(
        "--controllers", nargs="*", default=["spgd", "physics"], choices=list(CONTROLLERS)
    )
    ap.add_argument(
        "--policy", nargs="*", default=[], help="folders written by agents.save, run too"
    )
    ap.add_argument(
        "--stale-s", type=float, default=0.5, help="the watchdog's limit on a frame's age (s)"
    )
    ap.add_argument(
        "--lockstep",
        type=int,
        default=0,
        metavar="STEPS",
        help="run each controller STEPS steps in lockstep instead (scores without timing)",
    )
    ap.add_argument("--no-kill", action="store_true", help="skip the IOC-SIGKILL check")
    ap.add_argument("--frames-only", action="store_true", help="a bench without length readouts")
    ap.add_argument(
        "--wrap", type=float, default=None, metavar="WL", help="the runner's --wrap (wl)"
    )
    ap.add_argument(
        "--idle-s", type=float, default=0.0, help="the bench runs uncontrolled this long first (s)"
    )
    ap.add_argument(
        "--seeds", type=int, nargs="+", default=[0], help="the benches' seeds, a run per seed"
    )
    ap.add_argument(
        "--learn",
        metavar="ALGO",
        help="instead: learn on each bench (agents.bench --learn), then run "
        "the checkpoint as a controller for --seconds on the same bench",
    )
    ap.add_argument(
        "--learn-steps", type=int, default=20_000, help="--learn: env steps of learning"
    )
    ap.add_argument(
        "--learn-seconds",
        type=float,
        default=None,
        metavar="S",
        help="--learn: the learning loop's limit (s; start-up not included): it stops at --learn-steps or "
        "S, whichever comes first",
    )
    ap.add_argument(
        "--from", dest="from_", metavar="DIR", help="--learn: start from this policy (agents.save)"
    )
    ap.add_argument(
        "--learn-set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="--learn: the learner's settings",
    )
    ap.add_argument(
        "--kill-learner-after",
        type=float,
        default=None,
        metavar="S",
        help="--learn: SIGKILL the learning run S seconds after its start (not before its first checkpoint), "
        "then continue it with --resume",
    )
    ap.add_argument(
        "--checkpoint-every",
        type=int,
        default=None,
        metavar="M",
        help="--learn: the runner's --checkpoint-every (env steps)",
    )
    ap.add_argument(
        "--catch-up-s",
        type=float,
        default=None,
        metavar="S",
        help="--learn: the runner's --catch-up-s",
    )
    ap.add_argument(
        "--trims",
        nargs="+",
        default=["none"],
        choices=["none", *sorted(TrimConfig.PRESETS)],
        metavar="NAME",
        help="each controller alone (none) and wrapped in each of these presets of the "
        "trim (agents.TrimConfig: %(choices)s)",
    )
    ap.add_argument(
        "--imperfection-scale",
        type=float,
        default=1.0,
        help="the benches' lab imperfections, x the preset",
    )
    ap.add_argument(
        "--unseen",
        action="store_true",
        help="each bench's per-stage errors re-drawn from its seed, "
        "as protocol (b)'s unseen benches (benchmarks.budget.plan)",
    )
    ap.add_argument(
        "--cpu",
        type=int,
        default=None,
        metavar="CORE",
        help="the controllers' runs on this CPU core only (the runner's --cpu; learning runs on any), the "
        "simulated bench on the others",
    )
    ap.add_argument(
        "--settle-s",
        type=float,
        nargs="+",
        default=[None],
        metavar="S",
        help="the runner's --settle-s (s), a run per value (--learn: the first; default: the runner's)",
    )
    ap.add_argument("--out", type=Path, default=Path("results/lab"))
    args = ap.parse_args(argv)
    try:
        _other_cores(args.cpu)
    except ValueError as exc:
        ap.error(str(exc))
    from agents.bench.devices import SETTLE_RANGE_S

    low, high = SETTLE_RANGE_S
    if any(s is not None and not low <= s <= high for s in args.settle_s):
        ap.error(f"--settle-s must be in [{low:g}, {high:g}] s, got {args.settle_s}")
    rows = []
    controllers = [(c, *CONTROLLERS[c]) for c in args.controllers] + [
        (Path(p).name, p, []) for p in args.policy
    ]
    runs = [] if args.learn else controllers  # --learn: the learners' runs instead
    if args.learn:
        for seed in args.seeds:
            learned, ran = run_learning(
                args.out / f"learn-{args.learn}-seed{seed}",
                args.learn,
                args.learn_steps,
                args.seconds,
                args.rates[0],
                args.stale_s,
                args.frames_only,
                args.wrap,
                args.idle_s,
                seed,
                args.from_,
                args.learn_set,
                args.imperfection_scale,
                args.unseen,
                args.kill_learner_after,
                args.catch_up_s,
                args.learn_seconds,
                args.checkpoint_every,
                args.cpu,
                args.settle_s[0],
            )
            for summary, name in ((learned, f"learning {args.learn}"), (ran, "its checkpoint")):
                rows.append(
                    {
                        **summary,
                        "controller": name,
                        "settings": [],
                        "rate": args.rates[0],
                        "bench_seed": seed,
                        "settle_s": args.settle_s[0],
                    }
                )
                print(table(rows[-1:]).splitlines()[-1], flush=True)
    trims = [(None, "") if t == "none" else (t, f" + trim {t}") for t in args.trims]
    for (name, controller, sets), (trim, suffix) in itertools.product(runs, trims):
        for rate, settle, seed in itertools.product(args.rates, args.settle_s, args.seeds):
            settled = "" if settle is None else f" (settle {1e3 * settle:g} ms)"
            folder = args.out / (
                f"{name}{'' if trim is None else '-trim-' + trim}-{rate:g}hz"
                + ("" if settle is None else f"-settle{1e3 * settle:g}ms")
                + (f"-seed{seed}" if args.seeds != [0] else "")
            )
            s = run_controller(
                folder,
                controller,
                sets,
                args.seconds,
                rate,
                args.stale_s,
                args.lockstep,
                args.frames_only,
                args.wrap,
                args.idle_s,
                seed,
                args.imperfection_scale,
                args.unseen,
                args.cpu,
                trim,
                settle,
            )
            rows.append(
                {
                    **s,
                    "controller": name + suffix + settled,
                    "settings": sets,
                    "rate": rate,
                    "bench_seed": seed,
                    "trim": trim,
                    "settle_s": settle,
                }
            )
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    ioc = (
        IOC_ARGS
        + (["--lockstep"] if args.lockstep else ["--rate", "100"])
        + (FRAMES_ONLY if args.frames_only else [])
    )
    ioc += ["--imperfection-scale", str(args.imperfection_scale)]
    result = {
        "ioc": ioc,
        "seconds": args.seconds,
        "frames_only": args.frames_only,
        "wrap": args.wrap,
        "idle_s": args.idle_s,
        "imperfection_scale": args.imperfection_scale,
        "unseen": args.unseen,
        "learn": args.learn,
        "learn_steps": args.learn_steps,
        "learn_seconds": args.learn_seconds,
        "from": args.from_,
        "kill_learner_after": args.kill_learner_after,
        "checkpoint_every": args.checkpoint_every,
        "catch_up_s": args.catch_up_s,
        "cpu": args.cpu,
        "lockstep_steps": args.lockstep,
        "stale_s": args.stale_s,
        "settle_s": args.settle_s,
        "rows": rows,
        "kill": None if args.no_kill else kill_check(args.out / "kill", args.stale_s),
    }
    print(table(rows))
    if result["kill"]:
        print("IOC SIGKILL:", dumps_json(result["kill"], indent=None))
    write_json_atomic(args.out / "lab.json", result)
    return result


if __name__ == "__main__":
    main()
