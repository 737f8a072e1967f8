"""The training driver of the off-policy learners (``agents.learners.offpolicy.td3``, ``agents.learners.offpolicy.droq``): seeds vmapped, the
warm-up and the training chunks (their building blocks: ``agents.learners.offpolicy.replay``), the curve, snapshots and continued runs.

A learner is a ``Learner``: its name, config type, ``build(env, h)`` (its networks, exploration
and update, wired through ``agents.learners.offpolicy.replay.replay_loop``), ``networks`` and ``greedy`` (its policy and params
template). Its training state is a NamedTuple with at least the fields ``actor`` (a flax TrainState) and
``agents.learners.offpolicy.replay.STATE``'s (``obs_norm``, ``buffer``, ...); the stored policy params are
``{"actor": actor params, "obs_norm": {mean, std}}``.

One training *iteration* = ``unroll`` batched env steps of ``num_envs`` instances (exploration
actions), their insertion into brax's ``UniformSamplingQueue``, then ``updates_per_iter``
gradient steps: the update-to-data ratio is ``updates_per_iter / (num_envs * unroll)`` (config
field ``utd_ratio``). Time-outs bootstrap: the stored discount is ``1 - terminated`` and the stored
next observation is ``info["final_observation"]`` (the pre-reset one).

Observations are standardised with a mean / std frozen after the random warm-up, computed over the
warm-up's observations that the buffer holds (the last ``buffer_size``); they are part of the policy params.

Continued training (``start_from``: TrainResults of the same learner and network sizes, one per seed):
the run starts from their networks, targets, optimiser states and observation statistics (kept
frozen) with an empty replay buffer, and its warm-up collects ``learning_starts`` steps with the
policy's own exploration instead of uniform random actions.

Wall time: ``total`` is everything; ``compile`` the jit compilations; ``evaluation`` the periodic
evaluation rollouts; ``simulation`` is the warm-up (a jitted env-only scan: uniform random
actions, ``step_batch`` and buffer insertion, no updates) plus, for the training chunks, the
warm-up's time per iteration (the faster of two timed runs) times the number of training
iterations (an estimate: it leaves out the actor's forward pass used for exploration);
``optimisation`` = training-chunk time - that estimate. The warm-up is ``ceil(learning_starts / (num_envs * unroll))``
iterations.

Curve (one point after the warm-up and after every training chunk of about ``eval_every`` env
steps): 'step', 'normalized_power' (mean P/Pmax over the last 10 of 200 steps of
``eval_episodes`` deterministic episodes on the training model, drift fully on, fixed key),
'final_normalized_power' (last step only), 'critic_loss', 'actor_loss' (chunk means).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from agents import api as base
from agents.learners.offpolicy import observer, replay
from agents.envs import built, train_env_config


class Learner(NamedTuple):
    """An off-policy learner: ``build(env, h) -> dict(init, warmup, fit_norm, train_chunk)``, its
    ``networks(h, num_actions) -> (actor, critic)`` (flax modules) and ``greedy(actor, params, obs) -> action``
    (its deterministic action at standardised observations)."""

    name: str
    config_type: type
    build: Callable
    networks: Callable
    greedy: Callable

    def stored_config(self, hyper: dict):
        """The config of a stored ``hyper`` dict (keys that are not fields are left out)."""
        names = {*self.config_type.names(), "config"}
        return self.config_type.from_hyper({k: v for k, v in hyper.items() if k in names})

    def _actor(self, env_config: dict, hyper: dict):
        """(the actor module, its observation size, the observer or None)."""
        h = self.stored_config(hyper).to_hyper()
        env, _ = built(train_env_config(env_config, h["train_reward"]))
        seen = self._observer(env_config, h)
        return (
            self.networks(h, env.num_actions)[0],
            env.observation_size + (seen.size if seen else 0),
            seen,
        )

    def params_template(self, env_config: dict, hyper: dict):
        """Pytree with the structure of the policy params: {"actor": flax params, "obs_norm": {mean, std}}."""
        actor, d, _ = self._actor(env_config, hyper)
        return {
            "actor": actor.init(jax.random.key(0), jnp.zeros((1, d))),
            "obs_norm": replay.identity_norm(d),
        }

    def make_policy(self, env_config: dict, hyper: dict) -> base.Policy:
        """The deterministic actor at observations standardised by the params' ``obs_norm``; ignores key, carry
        and probe. With an observer (``agents.learners.offpolicy.observer``), the observer's estimate is appended first (its
        carry is the policy's)."""
        actor, _, seen = self._actor(env_config, hyper)

        def greedy(params, obs):
            return self.greedy(actor, params["actor"], replay.normalise(params["obs_norm"], obs))

        if seen is not None:
            return observer.policy(seen, greedy)

        def act(params, carry, obs, key, probe):
            del key, probe
            return greedy(params, obs), carry

        return base.Policy(lambda key, obs: (), act)

    @staticmethod
    def _observer(env_config: dict, h: dict):
        """The observer of the stored hyperparameters ``h`` on the learner's training environment, or None."""
        return observer.of_learner(train_env_config(env_config, h["train_reward"]), h)

    def training_env(self, env, env_config: dict, h: dict):
        """The batched env the learner trains on: ``env`` (of ``train_env_config(env_config, h["train_reward"])``),
        wrapped by ``agents.learners.offpolicy.observer.Observed`` with an observer."""
        seen = self._observer(env_config, h)
        return env if seen is None else observer.Observed(env, seen)


def seed_axes(ts):
    """vmap axes of a seed-batched training state: 0 for every per-seed leaf; ``None`` for what
    all seeds share (the step counts and buffer positions, which advance identically, and the
    environment parameters). Shared counters keep ``lax.cond`` a real branch under vmap (the
    buffer's wrap-around roll, the delayed actor update) instead of computing both sides."""
    axes = jax.tree.map(lambda _: 0, ts)
    buffer = axes.buffer.replace(insert_position=None, sample_position=None)
    return axes._replace(buffer=buffer, updates=None, env_params=None)


def _placed_first(place, out):
    """``(place(ts), rest)`` of a ``(ts, rest)`` pair."""
    return place(out[0]), out[1]


def _over_seeds(fns: dict, evaluate_fn, ts_shape, num_seeds: int, sharding) -> dict:
    """The training functions on a leading seed axis, jitted: vmapped for several seeds; for one,
    the plain functions with that axis squeezed and restored inside the jit (a size-1 vmap
    measured ~10% slower on CPU). With a ``sharding`` of the seed axis, every returned state is
    constrained to it (per-seed leaves split over devices, shared leaves replicated), so each
    compiled function gets the layout it was compiled for."""
    axes = seed_axes(ts_shape)
    is_none = lambda x: x is None  # noqa: E731

    def place(ts):
        if sharding is None:
            return ts
        shared = jax.sharding.NamedSharding(sharding.mesh, jax.sharding.PartitionSpec())
        return jax.tree.map(
            lambda a, sub: jax.lax.with_sharding_constraint(sub, sharding if a == 0 else shared),
            axes,
            ts,
            is_leaf=is_none,
        )

    if num_seeds > 1:

        def over(f, in_axes, out_axes):
            return jax.vmap(f, in_axes=in_axes, out_axes=out_axes)
    else:

        def reshape(tree, axes, fn):
            return jax.tree.map(
                lambda a, sub: sub if a is None else jax.tree.map(fn, sub),
                axes,
                tree,
                is_leaf=is_none,
            )

        def over(f, in_axes, out_axes):
            def one(*args):
                out = f(*(reshape(x, a, lambda v: v[0]) for x, a in zip(args, in_axes)))
                return reshape(out, out_axes, lambda v: v[None])

            return one

    def train_chunk(ts, n):
        ts, metrics = over(lambda t: fns["train_chunk"](t, n), (axes,), (axes, 0))(ts)
        return place(ts), metrics

    return dict(
        init=jax.jit(lambda k, p: place(over(fns["init"], (0, None), axes)(k, p))),
        warmup=jax.jit(
            lambda ts, n, random: _placed_first(
                place, over(lambda t: fns["warmup"](t, n, random), (axes,), (axes, 0))(ts)
            ),
            static_argnums=(1, 2),
        ),
        fit_norm=jax.jit(lambda ts, obs: place(over(fns["fit_norm"], (axes, 0), axes)(ts, obs))),
        train_chunk=jax.jit(train_chunk, static_argnums=1, donate_argnums=0),
        evaluate=jax.jit(over(evaluate_fn, (0, None, 0, None), 0)),
    )


# Hyperparameters that leave the compiled training programs unchanged.
_RUN_KEYS = ("config", "total_steps", "learning_starts", "eval_every", "eval_episodes")
_BUILDS: dict = {}


def _cached_build(learner: Learner, env_config: dict, h: dict, num_seeds: int) -> dict:
    """Seed-vmapped jitted training functions, built once per (learner, static env config,
    hyperparameters) in this process, so that other seeds or modes (their ``EnvParams`` are
    arguments) do not recompile. ``compiled(name, *args)`` compiles ahead of time once per argument signature."""
    env, env_params = built(train_env_config(env_config, h["train_reward"]))
    sharding = base.split_over_devices(num_seeds, "seeds")
    key = (
        learner.name,
        env.config,
        repr(sorted((k, v) for k, v in h.items() if k not in _RUN_KEYS)),
        num_seeds > 1,
        sharding,
    )
    if key not in _BUILDS:
        raw = learner.build(learner.training_env(env, env_config, h), h)
        evaluate_fn = base.evaluator(
            env, learner.make_policy(env_config, h), env.config.max_steps, 10
        )
        ts_shape = jax.eval_shape(raw["init"], jax.random.key(0), env_params)
        fns = _over_seeds(raw, evaluate_fn, ts_shape, num_seeds, sharding)
        fns["sharding"] = sharding
        compiled = {}

        def get_compiled(name, *args):
            """``name`` ("warmup": args (ts, length, random); "train_chunk": args (ts, length); "evaluate":
            its args) compiled."""
            static = args[1:] if name in ("warmup", "train_chunk") else None
            arrays = args[:1] if static is not None else args
            sig = (
                name,
                static,
                str(
                    jax.tree.map(lambda x: (x.shape, x.dtype, getattr(x, "sharding", None)), arrays)
                ),
            )
            if sig not in compiled:
                compiled[sig] = fns[name].lower(*args).compile()
            return compiled[sig]

        fns["compiled"] = get_compiled
        _BUILDS[key] = fns
    return _BUILDS[key], env_params


def check_seed(seed):
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"seed must be an int, got {seed!r}")
    return int(seed)


def schedule(h: dict) -> tuple[int, int, int]:
    """(warm-up iterations, training chunks, iterations per chunk) of ``h["total_steps"]`` env steps:
    the warm-up collects at least ``learning_starts`` steps, then chunks of about ``eval_every`` steps
    run whole iterations of ``num_envs * unroll`` steps, never past ``total_steps`` (the remainder of
    less than one iteration per chunk is not run)."""
    per_iter = h["num_envs"] * h["unroll"]
    warm_iters = -(-h["learning_starts"] // per_iter)
    if warm_iters * per_iter > h["total_steps"]:
        raise ValueError(
            f"total_steps must be >= the warm-up of learning_starts = {h['learning_starts']} rounded up "
            f"to whole iterations of num_envs * unroll = {per_iter} ({warm_iters * per_iter}), "
            f"got {h['total_steps']}"
        )
    train_iters = max(0, (h["total_steps"] - warm_iters * per_iter) // per_iter)
    n_chunks = -(-train_iters // max(1, h["eval_every"] // per_iter)) if train_iters else 0
    return warm_iters, n_chunks, (train_iters // n_chunks if n_chunks else 0)


def _warm_up(fns: dict, ts, warm_iters: int, timing: dict, random: bool = True):
    """(state after the warm-up (uniform random actions, then the observation statistics frozen; or,
    with ``random=False``, the policy's exploration and the statistics kept), simulation seconds per
    iteration); adds the compile and simulation time to ``timing``."""
    t0 = time.perf_counter()
    warmup = fns["compiled"]("warmup", ts, warm_iters, random)
    t1 = time.perf_counter()
    ts, warm_obs = jax.block_until_ready(warmup(ts))
    t2 = time.perf_counter()
    jax.block_until_ready(warmup(ts))  # a second, discarded timing run: the first one is noisier
    timing["compile"] += t1 - t0
    timing["simulation"] += t2 - t1
    return (fns["fit_norm"](ts, warm_obs) if random else ts), min(
        t2 - t1, time.perf_counter() - t2
    ) / warm_iters


# The fields of a training state that a run does not carry over to a continued one.
_FRESH = ("buffer", "env_state", "obs", "key", "updates", "env_params")


def _continued(ts, learner: Learner, start_from, seeds, sharding) -> object:
    """``ts`` (fresh, seed-batched) with the learned arrays of ``start_from`` (one TrainResult per seed, or
    one TrainResult for one seed) in its own structure (this run's optimisers and settings)."""
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
                f"start_from must hold {learner.name} TrainResults trained in this process (with their "
                f"training state), got {getattr(r, 'algo', type(r).__name__)!r}"
            )
    stacked = jax.tree.map(lambda *xs: np.stack(xs), *[r.state for r in start_from])
    fields = {}
    for name, value in stacked.items():
        fresh = getattr(ts, name)
        leaves, shapes = jax.tree.leaves(value), [x.shape for x in jax.tree.leaves(fresh)]
        if [x.shape for x in leaves] != shapes:
            raise ValueError(
                f"start_from's {name} does not fit this run: network sizes must match (and alpha_lr "
                "be 0 in both runs or in neither)"
            )
        fields[name] = jax.tree.unflatten(jax.tree.structure(fresh), leaves)
    return ts._replace(**jax.device_put(fields, sharding))


def train_seeds(
    learner: Learner,
    env_config: dict,
    *,
    seeds: Sequence[int],
    total_steps: int | None = None,
    progress_fn: Callable[[int, dict], None] | None = None,
    config=None,
    snapshot_fn: Callable[[int, list], None] | None = None,
    start_from=None,
    **hyper,
) -> list[base.TrainResult]:
    """Train ``learner`` for several seeds at once: one jitted call vmapped over the seeds (sharded
    over the local devices when they divide the seed count). See ``agents.learners.offpolicy.td3.train_seeds``.
    ``snapshot_fn(step, params)`` (optional) gets each seed's policy params (host copies) after the
    warm-up and after every training chunk: a run of ``total_steps`` T passes through the states of
    the shorter runs whose budgets end a chunk (multiples of ``eval_every`` after the warm-up).
    ``start_from`` (optional): one TrainResult of this learner per seed, continued (module docstring)."""
    env_config = base.check_env_config(env_config)
    seeds, h = _run_settings(learner, seeds, total_steps, config, hyper)
    warm_iters, n_chunks, chunk = schedule(h)
    per_iter = h["num_envs"] * h["unroll"]
    fns, env_params = _cached_build(learner, env_config, h, len(seeds))
    eval_ids = jnp.arange(h["eval_episodes"])

    t_start = time.perf_counter()
    timing = dict(simulation=0.0, optimisation=0.0, evaluation=0.0, compile=0.0)
    keys = jax.vmap(jax.random.split)(jax.vmap(jax.random.key)(jnp.asarray(seeds)))
    k_init, k_eval = keys[:, 0], keys[:, 1]
    if fns["sharding"] is not None:
        k_init, k_eval = jax.device_put((k_init, k_eval), fns["sharding"])
    ts = fns["init"](k_init, env_params)
    if start_from is not None:
        ts = _continued(ts, learner, start_from, seeds, fns["sharding"])
    ts, sim_per_iter = _warm_up(fns, ts, warm_iters, timing, random=start_from is None)

    t0 = time.perf_counter()
    evaluate_fn = fns["compiled"]("evaluate", policy_params(ts), env_params, k_eval, eval_ids)
    timing["compile"] += time.perf_counter() - t0

    def run_eval(ts):
        t0 = time.perf_counter()
        npow = evaluate_fn(policy_params(ts), env_params, k_eval, eval_ids)[0]
        npow = np.asarray(npow)  # (seeds, steps, episodes)
        timing["evaluation"] += time.perf_counter() - t0
        return npow[:, -10:].mean((1, 2)), npow[:, -1].mean(1)

    def report(step, npow, m=None):
        if snapshot_fn is not None:
            params = jax.device_get(policy_params(ts))
            snapshot_fn(step, [jax.tree.map(lambda x: x[i], params) for i in range(len(seeds))])
        if progress_fn is not None:
            progress_fn(
                step,
                dict(
                    normalized_power=float(npow.mean()),
                    elapsed_s=time.perf_counter() - t_start,
                    update_ratio=replay.updates_per_iter(h) / per_iter,
                    **_chunk_metrics(m),
                ),
            )

    nan = np.full(len(seeds), np.nan)
    step = warm_iters * per_iter
    sim_per_chunk = sim_per_iter * chunk
    if chunk:
        t0 = time.perf_counter()
        train_compiled = fns["compiled"]("train_chunk", ts, chunk)
        timing["compile"] += time.perf_counter() - t0
    npow, final = run_eval(ts)
    steps, npows, finals, closses, alosses = [step], [npow], [final], [nan], [nan]
    report(step, npow)
    for _ in range(n_chunks):
        t0 = time.perf_counter()
        ts, m = train_compiled(ts)
        m = jax.device_get(m)
        dt = time.perf_counter() - t0
        timing["simulation"] += min(sim_per_chunk, dt)
        timing["optimisation"] += max(0.0, dt - sim_per_chunk)
        step += chunk * per_iter
        npow, final = run_eval(ts)
        steps.append(step), npows.append(npow), finals.append(final)
        closses.append(np.asarray(m["critic_loss"])), alosses.append(np.asarray(m["actor_loss"]))
        report(step, npow, m)
    timing["total"] = time.perf_counter() - t_start
    curves = dict(
        normalized_power=np.stack(npows, 1),
        final_normalized_power=np.stack(finals, 1),
        critic_loss=np.stack(closses, 1),
        actor_loss=np.stack(alosses, 1),
    )
    return _results(learner, env_config, h, seeds, ts, np.asarray(steps), curves, timing)


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


def _run_settings(learner: Learner, seeds, total_steps, config, hyper: dict) -> tuple[list, dict]:
    """(the checked seeds, the run's stored hyperparameters: ``config`` and ``hyper`` resolved, ``total_steps``
    over the preset's)."""
    seeds = [check_seed(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be a non-empty sequence of distinct ints, got {seeds!r}")
    c = learner.config_type.make(config, **hyper)
    if total_steps is not None:
        c = dataclasses.replace(c, total_steps=total_steps)
    return seeds, c.to_hyper()


def _results(
    learner: Learner,
    env_config: dict,
    h: dict,
    seeds: list,
    ts,
    steps: np.ndarray,
    curves: dict,
    timing: dict,
) -> list[base.TrainResult]:
    """One TrainResult per seed of the seed-batched final state ``ts``, ``curves`` (name -> (seeds, points)) at
    env ``steps`` and the call's ``timing`` (s, shared out over the seeds)."""
    timing = {k: v / len(seeds) for k, v in timing.items()}
    timing["seeds_in_call"] = len(seeds)
    params = jax.device_get(policy_params(ts))
    kept = jax.device_get({k: v for k, v in ts._asdict().items() if k not in _FRESH})
    return [
        base.TrainResult(
            learner.name,
            env_config,
            dict(h),
            jax.tree.map(lambda x: x[i], params),
            dict(step=steps, **{k: v[i] for k, v in curves.items()}),
            dict(timing),
            seed,
            jax.tree.map(lambda x: x[i], kept),
        )
        for i, seed in enumerate(seeds)
    ]
