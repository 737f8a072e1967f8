"""Learning on a lab's budget: P / P_best against env steps of the target system, from scratch.

The plan is three functions, importable by any runner:
- ``cells(preset) -> list[dict]``: JSON-able work units, one per (controller, environment, seed);
- ``compute(cell) -> dict``: train once to the last checkpoint, evaluate the policy at every
  checkpoint of env steps (``agents.evaluate``, final-step P / P_best, the testing environment);
- ``report(records, out_dir) -> str``: budget.md (table of the median env steps to reach 0.9 and
  the mean P / P_best at each checkpoint), budget.png (P / P_best against env steps, log x, one
  line per controller, min-max band over seeds) and budget.json.

A learner's checkpoints are the states its one run passes through: with ``eval_every`` dividing
the checkpoints after the warm-up, the run to 20k env steps holds, at 10k, exactly the state of a
run of 10k (``agents.offpolicy.train_seeds``'s ``snapshot_fn``). Learners trained by brax (PPO,
SAC) are trained once per checkpoint; a run that overruns its budget is recorded as an error. SPGD
and the physics-informed controller learn nothing: their one evaluation (one cell, under the first
seed) is drawn at every checkpoint, as references. Only protocol (a) (from scratch on the target)
is planned here; pretraining on the simulator and adapting on a bench is not.

    python -m benchmarks.budget --out results/budget            # preset "default"
    python -m benchmarks.budget --quick --out results/budget-quick
    python -m benchmarks.budget --only droq spgd physics --seeds 11 12 13 --out results/budget

Finished cells are stored in ``<out>/cells`` (``benchmarks.cells.CellStore``): a rerun reuses them.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

from agents.registry import NAMES

CHECKPOINTS = (1000, 2000, 5000, 10_000, 20_000)
HARD = dict(stages=5, mode="hard", model="phasor")
ENVS = {"hard": HARD, "hard + lab": dict(HARD, imperfections="lab")}
OFF_POLICY = ("droq", "td3")  # trained once, evaluated at every checkpoint it passes
REFERENCES = ("spgd", "physics")
TARGET = 0.9

PRESETS = {
    "quick": dict(envs={"easy 3": dict(stages=3, mode="easy", model="phasor")}, seeds=(0,), checkpoints=(600, 1200),
                  episodes=4, eval_seed=4242,
                  learners={"droq": {"config": "budget", "learning_starts": 200, "eval_every": 200, "utd_ratio": 2.0,
                                     "hidden": [32, 32], "critic_hidden": [32, 32], "batch_size": 64}},
                  references={"spgd": {}, "physics": {"config": "frames", "starts": 4, "iters": 4}}),
    "default": dict(envs=ENVS, seeds=(11, 12, 13, 14, 15), checkpoints=CHECKPOINTS, episodes=32, eval_seed=4242,
                    learners={"droq": {"config": "budget"}, "td3": {"config": "budget"},
                              "sac": {"config": "budget"},  # PPO: 1,000 env steps per iteration (25 x 8 x 5)
                              "ppo": {"config": "paper", "unroll_length": 25, "batch_size": 5, "num_evals": 2}},
                    references={"spgd": {}, "physics": {"config": "frames"}}),
}


def cells(preset: str, only=None, seeds=None, envs=None) -> list[dict]:
    """The work units of ``preset`` ("quick" | "default"): learners and references x environments x
    seeds; ``only`` (controllers), ``seeds`` and ``envs`` (names) narrow them."""
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {preset!r}")
    p = PRESETS[preset]
    for name, chosen, known in (("only", only, [*p["learners"], *p["references"]]), ("envs", envs, p["envs"])):
        if chosen is not None and not set(chosen) <= set(known):
            raise ValueError(f"{name} must name some of {sorted(known)}, got {sorted(chosen)}")
    out = []
    for env_name, env_config in p["envs"].items():
        if envs is not None and env_name not in envs:
            continue
        for kind, algos in (("learner", p["learners"]), ("reference", p["references"])):
            for algo, hyper in algos.items():
                if only is not None and algo not in only:
                    continue
                chosen = list(p["seeds"] if seeds is None else seeds)
                for seed in chosen[:1] if kind == "reference" else chosen:  # references: no training seed
                    out.append(dict(kind=kind, algo=algo, hyper=dict(hyper), env=env_name, env_config=dict(env_config),
                                    seed=int(seed), checkpoints=list(p["checkpoints"]), episodes=p["episodes"],
                                    eval_seed=p["eval_seed"]))
    return out


def _score(result_or_policy, env_config: dict, cell: dict) -> float:
    """Final-step P / P_best, mean over the cell's test episodes (seed ``eval_seed``)."""
    import agents
    import ops_jax

    ev = agents.evaluate(result_or_policy, env_config, episodes=cell["episodes"], seed=cell["eval_seed"])
    env, params = ops_jax.make(**env_config)
    ratio = env.p_max / float(params.lab.p_best) if env.config.imperfect else 1.0
    return float(ev.summary["final_mean"] * ratio)


def _off_policy(cell: dict) -> dict:
    """One run to the last checkpoint, its snapshots evaluated: {checkpoint: score}, wall s."""
    from agents import base, offpolicy

    module = base.algo_module(cell["algo"])
    env_config, marks = cell["env_config"], set(cell["checkpoints"])
    h = module.LEARNER.config_type.make(**cell["hyper"]).to_hyper()
    warm, n_chunks, chunk = offpolicy.schedule({**h, "total_steps": max(marks)})
    per_iter = h["num_envs"] * h["unroll"]
    ends = {per_iter * (warm + chunk * i) for i in range(n_chunks + 1)}
    if not marks <= ends:
        raise ValueError(f"checkpoints {sorted(marks - ends)} are not chunk ends of this config (eval_every, "
                         "learning_starts)")
    snapshots = {}
    t0 = time.perf_counter()
    (result,) = offpolicy.train_seeds(module.LEARNER, env_config, seeds=[cell["seed"]], total_steps=max(marks),
                                      snapshot_fn=lambda step, ps: snapshots.update({step: ps[0]}) if step in marks
                                      else None, **cell["hyper"])
    wall = time.perf_counter() - t0
    policy = result.policy()
    return {"scores": {str(k): _score((policy, snapshots[k]), env_config, cell) for k in sorted(marks)},
            "train_s": wall}


def _per_budget(cell: dict) -> dict:
    """A run per checkpoint (brax's trainers); a budget the config refuses, or one smaller than a single
    training step (which the trainer runs anyway), is recorded as an error, without a score; ``steps``:
    the env steps each scored run took."""
    import agents

    scores, steps, errors, wall = {}, {}, {}, 0.0
    for k in cell["checkpoints"]:
        t0 = time.perf_counter()
        try:
            result = agents.train(cell["algo"], cell["env_config"], seed=cell["seed"], total_steps=k, **cell["hyper"])
        except ValueError as exc:
            errors[str(k)] = str(exc)
            continue
        wall += time.perf_counter() - t0
        trained = result.env_steps
        if trained > k:
            errors[str(k)] = f"trained {trained} env steps for a budget of {k}"
            continue
        scores[str(k)], steps[str(k)] = _score(result, cell["env_config"], cell), trained
    return {"scores": scores, "steps": steps, "errors": errors, "train_s": wall}


def compute(cell: dict) -> dict:
    """The record of one cell: ``scores`` {checkpoint (str): final P / P_best}, ``train_s``."""
    import agents

    if cell["kind"] == "reference":
        t0 = time.perf_counter()
        result = agents.train(cell["algo"], cell["env_config"], seed=cell["seed"], **cell["hyper"])
        score = _score(result, cell["env_config"], cell)
        return {"scores": {str(k): score for k in cell["checkpoints"]}, "train_s": time.perf_counter() - t0}
    if cell["algo"] in OFF_POLICY:
        return _off_policy(cell)
    return _per_budget(cell)


def steps_to_target(checkpoints, scores: dict, target: float = TARGET):
    """The first checkpoint whose score reaches ``target``, or None."""
    return next((k for k in checkpoints if scores.get(str(k), -np.inf) >= target), None)


def _groups(records) -> dict:
    """{(env, algo): [record, ...]} in first-seen order."""
    groups = {}
    for r in records:
        groups.setdefault((r["cell"]["env"], r["cell"]["algo"]), []).append(r)
    return groups


def _median_steps(rs) -> str:
    """Median over seeds of the env steps to reach the target ("not reached" when most seeds never do)."""
    reached = [steps_to_target(r["cell"]["checkpoints"], r["result"]["scores"]) for r in rs]
    ks = sorted(np.inf if k is None else k for k in reached)
    m = float(np.median(ks))
    return "not reached" if not np.isfinite(m) else f"{m:,.0f} ({sum(k is not None for k in reached)}/{len(rs)})"


def _figure(groups: dict, path: Path) -> None:
    from benchmarks.sweep_report import _plt

    plt = _plt()
    envs = list(dict.fromkeys(env for env, _ in groups))
    fig, axes = plt.subplots(1, len(envs), figsize=(5.5 * len(envs), 4), squeeze=False, sharey=True)
    algos = list(dict.fromkeys(a for _, a in groups))
    for ax, env in zip(axes[0], envs):
        for i, algo in enumerate(algos):
            rs = groups.get((env, algo))
            if not rs:
                continue
            ks = [k for k in rs[0]["cell"]["checkpoints"] if all(str(k) in r["result"]["scores"] for r in rs)]
            y = np.array([[r["result"]["scores"][str(k)] for k in ks] for r in rs])
            style = "--" if rs[0]["cell"]["kind"] == "reference" else "-"
            ax.plot(ks, y.mean(0), style, marker="o", ms=3, color=f"C{i}", label=NAMES.get(algo, algo))
            ax.fill_between(ks, y.min(0), y.max(0), color=f"C{i}", alpha=0.15, lw=0)
        ax.axhline(TARGET, color="grey", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_xlabel("env steps of the target system")
        ax.set_title(env)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("final P / P_best (mean over seeds, band: min-max)")
    axes[0][-1].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def report(records: list[dict], out_dir) -> str:
    """budget.md (returned), budget.png and budget.json in ``out_dir``; ``records``: [{"cell", "result"}]."""
    from agents.io import write_json_atomic

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    groups = _groups(records)
    checkpoints = sorted({k for r in records for k in r["cell"]["checkpoints"]})
    first = records[0]["cell"]
    lines = ["# Learning on a lab's budget", "",
             f"Final P / P_best after each number of env steps of the target system (mean ± std over seeds; each "
             f"seed: {first['episodes']} test episodes of 200 steps, evaluation seed {first['eval_seed']}), trained "
             f"from scratch; median env steps to reach {TARGET} over seeds (seeds that reach it / seeds; "
             "\"not reached\" when most never do within the budget). References learn nothing.", "",
             "| environment | controller | median steps to 0.9 | " + " | ".join(f"{k:,}" for k in checkpoints) + " |",
             "|---|---|---|" + "---|" * len(checkpoints)]
    for (env, algo), rs in groups.items():
        row = []
        for k in checkpoints:
            v = [r["result"]["scores"][str(k)] for r in rs if str(k) in r["result"]["scores"]]
            row.append(f"{np.mean(v):.3f} ± {np.std(v):.3f}" if v else "-")
        if rs[0]["cell"]["kind"] == "reference":
            who, steps = f"{NAMES.get(algo, algo)} (reference)", "no training"
        else:
            seeds = ", ".join(str(r["cell"]["seed"]) for r in rs)
            who, steps = f"{NAMES.get(algo, algo)} (seeds {seeds})", _median_steps(rs)
        lines.append(f"| {env} | {who} | {steps} | " + " | ".join(row) + " |")
    walls = {algo: np.median([r["result"]["train_s"] for (_, a), rs in groups.items() if a == algo for r in rs])
             for algo in dict.fromkeys(a for _, a in groups)}
    lines += ["", "Median wall time per cell (training to the last checkpoint, s): "
              + ", ".join(f"{NAMES.get(a, a)} {w:.0f}" for a, w in walls.items()) + ".",
              "", f"{time.strftime('%Y-%m-%d', time.gmtime())}, host {platform.node()} "
              f"({platform.processor() or platform.machine()}).", "", "![P / P_best against env steps](budget.png)"]
    _figure(groups, out / "budget.png")
    write_json_atomic(out / "budget.json", records)
    text = "\n".join(lines) + "\n"
    (out / "budget.md").write_text(text)
    return text


def main(argv=None) -> str:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.budget", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the tiny preset (seconds)")
    ap.add_argument("--out", type=Path, required=True, help="output folder")
    ap.add_argument("--only", nargs="+", default=None, help="controllers (default: all of the preset)")
    ap.add_argument("--seeds", nargs="+", type=int, default=None, help="training seeds (default: the preset's)")
    ap.add_argument("--envs", nargs="+", default=None, help="environments by name (default: all of the preset)")
    args = ap.parse_args(argv)
    from benchmarks.cells import CellStore

    store = CellStore(args.out / "cells")
    plan = cells("quick" if args.quick else "default", args.only, args.seeds, args.envs)
    records = []
    for i, cell in enumerate(plan):
        label = f"{cell['env']}-{cell['algo']}-s{cell['seed']}"
        t0 = time.perf_counter()
        result = store.get(label, cell, lambda: compute(cell))
        records.append({"cell": cell, "result": result})
        print(f"[{i + 1}/{len(plan)}] {label}: " + ", ".join(f"{k} {v:.3f}" for k, v in result["scores"].items())
              + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
    text = report(records, args.out)
    print(text)
    return text


if __name__ == "__main__":
    main()
