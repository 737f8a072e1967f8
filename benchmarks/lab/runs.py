"""The runs of ``benchmarks.lab``, each against a fresh simulated bench (``ops_jax.ioc``): a
controller's, a learning run's followed by its checkpoint's, and the check of how the runner ends
when the IOC is SIGKILLed."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from agents.bench.report import add_ceilings
from agents.io import read_json
from benchmarks.lab.processes import START_S, TICK_LOG, Process, early_frames, start_ioc

IOC_ARGS = ["--stages", "5", "--mode", "hard", "--imperfections", "lab"]
# name: (controller, settings). The physics-informed controller's best settings at the lab level
# (docs/imperfections.md); SPGD as tuned for the simulator, and with a dither above the bench's
# noise between two frames (docs/lab.md).
CONTROLLERS = {
    "spgd": ("spgd", []),
    "spgd-bench": ("spgd", ["delta=0.01", "kp_min=0.05"]),
    "physics": ("physics", ["identify=True", "use_lengths=True", "starts=8", "iters=6"]),
    # the detector's frames alone: the ideal model's fit (comparing the latest frame with the one
    # before it, or with the three before it), or the fit that identifies the imperfections
    "physics-frames": ("physics", ["config=frames", "starts=8", "iters=6"]),
    # the runner's own choice (on a bench without length readouts: the frames configuration, 16 x 8
    # fit)
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


@dataclass(frozen=True)
class RunSettings:
    """A run's settings on the simulated bench: ``seconds`` of control (s) at the runner's rate cap
    ``rate`` (Hz), its watchdog's ``stale_s`` (s); ``lockstep`` > 0: that many steps in lockstep (0:
    the IOC at 100 Hz); ``frames_only``: no length readouts; ``wrap``: the runner's ``--wrap`` (wl;
    None: none); ``idle_s``: the bench uncontrolled this long first (s); ``seed``: the bench's seed;
    ``scale``: its lab imperfections x the preset; ``unseen``: its per-stage errors re-drawn from
    ``seed`` (``unseen_args``); ``cpu``: the runner on that core and the IOC on the others (None:
    any); ``settle_s``: the runner's ``--settle-s`` (s; None: its default)."""

    seconds: float
    rate: float
    stale_s: float
    lockstep: int = 0
    frames_only: bool = False
    wrap: float | None = None
    idle_s: float = 0.0
    seed: int = 0
    scale: float = 1.0
    unseen: bool = False
    cpu: int | None = None
    settle_s: float | None = None


@dataclass(frozen=True)
class LearnSettings:
    """A learning run's settings: ``agents.bench --learn ALGO --steps STEPS`` (from ``start_from``,
    an ``agents.save`` folder; ``sets``: its ``--set`` values); ``kill_after``: SIGKILLed that many
    seconds (s) after its start, or once it has written its first checkpoint if later, and continued
    with ``--resume`` (None: not killed); ``catch_up_s``, ``learn_seconds`` (its ``--seconds``: it
    stops at ``steps`` or then, whichever comes first), ``checkpoint_every``: the runner's options
    (None: its defaults)."""

    algo: str
    steps: int
    start_from: str | None = None
    sets: tuple = ()
    kill_after: float | None = None
    catch_up_s: float | None = None
    learn_seconds: float | None = None
    checkpoint_every: int | None = None


def _bench_args(run: RunSettings) -> list:
    """The runner's arguments shared by every run on the simulated bench (``settle_s`` None: the
    runner's default)."""
    return (
        ["--prefix", "OPS:", "--rate", run.rate, "--stale-s", run.stale_s]
        + (["--no-lengths"] if run.frames_only else [])
        + (["--wrap", run.wrap] if run.wrap is not None else [])
        + (["--settle-s", run.settle_s] if run.settle_s is not None else [])
    )


def _sets(values) -> list:
    """``--set V`` for each of ``values`` (the runner takes one setting per ``--set``)."""
    return [x for v in values for x in ("--set", v)]


def _cpu(core: int | None) -> list:
    """The runner's ``--cpu CORE`` (none for None)."""
    return [] if core is None else ["--cpu", core]


def other_cores(core: int | None) -> set | None:
    """The cores this process may use but ``core``: the simulated bench's when the runner has
    ``core`` (None: any)."""
    if core is None:
        return None
    from agents.bench.prepare import usable_cores

    return (usable_cores(core) - {core}) or None


def _run(out: Path, args: list, env: dict, timeout: float, bench: dict) -> dict:
    """``python -m agents.bench ARGS --out OUT``; its summary.json, with the ceilings of the bench
    whose ``ops_jax.make`` options are ``bench`` written into it (``agents.bench.report``), and
    ``first_tick``, the bench's tick at the run's first step, and ``wall_s``, the process's seconds
    from its start (imports and compiling included)."""
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
        **add_ceilings(out, bench),
        "first_tick": first["doc"]["data"]["bench_detector_tick"],
        "wall_s": wall_s,
        "early_frames": early,
        "early_frames_checked": checked,
    }


def unseen_args(seed: int, scale: float) -> list:
    """IOC options of protocol (b)'s unseen bench ``seed`` (``benchmarks.budget.plan.unseen_bench``:
    the lab preset at ``scale``, its per-stage error patterns re-drawn from the seed)."""
    from benchmarks.budget.plan import unseen_bench

    drawn = unseen_bench({"stages": 5}, seed, scale)
    return [
        x
        for k, v in drawn.items()
        if isinstance(v, list)
        for x in (f"--{k.replace('_', '-')}", str(tuple(v)))
    ]


def ioc_args(run: RunSettings) -> list:
    """The arguments of ``run``'s simulated bench (``IOC_ARGS``)."""
    clock = ["--lockstep"] if run.lockstep else ["--rate", 100]
    drawn = unseen_args(run.seed, run.scale) if run.unseen else []
    own = ["--prefix", "OPS:", *clock, "--seed", run.seed]
    frames = FRAMES_ONLY if run.frames_only else []
    return own + IOC_ARGS + ["--imperfection-scale", run.scale, *drawn, *frames]


def bench_env(run: RunSettings) -> dict:
    """The ``ops_jax.make`` options of ``run``'s simulated bench, as the IOC reads its arguments."""
    from ops_jax import ioc

    ns = ioc.parser().parse_args([str(a) for a in ioc_args(run)])
    return {"stages": ns.stages, "mode": ns.mode, **ioc.make_options(ns)}


def _ioc(out: Path, run: RunSettings) -> Process:
    """The simulated bench of ``run``, serving, on the cores the runner leaves."""
    return start_ioc(out, *ioc_args(run), cpus=other_cores(run.cpu))


def run_controller(
    out: Path, controller: str, sets, run: RunSettings, trim: str | None = None
) -> dict:
    """One run of ``controller`` (its ``--set`` values ``sets``) against a fresh IOC as ``run``
    says, started ``run.idle_s`` after the IOC serves, the controller wrapped in the trim's preset
    ``trim`` (None: alone); returns its summary.json with ``first_tick``."""
    out.mkdir(parents=True, exist_ok=True)
    ioc = _ioc(out, run)
    try:
        time.sleep(run.idle_s)
        args = [*_bench_args(run), "--controller", controller, "--seconds", run.seconds]
        args += ["--lockstep", "--steps", run.lockstep] if run.lockstep else []
        args += _sets(sets) + _cpu(run.cpu) + ([] if trim is None else ["--trim", f"config={trim}"])
        timeout = START_S + 2 * run.seconds + run.lockstep
        return _run(out / "run", args, ioc.env, timeout, bench_env(run))
    finally:
        ioc.kill()


def _learning_args(learning: LearnSettings, run: RunSettings) -> list:
    """The learning run's own arguments (those ``--resume`` keeps: neither ``--from`` nor
    ``--set``)."""
    args = [*_bench_args(run), "--learn", learning.algo, "--steps", learning.steps]
    args += [] if learning.catch_up_s is None else ["--catch-up-s", learning.catch_up_s]
    args += [] if learning.learn_seconds is None else ["--seconds", learning.learn_seconds]
    every = learning.checkpoint_every
    return args + ([] if every is None else ["--checkpoint-every", every])


def _kill_at_first_checkpoint(
    out: Path, args: list, env: dict, learning: LearnSettings, rate: float
) -> float:
    """Start the learning run ``args`` and SIGKILL it ``learning.kill_after`` s after its start, or
    once it has written its first checkpoint if later; the seconds it ran."""
    killed = Process("agents.bench", [*args, "--out", out / "learn"], env, out / "learn-killed.log")
    started = time.monotonic()
    limit = START_S + learning.kill_after + 10 * learning.steps / rate
    while (
        time.monotonic() - started < learning.kill_after
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
    return time.monotonic() - started


def run_learning(out: Path, learning: LearnSettings, run: RunSettings) -> tuple[dict, dict]:
    """``learning`` against a fresh IOC as ``run`` says (free-running: ``run.lockstep`` must be 0)
    started ``run.idle_s`` before, then its checkpoint as a controller for ``run.seconds`` on the
    same bench (on core ``run.cpu``; the learning run on any): the two summaries. Killed
    (``learning.kill_after``): the summary, the resumed run's, adds ``killed_after_s``."""
    if run.lockstep:
        raise ValueError(f"lockstep must be 0 for a learning run, got {run.lockstep}")
    out.mkdir(parents=True, exist_ok=True)
    ioc = _ioc(out, run)
    try:
        time.sleep(run.idle_s)
        own = _learning_args(learning, run)
        learn = own + (["--from", learning.start_from] if learning.start_from else [])
        learn += _sets(learning.sets)
        if learning.kill_after is not None:
            killed_after = _kill_at_first_checkpoint(out, learn, ioc.env, learning, run.rate)
            learn = [*own, "--resume"]  # the run's own settings, from its checkpoint
        bench = bench_env(run)
        learn_s = START_S + 10 * learning.steps / run.rate
        learned = _run(out / "learn", learn, ioc.env, learn_s, bench)
        if learning.kill_after is not None:
            learned["killed_after_s"] = killed_after
        checkpoint = [*_bench_args(run), "--controller", out / "learn" / "checkpoint"]
        checkpoint += ["--seconds", run.seconds, *_cpu(run.cpu)]
        ran = _run(out / "run", checkpoint, ioc.env, START_S + 2 * run.seconds, bench)
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
