"""Controllers on the simulated bench over real Channel Access: each run against a fresh IOC
(``python -m ops_jax.ioc``, same seed) on a free localhost port, then the IOC SIGKILLed mid-run.
Prints the table and writes ``lab.json`` (needs the ``lab`` extra).

    python -m benchmarks.lab --seconds 60 --rates 100 50 25 --out results/lab [--policy DIR ...]
    python -m benchmarks.lab --frames-only --wrap 0.5 --idle-s 10 --seeds 1 2 3 \\
        --controllers physics-frames
    python -m benchmarks.lab --lockstep 600 --controllers --policy DIR --trims none guarded bench \\
        --seeds 1 2 3

``--frames-only``: the bench serves no length readouts (``--observe-lengths False``) and the runner
maps none; ``--wrap WL``: the runner's ``--wrap``; ``--idle-s``: the bench runs uncontrolled this
long before the runner starts (its own start-up comes on top: the summary's ``first_tick`` is the
tick of its first step); ``--seeds``: the benches' seeds (``--seed`` of the IOC), a run per seed;
``--learn ALGO``: learn on each bench, then run the checkpoint (``--kill-learner-after S``: the
learning run SIGKILLed after S seconds and resumed); ``--trims``: each controller run alone ("none")
and wrapped in each named preset of the extremum-seeking trim (``agents.controllers.trim``: the
runner's ``--trim config=NAME``).

Columns: the runner's control rate cap, achieved control steps per second, frames (IOC ticks) per
step, step latency (from a frame's arrival to the last setpoint written) p50 / p99, the runner's CPU
time per step (all its threads), mean P / P_best over the last 80 % of the run and that as a
fraction of the bench's held and predicted ceilings (``ops_jax.imperfections.ceilings``, known here
from the IOC's options and written into each run's summary.json), and the early frames: steps whose
frame, taken as the bench's answer to the step before, the IOC had computed before that step's move
reached it (``early_frames`` of ``early_frames_checked`` steps, from the IOC's ``--tick-log``): the
mapping's ``detector.settle_s`` was too short for them.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
from pathlib import Path

from agents.io import dumps_json, write_json_atomic
from benchmarks.lab.runs import (
    CONTROLLERS,
    FRAMES_ONLY,
    IOC_ARGS,
    LearnSettings,
    RunSettings,
    kill_check,
    other_cores,
    run_controller,
    run_learning,
)


def table(rows: list) -> str:
    """The markdown table of ``rows`` (one per run: its summary with the row's labels)."""
    head = (
        "| controller | bench seed | first tick | rate cap (Hz) | steps/s | frames/step | "
        "latency p50 / p99 (ms) | CPU ms/step | P / P_best | of held / predicted ceiling | "
        "clipped / wrapped moves | early frames | stopped by |\n" + "|---" * 13 + "|"
    )
    fraction = lambda v: "–" if v is None else f"{v:.4f}"
    body = [
        f"| {r['controller']} | {r['bench_seed']} | {r['first_tick']} | {r['rate']:g} | "
        f"{r['rate_hz']:.1f} | {r['frames_per_step']:.2f} | "
        f"{r['latency_ms_p50']:.2f} / {r['latency_ms_p99']:.2f} | {r['cpu_ms_per_step']:.2f} | "
        f"{r['p_over_pbest_mean']:.4f} | {fraction(r.get('p_over_held_mean'))} / "
        f"{fraction(r.get('p_over_held_predicted_mean'))} | "
        f"{r['clipped_moves']} / {r['wrapped_moves']} | "
        f"{r['early_frames']} / {r['early_frames_checked']} | {r['stopped_by']} |"
        for r in rows
    ]
    return "\n".join([head, *body])


def _add_run_options(ap: argparse.ArgumentParser) -> None:
    """The options of every run: duration, rates, controllers, the watchdog and the bench."""
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


def _add_learning_options(ap: argparse.ArgumentParser) -> None:
    """The options of ``--learn``: the learning run before its checkpoint's."""
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
        help="--learn: the learning loop's limit (s; start-up not included): it stops at "
        "--learn-steps or S, whichever comes first",
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
        help="--learn: SIGKILL the learning run S seconds after its start (not before its first "
        "checkpoint), then continue it with --resume",
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


def _add_bench_options(ap: argparse.ArgumentParser) -> None:
    """The options of the trims, the benches' imperfections, the cores, the settle time and the
    output."""
    from agents import TrimConfig

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
        help="the controllers' runs on this CPU core only (the runner's --cpu; learning runs on "
        "any), the simulated bench on the others",
    )
    ap.add_argument(
        "--settle-s",
        type=float,
        nargs="+",
        default=[None],
        metavar="S",
        help="the runner's --settle-s (s), a run per value (--learn: the first; default: the "
        "runner's)",
    )
    ap.add_argument("--out", type=Path, default=Path("results/lab"))


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.lab``."""
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.lab", description=__doc__.split("\n")[0]
    )
    _add_run_options(ap)
    _add_learning_options(ap)
    _add_bench_options(ap)
    return ap


def _parse(argv) -> argparse.Namespace:
    """The parsed command line; ``--cpu`` out of reach and ``--settle-s`` out of range fail naming
    them."""
    ap = parser()
    args = ap.parse_args(argv)
    try:
        other_cores(args.cpu)
    except ValueError as exc:
        ap.error(str(exc))
    from agents.bench.mapping import SETTLE_RANGE_S

    low, high = SETTLE_RANGE_S
    if any(s is not None and not low <= s <= high for s in args.settle_s):
        ap.error(f"--settle-s must be in [{low:g}, {high:g}] s, got {args.settle_s}")
    return args


def _run_settings(args: argparse.Namespace, rate: float, seed: int, settle_s) -> RunSettings:
    """The settings of a run at ``rate`` (Hz) on the bench of ``seed`` with the runner's
    ``settle_s`` (s)."""
    return RunSettings(
        seconds=args.seconds,
        rate=rate,
        stale_s=args.stale_s,
        lockstep=args.lockstep,
        frames_only=args.frames_only,
        wrap=args.wrap,
        idle_s=args.idle_s,
        seed=seed,
        scale=args.imperfection_scale,
        unseen=args.unseen,
        cpu=args.cpu,
        settle_s=settle_s,
    )


def _print_row(rows: list) -> None:
    """The table's line of the last row, as it comes."""
    print(table(rows[-1:]).splitlines()[-1], flush=True)


def _learning_rows(args: argparse.Namespace) -> list:
    """``--learn``: per bench seed, the learning run's row and its checkpoint's (at the first rate
    and settle)."""
    learning = LearnSettings(
        algo=args.learn,
        steps=args.learn_steps,
        start_from=args.from_,
        sets=tuple(args.learn_set),
        kill_after=args.kill_learner_after,
        catch_up_s=args.catch_up_s,
        learn_seconds=args.learn_seconds,
        checkpoint_every=args.checkpoint_every,
    )
    rows = []
    for seed in args.seeds:
        run = _run_settings(args, args.rates[0], seed, args.settle_s[0])
        learned, ran = run_learning(
            args.out / f"learn-{args.learn}-seed{seed}",
            learning,
            dataclasses.replace(run, lockstep=0),
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
            _print_row(rows)
    return rows


def _controller_rows(args: argparse.Namespace, rows: list) -> list:
    """Each controller (and policy), alone and in each trim, per rate, settle and bench seed:
    ``rows`` and their rows (none with ``--learn``)."""
    controllers = [(c, *CONTROLLERS[c]) for c in args.controllers] + [
        (Path(p).name, p, []) for p in args.policy
    ]
    runs = [] if args.learn else controllers  # --learn: the learners' runs instead
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
                folder, controller, sets, _run_settings(args, rate, seed, settle), trim
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
            _print_row(rows)
    return rows


def _result(args: argparse.Namespace, rows: list) -> dict:
    """lab.json's content: the IOC's options, the command's settings, the rows and the IOC-SIGKILL
    check."""
    ioc = (
        IOC_ARGS
        + (["--lockstep"] if args.lockstep else ["--rate", "100"])
        + (FRAMES_ONLY if args.frames_only else [])
    )
    ioc += ["--imperfection-scale", str(args.imperfection_scale)]
    return {
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


def main(argv=None) -> dict:
    """Run the command line ``argv``; print the table and write ``OUT/lab.json``: its content."""
    args = _parse(argv)
    rows = _controller_rows(args, _learning_rows(args) if args.learn else [])
    result = _result(args, rows)
    print(table(rows))
    if result["kill"]:
        print("IOC SIGKILL:", dumps_json(result["kill"], indent=None))
    write_json_atomic(args.out / "lab.json", result)
    return result
