"""Batching rules of ``ops_jax.env.OPSEnv``: the vmap axes of an ``EnvParams`` and the auto-reset
that, under ``jax.vmap`` (nested too), computes the next episode only when some instance is done.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap

from ops_jax import imperfections


def params_axes(params):
    """The ``jax.vmap`` in_axes of ``params``: 0 per batched (B,) field, None per shared one."""
    axes = jax.tree.map(
        lambda x: 0 if jnp.ndim(x) > 0 else None, dataclasses.replace(params, lab=None)
    )
    return dataclasses.replace(axes, lab=imperfections.batch_axes(params.lab))


def auto_reset(env, done, key, state, fallback, params):
    """``env.next_episode(key, state, params)`` where ``done``, else ``fallback`` (obs, state);
    under ``jax.vmap`` the reset runs only on calls where some instance is done."""
    return _auto_reset_ad(env, done, key, state, fallback, params)


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _auto_reset_ad(env, done, key, state, fallback, params):
    """``_auto_reset`` whose derivatives (reverse mode included) go through a per-instance
    select."""
    return _auto_reset(env, ())(done, key, state, fallback, params)


@_auto_reset_ad.defjvp
def _auto_reset_jvp(env, primals, tangents):
    def plain(done, key, state, fallback, params):
        return jax.tree.map(
            lambda a, b: jnp.where(done, a, b), env.next_episode(key, state, params), fallback
        )

    return _auto_reset_ad(env, *primals), jax.jvp(plain, primals, tangents)[1]


def _auto_reset(env, levels: tuple):
    """``env.auto_reset`` on arguments with ``len(levels)`` leading batch axes; ``levels[j]``
    (outermost first) says per argument leaf whether it carries axis j. The reset runs when any
    instance is done."""

    @custom_vmap
    def reset_where_done(done, key, state, fallback, params):
        def one(d, k, s, fb, p):
            return jax.tree.map(lambda a, b: jnp.where(d, a, b), env.next_episode(k, s, p), fb)

        for batched in reversed(levels):
            one = jax.vmap(one, in_axes=tuple(jax.tree.map(lambda b: 0 if b else None, batched)))
        args = (done, key, state, fallback, params)
        return jax.lax.cond(jnp.any(done), one, lambda *a: a[3], *args)

    @reset_where_done.def_vmap
    def rule(axis_size, in_batched, done, key, state, fallback, params):
        # The fallback (hence the result) carries every batch axis, so both cond branches agree.
        fallback = jax.tree.map(
            lambda x, b: x if b else jnp.broadcast_to(x, (axis_size, *jnp.shape(x))),
            fallback,
            in_batched[3],
        )
        in_batched[3] = jax.tree.map(lambda b: True, in_batched[3])
        out = _auto_reset(env, (tuple(in_batched), *levels))(done, key, state, fallback, params)
        return out, jax.tree.map(lambda x: True, out)

    return reset_where_done
