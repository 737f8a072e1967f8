"""The seed-vmapped, jitted training programs of an off-policy learner
(``agents.learners.offpolicy.driver``), a ``Programs`` record built once per learner, static
environment configuration and config in a process."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import jax

from agents import evaluation
from agents.envs import built, train_env_config
from ops_jax import EnvSpec


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


@dataclasses.dataclass(frozen=True)
class Programs:
    """An off-policy learner's jitted training programs on a leading seed axis (``cached_build``):
    ``init(keys, env_params)``, ``warmup(ts, n, random)``, ``fit_norm(ts, obs)``,
    ``train_chunk(ts, n)`` (donates ``ts``), ``evaluate(params, env_params, keys, ids)``; the seed
    axis's ``sharding`` (None: one device); ``compiled(name, *args)`` each compiled ahead of time
    once per argument signature."""

    init: Callable
    warmup: Callable
    fit_norm: Callable
    train_chunk: Callable
    evaluate: Callable
    sharding: Any
    _compiled: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)

    def compiled(self, name: str, *args):
        """The program ``name`` ("warmup": args (ts, length, random); "train_chunk": args (ts,
        length); "evaluate": its args) compiled for ``args``."""
        static = args[1:] if name in ("warmup", "train_chunk") else None
        arrays = args[:1] if static is not None else args
        layout = jax.tree.map(lambda x: (x.shape, x.dtype, getattr(x, "sharding", None)), arrays)
        sig = (name, static, str(layout))
        if sig not in self._compiled:
            self._compiled[sig] = getattr(self, name).lower(*args).compile()
        return self._compiled[sig]


def _over_seeds(loop, evaluate_fn, ts_shape, num_seeds: int, sharding) -> Programs:
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
        ts, metrics = over(lambda t: loop.train_chunk(t, n), (axes,), (axes, 0))(ts)
        return place(ts), metrics

    return Programs(
        init=jax.jit(lambda k, p: place(over(loop.init, (0, None), axes)(k, p))),
        warmup=jax.jit(
            lambda ts, n, random: _placed_first(
                place, over(lambda t: loop.warmup(t, n, random), (axes,), (axes, 0))(ts)
            ),
            static_argnums=(1, 2),
        ),
        fit_norm=jax.jit(lambda ts, obs: place(over(loop.fit_norm, (axes, 0), axes)(ts, obs))),
        train_chunk=jax.jit(train_chunk, static_argnums=1, donate_argnums=0),
        evaluate=jax.jit(over(evaluate_fn, (0, None, 0, None), 0)),
        sharding=sharding,
    )


# The config's fields that leave the compiled training programs unchanged.
_RUN_FIELDS = ("config", "total_steps", "learning_starts", "eval_every", "eval_episodes")
_BUILDS: dict = {}


def cached_build(learner, env_spec: EnvSpec, c, num_seeds: int) -> tuple[Programs, Any]:
    """(the seed-vmapped jitted training ``Programs``, the training environment's params), built
    once per (learner, static env config, config fields but ``_RUN_FIELDS``) in this process, so
    that other seeds or modes (their ``EnvParams`` are arguments) do not recompile."""
    env, env_params = built(train_env_config(env_spec, c.train_reward))
    sharding = evaluation.split_over_devices(num_seeds, "seeds")
    fields = tuple(
        (f.name, getattr(c, f.name)) for f in dataclasses.fields(c) if f.name not in _RUN_FIELDS
    )
    key = (learner.name, env.config, fields, num_seeds > 1, sharding)
    if key not in _BUILDS:
        loop = learner.build(learner.training_env(env, env_spec, c), c)
        evaluate_fn = evaluation.evaluator(
            env, learner.make_policy(env_spec, c), env.config.max_steps, 10
        )
        ts_shape = jax.eval_shape(loop.init, jax.random.key(0), env_params)
        _BUILDS[key] = _over_seeds(loop, evaluate_fn, ts_shape, num_seeds, sharding)
    return _BUILDS[key], env_params
