"""This machine's accelerator (or CPU) in one command under a time budget: env-steps/s of
``env.step_batch`` and of ``ops_jax.rollout`` (phasor and field models, N = 5, 7, 10, batches
2^10 .. 2^20 until the budget or the device's memory ends), the training rates of DroQ (its "budget"
preset, 20k env steps), TD3 and SAC (brax), and the wall time of the quick sweep's table-1 section.

    # on a GPU: benchmarks/measured/device.json; on a CPU: benchmarks/measured/device-cpu.json
    python -m benchmarks.speed.device
    python -m benchmarks.speed.device --budget-s 300
    python -m benchmarks.speed.device --tiny               # test sizes (CPU, tens of seconds)
    python -m benchmarks.speed.device --sections step_batch droq --out results/device.json

Each section runs in a fresh process with a deadline, its share of ``--budget-s`` (time a section
leaves unused goes to the ones after it); a process still running past its deadline is stopped. The
JSON is written after every section, each with ``status`` (ok | failed | skipped), ``wall_s``, its
error on failure and what it measured before failing. A batch scan doubles the batch until the next
doubling would pass its deadline or the device runs out of memory (``oom_at_batch``). Env-steps/s as
in ``benchmarks.speed.throughput``: a jitted 200-step scan, compilation timed apart, median of the
repeats after a warm-up. Training: ``agents.train`` from a cold start, wall time with and without
the XLA compilation inside it.
"""

from __future__ import annotations

import os

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")  # before jax loads: no XLA C++ log lines

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402

from benchmarks.speed.device_table import best_phasor_n5, compare_table  # noqa: E402
from agents.io import write_json_atomic  # noqa: E402
from ops_jax.cli.progress import keep_ctrl_c  # noqa: E402
from benchmarks.speed.batch_scan import MIN_SECTION_S, short_error  # noqa: E402
from benchmarks.speed.device_sections import (  # noqa: E402
    ROOT,
    SECTION_FNS,
    TRAIN,
    _pythonpath,
    _stop,
    device_info,
)

MEASURED = ROOT / "benchmarks" / "measured"
# Sections in the order they run, with their weights in the split of the time budget.
WEIGHTS = {
    "step_batch": 0.30,
    "rollout": 0.17,
    "droq": 0.18,
    "td3": 0.07,
    "sac": 0.10,
    "sweep": 0.18,
}
SECTIONS = tuple(WEIGHTS)
TARGET_PHASOR_N5 = 1e8  # env-steps/s, phasor N = 5, one GPU
GRACE_S = 15.0  # seconds a section's process gets past its deadline before it is stopped
CHILD_ENV = {"XLA_PYTHON_CLIENT_PREALLOCATE": "false", "XLA_PYTHON_CLIENT_MEM_FRACTION": "0.9"}


def default_out(platform_name: str, root: Path = ROOT) -> Path:
    """benchmarks/measured/device.json for a GPU, device-cpu.json for anything else."""
    name = "device.json" if platform_name == "gpu" else "device-cpu.json"
    return root / "benchmarks" / "measured" / name


def child_main(args) -> int:
    """Run one section (or ``info``) in this process, saving its results to ``--child-out``."""
    path = Path(args.child_out)
    deadline = time.monotonic() + args.deadline_s
    out: dict = {}
    live = [out]

    def record(partial):
        live[0] = partial
        write_json_atomic(path, dict(result=partial, error=None))

    def at_deadline():
        """Past the deadline (a batch or training chunk still running): keep what is measured and
        exit. A scan section is then complete up to its budget (exit 0), a training run is not (exit
        1)."""
        partial = live[0]
        running = partial.pop("running", None) if isinstance(partial, dict) else None
        scan = args.child in ("step_batch", "rollout")
        if running and partial.get("configs"):
            cfg = partial["configs"][-1]
            cfg.update(stopped="deadline", deadline_at_batch=running["batch"])
        error = None if scan else f"still running at its deadline ({args.deadline_s:.0f} s)"
        try:
            write_json_atomic(path, dict(result=partial, error=error))
        finally:
            sys.stdout.flush()
            os._exit(0 if scan else 1)

    if args.child not in ("info", "sweep"):  # the sweep stops its own process at the deadline
        import threading

        watchdog = threading.Timer(max(0.0, deadline - time.monotonic()) + 2.0, at_deadline)
        watchdog.daemon = True
        watchdog.start()
    try:
        result = (
            device_info()
            if args.child == "info"
            else SECTION_FNS[args.child](args, deadline, record)
        )
    except BaseException as err:  # noqa: BLE001 (written down for the parent, then the exit status says it)
        if not isinstance(err, (Exception, KeyboardInterrupt)):
            raise
        partial = json.loads(path.read_text())["result"] if path.exists() else out
        write_json_atomic(
            path,
            dict(
                result=partial,
                error=short_error(err),
                traceback=traceback.format_exc(limit=6)[-2000:],
            ),
        )
        return 1
    write_json_atomic(path, dict(result=result, error=None))
    return 0


# --------------------------------------------------------------------------------------------------
# The parent: runs the sections in child processes, writes the JSON after each.


def _child_command(name: str, args, out: str, budget_s: float) -> list:
    """The command line of section ``name``'s child process, writing its JSON to ``out``."""
    cmd = [
        sys.executable,
        "-m",
        "benchmarks.speed.device",
        "--child",
        name,
        "--child-out",
        out,
        "--deadline-s",
        f"{budget_s:.1f}",
        "--repeats",
        str(args.repeats),
        "--models",
        *args.models,
        "--stages",
        *map(str, args.stages),
        "--steps",
        *[f"{k}={v}" for k, v in args.steps.items()],
    ]
    if args.batch_exp:
        cmd += ["--batch-exp", *map(str, args.batch_exp)]
    if args.tiny:
        cmd.append("--tiny")
    return cmd


def run_child(name: str, args, budget_s: float, kill_after_s: float) -> dict:
    """Run section ``name`` in a child process with ``budget_s`` seconds; stopped after
    ``kill_after_s``. Returns {status, wall_s, budget_s, error, ...results}."""
    fd, tmp = tempfile.mkstemp(prefix=f"device-{name}-", suffix=".json")
    os.close(fd)
    os.unlink(tmp)
    cmd = _child_command(name, args, tmp, budget_s)
    env = {**os.environ, "PYTHONPATH": _pythonpath()}
    for k, v in CHILD_ENV.items():
        env.setdefault(k, v)
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd, cwd=ROOT, env=env, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    killed = False
    try:
        _, stderr = proc.communicate(timeout=kill_after_s)
    except subprocess.TimeoutExpired:
        killed = True
        _stop(proc, signal.SIGKILL, 5.0)
        stderr = proc.stderr.read() if proc.stderr else ""
    wall = time.perf_counter() - t0
    saved = {}
    if os.path.exists(tmp):
        try:
            saved = json.loads(Path(tmp).read_text())
        finally:
            os.unlink(tmp)
    res = dict(status="ok", wall_s=wall, budget_s=budget_s, error=None)
    res.update(saved.get("result") or {})
    if killed:
        res.update(
            status="failed",
            error=f"stopped {kill_after_s:.0f} s after it started (its deadline and grace)",
        )
    elif proc.returncode != 0:
        tail = " | ".join((stderr or "").strip().splitlines()[-3:])
        res.update(
            status="failed", error=saved.get("error") or f"exit status {proc.returncode}: {tail}"
        )
        if saved.get("traceback"):
            res["traceback"] = saved["traceback"]
    return res


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m benchmarks.speed.device``."""
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.speed.device",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        "--sections",
        nargs="+",
        default=None,
        metavar="SECTION",
        help=f"sections to run, in this order (default: {' '.join(SECTIONS)}; --tiny leaves out "
        "sweep unless named); an unknown name is recorded as a failed section",
    )
    ap.add_argument(
        "--budget-s", type=float, default=450.0, help="seconds for everything (default 450)"
    )
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="JSON file (default: benchmarks/measured/device.json on a GPU, device-cpu.json "
        "otherwise)",
    )
    ap.add_argument(
        "--tiny",
        action="store_true",
        help="test sizes: batches 2^4..2^6, N = 5, a few hundred training steps, sweep left out",
    )
    ap.add_argument("--models", nargs="+", default=["phasor", "field"], choices=["phasor", "field"])
    ap.add_argument(
        "--stages",
        type=int,
        nargs="+",
        default=None,
        help="stage counts (default 5 7 10; --tiny: 5)",
    )
    _size_options(ap)
    ap.add_argument(
        "--table",
        nargs="+",
        type=Path,
        metavar="JSON",
        help="print these runs' JSON side by side as a markdown table, and measure nothing",
    )
    _child_options(ap)
    return ap


def _size_options(ap: argparse.ArgumentParser) -> None:
    """The sizes of the measurements: training steps, batches, repeats."""
    ap.add_argument(
        "--steps",
        nargs="*",
        default=[],
        metavar="ALGO=N",
        help="training env steps other than the defaults (droq=20000 td3=30000 sac=30000)",
    )
    ap.add_argument(
        "--batch-exp",
        type=int,
        nargs="+",
        default=None,
        metavar="K",
        help="batch sizes 2^LO .. 2^HI [in steps of 2^STRIDE] (default 10 20; --tiny: 4 6)",
    )
    ap.add_argument(
        "--repeats", type=int, default=None, help="timed runs per batch (default 3; --tiny: 2)"
    )


def _child_options(ap: argparse.ArgumentParser) -> None:
    """The options by which the parent runs one section in a child process (not shown by --help)."""
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--child-out", help=argparse.SUPPRESS)
    ap.add_argument("--deadline-s", type=float, default=60.0, help=argparse.SUPPRESS)


def parse_args(argv=None):
    """The parsed command line ``argv``, its defaults filled in and its values checked."""
    ap = parser()
    args = ap.parse_args(argv)
    args.stages = args.stages or ([5] if args.tiny else [5, 7, 10])
    args.repeats = args.repeats or (2 if args.tiny else 3)
    steps = {}
    for item in args.steps:
        algo, _, n = item.partition("=")
        if algo not in TRAIN or not n.isdigit() or int(n) < 1:
            ap.error(f"--steps takes ALGO=N with ALGO in {list(TRAIN)} and N >= 1, got {item!r}")
        steps[algo] = int(n)
    args.steps = steps
    if args.batch_exp is not None and (
        len(args.batch_exp) not in (2, 3)
        or min(args.batch_exp) < 0
        or args.batch_exp[0] > args.batch_exp[1]
        or args.batch_exp[2:3] == [0]
    ):
        ap.error(
            "--batch-exp takes LO HI [STRIDE] with 0 <= LO <= HI and STRIDE >= 1, got "
            f"{args.batch_exp}"
        )
    if args.budget_s <= 0 or args.repeats < 1:
        ap.error("--budget-s must be > 0 and --repeats >= 1")
    return args


def _section(name: str, rest: list, args, left: float, counter: str) -> dict:
    """Run section ``name`` with its share of the ``left`` seconds (by ``WEIGHTS`` over the sections
    ``rest``, this one first); a failed or skipped record where it is unknown or no time is left."""
    if name not in SECTION_FNS:
        error = f"unknown section {name!r}; known: {', '.join(SECTIONS)}"
        return dict(status="failed", wall_s=0.0, budget_s=0.0, error=error)
    if left < MIN_SECTION_S:
        error = f"{left:.0f} s left of --budget-s {args.budget_s:g}"
        return dict(status="skipped", wall_s=0.0, budget_s=max(0.0, left), error=error)
    share = left * WEIGHTS[name] / sum(WEIGHTS.get(n, 0.0) for n in rest)
    print(f"{counter} {name}: {share:.0f} s", flush=True)
    return run_child(name, args, share, min(share + GRACE_S, left + GRACE_S))


def main(argv=None) -> dict:
    """Measure the sections in child processes under ``--budget-s``; the JSON document written."""
    keep_ctrl_c()
    args = parse_args(argv)
    if args.child:
        raise SystemExit(child_main(args))
    if args.table:
        print(compare_table([json.loads(p.read_text()) for p in args.table]))
        return {}
    t_start = time.monotonic()
    deadline = t_start + args.budget_s
    names = list(args.sections or [s for s in SECTIONS if not (args.tiny and s == "sweep")])
    info = run_child("info", args, min(120.0, args.budget_s), min(120.0, args.budget_s) + GRACE_S)
    platform_name = (info.get("device") or {}).get("platform", "unknown")
    out = args.out or default_out(platform_name)
    doc = dict(
        device=info.get("device"),
        jax=info.get("jax"),
        jaxlib=info.get("jaxlib"),
        date=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        host=info.get("host") or platform.node(),
        cpu_count=os.cpu_count(),
        machine=platform.machine(),
        command=" ".join(
            ["python -m benchmarks.speed.device", *(sys.argv[1:] if argv is None else argv)]
        ),
        budget_s=args.budget_s,
        tiny=args.tiny,
        env={k: os.environ.get(k, v) for k, v in CHILD_ENV.items()},
        phasor_n5_steps_per_s=None,
        target_phasor_n5_steps_per_s=TARGET_PHASOR_N5,
        sections={},
        finished=False,
    )
    if info["status"] != "ok":
        doc["info_error"] = info["error"]
    print(f"device: {doc['device']}; jax {doc['jax']}; writing {out}", flush=True)
    write_json_atomic(out, doc)
    for i, name in enumerate(names):
        res = _section(
            name, names[i:], args, deadline - time.monotonic(), f"[{i + 1}/{len(names)}]"
        )
        doc["sections"][name] = res
        doc["phasor_n5_steps_per_s"] = best_phasor_n5(doc["sections"])
        doc["wall_s"] = time.monotonic() - t_start
        write_json_atomic(out, doc)
        print(
            f"  {name}: {res['status']} in {res['wall_s']:.1f} s"
            + (f" ({res['error']})" if res["error"] else ""),
            flush=True,
        )
    doc["finished"] = True
    doc["wall_s"] = time.monotonic() - t_start
    write_json_atomic(out, doc)
    rate = doc["phasor_n5_steps_per_s"]
    print(f"phasor N = 5: {rate:,.0f} env-steps/s" if rate else "phasor N = 5: not measured")
    print(f"wrote {out} in {doc['wall_s']:.0f} s")
    return doc


if __name__ == "__main__":
    main()
