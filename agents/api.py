"""The one interface of all controllers: ``train`` / ``evaluate`` / ``save`` / ``load``.

A controller is a ``Policy``: ``init(key, obs) -> carry`` and
``act(params, carry, obs, key, probe) -> (actions, carry)`` on a batch (obs (B, D), actions (B, N)
in [-1, 1]). ``probe(offsets (B, N) wl, active=None) -> P / P_max (B,)`` is an extra detector
reading at the current lengths plus ``offsets`` (a dither measurement, e.g. SPGD's); ``active`` (B,)
bool, None: all, leaves it out where False (nothing moves, no frame passes, the result is NaN
there). ``evaluate`` counts every reading made as a measurement (``measurements_per_step``: the
observation's frame plus the probes made, the mean over steps and episodes). Learned policies ignore
carry and probe. A policy that compares frames through its own last move (the physics-informed fit,
the fit observer) has ``sent``: a wrapper that moves the lines otherwise (the trim) tells it the
move it sent instead.

Each algorithm module (``agents.controllers.spgd``, ``agents.learners.brax.ppo``, ...; registered in
``agents.registry``, its interface ``agents.registry.AlgoModule``) provides
``train(env_config, *, seed, total_steps, progress_fn, config, **overrides) -> TrainResult``
(``env_config``: an ``ops_jax.EnvSpec`` or a dict of its options; ``config``: a preset name or the
algorithm's config type of ``agents.config``, ``overrides``: its fields; ``progress_fn(step: int,
metrics: dict)`` after each evaluation, metrics including ``normalized_power``),
``make_policy(env_spec, config) -> Policy`` and ``params_template(env_spec, config)`` (a pytree of
the parameters' structure, for ``load``) of a ``TrainResult``'s ``EnvSpec`` and config object.
``make_policy`` may depend only on ``config`` and the static ``EnvConfig`` of ``env_spec``: numbers
from ``EnvParams`` (mode, noise, action scale) belong in the params, so one compiled evaluation
serves a policy trained in any mode. Dicts are the stored form only: ``save`` writes
``env_spec.as_dict()`` and ``config.to_hyper()``, ``load`` reads them back.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from agents import registry
from agents.config import AlgoConfig
from agents.learners import budgets
from agents.envs import built, check_env_config, check_env_spec  # noqa: F401  (check_env_config)
from agents.evaluation import cached_evaluator, episode_ids
from agents.io import dumps_json, read_json, temp_dir
from ops_jax import EnvSpec
from ops_jax import lock
from ops_jax.cli.progress import reporting

ALGOS = registry.REGISTRY  # name -> registry.Algo
CHECKPOINT_VERSION = 1


class Policy(NamedTuple):
    init: Callable  # (key, obs (B, D)) -> carry
    act: Callable  # (params, carry, obs (B, D), key, probe) -> (actions (B, N), carry)
    # (params, carry, actions (B, N)) -> carry: the move really sent where a wrapper (the trim) sent
    # another than ``act``'s, for a policy that reads its own last move (the fit's); None: the
    # policy keeps no record of it
    sent: Callable | None = None


@dataclasses.dataclass
class TrainResult:
    """What training returns. ``curve``: arrays keyed 'step' (env steps) and at least
    'normalized_power' (evaluation P/Pmax at that step); ``wall_time``: seconds split into
    'simulation', 'optimisation' and 'total'; ``env_spec``: the training environment's
    ``ops_jax.EnvSpec``; ``config``: the algorithm's config (``agents.config.AlgoConfig``) it
    trained with; ``state``: the off-policy learners' training state without replay buffer and
    environment (critics, targets, optimiser states), which a later run continues with
    ``start_from``; kept in memory only (``save`` writes the policy)."""

    algo: str
    env_spec: EnvSpec
    config: AlgoConfig
    params: Any
    curve: dict
    wall_time: dict
    seed: int
    state: Any = None

    def __post_init__(self):
        for name, kind, said in (
            ("env_spec", EnvSpec, "ops_jax.EnvSpec (of a dict: EnvSpec.from_options)"),
            ("config", AlgoConfig, "agents.config.AlgoConfig (of a dict: its type's from_hyper)"),
        ):
            if not isinstance(value := getattr(self, name), kind):
                raise TypeError(f"{name} must be an {said}, got {type(value).__name__}")

    @property
    def env_steps(self) -> int:
        """Env steps trained (the last curve point; 0 for a controller with nothing to train)."""
        steps = np.asarray(self.curve.get("step", ()))
        return int(steps[-1]) if steps.size else 0

    def policy(self) -> Policy:
        return algo_module(self.algo).make_policy(self.env_spec, self.config)

    def __repr__(self) -> str:
        """The run in one line: algorithm, seed, env steps, the curve's last P/Pmax, wall time (no
        arrays)."""
        npow = np.asarray(self.curve.get("normalized_power", ()))
        last = f", last normalized_power={float(npow[-1]):.4g}" if npow.size else ""
        wall = {k: round(float(v), 2) for k, v in self.wall_time.items()}
        return (
            f"TrainResult(algo={self.algo!r}, seed={self.seed}, env_steps={self.env_steps}, "
            f"curve={npow.size} points{last}, wall_time={wall}, "
            f"config={getattr(self.config, 'config', None)!r})"
        )


class EvalResult(NamedTuple):
    """``normalized_power``: P/Pmax (episodes, steps) after each control step;
    ``normalized_power_best``: P/P_best, P_best the best P reachable with the configuration's static
    imperfections (P_max on the ideal system: then the same array); ``summary``: final mean/std,
    steps to reach 0.9 (median over episodes that reach it) and the fraction that do, measurements
    per control step, inference time per control step (s, batched), ``final_mean_best``,
    ``final_std_best`` and ``mean_last10_best`` (of P/P_best; P/Pmax's on the ideal system),
    ``score``: the ratio to report ("P/P_best" with imperfections, else "P/Pmax")."""

    normalized_power: np.ndarray
    terminated: np.ndarray
    summary: dict
    normalized_power_best: np.ndarray

    def __repr__(self) -> str:
        """The summary's numbers (4 significant digits) and the arrays' shapes, not their values."""
        said = {
            k: float(f"{v:.4g}") if isinstance(v, float) else v for k, v in self.summary.items()
        }
        episodes, steps = np.shape(self.normalized_power)
        return f"EvalResult(summary={said}, normalized_power: {episodes} episodes x {steps} steps)"


def algo_module(algo: str) -> registry.AlgoModule:
    return registry.get(algo).load()


def train(
    algo: str,
    env_config: EnvSpec | dict,
    *,
    seed: int = 0,
    total_steps: int | None = None,
    progress_fn: Callable[[int, dict], None] | None = None,
    progress: bool | None = None,
    **hyper,
) -> TrainResult:
    """Train ``algo`` (a name of ``ALGOS``) on the environment of ``env_config`` (an
    ``ops_jax.EnvSpec`` or a dict of ``ops_jax.make`` options, converted once:
    ``TrainResult.env_spec``). ``hyper``: ``config`` (a preset name or a config
    of ``agents.config``) and overrides of its fields; ``progress_fn(step, metrics)`` is called
    after each evaluation. ``progress``: a progress bar on stderr
    (``ops_jax.cli.progress.StepProgress``; None: when stderr is a terminal, False: none); a budget
    the warm-up takes most of is warned about first (``agents.learners.budgets.BudgetWarning``)."""
    module = algo_module(algo)
    env_spec = check_env_spec(env_config)
    if total_steps is not None and (
        not isinstance(total_steps, (int, np.integer)) or total_steps < 0
    ):
        raise ValueError(f"total_steps must be an integer >= 0, got {total_steps!r}")
    total = budgets.warn(algo, hyper, total_steps)
    with reporting(progress, progress_fn, total, f"{algo} seed {seed}") as report:
        return module.train(
            env_spec, seed=seed, total_steps=total_steps, progress_fn=report, **hyper
        )


def train_seeds(
    algo: str,
    env_config: EnvSpec | dict,
    *,
    seeds,
    total_steps: int | None = None,
    progress_fn: Callable[[int, dict], None] | None = None,
    progress: bool | None = None,
    **hyper,
) -> list[TrainResult]:
    """``train`` for each of ``seeds``: in one vmapped call where the algorithm supports it
    (``Algo.vmaps_seeds``, e.g. ``agents.learners.offpolicy.td3.train_seeds``; one progress bar),
    else one call per seed."""
    module = algo_module(algo)
    env_spec = check_env_spec(env_config)
    seeds = list(seeds)
    if not registry.get(algo).vmaps_seeds:
        return [
            train(
                algo,
                env_spec,
                seed=s,
                total_steps=total_steps,
                progress_fn=progress_fn,
                progress=progress,
                **hyper,
            )
            for s in seeds
        ]
    total = budgets.warn(algo, hyper, total_steps)
    with reporting(progress, progress_fn, total, f"{algo} {len(seeds)} seeds") as report:
        return module.train_seeds(
            env_spec, seeds=seeds, total_steps=total_steps, progress_fn=report, **hyper
        )


def evaluated_result(
    algo: str,
    env_spec: EnvSpec,
    config: AlgoConfig,
    params,
    seed: int,
    episodes: int = 32,
    progress_fn: Callable[[int, dict], None] | None = None,
) -> TrainResult:
    """The TrainResult of a controller with nothing to train (SPGD, physics-informed): its curve is
    a short evaluation (``episodes`` episodes, seed ``seed``), P/Pmax per control step, reported
    to ``progress_fn(0, metrics)`` (0 env steps of training). Evaluated as the result itself, so
    later evaluations of it reuse the compiled program."""
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"curve_episodes must be an integer >= 1, got {episodes!r}")
    t0 = time.perf_counter()
    result = TrainResult(algo, env_spec, config, params, {}, {}, int(seed))
    npow = evaluate(result, env_spec, episodes=episodes, seed=int(seed)).normalized_power.mean(0)
    total = time.perf_counter() - t0
    result.curve = {"step": np.arange(1, npow.size + 1), "normalized_power": npow}
    result.wall_time = {"simulation": total, "optimisation": 0.0, "total": total}
    if progress_fn is not None:
        progress_fn(0, {"normalized_power": float(npow[-1]), "elapsed_s": total})
    return result


def _as_policy(result_or_policy):
    if isinstance(result_or_policy, TrainResult):
        return result_or_policy.policy(), result_or_policy.params
    if (
        isinstance(result_or_policy, tuple)
        and len(result_or_policy) == 2
        and isinstance(result_or_policy[0], Policy)
    ):
        return result_or_policy
    if isinstance(result_or_policy, Policy):
        return result_or_policy, None
    raise TypeError("evaluate takes a TrainResult, a Policy or a (Policy, params) pair")


def evaluate(
    result_or_policy,
    env_config: EnvSpec | dict,
    *,
    episodes: int = 20,
    seed: int = 0,
    steps: int | None = None,
    drift_episode: int = 10,
) -> EvalResult:
    """Run ``episodes`` independent test episodes of ``steps`` control steps (default: the
    configuration's max_steps) on the environment of ``env_config`` (an ``ops_jax.EnvSpec`` or a
    dict) in one jitted scan, without auto-reset. Each episode starts as the ``drift_episode``-th
    reset of its environment, so hard mode's drift is fully on (r in [-1, 1]); a different ``seed``
    gives a different drift realisation (the paper's testing environment). The evaluation is
    deterministic: a repeated call computes the same numbers again (only the compiled program is
    kept). A ``TrainResult`` evaluated on an environment whose observation or action layout differs
    from its training environment's raises ValueError naming both layouts."""
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"episodes must be an integer >= 1, got {episodes!r}")
    env, env_params = built(check_env_spec(env_config))
    if isinstance(result_or_policy, TrainResult):
        trained_layout = built(result_or_policy.env_spec)[0].layout
        if trained_layout != env.layout:
            raise ValueError(
                f"the {result_or_policy.algo} policy was trained on observations of "
                f"{trained_layout.describe()}; env_config gives {env.layout.describe()}"
            )
    policy, params = _as_policy(result_or_policy)
    steps = int(steps or env.config.max_steps)
    ident = _source_ident(result_or_policy, policy)
    run, warm = cached_evaluator(ident, policy, env, steps, int(drift_episode))
    key = jax.random.key(seed)
    ids = episode_ids(int(episodes))
    signature = (
        int(episodes),
        str(jax.tree.map(lambda x: (jnp.shape(x), jnp.result_type(x)), params)),
    )
    if signature not in warm:  # compile and warm up once per argument signature
        jax.block_until_ready(run(params, env_params, key, ids))
        warm.add(signature)
    t0 = time.perf_counter()
    npow, term, made = jax.block_until_ready(run(params, env_params, key, ids))
    elapsed = time.perf_counter() - t0
    npow, term = np.asarray(npow).T, np.asarray(term).T
    made = float(np.asarray(made).mean(dtype=np.float64))  # readings per step
    summary = summarize(npow, measurements_per_step=made, inference_s_per_step=elapsed / steps)
    npow_best, summary["score"] = npow, "P/Pmax"
    if env.config.imperfect:  # P/P_best = P/Pmax x Pmax/P_best
        npow_best = (npow * (env.p_max / np.float64(env_params.lab.p_best))).astype(npow.dtype)
        summary["score"] = "P/P_best"
    best = summarize(npow_best) if npow_best is not npow else summary
    summary.update(
        final_mean_best=best["final_mean"],
        final_std_best=best["final_std"],
        mean_last10_best=best["mean_last10"],
    )
    return EvalResult(npow, term, summary, npow_best)


def summarize(npow: np.ndarray, **extra) -> dict:
    """Summary statistics of P/Pmax curves (episodes, steps); the lock figures over episodes
    (``ops_jax.lock``: median lock step and RMS power noise after lock, ``None`` where none
    locks)."""
    final = npow[:, -1]
    reached = npow >= 0.9
    first = np.where(reached.any(1), reached.argmax(1) + 1, -1)
    ok = first[first > 0]
    return dict(
        final_mean=float(final.mean()),
        final_std=float(final.std()),
        mean_last10=float(npow[:, -10:].mean()),
        steps_to_0p9_median=float(np.median(ok)) if ok.size else float("nan"),
        fraction_reached_0p9=float(ok.size / len(first)),
        episodes=int(npow.shape[0]),
        steps=int(npow.shape[1]),
        **lock.episode_summary(npow),
        **extra,
    )


def _source_ident(source, policy: Policy):
    """What the evaluated program is built from: a ``TrainResult``'s algorithm, static training
    configuration (not its mode: see the module docstring) and config, or a policy's identity."""
    if isinstance(source, TrainResult):
        return ("result", source.algo, built(source.env_spec)[0].config, source.config)
    return ("policy", policy)


# -- checkpoints --------------------------------------------------------------------------------


def save(path, result: TrainResult) -> Path:
    """Write ``result`` to the folder ``path`` (meta.json + params.msgpack), atomically: a
    temporary folder is renamed into place, so a crash never leaves a half-written checkpoint."""
    from flax import serialization

    path = Path(path)
    blob = serialization.msgpack_serialize(
        serialization.to_state_dict(jax.device_get(result.params))
    )
    meta = dict(
        version=CHECKPOINT_VERSION,
        algo=result.algo,
        env_config=result.env_spec.as_dict(),
        hyper=result.config.to_hyper(),
        seed=result.seed,
        wall_time=result.wall_time,
        curve={k: np.asarray(v).tolist() for k, v in result.curve.items()},
        params_sha256=hashlib.sha256(blob).hexdigest(),
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_dir(path.parent, path.name)
    (tmp / "params.msgpack").write_bytes(blob)
    # strict JSON: a curve's NaN (no loss yet) as null, read back as NaN by ``load``
    (tmp / "meta.json").write_text(dumps_json(meta))
    if path.exists():
        shutil.rmtree(path)
    os.replace(tmp, path)
    return path


def load(path) -> TrainResult:
    """Read a checkpoint written by ``save``; a missing or corrupt one raises a clear error."""
    from flax import serialization

    path = Path(path)
    meta_file, blob_file = path / "meta.json", path / "params.msgpack"
    if not meta_file.exists() or not blob_file.exists():
        raise FileNotFoundError(f"no checkpoint at {path} (expected meta.json and params.msgpack)")
    try:
        meta = read_json(meta_file)
        blob = blob_file.read_bytes()
        if hashlib.sha256(blob).hexdigest() != meta["params_sha256"]:
            raise ValueError("params.msgpack does not match the checksum in meta.json")
        state = serialization.msgpack_restore(blob)
        module = algo_module(meta["algo"])
        env_spec = EnvSpec.from_options(meta["env_config"])
        config = registry.get(meta["algo"]).config.from_stored(meta["hyper"])
        template = module.params_template(env_spec, config)
        params = serialization.from_state_dict(template, state) if template is not None else state
    except (ValueError, KeyError, TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"corrupt checkpoint at {path}: {exc}") from exc
    curve = {k: np.asarray(v) for k, v in meta["curve"].items()}
    return TrainResult(
        meta["algo"],
        env_spec,
        config,
        params,
        curve,
        meta["wall_time"],
        meta["seed"],
    )
