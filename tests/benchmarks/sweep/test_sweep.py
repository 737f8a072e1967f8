"""The sweep: Welch bolding against scipy, the resumable cell store, --quick end to end, resume
after SIGKILL."""

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import ttest_ind

from agents import PhysicsConfig, TD3Config
from benchmarks.sweep import command as sweep
from benchmarks.sweep.units import Sweep
from benchmarks.cells import CellStore
from benchmarks.sweep.records import SectionUnit
from benchmarks.sweep.report import _steps_cell, bold_mask, bold_rule, convergence_step
from processes import default_sigint, descendants

REPO = Path(__file__).resolve().parents[3]


def test_bold_rule_matches_welch():
    samples = {
        "a": [0.90, 0.92, 0.91, 0.93, 0.89],
        "b": [0.88, 0.93, 0.90, 0.94, 0.86],  # not significantly below a
        "c": [0.50, 0.52, 0.49, 0.51, 0.50],  # clearly below
    }
    mask = bold_mask(samples)
    assert mask == {
        "a": True,
        "b": ttest_ind(samples["a"], samples["b"], equal_var=False).pvalue >= 0.05,
        "c": False,
    }
    assert mask["b"] is True
    # Equal constant samples: not different; different constants: different.
    assert bold_mask({"x": [1.0] * 3, "y": [1.0] * 3, "z": [0.5] * 3}) == {
        "x": True,
        "y": True,
        "z": False,
    }
    # Fewer than 3 seeds: nothing is bold, however far apart (two seeds of 0.999 against 0.315 +-
    # 0.231).
    assert bold_mask({"spgd": [0.999, 0.999], "td3": [0.084, 0.546]}) == {
        "spgd": False,
        "td3": False,
    }
    assert "No bold" in bold_rule(2) and "Welch" in bold_rule(5)


def test_convergence_step():
    steps = np.arange(10) * 100
    values = [0.1, 0.3, 0.6, 0.8, 0.9, 0.95, 0.94, 0.95, 0.96, 0.95]
    assert convergence_step(steps, values) == 500
    flat = [0.3, 0.31, 0.3, 0.29]  # never changed: nothing converged
    assert np.isnan(convergence_step(np.arange(4) * 100, flat))
    assert _steps_cell([np.nan, np.nan]) == "not reached"
    assert (
        _steps_cell([500.0, np.nan]) == "500 ± 0 (1 of 2 seeds)"
        and _steps_cell([400.0, 600.0]) == "500 ± 100"
    )


def test_cell_store_resumes_and_detects_corruption(tmp_path):
    logs = []
    store = CellStore(tmp_path, logs.append)
    calls = []
    compute = lambda: calls.append(1) or {"value": len(calls)}
    assert store.get("a", {"x": 1}, compute) == {"value": 1}
    assert store.get("a", {"x": 1}, compute) == {"value": 1} and len(calls) == 1
    assert store.get("a", {"x": 2}, compute) == {"value": 2}  # another configuration: another cell
    assert (
        store.get("b", {"x": 2}, compute) == {"value": 2} and len(calls) == 2
    )  # moved in its plan: found by hash
    path = store.path("a", {"x": 1})
    path.write_text(path.read_text()[:10])  # truncated
    assert store.get("a", {"x": 1}, compute) == {"value": 3}
    assert any("unreadable" in m for m in logs)
    assert not list(tmp_path.glob("*.tmp"))


def test_units_cover_every_cell_once_after_their_checkpoints(tmp_path):
    preset = sweep.build_preset(
        argparse.Namespace(quick=False, preset="default", seeds=None, algos=None)
    )
    units = Sweep(preset, tmp_path, print).units(sweep.SECTIONS)
    labels = [c.label for u in units for c in u.cells]
    assert len(labels) == len(set(labels)) == 282  # the default preset's cells, each in one unit
    produced = {}
    for u in units:
        assert all(d in produced for d in u.deps), (
            u.key
        )  # in order: what a unit needs comes before it
        produced[u.key] = {c.label for c in u.cells}
        if u.kind == "eval":
            assert u.train.label in produced[u.deps[0]]
            assert all(
                c.config["checkpoint"] == f"checkpoints/{u.train.label}-{u.train.key}"
                for c in u.cells
            )
        assert u.cost > 0
    td3 = [u for u in units if u.kind == "train" and u.algo == "td3"]
    # a training cell names every setting its preset resolves to: a changed preset is another cell
    td3_config = td3[0].cells[0].config
    assert td3_config["settings"] == TD3Config.make(**td3_config["hyper"]).to_hyper()
    assert all(
        list(u.seeds) == [c.config["seed"] for c in u.cells] for u in units if u.kind == "train"
    )
    assert {len(u.seeds) for u in td3} == {5}  # vmapped seeds: one unit per table-1 mode
    assert {len(u.seeds) for u in units if u.kind == "train" and u.algo == "ppo"} == {1}


def test_reality_report_of_the_quick_preset_reads_each_score_against_its_levels_ceilings(tmp_path):
    """The reality section's report (quick preset): reality.md and reality.csv carry the held and
    predicted ceilings of each imperfect level (``ops_jax.imperfections.ceilings`` of its test
    environment), the scores over each, and the ideal level's reason for having none."""
    from benchmarks.sweep.reality import LEVELS, Reality, level_ceilings, level_env
    from ops_jax import EnvSpec
    from ops_jax.imperfections import ceilings

    preset = sweep.build_preset(
        argparse.Namespace(quick=True, preset="default", seeds=None, algos=None)
    )
    results = {"spgd/ideal": {level: [0.9, 0.94] for level, _ in LEVELS}}
    Reality().report(argparse.Namespace(out=tmp_path, preset=preset), results)
    lab = ceilings(EnvSpec.from_options(level_env(1.0)))
    assert level_ceilings()["lab"] is lab and level_ceilings()["none"].held is None
    md = (tmp_path / "reality.md").read_text()
    assert (
        f"| SPGD (ideal) | lab | 0.9200 | {lab.held:.4f} | {lab.predicted:.4f} | "
        f"{0.92 / lab.held:.4f} | {0.92 / lab.predicted:.4f} |" in md
    )
    assert "| SPGD (ideal) | none | 0.9200 | – | – | – | – |" in md
    assert "none: the ideal system" in md and "4,096 draws from seed 0" in md
    assert 0.95 < lab.held < lab.predicted < 1.0  # the lab preset: vibration held, then predicted
    rows = (tmp_path / "reality.csv").read_text().splitlines()
    assert rows[0].endswith(",held,predicted,mean_over_held,mean_over_predicted")


def test_reality_units_train_each_variant_then_test_it_at_each_level(tmp_path):
    preset = sweep.build_preset(
        argparse.Namespace(quick=True, preset="default", seeds=None, algos=None)
    )
    units = Sweep(preset, tmp_path, print).units(["reality"])
    trains = [u for u in units if u.kind == "train"]
    learners = ("ppo", "sac", "td3")
    prefixes = {f"reality-ideal-{a}" for a in preset["algos"]} | {
        f"reality-randomised-{a}" for a in learners
    }
    physics = {"reality-identify-physics", "reality-readout-physics"}
    assert {u.controller.prefix for u in trains} == prefixes | physics
    for u in trains:
        config, prefix = u.cells[0].config, u.controller.prefix
        assert config["env"]["stages"] == 5 and config["env"]["mode"] == "hard"
        assert (config["env"].get("randomize") == 1.0) == ("randomised" in prefix)
        if prefix.endswith(
            "-physics"
        ):  # the frames-only model, identifying, identifying + readout (the default)
            h = PhysicsConfig.from_hyper(config["hyper"])
            assert h.identify == (prefix in physics)
            assert h.use_lengths == ("readout" in prefix)
    seeds = sorted(
        s for u in trains for s in u.seeds if u.controller.prefix == "reality-randomised-sac"
    )
    assert seeds == list(range(preset["reality_seeds"]))
    evals = [u for u in units if u.kind == "eval"]
    assert len(evals) == (len(prefixes) + len(physics)) * preset["reality_seeds"]
    for u in evals:
        assert [c.config["env"].get("imperfection_scale", 0.0) for c in u.cells] == [0.0, 1.0, 2.0]
        assert u.cost > 0 and u.deps
    assert not [
        u for u in Sweep(preset, tmp_path, print).units(sweep.SECTIONS) if "reality" in u.key
    ]
    # The default preset's own reality budgets: SAC's trainings there run longer than its table-1
    # ones.
    default = sweep.build_preset(
        argparse.Namespace(quick=False, preset="default", seeds=None, algos=None)
    )
    steps = {
        (u.controller.prefix, c.config["steps"])
        for u in Sweep(default, tmp_path, print).units(["reality", "table1"])
        if u.kind == "train" and u.algo in ("sac", "ppo")
        for c in u.cells
    }
    assert {st for prefix, st in steps if prefix.startswith("reality-") and "sac" in prefix} == {
        300_000
    }
    assert {st for prefix, st in steps if prefix.startswith("table1-") and "sac" in prefix} == {
        default["budgets"]["sac"]
    }
    assert {st for _, st in steps if st != 300_000} == {
        default["budgets"]["sac"],
        default["budgets"]["ppo"],
    }


def test_pick_keeps_workers_on_their_algorithm():
    from collections import Counter

    from benchmarks.sweep.schedule import pick

    ready = [
        SectionUnit(key=k, algo=a, section=a, cells=(), cost=1.0)
        for k, a in zip("abc", ("ppo", "sac", "td3"))
    ]
    remaining = {"ppo": 100.0, "sac": 50.0, "td3": 10.0}
    assert pick(ready, "td3", Counter(), remaining).key == "c"  # warm programs first
    assert pick(ready, None, Counter(), remaining).key == "a"  # else the most remaining work
    assert (
        pick(ready, None, Counter(ppo=1), remaining).key == "b"
    )  # not an algorithm another worker runs
    assert pick(ready, None, Counter(ppo=1, sac=1, td3=1), remaining).key == "a"
    assert pick([], "ppo", Counter(), remaining) is None


def _run_sweep(args, env_extra=None, **kw):
    env = {**os.environ, "PYTHONPATH": str(REPO), **(env_extra or {})}
    return subprocess.Popen(
        [sys.executable, "-m", "benchmarks.sweep", *args],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


RAY_AGENTS = ("ray::DashboardAgent", "ray::RuntimeEnvAgent")  # a Ray node's idle helper processes


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def test_resume_after_sigkill(tmp_path):
    out = tmp_path / "run"
    args = ["--quick", "--algos", "spgd", "--only", "table1", "--out", str(out)]
    proc = _run_sweep(args)
    deadline = time.time() + 240
    while time.time() < deadline and not list((out / "cells").glob("*.json")):
        time.sleep(0.2)
    spawned = descendants([proc.pid])  # the local Ray instance and its workers
    assert spawned
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    if (
        sys.platform == "linux"
    ):  # the workers, raylet and GCS die with the command (an orphan would run on)
        agents = {pid for pid in spawned if _cmdline(pid).startswith(RAY_AGENTS)}
        deadline = time.time() + 20
        while time.time() < deadline and [
            pid for pid in spawned - agents if Path(f"/proc/{pid}").exists()
        ]:
            time.sleep(0.2)
        assert not [pid for pid in spawned - agents if Path(f"/proc/{pid}").exists()]
        for (
            pid
        ) in agents:  # idle; they notice the raylet's death on their own, after a minute or more
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
    first = sorted((out / "cells").glob("*.json"))
    assert first, "no cell finished before the deadline"
    stamp = {p.name: p.stat().st_mtime_ns for p in first}
    stdout, stderr = _run_sweep(args).communicate(timeout=400)
    assert "reused" in stdout, stderr[-2000:]
    assert "reused from an earlier run" in stderr  # the resumed run's progress line says so
    for p in first:
        assert p.stat().st_mtime_ns == stamp[p.name], f"{p.name} was recomputed"
    reused = int(stdout.split(" reused")[0].rsplit(", ", 1)[1])
    assert reused >= len(first)
    assert (out / "table1.md").exists()
    # A checkpoint that no longer loads (here: corrupted) is reported and its cell trained again.
    cell = first[0]
    blob = out / json.loads(cell.read_text())["result"]["checkpoint"] / "params.msgpack"
    blob.write_bytes(blob.read_bytes()[:-3] + b"xyz")
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json")}
    stdout, stderr = _run_sweep(args).communicate(timeout=400)
    assert "unusable" in stderr, stderr[-2000:]
    assert cell.stat().st_mtime_ns != stamps[cell.name]
    assert all(
        p.stat().st_mtime_ns == t
        for p, t in ((out / "cells" / n, t) for n, t in stamps.items())
        if p.name != cell.name
    )


def test_worker_crash_is_resumed(tmp_path):
    """A worker that dies of a crash signal (here injected: SIGSEGV after its second computed cell)
    is restarted by Ray, which retries its unit; the run completes."""
    out = tmp_path / "run"
    args = ["--quick", "--algos", "spgd", "--only", "table1", "--out", str(out)]
    hook = str(REPO / "tests" / "crash_hook")  # its sitecustomize crashes a process of the run once
    proc = _run_sweep(
        args,
        env_extra={
            "OPS_SWEEP_CRASH_AFTER": "2",
            "OPS_SWEEP_CRASH_MARKER": str(out / ".crash-injected"),
            "PYTHONPATH": f"{hook}{os.pathsep}{REPO}",
        },
    )
    stdout, stderr = proc.communicate(timeout=400)
    assert proc.returncode == 0, stderr[-2000:]
    assert (out / ".crash-injected").exists()
    assert "Fatal Python error: Segmentation fault" in stderr  # the worker runs with faulthandler
    assert "(6 cells computed, 0 reused)" in stdout
    assert len(list((out / "cells").glob("*.json"))) == 6  # 3 modes x 2 seeds
    assert (out / "table1.md").exists()


def test_remaining_work_follows_measured_cost_per_kind():
    from collections import Counter

    from benchmarks.sweep.schedule import projected_seconds

    left = Counter({"train ppo": 100.0, "eval": 10.0})
    assert (
        projected_seconds(left, Counter(), Counter()) == 110.0
    )  # the estimates before anything finished
    # PPO units took twice their estimate, evaluations a tenth: each kind scaled by its own ratio.
    assert (
        projected_seconds(
            left,
            Counter({"train ppo": 50.0, "eval": 10.0}),
            Counter({"train ppo": 100.0, "eval": 1.0}),
        )
        == 201.0
    )
    # A kind not seen finish yet takes the overall ratio (here 101 / 60).
    assert (
        abs(
            projected_seconds(
                Counter({"train sac": 60.0}),
                Counter({"train ppo": 50.0, "eval": 10.0}),
                Counter({"train ppo": 100.0, "eval": 1.0}),
            )
            - 101.0
        )
        < 1e-9
    )


def test_a_section_plugs_into_the_plan(tmp_path):
    """A section given as cells(preset), compute(cell) and report(records, out) is planned, computed
    into the cell store, resumed and reported like the built-in ones."""
    from benchmarks.sweep import plan as sweep_plan
    from benchmarks.sweep.section import CellSection

    computed = []

    def cells(preset):
        return [dict(label=f"square-{x}", x=x, cost=0.5) for x in range(preset["seeds"])]

    def compute(cell):
        computed.append(cell["x"])
        return {"square": cell["x"] ** 2}

    def report(records, out):
        text = "\n".join(f"{c['x']} {r['square']}" for c, r in records)
        (out / "squares.md").write_text(text)
        return text

    sweep_plan.register(CellSection("squares", cells, compute, report))
    try:
        preset = sweep.build_preset(
            argparse.Namespace(quick=True, preset="default", seeds=3, algos=None)
        )
        plan = Sweep(preset, tmp_path, print)
        units = plan.units(["squares"])
        assert [u.key for u in units] == ["square-0", "square-1", "square-2"] and units[
            0
        ].cost == 0.5
        plan.compute_unit(units[1])
        assert computed == [1] and [u.key for u in units if plan.todo(u)] == [
            "square-0",
            "square-2",
        ]
        assert Sweep(preset, tmp_path, print).run(["squares"]) == (2, 1)
        assert (
            sorted(computed) == [0, 1, 2]
            and (tmp_path / "squares.md").read_text() == "0 0\n1 1\n2 4"
        )
        assert (
            "squares" not in sweep.SECTIONS
            and "squares.md" in (tmp_path / "summary.md").read_text()
        )
    finally:
        sweep_plan.unregister("squares")


def test_docs_section_snippet_runs(tmp_path):
    from benchmarks.sweep import plan as sweep_plan

    text = (REPO / "docs" / "sweep.md").read_text()
    snippet = text.split("## Sections", 1)[1].split("```python", 1)[1].split("```", 1)[0]
    exec(snippet, {})
    try:
        preset = sweep.build_preset(
            argparse.Namespace(quick=True, preset="default", seeds=2, algos=None)
        )
        assert Sweep(preset, tmp_path, print).run(["squares"]) == (2, 0)
        assert "'square': 1" in (tmp_path / "squares.md").read_text()
    finally:
        sweep_plan.unregister("squares")


def test_progress_fraction_never_decreases_and_its_total_is_smoothed():
    from benchmarks.sweep.schedule import SmoothedTotal

    smoothed = SmoothedTotal(weight=0.3)
    shown = []
    # (done, projected total): a slow unit finishes at 2.5x its estimate, the projection jumps from
    # 100 to 250
    for done, projected in [
        (10, 100),
        (20, 100),
        (30, 250),
        (40, 240),
        (60, 200),
        (90, 120),
        (120, 120),
    ]:
        shown.append((done, smoothed(done, projected)))
    fractions = [d / t for d, t in shown]
    assert all(b >= a for a, b in zip(fractions, fractions[1:])), fractions
    assert shown[2][1] < 250  # the jump is smoothed: part of the way at once
    assert shown[-1][1] == 120 and fractions[-1] == 1.0  # nothing left: exactly done


def test_ctrl_c_keeps_the_cells_and_says_how_to_resume(tmp_path):
    """SIGINT (Ctrl-C) during a sweep: one line saying what was kept and how to resume, no
    traceback, exit status 130, the local Ray instance's workers gone within seconds."""
    out = tmp_path / "run"
    proc = _run_sweep(
        ["--quick", "--algos", "spgd", "--only", "table1", "--out", str(out)],
        preexec_fn=default_sigint,
    )
    try:
        deadline = time.time() + 240
        while (
            time.time() < deadline
            and not list((out / "cells").glob("*.json"))
            and proc.poll() is None
        ):
            time.sleep(0.2)
        assert proc.poll() is None and list((out / "cells").glob("*.json")), (
            "no cell finished before the deadline"
        )
        spawned = descendants([proc.pid])
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)  # the watchdog: a hang fails here
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr[-2000:]
    assert "Traceback" not in stderr, stderr[-3000:]
    kept = len(list((out / "cells").glob("*.json")))
    last = stderr.strip().splitlines()[-1]
    assert (
        last == f"interrupted: {kept} finished cells are kept in {out}/cells; run the same command "
        "again to resume"
    )
    if sys.platform == "linux":
        workers = {
            pid
            for pid in spawned
            if "ray::" in _cmdline(pid) and not _cmdline(pid).startswith(RAY_AGENTS)
        }
        deadline = time.time() + 10
        while time.time() < deadline and [pid for pid in workers if Path(f"/proc/{pid}").exists()]:
            time.sleep(0.2)
        assert not [pid for pid in workers if Path(f"/proc/{pid}").exists()]
        for (
            pid
        ) in spawned:  # what is left of the local instance (idle agents) does not outlive the test
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def test_local_workers_get_disjoint_cpu_shares_and_pinning_holds_for_later_threads():
    from benchmarks.sweep.executor import cpu_shares

    cpus = sorted(os.sched_getaffinity(0))
    for n in range(2, len(cpus) + 1):
        shares = cpu_shares(n)
        assert len(shares) == n and all(shares) and sorted(c for s in shares for c in s) == cpus
    assert cpu_shares(len(cpus) + 1) == [None] * (len(cpus) + 1) and cpu_shares(1) == [None]
    code = (
        "import os, threading; from benchmarks.sweep.executor import pin; pin([%d]); seen = []; t "
        "= threading.Thread(target=lambda: seen.append(os.sched_getaffinity(0))); "
        "t.start(); t.join(); print(sorted(os.sched_getaffinity(0)), sorted(seen[0]))" % cpus[-1]
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=60
    )
    assert out.stdout.split() == [f"[{cpus[-1]}]", f"[{cpus[-1]}]"], out.stderr


def test_lock_table_reads_the_cells_lock_figures_and_shows_a_dash_for_older_cells(tmp_path):
    """lock.md from stored evaluations (JSON round trip): SPGD's cells hold the lock figures, TD3's
    were stored before them (a dash), but for one seed in hard mode; episodes that never lock are
    counted out."""
    from benchmarks.sweep.lock_table import lock_table
    from benchmarks.sweep.paper import MODES
    from benchmarks.sweep.plan import table1_ceilings
    from ops_jax import lock

    k = np.arange(100)
    locks = lambda *at: np.stack([np.where(k < s, 0.2, 0.9) for s in at])  # locked at step s + 1
    never = 0.5 + 0.3 * (k % 2)
    stored = lambda traces: json.loads(json.dumps({"summary": lock.episode_summary(traces)}))
    old = {"summary": {"final_mean": 0.5, "steps_to_0p9_median": float("nan")}}
    runs = {}
    for mode in MODES:
        runs[mode, "spgd", 0] = {
            "train_env": stored(locks(9, 19)),
            "test_env": stored(locks(9, 29)),
        }
        runs[mode, "spgd", 1] = {
            "train_env": stored(locks(29, 39)),
            "test_env": stored(locks(49, 49)),
        }
        for s in (0, 1):
            runs[mode, "td3", s] = {"train_env": old, "test_env": old}
    runs["hard", "td3", 1] = {"train_env": old, "test_env": stored(np.stack([never, never]))}
    p = dict(algos=["spgd", "td3"], seeds=2, episodes=2, name="synthetic")
    lock_table(tmp_path, runs, p, table1_ceilings())
    md = (tmp_path / "lock.md").read_text()
    # SPGD testing: seed medians 20 and 50 -> 35 ± 15; RMS 0 (a flat lock)
    assert "| easy | testing | SPGD | 100% | 35 ± 15 | 0.00 ± 0.00 |" in md
    assert "| medium | training | SPGD | 100% | 25 ± 10 | 0.00 ± 0.00 |" in md
    assert "| easy | testing | TD3 | – | – | – |" in md
    assert "| hard | testing | TD3 | 0% (1 of 2 seeds) | not reached | not locked |" in md
    assert "the band within 2% of its held level" in md
    # the table-1 environments are ideal: no ceiling, the reason named for each mode; TD3's old
    # cells hold their final score, SPGD's synthetic summaries none
    assert "| easy | testing | SPGD | 100% | 35 ± 15 | 0.00 ± 0.00 | – | – | – | – | – |" in md
    assert "| easy | testing | TD3 | – | – | – | 0.5000 | – | – | – | – |" in md
    assert all(f"{m}: the ideal system: no imperfections" in md for m in MODES)


def test_lock_table_gives_the_score_as_a_fraction_of_each_ceiling(tmp_path):
    """lock.md's ceiling columns: the seeds' mean final P / P_best, the mode's held and predicted
    ceilings and the score over each."""
    from benchmarks.sweep.lock_table import lock_table
    from benchmarks.sweep.paper import MODES
    from ops_jax.imperfections import Ceilings

    summary = lambda final: {"summary": {"final_mean_best": final, "fraction_locked": None}}
    runs = {
        (mode, "spgd", s): {"train_env": summary(0.9 + s / 100), "test_env": summary(0.8)}
        for mode in MODES
        for s in (0, 1)
    }
    ceilings = {mode: Ceilings(0.95, 0.98, None, 128, 3) for mode in MODES}
    lock_table(tmp_path, runs, dict(algos=["spgd"], seeds=2, episodes=2, name="x"), ceilings)
    md = (tmp_path / "lock.md").read_text()
    # training: (0.90 + 0.91) / 2 = 0.905; 0.905 / 0.95 = 0.9526, / 0.98 = 0.9235
    assert (
        "| hard | training | SPGD | – | – | – | 0.9050 | 0.9500 | 0.9800 | 0.9526 | 0.9235 |" in md
    )
    assert (
        "| easy | testing | SPGD | – | – | – | 0.8000 | 0.9500 | 0.9800 | 0.8421 | 0.8163 |" in md
    )
    assert "128 draws from seed 3" in md and "no ceiling missing" in md
