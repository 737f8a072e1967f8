"""The seed-vmapped, jitted training functions of an off-policy learner
(``agents.learners.offpolicy.driver``), built once per learner, static environment configuration and
hyperparameters in a process."""

from __future__ import annotations

import jax

from agents import evaluation
from agents.envs import built, train_env_config


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


def cached_build(learner, env_config: dict, h: dict, num_seeds: int) -> dict:
    """Seed-vmapped jitted training functions, built once per (learner, static env config,
    hyperparameters) in this process, so that other seeds or modes (their ``EnvParams`` are
    arguments) do not recompile. ``compiled(name, *args)`` compiles ahead of time once per argument
    signature."""
    env, env_params = built(train_env_config(env_config, h["train_reward"]))
    sharding = evaluation.split_over_devices(num_seeds, "seeds")
    key = (
        learner.name,
        env.config,
        repr(sorted((k, v) for k, v in h.items() if k not in _RUN_KEYS)),
        num_seeds > 1,
        sharding,
    )
    if key not in _BUILDS:
        raw = learner.build(learner.training_env(env, env_config, h), h)
        evaluate_fn = evaluation.evaluator(
            env, learner.make_policy(env_config, h), env.config.max_steps, 10
        )
        ts_shape = jax.eval_shape(raw["init"], jax.random.key(0), env_params)
        fns = _over_seeds(raw, evaluate_fn, ts_shape, num_seeds, sharding)
        fns["sharding"] = sharding
        compiled = {}

        def get_compiled(name, *args):
            """``name`` ("warmup": args (ts, length, random); "train_chunk": args (ts, length);
            "evaluate": its args) compiled."""
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
