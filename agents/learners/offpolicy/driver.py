"""The training driver of the off-policy learners (``agents.learners.offpolicy.td3``,
``agents.learners.offpolicy.droq``): seeds vmapped, the warm-up and the training chunks (their
building blocks: ``agents.learners.offpolicy.replay``), the curve, snapshots and continued runs.

A learner is a ``Learner``: its name, config type, ``build(env, config)`` (its networks, exploration
and update, wired through ``agents.learners.offpolicy.replay.replay_loop``), ``networks`` and
``greedy`` (its policy and params template); ``entry_points`` gives its module's ``train`` and
``train_seeds``. Its training state is a NamedTuple with at least the fields
``actor`` (a flax TrainState) and ``agents.learners.offpolicy.replay.STATE``'s (``obs_norm``,
``buffer``, ...); the stored policy params are ``{"actor": actor params, "obs_norm": {mean, std}}``.

One training *iteration* = ``unroll`` batched env steps of ``num_envs`` instances (exploration
actions), their insertion into brax's ``UniformSamplingQueue``, then ``updates_per_iter``
gradient steps: the update-to-data ratio is ``updates_per_iter / (num_envs * unroll)`` (config
field ``utd_ratio``). Time-outs bootstrap: the stored discount is ``1 - terminated`` and the stored
next observation is ``info["final_observation"]`` (the pre-reset one).

Observations are standardised with a mean / std frozen after the random warm-up, computed over the
warm-up's observations that the buffer holds (the last ``buffer_size``); they are part of the policy
params.

Continued training (``start_from``: TrainResults of the same learner and network sizes, one per
seed): the run starts from their networks, targets, optimiser states and observation statistics
(kept frozen) with an empty replay buffer, and its warm-up collects ``learning_starts`` steps with
the policy's own exploration instead of uniform random actions.

Wall time: ``total`` is everything; ``compile`` the jit compilations; ``evaluation`` the periodic
evaluation rollouts; ``simulation`` is the warm-up (a jitted env-only scan: uniform random actions,
``step_batch`` and buffer insertion, no updates) plus, for the training chunks, the warm-up's time
per iteration (the faster of two timed runs) times the number of training iterations (an estimate:
it leaves out the actor's forward pass used for exploration); ``optimisation`` = training-chunk
time - that estimate. The warm-up is ``ceil(learning_starts / (num_envs * unroll))`` iterations.

Checkpoints (``checkpoints``, one seed): the whole training state between two chunks, written every
``Checkpoints.every`` env steps and on SIGINT or SIGTERM; a later call with the same settings
continues from it through the same chunks, to the same result
(``agents.learners.offpolicy.checkpoint``).

Curve (one point after the warm-up and after every training chunk of about ``eval_every`` env
steps): 'step', 'normalized_power' (mean P/Pmax over the last 10 of 200 steps of
``eval_episodes`` deterministic episodes on the training model, drift fully on, fixed key),
'final_normalized_power' (last step only), 'critic_loss', 'actor_loss' (chunk means).
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from agents import api as base
from agents.learners.offpolicy import build, checkpoint, replay
from agents.learners.offpolicy.learner import Learner
from agents.envs import check_env_spec
from ops_jax import EnvSpec


def check_seed(seed):
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"seed must be an int, got {seed!r}")
    return int(seed)


def schedule(c) -> tuple[int, int, int]:
    """(warm-up iterations, training chunks, iterations per chunk) of ``c.total_steps`` env steps
    (``c`` a ``replay.ReplayConfig``): the warm-up collects at least ``learning_starts`` steps, then
    chunks of about ``eval_every`` steps run whole iterations of ``num_envs * unroll`` steps, never
    past ``total_steps`` (the remainder of less than one iteration per chunk is not run)."""
    per_iter = c.num_envs * c.unroll
    warm_iters = -(-c.learning_starts // per_iter)
    if warm_iters * per_iter > c.total_steps:
        raise ValueError(
            f"total_steps must be >= the warm-up of learning_starts = {c.learning_starts} "
            f"rounded up to whole iterations of num_envs * unroll = {per_iter} "
            f"({warm_iters * per_iter}), got {c.total_steps}"
        )
    train_iters = max(0, (c.total_steps - warm_iters * per_iter) // per_iter)
    n_chunks = -(-train_iters // max(1, c.eval_every // per_iter)) if train_iters else 0
    return warm_iters, n_chunks, (train_iters // n_chunks if n_chunks else 0)


def _warm_up(programs: build.Programs, ts, warm_iters: int, timing: dict, random: bool = True):
    """(state after the warm-up (uniform random actions, then the observation statistics frozen; or,
    with ``random=False``, the policy's exploration and the statistics kept), simulation seconds per
    iteration); adds the compile and simulation time to ``timing``."""
    t0 = time.perf_counter()
    warmup = programs.compiled("warmup", ts, warm_iters, random)
    t1 = time.perf_counter()
    ts, warm_obs = jax.block_until_ready(warmup(ts))
    t2 = time.perf_counter()
    jax.block_until_ready(warmup(ts))  # a second, discarded timing run: the first one is noisier
    timing["compile"] += t1 - t0
    timing["simulation"] += t2 - t1
    return (programs.fit_norm(ts, warm_obs) if random else ts), min(
        t2 - t1, time.perf_counter() - t2
    ) / warm_iters


# The fields of a training state that a run does not carry over to a continued one.
_FRESH = ("buffer", "env_state", "obs", "key", "updates", "env_params")


def _continued(ts, learner: Learner, start_from, seeds, sharding) -> object:
    """``ts`` (fresh, seed-batched) with the learned arrays of ``start_from`` (one TrainResult per
    seed, or one TrainResult for one seed) in its own structure (this run's optimisers and
    settings)."""
    if isinstance(start_from, base.TrainResult):
        start_from = [start_from]
    start_from = list(start_from)
    if len(start_from) != len(seeds):
        raise ValueError(
            f"start_from must hold one TrainResult per seed ({len(seeds)}), got {len(start_from)}"
        )
    for r in start_from:
        if not isinstance(r, base.TrainResult) or r.algo != learner.name or r.state is None:
            raise ValueError(
                f"start_from must hold {learner.name} TrainResults trained in this process (with "
                f"their training state), got {getattr(r, 'algo', type(r).__name__)!r}"
            )
    stacked = jax.tree.map(lambda *xs: np.stack(xs), *[r.state for r in start_from])
    fields = {}
    for name, value in stacked.items():
        fresh = getattr(ts, name)
        leaves, shapes = jax.tree.leaves(value), [x.shape for x in jax.tree.leaves(fresh)]
        if [x.shape for x in leaves] != shapes:
            raise ValueError(
                f"start_from's {name} does not fit this run: network sizes must match (and "
                "alpha_lr be 0 in both runs or in neither)"
            )
        fields[name] = jax.tree.unflatten(jax.tree.structure(fresh), leaves)
    return ts._replace(**jax.device_put(fields, sharding))


def train_seeds(
    learner: Learner,
    env_config: EnvSpec | dict,
    *,
    seeds: Sequence[int],
    total_steps: int | None = None,
    progress_fn: Callable[[int, dict], None] | None = None,
    config=None,
    snapshot_fn: Callable[[int, list], None] | None = None,
    start_from=None,
    checkpoints: checkpoint.Checkpoints | None = None,
    **hyper,
) -> list[base.TrainResult]:
    """Train ``learner`` for several seeds at once: one jitted call vmapped over the seeds (sharded
    over the local devices when they divide the seed count). See
    ``agents.learners.offpolicy.td3.train_seeds``. ``snapshot_fn(step, params)`` (optional) gets
    each seed's policy params (host copies) after the warm-up and after every training chunk: a run
    of ``total_steps`` T passes through the states of the shorter runs whose budgets end a chunk
    (multiples of ``eval_every`` after the warm-up). ``start_from`` (optional): one TrainResult of
    this learner per seed, continued (module docstring). ``checkpoints`` (optional; one seed, no
    ``start_from``): an ``agents.learners.offpolicy.checkpoint.Checkpoints``: the run checkpoints as
    it trains, continues the run stored there, and stops on SIGINT or SIGTERM at the end of the
    current chunk with a checkpoint (raising ``checkpoint.Stopped``)."""
    env_spec = check_env_spec(env_config)
    seeds, c = _run_settings(learner, seeds, total_steps, config, hyper)
    if checkpoints is not None and (len(seeds) > 1 or start_from is not None):
        raise ValueError("checkpoints take one seed and no start_from")
    warm_iters, n_chunks, chunk = schedule(c)
    programs, env_params = build.cached_build(learner, env_spec, c, len(seeds))
    trainer = _Trainer(learner, env_spec, c, seeds, programs, env_params)
    trainer.progress_fn, trainer.snapshot_fn = progress_fn, snapshot_fn
    with checkpoints.stop_requests() if checkpoints else contextlib.nullcontext():
        ts = programs.init(trainer.k_init, env_params)
        run = checkpoints.restore(ts, trainer.wanted) if checkpoints else None
        trainer.checkpoints = checkpoints
        if run is None:
            if start_from is not None:
                ts = _continued(ts, learner, start_from, seeds, programs.sharding)
            run = trainer.start(ts, warm_iters, random=start_from is None)
            trainer.record(run, None, last=n_chunks == 0)
        else:  # this call's seconds add to the stored run's
            trainer.t_start -= run.timing.pop("total")
            trainer.compile_evaluation(run)
        trainer.train(run, n_chunks, chunk)
    return trainer.results(run)


class _Trainer:
    """One call of ``train_seeds``: its evaluation, reports, checkpoints and training chunks around
    a ``Run``."""

    progress_fn = snapshot_fn = checkpoints = None

    def __init__(self, learner, env_spec: EnvSpec, c, seeds, programs, env_params):
        self.learner, self.env_spec, self.config, self.seeds = learner, env_spec, c, seeds
        self.programs, self.env_params, self.t_start = programs, env_params, time.perf_counter()
        self.eval_ids, self.per_iter = jnp.arange(c.eval_episodes), c.num_envs * c.unroll
        self.wanted = checkpoint.identity(learner.name, env_spec.as_dict(), c.to_hyper(), seeds)
        keys = jax.vmap(jax.random.split)(jax.vmap(jax.random.key)(jnp.asarray(seeds)))
        self.k_init, self.k_eval = keys[:, 0], keys[:, 1]
        if programs.sharding is not None:
            self.k_init, self.k_eval = jax.device_put((self.k_init, self.k_eval), programs.sharding)

    def start(self, ts, warm_iters: int, random: bool):
        """The ``Run`` after the warm-up of the fresh (or continued) state ``ts``, its evaluation
        compiled."""
        timing = dict(simulation=0.0, optimisation=0.0, evaluation=0.0, compile=0.0)
        ts, sim_per_iter = _warm_up(self.programs, ts, warm_iters, timing, random)
        curve = {k: [] for k in checkpoint.CURVE}
        run = checkpoint.Run(ts, warm_iters * self.per_iter, 0, curve, timing, sim_per_iter)
        self.compile_evaluation(run)
        return run

    def compile_evaluation(self, run) -> None:
        t0 = time.perf_counter()
        args = (policy_params(run.ts), self.env_params, self.k_eval, self.eval_ids)
        self.evaluate = self.programs.compiled("evaluate", *args)
        run.timing["compile"] += time.perf_counter() - t0

    def record(self, run, m, last: bool) -> None:
        """Evaluate the run's state, add the curve point, report it; then a checkpoint when due or
        asked for (``checkpoint.Stopped`` after the latter)."""
        t0 = time.perf_counter()
        npow = self.evaluate(policy_params(run.ts), self.env_params, self.k_eval, self.eval_ids)[0]
        npow = np.asarray(npow)  # (seeds, steps, episodes)
        run.timing["evaluation"] += time.perf_counter() - t0
        nan = np.full(len(self.seeds), np.nan)
        point = dict(
            step=run.step,
            normalized_power=npow[:, -10:].mean((1, 2)),
            final_normalized_power=npow[:, -1].mean(1),
            critic_loss=nan if m is None else np.asarray(m["critic_loss"]),
            actor_loss=nan if m is None else np.asarray(m["actor_loss"]),
        )
        for k, v in point.items():
            run.curve[k].append(v)
        self.report(run, point["normalized_power"], m)
        self.keep(run, last)

    def keep(self, run, last: bool) -> None:
        """A checkpoint of ``run`` when one is due (not at the ``last`` point: the caller saves the
        result) or a signal asked the run to stop (``checkpoint.Stopped`` raised after it)."""
        ck = self.checkpoints
        if ck is not None and (ck.stop_signal is not None or (ck.due(run.step) and not last)):
            if ck.saved_step != run.step:
                ck.write(run_with_total(run, self.t_start), self.wanted, self.results(run)[0])
            if ck.stop_signal is not None:
                raise checkpoint.Stopped(ck.stop_signal, run.step)

    def report(self, run, npow, m) -> None:
        if self.snapshot_fn is not None:
            params = jax.device_get(policy_params(run.ts))
            self.snapshot_fn(
                run.step, [jax.tree.map(lambda x: x[i], params) for i in range(len(self.seeds))]
            )
        if self.progress_fn is not None:
            self.progress_fn(
                run.step,
                dict(
                    normalized_power=float(npow.mean()),
                    elapsed_s=time.perf_counter() - self.t_start,
                    update_ratio=replay.updates_per_iter(self.config) / self.per_iter,
                    **_chunk_metrics(m),
                ),
            )

    def train(self, run, n_chunks: int, chunk: int) -> None:
        """The run's remaining training chunks, each followed by ``record``."""
        if run.chunks >= n_chunks:
            return
        t0 = time.perf_counter()
        train_compiled = self.programs.compiled("train_chunk", run.ts, chunk)
        run.timing["compile"] += time.perf_counter() - t0
        sim_per_chunk = run.sim_per_iter * chunk
        while run.chunks < n_chunks:
            self.keep(run, last=True)  # a stop asked for while compiling: before the next chunk
            t0 = time.perf_counter()
            run.ts, m = train_compiled(run.ts)
            m = jax.device_get(m)
            dt = time.perf_counter() - t0
            run.timing["simulation"] += min(sim_per_chunk, dt)
            run.timing["optimisation"] += max(0.0, dt - sim_per_chunk)
            run.step, run.chunks = run.step + chunk * self.per_iter, run.chunks + 1
            self.record(run, m, last=run.chunks == n_chunks)

    def results(self, run) -> list[base.TrainResult]:
        """One TrainResult per seed of ``run`` (its seconds shared out over the seeds)."""
        n, ts = len(self.seeds), run.ts
        timing = {k: v / n for k, v in run_with_total(run, self.t_start).timing.items()}
        params = jax.device_get(policy_params(ts))
        kept = jax.device_get({k: v for k, v in ts._asdict().items() if k not in _FRESH})
        curve = {k: np.stack(run.curve[k], 1) for k in checkpoint.CURVE if k != "step"}
        return [
            base.TrainResult(
                self.learner.name,
                self.env_spec,
                self.config,
                jax.tree.map(lambda x: x[i], params),
                dict(step=np.asarray(run.curve["step"]), **{k: v[i] for k, v in curve.items()}),
                dict(timing, seeds_in_call=n),
                seed,
                jax.tree.map(lambda x: x[i], kept),
            )
            for i, seed in enumerate(self.seeds)
        ]


def run_with_total(run, t_start: float):
    """``run`` with its seconds' ``total`` (from ``t_start``, perf_counter) added to a copy of its
    timing."""
    return dataclasses.replace(run, timing=dict(run.timing, total=time.perf_counter() - t_start))


def policy_params(ts) -> dict:
    """The stored policy params of a training state: ``{"actor", "obs_norm"}``."""
    return {"actor": ts.actor.params, "obs_norm": ts.obs_norm}


def _chunk_metrics(m) -> dict:
    """The progress metrics of a training chunk's metrics ``m`` (none before the first chunk)."""
    if m is None:
        return {}
    return dict(
        critic_loss=float(m["critic_loss"].mean()),
        actor_loss=float(np.nanmean(m["actor_loss"])),
        reward=float(m["reward"].mean()),
    )


def _run_settings(learner: Learner, seeds, total_steps, config, hyper: dict) -> tuple[list, object]:
    """(the checked seeds, the run's config: ``config`` and ``hyper`` resolved, ``total_steps`` over
    the preset's)."""
    seeds = [check_seed(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be a non-empty sequence of distinct ints, got {seeds!r}")
    c = learner.config_type.make(config, **hyper)
    if total_steps is not None:
        c = dataclasses.replace(c, total_steps=total_steps)
    return seeds, c


def entry_points(learner: Learner, module: str, train_doc: str, seeds_doc: str):
    """(``train``, ``train_seeds``) of the module ``module`` of ``learner``, with these docstrings:
    ``train_seeds(env_config, *, seeds, **options)`` is the one above for ``learner``,
    ``train(env_config, *, seed=0, **options)`` the same for one seed."""

    def learner_seeds(env_config, *, seeds, **options) -> list[base.TrainResult]:
        return train_seeds(learner, env_config, seeds=seeds, **options)

    def train(env_config, *, seed=0, **options) -> base.TrainResult:
        return learner_seeds(env_config, seeds=[check_seed(seed)], **options)[0]

    for f, name, doc in ((train, "train", train_doc), (learner_seeds, "train_seeds", seeds_doc)):
        f.__name__ = f.__qualname__ = name
        f.__module__, f.__doc__ = module, doc
    return train, learner_seeds
