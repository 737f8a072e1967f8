"""The shared machinery of the off-policy learners (``agents.td3``, ``agents.droq``): replay buffer,
exploration / update loop as jitted ``lax.scan`` chunks, seeds vmapped, the training driver.

A learner is a ``Learner``: its name, config type, ``build(env, h)`` (its networks, exploration
and update, wired through ``replay_loop``) and ``make_policy``. Its training state is a NamedTuple
with at least the fields ``actor`` (a flax TrainState), ``obs_norm``, ``buffer``, ``env_state``,
``obs``, ``key``, ``updates`` and ``env_params``; the stored policy params are
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

from agents import base
from agents.envs import built, train_env_config


class Learner(NamedTuple):
    """An off-policy learner: ``build(env, h) -> dict(init, warmup, fit_norm, train_chunk)``,
    ``make_policy(env_config, hyper) -> base.Policy``."""

    name: str
    config_type: type
    build: Callable
    make_policy: Callable


def normalise(norm, obs):
    return (obs - norm["mean"]) / norm["std"]


def updates_per_iter(h: dict) -> int:
    """Gradient steps per iteration: ``updates_per_iter``, or ``utd_ratio * num_envs * unroll``."""
    if h["updates_per_iter"] is not None:
        return h["updates_per_iter"]
    return round(h["utd_ratio"] * h["num_envs"] * h["unroll"])


def identity_norm(d: int) -> dict:
    """Observation statistics that leave ``d``-dimensional observations unchanged."""
    return {"mean": jnp.zeros(d), "std": jnp.ones(d)}


def train_state(params, tx):
    """A flax TrainState with an array step count (vmapped over seeds like every leaf)."""
    from flax.training.train_state import TrainState

    return TrainState.create(apply_fn=None, params=params, tx=tx).replace(step=jnp.int32(0))


def replay_buffer(env, h):
    """brax's uniform replay queue of (obs, action, reward, discount, next_obs) transitions."""
    from brax.training.replay_buffers import UniformSamplingQueue

    d, n = env.observation_size, env.num_actions
    dummy = dict(obs=jnp.zeros(d), action=jnp.zeros(n), reward=jnp.zeros(()), discount=jnp.zeros(()),
                 next_obs=jnp.zeros(d))
    return UniformSamplingQueue(h["buffer_size"], dummy, h["batch_size"])


def start(env, h, buffer, actor, critic, key, env_params):
    """(actor params, critic params, buffer state, env state, first observations, run key) of a fresh run."""
    k_a, k_c, k_buf, k_env, k_run = jax.random.split(key, 5)
    dummy_obs, dummy_act = jnp.zeros((1, env.observation_size)), jnp.zeros((1, env.num_actions))
    obs, env_state = env.reset_batch(jax.random.split(k_env, h["num_envs"]), env_params)
    return (actor.init(k_a, dummy_obs), critic.init(k_c, dummy_obs, dummy_act), buffer.init(k_buf), env_state, obs,
            k_run)


def delayed(ts, h, actor_step):
    """``actor_step(ts) -> (ts, actor loss)`` every ``policy_delay`` gradient steps (NaN loss
    otherwise), then the gradient step count advanced."""
    ts, aloss = jax.lax.cond(ts.updates % h["policy_delay"] == 0, actor_step, lambda ts: (ts, jnp.float32(jnp.nan)), ts)
    return ts._replace(updates=ts.updates + 1), aloss


def replay_loop(env, h, buffer, explore, update) -> dict:
    """The jitted-scan pieces of training around ``explore(ts, key, obs, random) -> actions`` and
    ``update(ts, _) -> (ts, (critic_loss, actor_loss))`` (one gradient step, sampling ``buffer``):
    ``warmup(ts, n, random)`` (n iterations of uniform random actions, or of the policy's exploration
    with ``random=False``; returns their observations (T, D)),
    ``fit_norm(ts, obs)`` and ``train_chunk(ts, n)`` (n iterations, returns chunk-mean metrics)."""
    b, d = h["num_envs"], env.observation_size

    def env_step(ts, key, random):
        k_act, k_env = jax.random.split(key)
        action = explore(ts, k_act, ts.obs, random)
        obs2, env_state, reward, term, _, info = env.step_batch(jax.random.split(k_env, b), ts.env_state,
                                                               action, ts.env_params)
        tr = dict(obs=ts.obs, action=action, reward=reward, discount=1.0 - term.astype(jnp.float32),
                  next_obs=info["final_observation"])
        return ts._replace(env_state=env_state, obs=obs2), tr

    def collect(ts, random):
        def body(ts, _):
            key, k = jax.random.split(ts.key)
            ts, tr = env_step(ts._replace(key=key), k, random)
            return ts._replace(buffer=buffer.insert(ts.buffer, tr)), (tr["reward"], tr["obs"])
        return jax.lax.scan(body, ts, None, length=h["unroll"])

    def iteration(ts, _):
        ts, (reward, _) = collect(ts, False)
        ts, (closs, aloss) = jax.lax.scan(update, ts, None, length=updates_per_iter(h))
        return ts, dict(reward=reward.mean(), critic_loss=closs.mean(), actor_loss=jnp.nanmean(aloss))

    def train_chunk(ts, length):
        ts, m = jax.lax.scan(iteration, ts, None, length=length)
        return ts, jax.tree.map(jnp.mean, m)

    def warmup(ts, length, random=True):
        def body(ts, _):
            ts, (_, obs) = collect(ts, random)
            return ts, obs

        ts, obs = jax.lax.scan(body, ts, None, length=length)
        return ts, obs.reshape(-1, d)

    def fit_norm(ts, obs):
        """Freeze the observation statistics from the warm-up's observations ``obs`` (T, D) that
        the buffer holds (the last ``buffer_size``); std floored at 1e-2."""
        if not h["normalize_obs"]:
            return ts
        kept = obs[-h["buffer_size"]:]
        mean = kept.mean(0)
        std = jnp.sqrt(((kept - mean) ** 2).mean(0))
        return ts._replace(obs_norm={"mean": mean, "std": jnp.maximum(std, 1e-2)})

    return dict(warmup=warmup, fit_norm=fit_norm, train_chunk=train_chunk)


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
        return jax.tree.map(lambda a, sub: jax.lax.with_sharding_constraint(sub, sharding if a == 0 else shared),
                            axes, ts, is_leaf=is_none)

    if num_seeds > 1:
        def over(f, in_axes, out_axes):
            return jax.vmap(f, in_axes=in_axes, out_axes=out_axes)
    else:
        def reshape(tree, axes, fn):
            return jax.tree.map(lambda a, sub: sub if a is None else jax.tree.map(fn, sub), axes, tree, is_leaf=is_none)

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
        warmup=jax.jit(lambda ts, n, random: _placed_first(place, over(lambda t: fns["warmup"](t, n, random), (axes,),
                                                                                  (axes, 0))(ts)),
                       static_argnums=(1, 2)),
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
    key = (learner.name, env.config, repr(sorted((k, v) for k, v in h.items() if k not in _RUN_KEYS)), num_seeds > 1,
           sharding)
    if key not in _BUILDS:
        raw = learner.build(env, h)
        evaluate_fn, _ = base.evaluator(env, learner.make_policy(env_config, h), env.config.max_steps, 10)
        ts_shape = jax.eval_shape(raw["init"], jax.random.key(0), env_params)
        fns = _over_seeds(raw, evaluate_fn, ts_shape, num_seeds, sharding)
        fns["sharding"] = sharding
        compiled = {}

        def get_compiled(name, *args):
            """``name`` ("warmup": args (ts, length, random); "train_chunk": args (ts, length); "evaluate":
            its args) compiled."""
            static = args[1:] if name in ("warmup", "train_chunk") else None
            arrays = args[:1] if static is not None else args
            sig = (name, static, str(jax.tree.map(lambda x: (x.shape, x.dtype, getattr(x, "sharding", None)),
                                                  arrays)))
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
        raise ValueError(f"total_steps must be >= the warm-up of learning_starts = {h['learning_starts']} rounded up "
                         f"to whole iterations of num_envs * unroll = {per_iter} ({warm_iters * per_iter}), "
                         f"got {h['total_steps']}")
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
    return (fns["fit_norm"](ts, warm_obs) if random else ts), min(t2 - t1, time.perf_counter() - t2) / warm_iters


# The fields of a training state that a run does not carry over to a continued one.
_FRESH = ("buffer", "env_state", "obs", "key", "updates", "env_params")


def _continued(ts, learner: Learner, start_from, seeds, sharding) -> object:
    """``ts`` (fresh, seed-batched) with the learned arrays of ``start_from`` (one TrainResult per seed, or
    one TrainResult for one seed) in its own structure (this run's optimisers and settings)."""
    if isinstance(start_from, base.TrainResult):
        start_from = [start_from]
    start_from = list(start_from)
    if len(start_from) != len(seeds):
        raise ValueError(f"start_from must hold one TrainResult per seed ({len(seeds)}), got {len(start_from)}")
    for r in start_from:
        if not isinstance(r, base.TrainResult) or r.algo != learner.name or r.state is None:
            raise ValueError(f"start_from must hold {learner.name} TrainResults trained in this process (with their "
                             f"training state), got {getattr(r, 'algo', type(r).__name__)!r}")
    stacked = jax.tree.map(lambda *xs: np.stack(xs), *[r.state for r in start_from])
    fields = {}
    for name, value in stacked.items():
        fresh = getattr(ts, name)
        leaves, shapes = jax.tree.leaves(value), [x.shape for x in jax.tree.leaves(fresh)]
        if [x.shape for x in leaves] != shapes:
            raise ValueError(f"start_from's {name} does not fit this run: network sizes must match (and alpha_lr "
                             "be 0 in both runs or in neither)")
        fields[name] = jax.tree.unflatten(jax.tree.structure(fresh), leaves)
    return ts._replace(**jax.device_put(fields, sharding))


def train_seeds(learner: Learner, env_config: dict, *, seeds: Sequence[int], total_steps: int | None = None,
                progress_fn: Callable[[int, dict], None] | None = None, config=None,
                snapshot_fn: Callable[[int, list], None] | None = None, start_from=None,
                **hyper) -> list[base.TrainResult]:
    """Train ``learner`` for several seeds at once: one jitted call vmapped over the seeds (sharded
    over the local devices when they divide the seed count). See ``agents.td3.train_seeds``.
    ``snapshot_fn(step, params)`` (optional) gets each seed's policy params (host copies) after the
    warm-up and after every training chunk: a run of ``total_steps`` T passes through the states of
    the shorter runs whose budgets end a chunk (multiples of ``eval_every`` after the warm-up).
    ``start_from`` (optional): one TrainResult of this learner per seed, continued (module docstring)."""
    env_config = base.check_env_config(env_config)
    seeds = [check_seed(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be a non-empty sequence of distinct ints, got {seeds!r}")
    c = learner.config_type.make(config, **hyper)
    if total_steps is not None:
        c = dataclasses.replace(c, total_steps=total_steps)
    h = c.to_hyper()
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

    def params_of(ts):
        return {"actor": ts.actor.params, "obs_norm": ts.obs_norm}

    t0 = time.perf_counter()
    evaluate_fn = fns["compiled"]("evaluate", params_of(ts), env_params, k_eval, eval_ids)
    timing["compile"] += time.perf_counter() - t0

    def run_eval(ts):
        t0 = time.perf_counter()
        npow, _ = evaluate_fn(params_of(ts), env_params, k_eval, eval_ids)
        npow = np.asarray(npow)  # (seeds, steps, episodes)
        timing["evaluation"] += time.perf_counter() - t0
        return npow[:, -10:].mean((1, 2)), npow[:, -1].mean(1)

    def report(step, npow, m=None):
        if snapshot_fn is not None:
            params = jax.device_get(params_of(ts))
            snapshot_fn(step, [jax.tree.map(lambda x: x[i], params) for i in range(len(seeds))])
        if progress_fn is not None:
            extra = {} if m is None else dict(critic_loss=float(m["critic_loss"].mean()),
                                              actor_loss=float(np.nanmean(m["actor_loss"])),
                                              reward=float(m["reward"].mean()))
            progress_fn(step, dict(normalized_power=float(npow.mean()), elapsed_s=time.perf_counter() - t_start,
                                   update_ratio=updates_per_iter(h) / per_iter, **extra))

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
    timing = {k: v / len(seeds) for k, v in timing.items()}
    timing["seeds_in_call"] = len(seeds)
    params = jax.device_get(params_of(ts))
    kept = jax.device_get({k: v for k, v in ts._asdict().items() if k not in _FRESH})
    curves = dict(normalized_power=np.stack(npows, 1), final_normalized_power=np.stack(finals, 1),
                  critic_loss=np.stack(closses, 1), actor_loss=np.stack(alosses, 1))
    return [base.TrainResult(learner.name, env_config, dict(h), jax.tree.map(lambda x: x[i], params),
                             dict(step=np.asarray(steps), **{k: v[i] for k, v in curves.items()}),
                             dict(timing), seed, jax.tree.map(lambda x: x[i], kept))
            for i, seed in enumerate(seeds)]


def mlp_module():
    """The flax MLP of the off-policy learners: ``MLP(hidden, out, layer_norm, dropout)``; each hidden
    layer is Dense, then Dropout (rate ``dropout``, active when called with ``train=True``), then
    LayerNorm (if ``layer_norm``), then ReLU (DroQ's critic order)."""
    import flax.linen as nn

    class MLP(nn.Module):
        hidden: tuple
        out: int
        layer_norm: bool = False
        dropout: float = 0.0

        @nn.compact
        def __call__(self, x, train: bool = False):
            for h in self.hidden:
                x = nn.Dense(h)(x)
                if self.dropout > 0:
                    x = nn.Dropout(self.dropout, deterministic=not train)(x)
                if self.layer_norm:
                    x = nn.LayerNorm()(x)
                x = nn.relu(x)
            return nn.Dense(self.out)(x)

    return MLP
