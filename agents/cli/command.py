"""Train one controller from the command line and write its checkpoint, curve and evaluation.

Run as ``python -m agents --algo td3 --out runs/td3 ...`` (``agents/__main__.py``). Writes into
``--out``: ``checkpoint/`` (``agents.save``; TD3 and DroQ also every ``--checkpoint-every`` env
steps, ``agents.learners.offpolicy.checkpoint``), ``curve.csv``, ``curve.png`` and ``summary.json``
(the testing environment's ``agents.evaluate`` summary, the wall time in parts); ``--logdir``:
TensorBoard event files (``agents.tensorboard``). An ``--out`` holding a run (``RUN_FILES``) is
refused (exit 2, before any work) unless ``--overwrite`` or ``--resume`` (TD3 and DroQ: continued to
its ``--steps`` total with its own options). A budget that takes no gradient step is refused before
any output (``agents.learners.budgets``). Ctrl-C: one line saying what was kept, exit 130
(SIGTERM 143); TD3 and DroQ write their checkpoint first, and the line says how to continue.
"""

from __future__ import annotations

import ast
import dataclasses
import json
import shlex
import shutil
import signal
import sys
import warnings
from pathlib import Path

import agents
from agents import api as base, registry
from agents.learners import budgets
from agents.registry import CONFIG_TYPES
from agents.io import write_json_atomic
from agents.cli.outputs import plot_curve, wall_time_line, write_curve_csv
from agents.learners.offpolicy.checkpoint import EVERY as CHECKPOINT_EVERY
from ops_jax.cli.progress import StepProgress, exit_interrupted, keep_ctrl_c
from ops_jax.cli.parser import ArgumentParser


# why a summary's number may be null (not finite)
NULL_REASONS = {"steps_to_0p9_median": "no episode reached P/Pmax 0.9"}


def parse_set(items) -> dict:
    """``key=value`` strings -> dict (values parsed as Python literals when possible)."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise ValueError(f"--set expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k] = ast.literal_eval(v)
        except (ValueError, SyntaxError):
            out[k] = v
    return out


RUN_FILES = ("checkpoint", "checkpoint.old", "summary.json", "curve.csv", "curve.png")


def held_run(out: Path) -> list[str]:
    """The files of a run of this command that ``out`` holds (none: no run)."""
    return [name for name in RUN_FILES if (out / name).exists()]


def resumable() -> list[str]:
    """The algorithms that checkpoint as they train and continue a run (the off-policy learners)."""
    return [a.name for a in registry.REGISTRY.values() if a.off_policy]


def refusal(args, out: Path) -> str | None:
    """Why the arguments cannot run on ``out`` as it is (a run there, and neither --resume nor
    --overwrite), or cannot resume; None when they can. Reads nothing but the folder's names: before
    any work."""
    held, can = held_run(out), resumable()
    if args.resume and args.overwrite:
        return "give --resume (continue the run in --out) or --overwrite (replace it), not both"
    if args.algo not in can and (args.resume or args.checkpoint_every is not None):
        option = "--resume" if args.resume else "--checkpoint-every"
        return (
            f"{option}: {args.algo} does not checkpoint while it trains, so it cannot continue a "
            f"run mid-way ({' and '.join(can)} can); --overwrite trains it again"
        )
    if args.resume and not held:
        return f"--resume: no run in {out} to continue; leave --resume out to start one"
    if held and not (args.resume or args.overwrite):
        return (
            f"--out {out} holds a run ({', '.join(held)}): give --resume to continue it or "
            "--overwrite to replace it"
        )
    return None


def check_resume(args, out: Path, env_spec, config) -> bool:
    """With --resume: ValueError unless ``out/checkpoint`` holds the training state of a run with
    these settings (False: train on), or the trained policy of one stopped before its evaluation was
    written (True: that is left)."""
    if not args.resume:
        return False
    from agents.learners.offpolicy import checkpoint

    if (out / "summary.json").exists():
        raise ValueError(f"--resume: the run in {out} is finished; --overwrite trains it again")
    if args.steps is not None:
        config = dataclasses.replace(config, total_steps=args.steps)
    wanted = checkpoint.identity(args.algo, env_spec.as_dict(), config.to_hyper(), [args.seed])
    try:
        if checkpoint.check_fits(out / "checkpoint", wanted) is not None:
            return False
        meta = json.loads((out / "checkpoint" / "meta.json").read_text())
        trained = [meta["algo"], meta["env_config"], meta["hyper"], [meta["seed"]]]
        if diffs := checkpoint.differences(checkpoint.identity(*trained), wanted):
            raise ValueError(
                f"the policy in {out / 'checkpoint'} is of another run: {'; '.join(diffs)}"
            )
    except (OSError, KeyError, TypeError):
        raise ValueError(
            f"--resume: the checkpoint in {out} holds no training state to continue; --overwrite "
            "trains it again"
        ) from None
    except ValueError as exc:
        raise ValueError(f"--resume: {exc}; give the options the run was started with") from None
    return True


def checkpointing(args, out: Path):
    """The run's ``Checkpoints`` into ``out/checkpoint`` (TD3, DroQ), else None."""
    if args.algo not in resumable():
        return None
    from agents.learners.offpolicy import checkpoint

    return checkpoint.Checkpoints(out / "checkpoint", args.checkpoint_every or CHECKPOINT_EVERY)


def replacing(args, out: Path, progress_fn):
    """``progress_fn``; with --overwrite, its first call first deletes the run in ``out``: once
    training has started, every check passed (a refused budget or a Ctrl-C while starting keeps the
    old run)."""
    if not args.overwrite:
        return progress_fn
    cleared = []

    def report(step: int, metrics: dict) -> None:
        if not cleared:
            for name in held_run(out):
                path = out / name
                shutil.rmtree(path) if path.is_dir() else path.unlink()
            cleared.append(step)
        progress_fn(step, metrics)

    return report


def interrupted(argv, out: Path, at: str, checkpoints, stop) -> tuple[str, int]:
    """The line and exit status of a training stopped by Ctrl-C or SIGTERM (``stop``): what was
    kept, how to go on."""
    status = 128 + getattr(stop, "signum", signal.SIGINT)
    saved = None if checkpoints is None else checkpoints.saved_step
    if saved is None:
        again = "run the same command again to train from the start"
        return f"stopped {at}; nothing written to {out}; {again}", status
    words = [
        w for w in (sys.argv[1:] if argv is None else argv) if w not in ("--overwrite", "--resume")
    ]
    again = shlex.join(["python", "-m", "agents", *words, "--resume"])
    return (
        f"stopped {at}; the run up to step {saved:,} is in {out / 'checkpoint'} (agents.load "
        f"reads it); continue it with: {again}",
        status,
    )


def parser() -> ArgumentParser:
    """The command line of ``python -m agents``."""
    ap = ArgumentParser(prog="python -m agents", description=__doc__.split("\n")[0])
    presets = "; ".join(
        f"{algo}: {', '.join(sorted(t.PRESETS))} (default {t.DEFAULT_PRESET})"
        for algo, t in sorted(CONFIG_TYPES.items())
    )
    ap.add_argument(
        "--algo", required=True, choices=sorted(base.ALGOS), help="the controller or learner"
    )
    ap.add_argument("--stages", type=int, default=5, help="delay lines N (default 5)")
    ap.add_argument(
        "--mode",
        default="hard",
        choices=["easy", "medium", "hard", "custom"],
        help="the noise and drift of the paper's modes (default hard)",
    )
    ap.add_argument("--out", type=Path, default=None, help="output folder (default runs/<algo>)")
    ap.add_argument(
        "--steps", type=int, default=None, help="env steps of training (default: the algorithm's)"
    )
    ap.add_argument("--seed", type=int, default=0, help="the training's random draws (default 0)")
    ap.add_argument(
        "--config",
        default=None,
        help=f"hyperparameter preset; {presets}",
    )
    ap.add_argument(
        "--episodes", type=int, default=50, help="final evaluation episodes (default 50)"
    )
    ap.add_argument("--eval-seed", type=int, default=1, help="seed of the testing environment")
    ap.add_argument(
        "--set", nargs="*", default=[], metavar="KEY=VALUE", help="hyperparameter overrides"
    )
    ap.add_argument(
        "--env", nargs="*", default=[], metavar="KEY=VALUE", help="extra ops_jax.make options"
    )
    ap.add_argument(
        "--logdir",
        type=Path,
        default=None,
        help="TensorBoard event files of the training curve (needs the tensorboard extra)",
    )
    ap.add_argument("--resume", action="store_true", help="continue the run in --out (td3, droq)")
    ap.add_argument("--overwrite", action="store_true", help="replace the run in --out")
    ap.add_argument(
        "--checkpoint-every",
        type=int,
        default=None,
        metavar="M",
        help="env steps between two checkpoints, rounded up to whole training chunks "
        f"(td3, droq; default {CHECKPOINT_EVERY})",
    )
    return ap


def main(argv=None) -> dict:
    """Train, evaluate and write one run from the command line ``argv``; its summary."""
    ap = parser()
    args = ap.parse_args(argv)
    out = args.out or Path("runs") / args.algo
    if (refused := refusal(args, out)) is not None:
        ap.exit(2, f"{ap.prog}: error: {refused}\n")
    keep_ctrl_c()

    try:
        module = base.algo_module(
            args.algo
        )  # its extra's imports fail here, before the progress starts
    except KeyboardInterrupt:
        exit_interrupted(f"stopped while starting; nothing written to {out}")
    ap.check_least(args, steps=0, episodes=1, checkpoint_every=1)
    env_spec, config, trained, warning = checked_run(ap, args, out, module)
    if trained:
        return finish_kept(args, out, env_spec, agents.load(out / "checkpoint"))
    if warning:
        print(f"{ap.prog}: warning: {warning}", file=sys.stderr, flush=True)
    return finish_kept(args, out, env_spec, trained_run(ap, args, argv, out, env_spec, config))


def checked_run(ap, args, out: Path, module) -> tuple:
    """(the run's EnvSpec, its config, whether only the evaluation of a trained policy is left, the
    budget's warning or None), every argument checked before the progress starts: a mistake exits
    with one line."""
    try:
        env_spec = base.check_env_spec(
            {"stages": args.stages, "mode": args.mode, **parse_set(args.env)}
        )
        config = CONFIG_TYPES[args.algo].make(args.config, **parse_set(args.set))
        if args.steps is not None and not hasattr(config, "total_steps"):
            raise ValueError(
                f"--steps: {args.algo} trains nothing (its curve is a short evaluation); leave it "
                "out"
            )
        module.make_policy(env_spec, config)
        trained = check_resume(args, out, env_spec, config)  # True: only its evaluation is left
        total = run_total(args, config)
        warning = None if total is None or trained else budgets.check(config, total, "--steps", " ")
    except (TypeError, ValueError) as exc:
        ap.exit(2, f"{ap.prog}: error: {exc}\n")
    return env_spec, config, trained, warning


def run_total(args, config) -> int | None:
    """The env steps the run trains: ``--steps``, else the config's (None: it trains nothing)."""
    return args.steps if args.steps is not None else getattr(config, "total_steps", None)


def trained_run(ap, args, argv, out: Path, env_spec, config):
    """The TrainResult of the run, its progress on a bar (and TensorBoard with ``--logdir``); a
    budget the trainer refuses exits with one line, a Ctrl-C with what was kept."""
    logger = tensorboard_logger(args)
    total = run_total(args, config)
    bar = StepProgress(total, f"{args.algo} {args.mode} N={args.stages}")
    checkpoints = checkpointing(args, out)
    show = bar
    if logger is not None:
        logger.then, show = show, logger
    try:
        with warnings.catch_warnings():  # the budget's warning is said above
            warnings.simplefilter("ignore", budgets.BudgetWarning)
            return base.train(
                args.algo,
                env_spec,
                seed=args.seed,
                total_steps=args.steps,
                progress_fn=replacing(args, out, show),
                progress=False,
                config=config,
                **({} if checkpoints is None else {"checkpoints": checkpoints}),
            )
    except ValueError as exc:
        if bar.first is not None:  # a failure during training: its traceback
            raise
        # the trainer's own checks of the budget against its config: one line, as the ones above
        bar.close()
        message = (
            str(exc).replace("total_steps", "--steps", 1) if args.steps is not None else str(exc)
        )
        ap.exit(2, f"{ap.prog}: error: {message}\n")
    except KeyboardInterrupt as stop:
        bar.close()
        step = getattr(stop, "step", bar.n)
        at = f"at step {step:,} of {total:,}" if total else "during training"
        exit_interrupted(*interrupted(argv, out, at, checkpoints, stop))
    finally:
        bar.close()
        if logger is not None:
            logger.close()


def tensorboard_logger(args):
    """The ``--logdir`` TensorBoard logger, or None; without the extra, exits with one line."""
    if args.logdir is None:
        return None
    from agents.tensorboard import TensorBoardLogger

    try:
        return TensorBoardLogger(args.logdir)
    except ImportError as e:  # one line naming the extra, not a traceback
        raise SystemExit(f"python -m agents --logdir: {e}") from None


def finish_kept(args, out: Path, env_spec, result) -> dict:
    """``finish``; a Ctrl-C there is one line saying what was kept (the trained policy: --resume
    evaluates it)."""
    try:
        return finish(args, out, env_spec, result)
    except KeyboardInterrupt:
        kept = ", ".join(sorted(p.name for p in out.iterdir())) if out.is_dir() else "nothing"
        exit_interrupted(
            f"stopped after training; kept in {out}: {kept} "
            f"(agents.load({str(out / 'checkpoint')!r}) gives the trained policy; --resume writes "
            "its evaluation)"
        )


def finish(args, out: Path, env_spec, result) -> dict:
    """Write the checkpoint, curve and evaluation summary of a finished training into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    agents.save(out / "checkpoint", result)
    write_curve_csv(out / "curve.csv", result.curve)
    plot_curve(
        out / "curve.png",
        result.curve,
        f"{args.algo}, {args.stages}-stage {args.mode}, seed {args.seed}",
    )
    ev = agents.evaluate(result, env_spec, episodes=args.episodes, seed=args.eval_seed)
    summary = dict(
        algo=args.algo,
        env_config=env_spec.as_dict(),
        seed=args.seed,
        hyper=result.config.to_hyper(),
        wall_time=result.wall_time,
        evaluation=ev.summary,
        train_steps=result.env_steps,
    )
    write_json_atomic(out / "summary.json", summary, reasons=NULL_REASONS)
    s = ev.summary
    best = (
        "_best" if s["score"] == "P/P_best" else ""
    )  # with imperfections: the ratio to the best reachable P
    also = f"; P/Pmax {s['final_mean']:.4f}" if best else ""
    print(
        f"{args.algo} {args.stages}-stage {args.mode} seed {args.seed}: testing {s['score']} "
        f"{s['final_mean' + best]:.4f} +- {s['final_std' + best]:.4f} (last 10 steps "
        f"{s['mean_last10' + best]:.4f}{also}), steps to 0.9: {s['steps_to_0p9_median']} "
        f"({s['fraction_reached_0p9']:.0%} reach it); {wall_time_line(result.wall_time)}; written "
        f"to {out}"
    )
    return summary


def run() -> None:
    """The ``ops-train`` command: ``main`` with its exit status (0 trained, 1 not)."""
    sys.exit(0 if main() else 1)
