"""ops_jax.noise: the unrolled Threefry hash gives jax.random.bits' words exactly, so every draw
(and every documented trajectory) is unchanged."""

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
