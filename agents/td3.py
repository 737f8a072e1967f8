"""TD3 (Fujimoto et al. 2018) in pure JAX, in the style of brax's trainers.

Flax (linen) networks in flax ``TrainState``s (optax Adam; targets by ``optax.incremental_update``),
brax's ``UniformSamplingQueue`` replay buffer, and the whole training loop as jitted ``lax.scan`` chunks over
the batched ``ops_jax`` environment (``env.reset_batch`` / ``env.step_batch``, ``model="phasor"`` unless the
env_config names a model).
Twin critics, target policy smoothing, delayed actor and target updates, Gaussian exploration.
Time-outs bootstrap: the stored discount is ``1 - terminated`` and the stored next observation is
``info["final_observation"]`` (the pre-reset one), so truncation is not treated as termination.

One training *iteration* = one batched env step of ``num_envs`` instances (exploration actions),
their insertion into the buffer, then ``updates_per_iter`` gradient steps (critic every step, actor
and targets every ``policy_delay`` steps). With ``unroll`` > 1 (the paper's SB3 setting: 100 env
steps, then 100 gradient steps) an iteration collects ``unroll`` batched steps first.

Observations are standardised with a mean / std frozen after the random warm-up (the offsets
x_i / 3 are ~0.05 while the powers span [-1, 1]), computed over the warm-up's observations that the
replay buffer holds (the last ``buffer_size``); the statistics are part of the policy params.

Wall time: ``total`` is everything; ``compile`` the jit compilations; ``evaluation`` the periodic
evaluation rollouts; ``simulation`` is the warm-up (a jitted env-only scan: uniform random
actions, ``step_batch`` and buffer insertion, no updates) plus, for the training chunks, the
warm-up's time per iteration (the faster of two timed runs) times the number of training
iterations (an estimate: it leaves out the actor's forward pass used for exploration);
``optimisation`` = training-chunk time - that estimate. The warm-up is ``ceil(learning_starts / (num_envs * unroll))``
iterations; ``learning_starts`` >= ``batch_size`` is required.

Curve (one point after the warm-up and after every training chunk of about ``eval_every`` env
steps): 'step', 'normalized_power' (mean P/Pmax over the last 10 of 200 steps of
``eval_episodes`` deterministic episodes on the training model, drift fully on, fixed key),
'final_normalized_power' (last step only), 'critic_loss', 'actor_loss' (chunk means).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from agents import base, brax_compat  # noqa: F401  (brax_compat: quiet brax import)
from agents.config import TD3Config
from agents.envs import built, train_env_config


# -- networks -----------------------------------------------------------------------------------

def _networks(hidden: Sequence[int], num_actions: int):
    import flax.linen as nn

    class MLP(nn.Module):
        out: int

        @nn.compact
        def __call__(self, x):
            for h in hidden:
                x = nn.relu(nn.Dense(h)(x))
            return nn.Dense(self.out)(x)

    class Actor(nn.Module):
        @nn.compact
        def __call__(self, obs):
            return jnp.tanh(MLP(num_actions)(obs))

    class Critic(nn.Module):
        @nn.compact
        def __call__(self, obs, action):
            x = jnp.concatenate([obs, action], -1)
            return MLP(1)(x)[..., 0], MLP(1)(x)[..., 0]

    return Actor(), Critic()


def _normalise(norm, obs):
    return (obs - norm["mean"]) / norm["std"]


def _stored_config(hyper: dict) -> TD3Config:
    """The config of a stored ``hyper`` dict (keys that are not fields are left out)."""
    return TD3Config.from_hyper({k: v for k, v in hyper.items() if k in TD3Config.names() or k == "config"})


def params_template(env_config: dict, hyper: dict):
    """Pytree with the structure of the policy params: {"actor": flax params, "obs_norm": {mean, std}}."""
    env, _ = built(train_env_config(env_config))
    actor, _ = _networks(_stored_config(hyper).hidden, env.num_actions)
    d = env.observation_size
    return {"actor": actor.init(jax.random.key(0), jnp.zeros((1, d))),
            "obs_norm": {"mean": jnp.zeros(d), "std": jnp.ones(d)}}


def make_policy(env_config: dict, hyper: dict) -> base.Policy:
    """The deterministic actor: a = tanh(MLP((obs - mean) / std)); ignores key, carry and probe."""
    env, _ = built(train_env_config(env_config))
    actor, _ = _networks(_stored_config(hyper).hidden, env.num_actions)

    def act(params, carry, obs, key, probe):
        del key, probe
        return actor.apply(params["actor"], _normalise(params["obs_norm"], obs)), carry

    return base.Policy(lambda key, obs: (), act)


# -- training -----------------------------------------------------------------------------------

class TD3State(NamedTuple):
    actor: Any  # flax TrainState: params, optimiser state
    critic: Any  # flax TrainState
    actor_target: Any  # params
    critic_target: Any  # params
    obs_norm: Any
    buffer: Any
    env_state: Any
    obs: jax.Array
    key: jax.Array
    updates: jax.Array  # gradient steps so far
    env_params: Any  # an argument, not a constant: one program serves every mode


def _losses(actor, critic, h):
    """``(critic_loss, actor_loss)``: clipped double-Q regression on smoothed target actions, and -Q1
    of the actor's actions."""
    gamma = h["gamma"]

    def critic_loss(cp, ts, batch, key):
        nobs = _normalise(ts.obs_norm, batch["next_obs"])
        obs = _normalise(ts.obs_norm, batch["obs"])
        a2 = actor.apply(ts.actor_target, nobs)
        eps = jnp.clip(h["target_noise"] * jax.random.normal(key, a2.shape), -h["noise_clip"], h["noise_clip"])
        a2 = jnp.clip(a2 + eps, -1, 1)
        q1t, q2t = critic.apply(ts.critic_target, nobs, a2)
        y = jax.lax.stop_gradient(batch["reward"] + gamma * batch["discount"] * jnp.minimum(q1t, q2t))
        q1, q2 = critic.apply(cp, obs, batch["action"])
        return jnp.mean((q1 - y) ** 2 + (q2 - y) ** 2)

    def actor_loss(ap, ts, batch):
        obs = _normalise(ts.obs_norm, batch["obs"])
        q1, _ = critic.apply(ts.critic.params, obs, actor.apply(ap, obs))
        return -jnp.mean(q1)

    return critic_loss, actor_loss


def _update_fn(actor, critic, buffer, h):
    """``update(ts, _)``: one gradient step of the critics on a sampled batch; every ``policy_delay``-th
    step also of the actor, and the targets' Polyak update."""
    import optax

    tau = h["tau"]
    critic_loss, actor_loss = _losses(actor, critic, h)

    def update(ts, _):
        buf, batch = buffer.sample(ts.buffer)
        key, k_noise = jax.random.split(ts.key)
        closs, grads = jax.value_and_grad(critic_loss)(ts.critic.params, ts, batch, k_noise)
        ts = ts._replace(critic=ts.critic.apply_gradients(grads=grads), buffer=buf, key=key)

        def actor_step(ts):
            aloss, g = jax.value_and_grad(actor_loss)(ts.actor.params, ts, batch)
            new_actor = ts.actor.apply_gradients(grads=g)
            return ts._replace(actor=new_actor,
                               actor_target=optax.incremental_update(new_actor.params, ts.actor_target, tau),
                               critic_target=optax.incremental_update(ts.critic.params, ts.critic_target, tau)), aloss

        ts, aloss = jax.lax.cond(ts.updates % h["policy_delay"] == 0, actor_step,
                                 lambda ts: (ts, jnp.float32(jnp.nan)), ts)
        return ts._replace(updates=ts.updates + 1), (closs, aloss)

    return update


def _collect_fn(env, actor, buffer, h):
    """``collect(ts, random)``: ``unroll`` steps of every environment with exploration noise (uniform
    random actions when ``random``), stored in the replay buffer."""
    b = h["num_envs"]

    def explore(ts, key, obs, random):
        k1, k2 = jax.random.split(key)
        greedy = actor.apply(ts.actor.params, _normalise(ts.obs_norm, obs))
        noisy = jnp.clip(greedy + h["expl_std"] * jax.random.normal(k1, greedy.shape), -1, 1)
        uniform = jax.random.uniform(k2, greedy.shape, minval=-1, maxval=1)
        return jnp.where(random, uniform, noisy)

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

    return collect


def _build(env, h):
    """TD3's jitted pieces on ``env`` with hyperparameters ``h``: init, warmup, fit_norm, train_chunk."""
    import optax
    from brax.training.replay_buffers import UniformSamplingQueue
    from flax.training.train_state import TrainState

    actor, critic = _networks(h["hidden"], env.num_actions)
    d, n, b = env.observation_size, env.num_actions, h["num_envs"]
    dummy = dict(obs=jnp.zeros(d), action=jnp.zeros(n), reward=jnp.zeros(()), discount=jnp.zeros(()),
                 next_obs=jnp.zeros(d))
    buffer = UniformSamplingQueue(h["buffer_size"], dummy, h["batch_size"])
    actor_tx, critic_tx = optax.adam(h["actor_lr"]), optax.adam(h["critic_lr"])
    update = _update_fn(actor, critic, buffer, h)
    collect = _collect_fn(env, actor, buffer, h)

    def iteration(ts, _):
        ts, (reward, _) = collect(ts, False)
        ts, (closs, aloss) = jax.lax.scan(update, ts, None, length=h["updates_per_iter"])
        return ts, dict(reward=reward.mean(), critic_loss=closs.mean(), actor_loss=jnp.nanmean(aloss))

    def train_chunk(ts, length):
        ts, m = jax.lax.scan(iteration, ts, None, length=length)
        return ts, jax.tree.map(jnp.mean, m)

    def warmup(ts, length):
        """``length`` iterations of random actions; returns the state and their observations (T, D)."""
        def body(ts, _):
            ts, (_, obs) = collect(ts, True)
            return ts, obs

        ts, obs = jax.lax.scan(body, ts, None, length=length)
        return ts, obs.reshape(-1, d)

    def init(key, env_params):
        k_a, k_c, k_buf, k_env, k_run = jax.random.split(key, 5)
        dummy_obs, dummy_act = jnp.zeros((1, d)), jnp.zeros((1, n))
        ap = actor.init(k_a, dummy_obs)
        cp = critic.init(k_c, dummy_obs, dummy_act)
        obs, env_state = env.reset_batch(jax.random.split(k_env, b), env_params)
        def state(net, params, tx):  # an array step count (vmapped over seeds like every leaf)
            return TrainState.create(apply_fn=net.apply, params=params, tx=tx).replace(step=jnp.int32(0))

        return TD3State(state(actor, ap, actor_tx), state(critic, cp, critic_tx), ap, cp,
                        {"mean": jnp.zeros(d), "std": jnp.ones(d)}, buffer.init(k_buf), env_state, obs, k_run,
                        jnp.int32(0), env_params)

    def fit_norm(ts, obs):
        """Freeze the observation statistics from the warm-up's observations ``obs`` (T, D) that
        the buffer holds (the last ``buffer_size``); std floored at 1e-2."""
        if not h["normalize_obs"]:
            return ts
        kept = obs[-h["buffer_size"]:]
        mean = kept.mean(0)
        std = jnp.sqrt(((kept - mean) ** 2).mean(0))
        return ts._replace(obs_norm={"mean": mean, "std": jnp.maximum(std, 1e-2)})

    return dict(init=init, warmup=warmup, fit_norm=fit_norm, train_chunk=train_chunk)


def _seed_axes(ts: TD3State) -> TD3State:
    """vmap axes of a seed-batched ``TrainState``: 0 for every per-seed leaf; ``None`` for what
    all seeds share (the step counts and buffer positions, which advance identically, and the
    environment parameters). Shared counters keep ``lax.cond`` a real branch under vmap (the
    buffer's wrap-around roll, the delayed actor update) instead of computing both sides."""
    axes = jax.tree.map(lambda _: 0, ts)
    buffer = axes.buffer.replace(insert_position=None, sample_position=None)
    return axes._replace(buffer=buffer, updates=None, env_params=None)


def _placed_first(place, out):
    """``(place(ts), rest)`` of a ``(ts, rest)`` pair."""
    return place(out[0]), out[1]


def _over_seeds(fns: dict, evaluate_fn, ts_shape: TD3State, num_seeds: int, sharding) -> dict:
    """The training functions on a leading seed axis, jitted: vmapped for several seeds; for one,
    the plain functions with that axis squeezed and restored inside the jit (a size-1 vmap is
    slower on CPU: docs/results.md). With a ``sharding`` of the seed axis, every returned state is
    constrained to it (per-seed leaves split over devices, shared leaves replicated), so each
    compiled function gets the layout it was compiled for."""
    axes = _seed_axes(ts_shape)
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
        warmup=jax.jit(lambda ts, n: _placed_first(place, over(lambda t: fns["warmup"](t, n), (axes,), (axes, 0))(ts)),
                       static_argnums=1),
        fit_norm=jax.jit(lambda ts, obs: place(over(fns["fit_norm"], (axes, 0), axes)(ts, obs))),
        train_chunk=jax.jit(train_chunk, static_argnums=1, donate_argnums=0),
        evaluate=jax.jit(over(evaluate_fn, (0, None, 0, None), 0)),
    )


_BUILD_KEYS = ("num_envs", "unroll", "updates_per_iter", "batch_size", "hidden", "actor_lr", "critic_lr", "gamma",
               "tau", "buffer_size", "expl_std", "target_noise", "noise_clip", "policy_delay", "normalize_obs")
_BUILDS: dict = {}


def _cached_build(env_config: dict, h: dict, num_seeds: int) -> dict:
    """Seed-vmapped jitted training functions, built once per (static env config, hyperparameters)
    in this process, so that other seeds or modes (their ``EnvParams`` are arguments) do not
    recompile. ``compiled(name, *args)`` compiles ahead of time once per argument signature."""
    env, env_params = built(train_env_config(env_config))
    sharding = base.split_over_devices(num_seeds, "seeds")
    key = (env.config, repr([(k, h[k]) for k in _BUILD_KEYS]), num_seeds > 1, sharding)
    if key not in _BUILDS:
        raw = _build(env, h)
        evaluate_fn, _ = base.evaluator(env, make_policy(env_config, h), env.config.max_steps, 10)
        ts_shape = jax.eval_shape(raw["init"], jax.random.key(0), env_params)
        fns = _over_seeds(raw, evaluate_fn, ts_shape, num_seeds, sharding)
        fns["sharding"] = sharding
        compiled = {}

        def get_compiled(name, *args):
            """``name`` ("warmup" | "train_chunk": args (ts, length); "evaluate": its args) compiled."""
            static = args[1] if name in ("warmup", "train_chunk") else None
            arrays = args[:1] if static is not None else args
            sig = (name, static, str(jax.tree.map(lambda x: (x.shape, x.dtype, getattr(x, "sharding", None)),
                                                  arrays)))
            if sig not in compiled:
                compiled[sig] = fns[name].lower(*args).compile()
            return compiled[sig]

        fns["compiled"] = get_compiled
        _BUILDS[key] = fns
    return _BUILDS[key], env_params


def _check_seed(seed):
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"seed must be an int, got {seed!r}")
    return int(seed)


def _schedule(h: dict) -> tuple:
    """``(env steps per iteration, warm-up iterations, training chunks, iterations per chunk)`` of a
    training of ``total_steps``, evaluated every ``eval_every`` env steps: the warm-up collects at least
    ``learning_starts`` steps, then chunks of about ``eval_every`` steps run whole iterations of
    ``num_envs * unroll`` steps, never past ``total_steps`` (a remainder under one iteration per chunk is not run)."""
    per_iter = h["num_envs"] * h["unroll"]
    warm_iters = -(-h["learning_starts"] // per_iter)
    if warm_iters * per_iter > h["total_steps"]:
        raise ValueError(f"total_steps must be >= the warm-up of learning_starts = {h['learning_starts']} rounded up "
                         f"to whole iterations of num_envs * unroll = {per_iter} ({warm_iters * per_iter}), "
                         f"got {h['total_steps']}")
    train_iters = max(0, (h["total_steps"] - warm_iters * per_iter) // per_iter)
    n_chunks = -(-train_iters // max(1, h["eval_every"] // per_iter)) if train_iters else 0
    return per_iter, warm_iters, n_chunks, (train_iters // n_chunks if n_chunks else 0)


def _warm_start(fns: dict, env_params, seeds: list, warm_iters: int, timing: dict) -> tuple:
    """The seeds' initial states after the random warm-up and the observation statistics: ``(state, evaluation
    keys, seconds of simulation per warm-up iteration)``; compile and simulation seconds added to ``timing``."""
    keys = jax.vmap(jax.random.split)(jax.vmap(jax.random.key)(jnp.asarray(seeds)))
    k_init, k_eval = keys[:, 0], keys[:, 1]
    if fns["sharding"] is not None:
        k_init, k_eval = jax.device_put((k_init, k_eval), fns["sharding"])
    ts = fns["init"](k_init, env_params)
    t0 = time.perf_counter()
    warmup = fns["compiled"]("warmup", ts, warm_iters)
    t1 = time.perf_counter()
    ts, warm_obs = jax.block_until_ready(warmup(ts))
    t2 = time.perf_counter()
    jax.block_until_ready(warmup(ts))  # a second, discarded timing run: the first one is noisier
    sim_per_iter = min(t2 - t1, time.perf_counter() - t2) / warm_iters
    timing["compile"] += t1 - t0
    timing["simulation"] += t2 - t1
    ts = fns["fit_norm"](ts, warm_obs)
    return ts, k_eval, sim_per_iter


def _results(env_config: dict, h: dict, seeds: list, params, curves: dict, timing: dict) -> list:
    """One ``TrainResult`` per seed from the seed-batched ``params`` and ``curves`` (lists over evaluations
    of arrays over seeds); wall times divided by the number of seeds."""
    steps, npows, finals, closses, alosses = (curves[k] for k in ("step", "normalized_power", "final_normalized_power",
                                                                  "critic_loss", "actor_loss"))
    timing = {k: v / len(seeds) for k, v in timing.items()}
    timing["seeds_in_call"] = len(seeds)
    curves = dict(normalized_power=np.stack(npows, 1), final_normalized_power=np.stack(finals, 1),
                  critic_loss=np.stack(closses, 1), actor_loss=np.stack(alosses, 1))
    return [base.TrainResult("td3", env_config, dict(h), jax.tree.map(lambda x: x[i], params),
                             dict(step=np.asarray(steps), **{k: v[i] for k, v in curves.items()}),
                             dict(timing), seed)
            for i, seed in enumerate(seeds)]


def train(env_config: dict, *, seed: int = 0, total_steps: int | None = None,
          progress_fn: Callable[[int, dict], None] | None = None, config: TD3Config | str | None = None,
          **hyper) -> base.TrainResult:
    """Train TD3 on ``built(env_config)`` (phasor model unless set) for ``total_steps`` env
    steps (default: the config's). ``config``: a ``TD3Config`` or a preset name ("fast" default |
    "paper"), ``hyper``: overrides of its fields. ``progress_fn(step, metrics)`` is called after every evaluation
    with metrics normalized_power, critic_loss, actor_loss, reward, elapsed_s. Trains at most ``total_steps``
    env steps (whole iterations, ``_schedule``); the curve's 'step' holds the true counts."""
    return train_seeds(env_config, seeds=[_check_seed(seed)], total_steps=total_steps, progress_fn=progress_fn,
                       config=config, **hyper)[0]


def train_seeds(env_config: dict, *, seeds: Sequence[int], total_steps: int | None = None,
                progress_fn: Callable[[int, dict], None] | None = None, config: TD3Config | str | None = None,
                **hyper) -> list[base.TrainResult]:
    """``train`` for several seeds at once: one jitted call vmapped over the seeds (sharded over the
    local devices when they divide the seed count). Each seed makes the same random draws as when
    trained alone, but the batched matrix products round differently and training amplifies the
    difference (docs/results.md), so a seed's result depends on the seed list it was trained with, bitwise
    reproducibly for the same list; on as many devices as seeds it is the solo result. Wall times
    are the call's divided by the number of seeds (``wall_time["seeds_in_call"]``); ``progress_fn``
    gets means over seeds."""
    env_config = base.check_env_config(env_config)
    seeds = [_check_seed(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be a non-empty sequence of distinct ints, got {seeds!r}")
    c = TD3Config.make(config, **hyper)
    if total_steps is not None:
        c = dataclasses.replace(c, total_steps=total_steps)
    h = c.to_hyper()
    per_iter, warm_iters, n_chunks, chunk = _schedule(h)  # a budget below the warm-up fails before compiling
    fns, env_params = _cached_build(env_config, h, len(seeds))
    eval_ids = jnp.arange(h["eval_episodes"])

    t_start = time.perf_counter()
    timing = dict(simulation=0.0, optimisation=0.0, evaluation=0.0, compile=0.0)
    ts, k_eval, sim_per_iter = _warm_start(fns, env_params, seeds, warm_iters, timing)

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
        if progress_fn is not None:
            extra = {} if m is None else dict(critic_loss=float(m["critic_loss"].mean()),
                                              actor_loss=float(np.nanmean(m["actor_loss"])),
                                              reward=float(m["reward"].mean()))
            progress_fn(step, dict(normalized_power=float(npow.mean()), elapsed_s=time.perf_counter() - t_start,
                                   **extra))

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
    curves = dict(step=steps, normalized_power=npows, final_normalized_power=finals, critic_loss=closses,
                  actor_loss=alosses)
    return _results(env_config, h, seeds, jax.device_get(params_of(ts)), curves, timing)
