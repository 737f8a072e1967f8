"""Learning on a lab's budget: P / P_best against env steps of the target system, from scratch.

The plan is three functions, importable by any runner:
- ``cells(preset) -> list[Cell]``: work units (``benchmarks.budget.cell.Cell``, JSON-able by
  ``to_dict``), one per (controller, environment, seed);
- ``compute(cell) -> dict``: train once to the last checkpoint, evaluate the policy at every
  checkpoint of env steps (``agents.evaluate``, final-step P / P_best, the testing environment);
- ``report(records, out_dir) -> str``: budget.md (table of the median env steps to reach 0.9 and
  the mean P / P_best at each checkpoint), budget.png (P / P_best against env steps, log x, one
  line per controller, min-max band over seeds) and budget.json.

A learner's checkpoints are the states its one run passes through: with ``eval_every`` dividing the
checkpoints after the warm-up, the run to 20k env steps holds, at 10k, exactly the state of a run of
10k (``agents.learners.offpolicy.driver.train_seeds``'s ``snapshot_fn``). Learners trained by brax
(PPO, SAC) are trained once per checkpoint; a run that overruns its budget is recorded as an error.
SPGD and the physics-informed controller learn nothing: their one evaluation (one cell, under the
first seed) is drawn at every checkpoint, as references. That is protocol (a), from scratch on the
target.

Protocol (b), simulator to bench (``adapt`` cells): a learner pretrained on the randomised simulator
(``randomize=1``: each episode's imperfections 0-2x the lab preset; ``randomize_layout=1``: its
signed per-stage error patterns permuted over the stages, signs flipped; any budget, the preset's
``pretrain_steps``), then trained on for at most ``checkpoints[-1]`` env steps on an unseen bench
(``unseen_bench`` of ``bench_env``: the lab preset at twice its magnitudes, its per-stage error
patterns re-drawn from a seed that pretraining never used), continuing from the pretrained networks
(``start_from``, agents.learners.offpolicy.driver); P / P_best on that bench before adapting and at
each checkpoint, beside the references' on the same bench (``bench reference`` cells: what a
controller that needs no training holds there); and the same policies with the preset's
extremum-seeking trim (``agents.controllers.trim``: one more probe per step, no learning), which
removes the static bias an adapted policy keeps.

    # preset "default": DroQ, references, protocol (b); "full": every learner (TD3, SAC, PPO too)
    python -m benchmarks.budget --out results/budget
    python -m benchmarks.budget --preset full --out results/budget
    python -m benchmarks.budget --preset quick --out results/budget-quick
    # the frames only
    python -m benchmarks.budget --preset frames-residual-history --out results/budget-frames
    python -m benchmarks.budget --only droq spgd physics --seeds 11 12 13 --out results/budget
    python -m benchmarks.budget --envs "unseen bench" --out results/budget   # protocol (b) only
    # protocol (b) with probes a frame later and the bench trim
    python -m benchmarks.budget --preset frames-residual-history --envs "unseen bench" \\
        --only droq --bench-probe frame --bench-trim bench --out results/budget-frames

The presets are benchmarks/budget/presets.py. Finished cells are stored in ``<out>/cells``
(``benchmarks.cells.CellStore``): a rerun reuses them.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from agents import TrimConfig
from agents.registry import get
from ops_jax.env import PROBES
from benchmarks.budget.cell import Cell
from benchmarks.budget.presets import PRESETS
from benchmarks.budget.report import BENCH, TARGET, report, steps_to_target  # noqa: F401
from benchmarks.costs import cost_model, train_s

REFERENCE_KINDS = (
    "reference",
    "bench reference",
)  # one evaluation: on a protocol (a) env / on a protocol (b) bench


def controllers(preset: str) -> tuple[dict, dict]:
    """({learner: hyper}, {reference: hyper}) of ``preset``: its ``controllers``, in their order
    (ValueError naming one that is not registered)."""
    chosen = PRESETS[preset]["controllers"]
    return tuple(
        {algo: hyper for algo, hyper in chosen.items() if get(algo).learner == learner}
        for learner in (True, False)
    )


def cost(cell: Cell) -> float:
    """Estimated seconds of ``cell`` (the algorithm's ``benchmarks.costs.CostModel``): its training
    runs and evaluations."""
    algo, ks = cell.algo, cell.checkpoints
    evals = cost_model(algo).eval_s
    if cell.kind in REFERENCE_KINDS:
        return train_s(algo, cell.hyper, 0) + evals
    if cell.kind == "adapt":  # pretraining, adapting; scores before, at each checkpoint and trimmed
        return (
            train_s(algo, cell.pretrain_hyper, cell.pretrain_steps)
            + train_s(algo, cell.hyper, max(ks))
            + (2 + 2 * len(ks)) * evals
        )
    if get(algo).off_policy:  # one run, evaluated at each checkpoint
        return train_s(algo, cell.hyper, max(ks)) + len(ks) * evals
    return sum(train_s(algo, cell.hyper, k) + evals for k in ks)  # a run per checkpoint


def unseen_bench(env_config: dict, seed: int, scale: float = 2.0) -> dict:
    """``env_config`` with the lab preset's imperfections at ``scale`` times their magnitudes, each
    per-stage error's pattern permuted over the stages and its signs flipped at random by ``seed``:
    a bench whose errors are as large as the largest that randomised training drew, in a layout it
    never saw."""
    from ops_jax import imperfections

    n = env_config["stages"]
    rng = np.random.default_rng(seed)
    lab = imperfections.preset("lab", n, scale)
    drawn = {
        k: (rng.permutation(v) * rng.choice([-1.0, 1.0], n)).tolist()
        for k, v in lab.items()
        if k in imperfections.LAYOUT
    }
    return dict(env_config, imperfections="lab", imperfection_scale=scale, **drawn)


def _check_options(preset: str, bench_scale, bench_probe, bench_trim) -> None:
    """ValueError naming the first of ``cells``'s options outside its accepted values."""
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {sorted(PRESETS)}, got {preset!r}")
    if bench_probe is not None and bench_probe not in PROBES:
        raise ValueError(f"bench_probe must be one of {list(PROBES)}, got {bench_probe!r}")
    if bench_trim is not None and bench_trim not in TrimConfig.PRESETS:
        raise ValueError(
            f"bench_trim must be one of {sorted(TrimConfig.PRESETS)}, got {bench_trim!r}"
        )
    if bench_scale is not None and (
        isinstance(bench_scale, bool)
        or not isinstance(bench_scale, (int, float))
        or not 0 < bench_scale <= 10
    ):
        raise ValueError(f"bench_scale must be a number in (0, 10], got {bench_scale!r}")


def _target_cells(p: dict, learners: dict, references: dict, only, seeds, envs) -> list[Cell]:
    """Protocol (a)'s cells of preset ``p``: learners under each seed, references under the first
    (no training seed), on each of its environments."""
    out = []
    for env_name, env_config in p["envs"].items():
        if envs is not None and env_name not in envs:
            continue
        for kind, algos in (("learner", learners), ("reference", references)):
            for algo, hyper in algos.items():
                if only is not None and algo not in only:
                    continue
                chosen = list(p["seeds"] if seeds is None else seeds)
                out += [
                    Cell(
                        kind=kind,
                        algo=algo,
                        hyper=dict(hyper),
                        env=env_name,
                        env_config=dict(env_config),
                        seed=int(seed),
                        checkpoints=p["checkpoints"],
                        episodes=p["episodes"],
                        eval_seed=p["eval_seed"],
                        settings=get(algo).settings(hyper),
                    )
                    for seed in (chosen[:1] if kind == "reference" else chosen)
                ]
    return out


def _bench_cells(p: dict, references: dict, seed: int, only, options: tuple) -> list[Cell]:
    """Protocol (b)'s cells of preset ``p`` and training ``seed`` on its unseen bench: the adapted
    learner, then the references; ``options``: ``cells``'s (bench_scale, bench_probe,
    bench_trim)."""
    adapt, (bench_scale, bench_probe, bench_trim) = p["adapt"], options
    bench_seed = int(seed) + adapt["bench_seed_offset"]
    scale = adapt["scale"] if bench_scale is None else bench_scale
    probe = {} if bench_probe is None else {"probe": bench_probe}
    on_bench = dict(
        env=BENCH,
        env_config=dict(unseen_bench(adapt["bench_env"], bench_seed, scale), **probe),
        bench_seed=bench_seed,
        seed=int(seed),
        checkpoints=adapt["checkpoints"],
        episodes=p["episodes"],
        eval_seed=p["eval_seed"],
    )
    out = []
    if only is None or adapt["algo"] in only:
        out.append(
            Cell(
                kind="adapt",
                algo=adapt["algo"],
                hyper=dict(adapt["hyper"]),
                **on_bench,
                pretrain_env=dict(adapt["pretrain_env"]),
                pretrain_steps=adapt["pretrain_steps"],
                pretrain_hyper=dict(adapt["pretrain_hyper"]),
                trim=dict(adapt["trim"]) if bench_trim is None else {"config": bench_trim},
                settings=[
                    get(adapt["algo"]).settings(adapt[k]) for k in ("pretrain_hyper", "hyper")
                ],
            )
        )
    return out + [
        Cell(
            kind="bench reference",
            algo=algo,
            hyper=dict(hyper),
            **on_bench,
            settings=get(algo).settings(hyper),
        )
        for algo, hyper in references.items()
        if only is None or algo in only
    ]


def cells(
    preset: str,
    only=None,
    seeds=None,
    envs=None,
    bench_scale=None,
    bench_probe=None,
    bench_trim=None,
) -> list[Cell]:
    """The work units of ``preset`` (``benchmarks.budget.presets``): learners and references x
    environments x seeds; ``only`` (controllers), ``seeds`` and ``envs`` (names) narrow them;
    ``bench_scale`` (in (0, 10]) sets protocol (b)'s unseen benches at that many times the lab
    preset instead of the preset's level; ``bench_probe`` (``ops_jax.env.PROBES``) how their probes
    are measured (None: the simulator's default); ``bench_trim`` (a ``TrimConfig`` preset) the trim
    around the adapted policies (None: the preset's)."""
    _check_options(preset, bench_scale, bench_probe, bench_trim)
    p = PRESETS[preset]
    learners, references = controllers(preset)
    adapt = p.get("adapt")
    known_envs = [*p["envs"], *([BENCH] if adapt else [])]
    for name, chosen, known in (
        ("only", only, [*learners, *references]),
        ("envs", envs, known_envs),
    ):
        if chosen is not None and not set(chosen) <= set(known):
            raise ValueError(f"{name} must name some of {sorted(known)}, got {sorted(chosen)}")
    out = _target_cells(p, learners, references, only, seeds, envs)
    if adapt and (envs is None or BENCH in envs):
        options = (bench_scale, bench_probe, bench_trim)
        for seed in p["seeds"] if seeds is None else seeds:
            out += _bench_cells(p, references, seed, only, options)
    return out


def _score(result_or_policy, env_config: dict, cell: Cell) -> float:
    """Final-step P / P_best, mean over the cell's test episodes (seed ``eval_seed``)."""
    import agents
    from agents.envs import best_ratio

    ev = agents.evaluate(result_or_policy, env_config, episodes=cell.episodes, seed=cell.eval_seed)
    return float(ev.summary["final_mean"] * best_ratio(env_config))


def _snapshot_run(cell: Cell, start_from=None):
    """One run of ``cell``'s off-policy learner to its last checkpoint: (result, {checkpoint: policy
    params})."""
    from agents import api as base
    from agents.learners.offpolicy import driver as offpolicy

    module = base.algo_module(cell.algo)
    marks = set(cell.checkpoints)
    learner_config = module.LEARNER.config_type.make(**cell.hyper)
    warm, n_chunks, chunk = offpolicy.schedule(
        dataclasses.replace(learner_config, total_steps=max(marks))
    )
    per_iter = learner_config.num_envs * learner_config.unroll
    ends = {per_iter * (warm + chunk * i) for i in range(n_chunks + 1)}
    if not marks <= ends:
        raise ValueError(
            f"checkpoints {sorted(marks - ends)} are not chunk ends of this config (eval_every, "
            "learning_starts)"
        )
    snapshots = {}
    (result,) = offpolicy.train_seeds(
        module.LEARNER,
        cell.env_config,
        seeds=[cell.seed],
        total_steps=max(marks),
        snapshot_fn=lambda step, ps: snapshots.update({step: ps[0]}) if step in marks else None,
        start_from=start_from,
        **cell.hyper,
    )
    return result, snapshots


def _scores(result, snapshots: dict, cell: Cell) -> dict:
    policy = result.policy()
    return {
        str(k): _score((policy, snapshots[k]), cell.env_config, cell) for k in sorted(snapshots)
    }


def _trimmed_scores(pretrained, result, snapshots: dict, cell: Cell) -> dict:
    """P / P_best with the cell's trim (``agents.controllers.trim``) around the pretrained policy
    ("0") and each snapshot."""
    from agents.controllers import trim

    policy, params = trim.trimmed(result, cell.trim, env_config=cell.env_config)
    states = {0: pretrained.params, **snapshots}
    return {
        str(k): _score((policy, dict(params, policy=states[k])), cell.env_config, cell)
        for k in sorted(states)
    }


def _off_policy(cell: Cell) -> dict:
    """One run to the last checkpoint, its snapshots evaluated: {checkpoint: score}, wall s."""
    t0 = time.perf_counter()
    result, snapshots = _snapshot_run(cell)
    wall = time.perf_counter() - t0
    return {"scores": _scores(result, snapshots, cell), "train_s": wall}


def _adapt(cell: Cell) -> dict:
    """Protocol (b): pretrain on the randomised simulator, score on the unseen bench (``before``),
    train on there from the pretrained state; ``scores`` at each checkpoint of bench env steps,
    ``trimmed``: the same with the trim ("0": the pretrained policy), ``pretrain_s``,
    ``train_s``."""
    import agents

    t0 = time.perf_counter()
    pretrained = agents.train(
        cell.algo,
        cell.pretrain_env,
        seed=cell.seed,
        total_steps=cell.pretrain_steps,
        progress=False,
        **cell.pretrain_hyper,
    )
    pretrain_s = time.perf_counter() - t0
    before = _score(pretrained, cell.env_config, cell)
    t0 = time.perf_counter()
    result, snapshots = _snapshot_run(cell, start_from=pretrained)
    wall = time.perf_counter() - t0
    return {
        "before": before,
        "scores": _scores(result, snapshots, cell),
        "trimmed": _trimmed_scores(pretrained, result, snapshots, cell),
        "pretrain_s": pretrain_s,
        "train_s": wall,
        "pretrain_steps": pretrained.env_steps,
    }


def _per_budget(cell: Cell) -> dict:
    """A run per checkpoint (brax's trainers); a budget the config refuses, or one smaller than a
    single training step (which the trainer runs anyway), is recorded as an error, without a score;
    ``steps``: the env steps each scored run took."""
    import agents

    scores, steps, errors, wall = {}, {}, {}, 0.0
    for k in cell.checkpoints:
        t0 = time.perf_counter()
        try:
            result = agents.train(
                cell.algo,
                cell.env_config,
                seed=cell.seed,
                total_steps=k,
                progress=False,
                **cell.hyper,
            )
        except ValueError as exc:
            errors[str(k)] = str(exc)
            continue
        wall += time.perf_counter() - t0
        trained = result.env_steps
        if trained > k:
            errors[str(k)] = f"trained {trained} env steps for a budget of {k}"
            continue
        scores[str(k)], steps[str(k)] = _score(result, cell.env_config, cell), trained
    return {"scores": scores, "steps": steps, "errors": errors, "train_s": wall}


def compute(cell: Cell) -> dict:
    """The record of one cell: ``scores`` {checkpoint (str): final P / P_best}, ``train_s``."""
    import agents

    if cell.kind in REFERENCE_KINDS:
        t0 = time.perf_counter()
        result = agents.train(
            cell.algo, cell.env_config, seed=cell.seed, progress=False, **cell.hyper
        )
        score = _score(result, cell.env_config, cell)
        return {
            "scores": {str(k): score for k in cell.checkpoints},
            "train_s": time.perf_counter() - t0,
        }
    if cell.kind == "adapt":
        return _adapt(cell)
    if get(cell.algo).off_policy:
        return _off_policy(cell)
    return _per_budget(cell)
