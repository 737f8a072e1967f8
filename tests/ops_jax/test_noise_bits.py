"""ops_jax.noise: the unrolled Threefry hash gives jax.random.bits' words exactly, and draws the
same standard draws from them as one pass would, so every draw (and every documented trajectory) is
unchanged."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ops_jax import noise


@pytest.mark.parametrize("n", [1, 2, 47, 301])
@pytest.mark.parametrize("make_key", [jax.random.key, jax.random.PRNGKey])
def test_bits_equal_jax_random_bits(n, make_key):
    key = make_key(n)
    np.testing.assert_array_equal(
        noise._threefry_bits(key, n), jax.random.bits(key, (n,), jnp.uint32)
    )


def test_batched_bits_under_jit_and_vmap_equal_jax_random_bits():
    keys = jax.random.split(jax.random.key(5), 257)
    ours = jax.jit(jax.vmap(lambda k: noise._threefry_bits(k, 47)))(keys)
    theirs = jax.vmap(lambda k: jax.random.bits(k, (47,), jnp.uint32))(keys)
    np.testing.assert_array_equal(ours, theirs)
    assert len(np.unique(np.asarray(ours))) > 0.99 * ours.size


def test_other_key_types_fall_back_to_jax_random_bits():
    key = jax.random.key(3, impl="rbg")
    np.testing.assert_array_equal(
        noise._threefry_bits(key, 9), jax.random.bits(key, (9,), jnp.uint32)
    )


def _draws_from_jax_random_bits(key, normal, uniform):
    """The draws computed from ``jax.random.bits`` in one pass (the definition ``draws`` keeps)."""
    sizes = [int(np.prod(s)) for s in (*normal.values(), *uniform.values())]
    n_normal = sum(sizes[: len(normal)])
    bits = jax.random.bits(key, (sum(sizes),), jnp.uint32)
    u = 2.0 * noise._unit(bits) - 1.0
    z = np.float32(np.sqrt(2.0)) * jax.lax.erf_inv(jnp.maximum(noise._LOW, u[:n_normal]))
    return jnp.concatenate([z, u[n_normal:]])


@pytest.mark.parametrize(
    "normal, uniform",
    [({"run": (1, 5), "obs": (37,)}, {"knot": (5,)}), ({"z": (3,)}, {}), ({}, {"u": (2, 9)})],
)
def test_draws_equal_their_one_pass_definition_under_vmap(normal, uniform):
    keys = jax.random.split(jax.random.key(11), 64)
    ours = jax.jit(jax.vmap(lambda k: noise.draws(k, normal=normal, uniform=uniform)))(keys)
    flat = jnp.concatenate([ours[name].reshape(64, -1) for name in (*normal, *uniform)], axis=1)
    theirs = jax.jit(jax.vmap(lambda k: _draws_from_jax_random_bits(k, normal, uniform)))(keys)
    np.testing.assert_array_equal(flat, theirs)
    assert len(np.unique(np.asarray(flat))) > 0.99 * flat.size
