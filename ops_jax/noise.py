"""Noise processes of the OPS control loop (physics.md section 5). Lengths in wavelengths (wl).

All functions are pure. ``draws`` turns one key into every standard draw a control step (or a
reset) needs, from the words of one ``jax.random.bits`` call: one threefry hash per 32-bit word
instead of a call per ``split`` / ``normal`` / ``uniform``, which shortens both the compiled
program and the step. The processes then map standard draws to lengths: ``z`` are standard
normals, ``u`` uniforms on [-1, 1).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

# The reference's free-running noise std (wl); observation entry e is mu_t in these units.
REFERENCE_SIGMA_WL = 5e-4

_ONE_BITS = np.uint32(0x3F800000)  # float32 1.0
_LOW = np.nextafter(np.float32(-1.0), np.float32(0.0))


def _unit(bits):
    """float32 in [0, 1) from the top 23 bits (as ``jax.random.uniform``)."""
    return jax.lax.bitcast_convert_type((bits >> np.uint32(9)) | _ONE_BITS, jnp.float32) - 1.0


_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


def _rotl(x, r):
    return (x << np.uint32(r)) | (x >> np.uint32(32 - r))


def _unrolled(key) -> bool:
    """Whether ``_threefry_bits`` hashes ``key`` itself (a threefry2x32 key, partitionable mode)."""
    return jax.random.key_impl(key) == "threefry2x32" and jax.config.jax_threefry_partitionable


def _threefry_bits(key, n: int, start=0):
    """``jax.random.bits(key, (n,), uint32)`` for a threefry2x32 key (partitionable mode): the
    same Threefry-2x32 hash of the counters (0, j), unrolled. JAX's CPU lowering runs the 20 rounds
    as a 5-iteration loop that writes both words to memory each pass; unrolled, XLA fuses the hash
    into the loops that use the bits. ``start``: the words from the ``start``-th on (a uint32,
    traced or not; threefry keys only). Other key types go through ``jax.random.bits``."""
    if not _unrolled(key):
        return jax.random.bits(key, (n,), jnp.uint32)
    k = jax.random.key_data(key)
    ks = (k[..., 0:1], k[..., 1:2])
    ks = (*ks, ks[0] ^ ks[1] ^ np.uint32(0x1BD11BDA))
    counter = jnp.arange(n, dtype=jnp.uint32) + jnp.asarray(start, jnp.uint32)
    x = [jnp.zeros((n,), jnp.uint32) + ks[0], counter + ks[1]]
    for i in range(5):
        for r in _ROTATIONS[i % 2]:
            x[0] = x[0] + x[1]
            x[1] = x[0] ^ _rotl(x[1], r)
        x = [x[0] + ks[(i + 1) % 3], x[1] + ks[(i + 2) % 3] + np.uint32(i + 1)]
    return x[0] ^ x[1]


def _standard(bits, is_normal):
    """U[-1, 1) from ``bits``, or N(0, 1) where ``is_normal`` (inverse erf, as
    ``jax.random.normal``)."""
    u = 2.0 * _unit(bits) - 1.0
    z = np.float32(np.sqrt(2.0)) * jax.lax.erf_inv(jnp.maximum(_LOW, u))
    return jnp.where(is_normal, z, u)


def draws(key, *, normal: dict | None = None, uniform: dict | None = None) -> dict:
    """Standard draws from one key: ``normal`` {name: shape} -> N(0, 1) float32 (inverse-erf of a
    uniform, as ``jax.random.normal``); ``uniform`` {name: shape} -> U[-1, 1) float32.

    The words are hashed and transformed in two halves by a two-pass ``lax.map``: the loop keeps
    the draws in memory, each half one vectorised elementwise pass. Left to itself XLA duplicates
    the cheap integer hash into every reader of a word (the inverse erf reads it several times)
    and fuses the inverse erf into each consumer's fusion (the observation frame's concatenation,
    the free run), where the CPU backend does not vectorise it (the same draws either way)."""
    specs = [(name, tuple(shape), int(np.prod(shape))) for name, shape in (normal or {}).items()]
    n_normal = sum(size for _, _, size in specs)
    specs += [(name, tuple(shape), int(np.prod(shape))) for name, shape in (uniform or {}).items()]
    n = max(1, sum(size for _, _, size in specs))
    if not _unrolled(key):
        return _named(_standard(_threefry_bits(key, n), jnp.arange(n) < n_normal), specs)
    half = (n + 1) // 2

    def chunk(start):
        index = jnp.arange(half, dtype=jnp.uint32) + start
        return _standard(_threefry_bits(key, half, start), index < n_normal)

    starts = jnp.arange(2, dtype=jnp.uint32) * np.uint32(half)
    return _named(jax.lax.map(chunk, starts).reshape(-1)[:n], specs)


def _named(values, specs) -> dict:
    """{name: the next ``size`` values reshaped to ``shape``} for each (name, shape, size)."""
    out, start = {}, 0
    for name, shape, size in specs:
        out[name] = values[start : start + size].reshape(shape)
        start += size
    return out


def clipped(z, loc, scale, width):
    """Normal(loc, scale) clipped to loc +- width * scale, from standard normals ``z``."""
    return loc + scale * jnp.clip(z, -width, width)


def free_run(z, mu, sigma):
    """Length change (wl) over one control period: the sum of ``feedback_k`` free-running draws,
    each clip(Normal(mu, sigma), mu +- 3 sigma) per stage. ``z`` (feedback_k, N) standard normals,
    ``mu`` (N,) the current mean."""
    return z.shape[0] * mu + sigma * jnp.clip(z, -3.0, 3.0).sum(0)


def initial_offsets(z, init_loc, spread):
    """Reset offsets from the optimum: clip(Normal(init_loc, s0), init_loc +- 2 s0), ``z`` (N,)."""
    return clipped(z, init_loc, spread, 2.0)


def episode_drift(u, episode, cap, ramp):
    """The reference's hard-mode drift factor r ~ Uniform(-s, s), s = min(cap, episode * ramp),
    where ``episode`` counts the resets before this one (0 at the first: no drift); ``u`` U[-1,
    1)."""
    return jnp.minimum(cap, episode * ramp) * u


def drift_knot(u, amplitude):
    """A knot of the within-episode piecewise-linear drift mean: Uniform(-amplitude, amplitude)
    (wl), ``u`` (N,) U[-1, 1)."""
    return amplitude * u


def piecewise_linear(prev_knot, next_knot, t, segment):
    """Value at step t of the line from ``prev_knot`` (at the segment start) to ``next_knot``."""
    frac = (t % segment) / segment
    return prev_knot + frac * (next_knot - prev_knot)
