"""This machine's accelerator (or CPU) in one command under a time budget: env-steps/s of
``env.step_batch`` and of ``ops_jax.rollout`` (phasor and field models, N = 5, 7, 10, batches 2^10 ..
2^20 until the budget or the device's memory ends), the training rates of DroQ (its "budget"
preset, 20k env steps), TD3 and SAC (brax), and the wall time of the quick sweep's table-1 section.

    python -m benchmarks.device                      # on a GPU: benchmarks/measured/device.json
    python -m benchmarks.device --budget-s 300       # on a CPU: benchmarks/measured/device-cpu.json
    python -m benchmarks.device --tiny               # test sizes (CPU, tens of seconds)
    python -m benchmarks.device --sections step_batch droq --out results/device.json

Each section runs in a fresh process with a deadline, its share of ``--budget-s`` (time a section
leaves unused goes to the ones after it); a process still running past its deadline is stopped. The
JSON is written after every section, each with ``status`` (ok | failed | skipped), ``wall_s``, its
error on failure and what it measured before failing. A batch scan doubles the batch until the next
doubling would pass its deadline or the device runs out of memory (``oom_at_batch``).
Env-steps/s as in ``benchmarks.throughput``: a jitted 200-step scan, compilation timed apart, median
of the repeats after a warm-up. Training: ``agents.train`` from a cold start, wall time with and
without the XLA compilation inside it.
"""

from __future__ import annotations

import os

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")  # before jax loads: no XLA C++ log lines

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402

from agents.io import write_json_atomic  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MEASURED = ROOT / "benchmarks" / "measured"
# Sections in the order they run, with their weights in the split of the time budget.
WEIGHTS = {"step_batch": 0.30, "rollout": 0.17, "droq": 0.18, "td3": 0.07, "sac": 0.10, "sweep": 0.18}
SECTIONS = tuple(WEIGHTS)
TARGET_PHASOR_N5 = 1e8  # env-steps/s, phasor N = 5, one GPU (issue 43)
ENV = {"stages": 5, "mode": "hard"}
# Training runs: env steps and hyperparameters (full size; --tiny below).
TRAIN = {
    "droq": (20_000, {"config": "budget"}),
    "td3": (30_000, {"config": "fast", "eval_every": 5000}),  # the default sweep's settings
    "sac": (30_000, {"config": "fast", "min_replay_size": 2048}),
}
TRAIN_TINY = {
    "droq": (300, {"config": "budget", "learning_starts": 128, "eval_every": 100, "eval_episodes": 2}),
    "td3": (512, {"config": "fast", "num_envs": 8, "learning_starts": 256, "eval_every": 128, "eval_episodes": 2}),
    "sac": (1024, {"config": "fast", "num_envs": 8, "min_replay_size": 256, "num_evals": 2, "num_eval_envs": 4,
                   "grad_updates_per_step": 2}),
}
# A (model, stages) configuration's weight in the split of a scan section's time (others: 1).
CONFIG_WEIGHTS = {("phasor", 5): 3.0}
GRACE_S = 15.0  # seconds a section's process gets past its deadline before it is stopped
MIN_SECTION_S = 5.0  # a section with less time than this left is skipped
CHILD_ENV = {"XLA_PYTHON_CLIENT_PREALLOCATE": "false", "XLA_PYTHON_CLIENT_MEM_FRACTION": "0.9"}


def default_out(platform_name: str, root: Path = ROOT) -> Path:
    """benchmarks/measured/device.json for a GPU, device-cpu.json for anything else."""
    name = "device.json" if platform_name == "gpu" else "device-cpu.json"
    return root / "benchmarks" / "measured" / name


def batches(tiny: bool, exps=None) -> list[int]:
    """The scanned batch sizes: 2^lo .. 2^hi in steps of 2^stride, ``exps`` = (lo, hi[, stride]) (default
    2^4 .. 2^6 with ``tiny``, else 2^10 .. 2^20)."""
    lo, hi, stride = (*(exps or ((4, 6) if tiny else (10, 20))), 1)[:3]
    return [2**k for k in range(lo, hi + 1, stride)]


def is_oom(err: BaseException) -> bool:
    """True for XLA's out-of-memory errors (RESOURCE_EXHAUSTED)."""
    text = f"{type(err).__name__}: {err}"
    return "RESOURCE_EXHAUSTED" in text or "out of memory" in text.lower() or isinstance(err, MemoryError)


def short_error(err: BaseException, limit: int = 600) -> str:
    """The first ``limit`` characters of ``type: message``."""
    text = f"{type(err).__name__}: {err}".strip()
    return text if len(text) <= limit else text[:limit] + " ..."


# ----------------------------------------------------------------------------------------------------
# The sections, each run in a child process: ``fn(args, deadline, record)``, record(dict) saving its
# results so far.


def device_info() -> dict:
    """The first JAX device's kind and platform, the device count, JAX's version and the host."""
    import jax
    import jaxlib

    d = jax.devices()[0]
    return dict(device=dict(kind=d.device_kind, platform=d.platform, count=jax.device_count(),
                            devices=[str(x) for x in jax.devices()]),
                jax=jax.__version__, jaxlib=jaxlib.__version__, host=platform.node(), cpu_count=os.cpu_count(),
                machine=platform.machine(), python=platform.python_version())


def _scan(measure_one, configs, batch_list, deadline: float, record, out: dict) -> None:
    """For each (model, stages) of ``configs``, ``measure_one(model, stages, batch) -> row`` over
    ``batch_list`` until the next batch would pass the config's share of the time to ``deadline`` or
    the device runs out of memory; rows and a summary per config go into ``out`` (saved by ``record``)."""
    import gc

    rows, summary = out.setdefault("rows", []), out.setdefault("configs", [])
    out["planned"] = [dict(model=m, stages=n) for m, n in configs]
    record(out)
    weights = [CONFIG_WEIGHTS.get(c, 1.0) for c in configs]
    for i, (model, n) in enumerate(configs):
        t_cfg = time.monotonic()
        if deadline - t_cfg < MIN_SECTION_S:
            break
        cfg_deadline = t_cfg + (deadline - t_cfg) * weights[i] / sum(weights[i:])
        s = dict(model=model, stages=n, batches=[], best_steps_per_s=None, best_batch=None, oom_at_batch=None,
                 stopped="end", error=None)
        summary.append(s)
        for b in batch_list:
            t0 = time.monotonic()
            out["running"] = dict(model=model, stages=n, batch=b)
            try:
                row = measure_one(model, n, b)
            except Exception as err:  # noqa: BLE001 (out of memory ends the scan; anything else is recorded)
                out.pop("running", None)
                gc.collect()
                s["stopped"] = "oom" if is_oom(err) else "error"
                s["oom_at_batch" if is_oom(err) else "error"] = b if is_oom(err) else short_error(err)
                break
            out.pop("running", None)
            cost = time.monotonic() - t0
            row["wall_s"] = cost
            rows.append(row)
            s["batches"].append(b)
            if s["best_steps_per_s"] is None or row["steps_per_s"] > s["best_steps_per_s"]:
                s["best_steps_per_s"], s["best_batch"] = row["steps_per_s"], b
            record(out)
            print(f"  {model} N={n} batch {b}: {row['steps_per_s']:,.0f} env-steps/s "
                  f"(compile {row['compile_s']:.1f} s)", flush=True)
            compile_s = min(row["compile_s"], cost)
            grow = 1.1 * (batch_list[batch_list.index(b) + 1] / b if b != batch_list[-1] else 1)
            if b != batch_list[-1] and time.monotonic() + compile_s + grow * (cost - compile_s) > cfg_deadline:
                s["stopped"] = "budget"
                break
        record(out)


def step_dtypes(stages: int, model: str) -> list[str]:
    """The dtypes of every array that ``reset_batch`` and ``step_batch`` return (traced, not run)."""
    import jax
    import jax.numpy as jnp

    import ops_jax

    env, params = ops_jax.make(stages, "hard", model=model)
    keys = jax.random.split(jax.random.key(0), 2)
    obs, state = jax.eval_shape(env.reset_batch, keys, params)
    stepped = jax.eval_shape(env.step_batch, keys, state, jnp.zeros((2, stages)), params)
    return sorted({str(x.dtype) for x in jax.tree.leaves((obs, state, stepped))})


def section_step_batch(args, deadline: float, record) -> dict:
    """env-steps/s of a jitted 200-step scan of ``env.step_batch`` (``benchmarks.throughput.measure``)."""
    import jax

    from benchmarks.throughput import SCAN_STEPS, measure

    out = dict(scan_steps=SCAN_STEPS, repeats=args.repeats, x64=bool(getattr(jax.config, "jax_enable_x64", False)),
               dtypes={m: step_dtypes(args.stages[0], m) for m in args.models})

    def one(model, n, b):
        (row,) = measure(n, model, b, args.repeats, paths=("step_batch",))
        return {k: row[k] for k in ("model", "stages", "batch", "compile_s", "median_scan_s", "steps_per_s")}

    _scan(one, [(m, n) for n in args.stages for m in args.models], batches(args.tiny, args.batch_exp), deadline, record, out)
    return out


def rollout_rate(stages: int, model: str, batch: int, repeats: int, steps: int = 200) -> dict:
    """env-steps/s of ``ops_jax.rollout`` (uniform random actions, the whole trajectory returned): the
    first call's time less the median of ``repeats`` later calls is its compilation."""
    import statistics

    import jax

    import ops_jax

    env, params = ops_jax.make(stages, "hard", model=model)

    def policy(key, obs):
        return jax.random.uniform(key, (obs.shape[0], stages), minval=-1.0, maxval=1.0)

    t0 = time.perf_counter()
    jax.block_until_ready(ops_jax.rollout(env, params, policy, jax.random.key(0), batch, steps))
    first = time.perf_counter() - t0
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(ops_jax.rollout(env, params, policy, jax.random.key(1 + i), batch, steps))
        times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    return dict(model=model, stages=stages, batch=batch, compile_s=max(0.0, first - median), median_scan_s=median,
                steps_per_s=batch * steps / median)


def section_rollout(args, deadline: float, record) -> dict:
    """env-steps/s of ``ops_jax.rollout`` over 200 steps, the trajectory kept on the device."""
    out = dict(scan_steps=200, repeats=args.repeats)
    _scan(lambda m, n, b: rollout_rate(n, m, b, args.repeats), [(m, n) for n in args.stages for m in args.models],
          batches(args.tiny, args.batch_exp), deadline, record, out)
    return out


class OutOfTime(Exception):
    """A training run stopped at its section's deadline."""


def train_rate(algo: str, steps: int, hyper: dict, deadline: float, record, out: dict) -> dict:
    """Train ``algo`` once from a cold start: env steps, wall seconds, XLA compile seconds and count,
    env-steps/s with and without compilation; stops at ``deadline`` (raising ``OutOfTime``)."""
    import jax

    import agents

    compile_s = [0.0, 0]

    def listen(name, secs, **_):
        if name == "/jax/core/compile/backend_compile_duration":
            compile_s[0] += secs
            compile_s[1] += 1

    jax.monitoring.register_event_duration_secs_listener(listen)
    out.update(algo=algo, env=ENV, total_steps=steps, hyper=hyper, progress=[])
    t0 = time.perf_counter()

    def progress_fn(step, metrics):
        elapsed = time.perf_counter() - t0
        out["progress"].append(dict(step=int(step), elapsed_s=elapsed, compile_s=compile_s[0],
                                    normalized_power=metrics.get("normalized_power")))
        out["steps_per_s_so_far"] = int(step) / max(elapsed, 1e-9)
        record(out)
        if time.monotonic() > deadline:
            raise OutOfTime(f"stopped at its deadline after {int(step):,} of {steps:,} env steps")

    result = agents.train(algo, ENV, seed=0, total_steps=steps, progress_fn=progress_fn, **hyper)
    wall = time.perf_counter() - t0
    trained = result.env_steps
    out.update(env_steps=trained, wall_s_train=wall, compile_s=compile_s[0], compiles=compile_s[1],
               steps_per_s=trained / wall, steps_per_s_excl_compile=trained / max(wall - compile_s[0], 1e-9),
               wall_time={k: v for k, v in result.wall_time.items() if isinstance(v, (int, float))})
    return out


def _train_section(algo: str):
    def run(args, deadline: float, record) -> dict:
        steps, hyper = (TRAIN_TINY if args.tiny else TRAIN)[algo]
        steps = args.steps.get(algo, steps)
        return train_rate(algo, steps, dict(hyper), deadline, record, {})
    run.__doc__ = f"Training rate of {algo}."
    return run


def section_sweep(args, deadline: float, record) -> dict:
    """Wall time of ``python -m benchmarks.sweep --quick --only table1`` (fresh output folder and
    compilation cache), in a process stopped at ``deadline``."""
    work = Path(tempfile.mkdtemp(prefix="ops-jax-device-sweep-"))
    base = ["-m", "benchmarks.sweep", "--quick", "--only", "table1"] + (["--algos", "spgd", "--seeds", "2"] if args.tiny
                                                                         else [])
    cmd = [sys.executable, *base, "--out", str(work / "out")]
    env = {**os.environ, "OPS_JAX_CACHE": str(work / "xla-cache"), "PYTHONPATH": _pythonpath()}
    out = dict(command=" ".join(["python", *base, "--out", "<tmp>"]))
    record(out)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    try:
        log, _ = proc.communicate(timeout=max(1.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        _stop(proc, signal.SIGINT, 8.0)
        out["wall_s_sweep"] = time.perf_counter() - t0
        record(out)
        raise OutOfTime(f"the quick sweep ran past its deadline ({out['wall_s_sweep']:.0f} s)") from None
    finally:
        summary = work / "out" / "summary.md"
        out["cells"] = len(list((work / "out" / "cells").glob("*.json"))) if (work / "out" / "cells").exists() else 0
        out["summary_written"] = summary.exists()
        shutil.rmtree(work, ignore_errors=True)
    out["wall_s_sweep"] = time.perf_counter() - t0
    out["exit_status"] = proc.returncode
    if proc.returncode != 0:
        raise RuntimeError(f"the quick sweep exited with {proc.returncode}: " + " | ".join(log.strip().splitlines()[-3:]))
    return out


SECTION_FNS = {"step_batch": section_step_batch, "rollout": section_rollout, "droq": _train_section("droq"),
               "td3": _train_section("td3"), "sac": _train_section("sac"), "sweep": section_sweep}


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
        """Past the deadline (a batch or training chunk still running): keep what is measured and exit.
        A scan section is then complete up to its budget (exit 0), a training run is not (exit 1)."""
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
        result = device_info() if args.child == "info" else SECTION_FNS[args.child](args, deadline, record)
    except BaseException as err:  # noqa: BLE001 (written down for the parent, then the exit status says it)
        if not isinstance(err, (Exception, KeyboardInterrupt)):
            raise
        partial = json.loads(path.read_text())["result"] if path.exists() else out
        write_json_atomic(path, dict(result=partial, error=short_error(err),
                                     traceback=traceback.format_exc(limit=6)[-2000:]))
        return 1
    write_json_atomic(path, dict(result=result, error=None))
    return 0


# ----------------------------------------------------------------------------------------------------
# The parent: runs the sections in child processes, writes the JSON after each.


def _pythonpath() -> str:
    """PYTHONPATH with this checkout first (children import the same packages)."""
    return os.pathsep.join([str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])


def _stop(proc: subprocess.Popen, sig: int, wait_s: float) -> None:
    """Send ``sig`` to ``proc``'s process group, then SIGKILL it if it is still running after ``wait_s``."""
    try:
        os.killpg(proc.pid, sig)
        proc.wait(timeout=wait_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    except ProcessLookupError:
        pass


def run_child(name: str, args, budget_s: float, kill_after_s: float) -> dict:
    """Run section ``name`` in a child process with ``budget_s`` seconds; stopped after ``kill_after_s``.
    Returns {status, wall_s, budget_s, error, ...results}."""
    fd, tmp = tempfile.mkstemp(prefix=f"device-{name}-", suffix=".json")
    os.close(fd)
    os.unlink(tmp)
    cmd = [sys.executable, "-m", "benchmarks.device", "--child", name, "--child-out", tmp,
           "--deadline-s", f"{budget_s:.1f}", "--repeats", str(args.repeats), "--models", *args.models,
           "--stages", *map(str, args.stages), "--steps", *[f"{k}={v}" for k, v in args.steps.items()]]
    if args.batch_exp:
        cmd += ["--batch-exp", *map(str, args.batch_exp)]
    if args.tiny:
        cmd.append("--tiny")
    env = {**os.environ, "PYTHONPATH": _pythonpath()}
    for k, v in CHILD_ENV.items():
        env.setdefault(k, v)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stderr=subprocess.PIPE, text=True, start_new_session=True)
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
        res.update(status="failed", error=f"stopped {kill_after_s:.0f} s after it started (its deadline and grace)")
    elif proc.returncode != 0:
        tail = " | ".join((stderr or "").strip().splitlines()[-3:])
        res.update(status="failed", error=saved.get("error") or f"exit status {proc.returncode}: {tail}")
        if saved.get("traceback"):
            res["traceback"] = saved["traceback"]
    return res


def _best_phasor_n5(sections: dict):
    s = sections.get("step_batch") or {}
    rates = [r["steps_per_s"] for r in s.get("rows", []) if r["model"] == "phasor" and r["stages"] == 5]
    return max(rates) if rates else None


def _scan_cell(section: dict, model: str, n: int) -> str:
    cfg = next((c for c in section.get("configs", []) if c["model"] == model and c["stages"] == n), None)
    if cfg is None:
        return "not run"
    if cfg["best_steps_per_s"] is None:
        return f"none ({cfg['stopped']})"
    if cfg["stopped"] == "oom":
        end = f", out of memory at {cfg['oom_at_batch']:,}"
    elif cfg["stopped"] in ("end", "error"):
        end = "" if cfg["stopped"] == "end" else ", then an error"
    else:  # budget, deadline: the scan stopped for time
        end = f", stopped for time after {cfg['batches'][-1]:,}"
    return f"{cfg['best_steps_per_s']:,.0f} (batch {cfg['best_batch']:,}{end})"


def _train_cell(section: dict) -> str:
    if section.get("env_steps"):
        return (f"{section['env_steps']:,} steps in {section['wall_s_train']:.1f} s: {section['steps_per_s']:,.0f}/s, "
                f"{section['steps_per_s_excl_compile']:,.0f}/s without {section['compile_s']:.0f} s compiling")
    last = (section.get("progress") or [None])[-1]
    if last:
        return f"{section['status']}: {last['step']:,} of {section['total_steps']:,} steps in {last['elapsed_s']:.0f} s"
    return f"{section.get('status', 'not run')}" + (f" ({section['error'][:60]})" if section.get("error") else "")


def compare_table(docs: list) -> str:
    """A markdown table of device JSON files side by side (one column each)."""
    head = [f"{(d.get('device') or {}).get('kind', '?')} ({(d.get('device') or {}).get('platform', '?')})" for d in docs]
    rows = [("host, date", [f"{d.get('host')}, {str(d.get('date'))[:10]}" for d in docs]),
            ("JAX", [str(d.get("jax")) for d in docs]),
            ("command", [f"`{d.get('command')}`" for d in docs])]
    sec = [d.get("sections", {}) for d in docs]
    for name, label in (("step_batch", "step_batch"), ("rollout", "ops_jax.rollout")):
        planned = [c for s in sec for c in s.get(name, {}).get("planned") or s.get(name, {}).get("configs", [])]
        pairs = sorted({(c["model"], c["stages"]) for c in planned}, key=lambda mn: (mn[0] != "phasor", mn[1]))
        for model, n in pairs:
            rows.append((f"{label}, {model} N = {n}: env-steps/s", [_scan_cell(s.get(name, {}), model, n) for s in sec]))
    for algo in ("droq", "td3", "sac"):
        rows.append((f"{algo} training", [_train_cell(s.get(algo, {})) for s in sec]))
    rows.append(("quick sweep, table1: wall s", [
        f"{s['sweep']['wall_s_sweep']:.0f} ({s['sweep']['status']})" if s.get("sweep", {}).get("wall_s_sweep")
        else _train_cell(s.get("sweep", {})) for s in sec]))
    rows.append(("whole command: wall s", [f"{d.get('wall_s', 0):.0f}" for d in docs]))
    lines = ["| | " + " | ".join(head) + " |", "|---|" + "---|" * len(docs)]
    lines += [f"| {label} | " + " | ".join(cells) + " |" for label, cells in rows]
    return "\n".join(lines)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks.device", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sections", nargs="+", default=None, metavar="SECTION",
                    help=f"sections to run, in this order (default: {' '.join(SECTIONS)}; --tiny leaves out sweep "
                         "unless named); an unknown name is recorded as a failed section")
    ap.add_argument("--budget-s", type=float, default=450.0, help="seconds for everything (default 450)")
    ap.add_argument("--out", type=Path, default=None,
                    help="JSON file (default: benchmarks/measured/device.json on a GPU, device-cpu.json otherwise)")
    ap.add_argument("--tiny", action="store_true",
                    help="test sizes: batches 2^4..2^6, N = 5, a few hundred training steps, sweep left out")
    ap.add_argument("--models", nargs="+", default=["phasor", "field"], choices=["phasor", "field"])
    ap.add_argument("--stages", type=int, nargs="+", default=None, help="stage counts (default 5 7 10; --tiny: 5)")
    ap.add_argument("--steps", nargs="*", default=[], metavar="ALGO=N",
                    help="training env steps other than the defaults (droq=20000 td3=30000 sac=30000)")
    ap.add_argument("--batch-exp", type=int, nargs="+", default=None, metavar="K",
                    help="batch sizes 2^LO .. 2^HI [in steps of 2^STRIDE] (default 10 20; --tiny: 4 6)")
    ap.add_argument("--repeats", type=int, default=None, help="timed runs per batch (default 3; --tiny: 2)")
    ap.add_argument("--table", nargs="+", type=Path, metavar="JSON",
                    help="print these runs' JSON side by side as a markdown table, and measure nothing")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--child-out", help=argparse.SUPPRESS)
    ap.add_argument("--deadline-s", type=float, default=60.0, help=argparse.SUPPRESS)
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
    if args.batch_exp is not None and (len(args.batch_exp) not in (2, 3) or min(args.batch_exp) < 0
                                       or args.batch_exp[0] > args.batch_exp[1] or args.batch_exp[2:3] == [0]):
        ap.error(f"--batch-exp takes LO HI [STRIDE] with 0 <= LO <= HI and STRIDE >= 1, got {args.batch_exp}")
    if args.budget_s <= 0 or args.repeats < 1:
        ap.error("--budget-s must be > 0 and --repeats >= 1")
    return args


def main(argv=None) -> dict:
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
    doc = dict(device=info.get("device"), jax=info.get("jax"), jaxlib=info.get("jaxlib"),
               date=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), host=info.get("host") or platform.node(),
               cpu_count=os.cpu_count(), machine=platform.machine(),
               command=" ".join(["python -m benchmarks.device", *(sys.argv[1:] if argv is None else argv)]),
               budget_s=args.budget_s, tiny=args.tiny, env={k: os.environ.get(k, v) for k, v in CHILD_ENV.items()},
               phasor_n5_steps_per_s=None, target_phasor_n5_steps_per_s=TARGET_PHASOR_N5, sections={},
               finished=False)
    if info["status"] != "ok":
        doc["info_error"] = info["error"]
    print(f"device: {doc['device']}; jax {doc['jax']}; writing {out}", flush=True)
    write_json_atomic(out, doc)
    for i, name in enumerate(names):
        left = deadline - time.monotonic()
        if name not in SECTION_FNS:
            res = dict(status="failed", wall_s=0.0, budget_s=0.0,
                       error=f"unknown section {name!r}; known: {', '.join(SECTIONS)}")
        elif left < MIN_SECTION_S:
            res = dict(status="skipped", wall_s=0.0, budget_s=max(0.0, left),
                       error=f"{left:.0f} s left of --budget-s {args.budget_s:g}")
        else:
            weights = [WEIGHTS.get(n, 0.0) for n in names[i:]]
            share = left * WEIGHTS[name] / sum(weights)
            print(f"[{i + 1}/{len(names)}] {name}: {share:.0f} s", flush=True)
            res = run_child(name, args, share, min(share + GRACE_S, left + GRACE_S))
        doc["sections"][name] = res
        doc["phasor_n5_steps_per_s"] = _best_phasor_n5(doc["sections"])
        doc["wall_s"] = time.monotonic() - t_start
        write_json_atomic(out, doc)
        print(f"  {name}: {res['status']} in {res['wall_s']:.1f} s" + (f" ({res['error']})" if res["error"] else ""),
              flush=True)
    doc["finished"] = True
    doc["wall_s"] = time.monotonic() - t_start
    write_json_atomic(out, doc)
    rate = doc["phasor_n5_steps_per_s"]
    print(f"phasor N = 5: {rate:,.0f} env-steps/s" if rate else "phasor N = 5: not measured")
    print(f"wrote {out} in {doc['wall_s']:.0f} s")
    return doc


if __name__ == "__main__":
    main()
