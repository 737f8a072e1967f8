"""The packed form of the Gymnasium adapters' steps (``ops_jax.adapters.gymnasium.env``): a step's
outputs as one float32 array (one device-to-host copy), and a pytree of 32-bit arrays as one float32
vector, bit-exact."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

SCALARS = (
    7  # per step: reward, terminated, truncated, power, P / P_max, P / P_best, action_nonfinite
)


def pack(obs, reward, terminated, truncated, info, extra=()):
    """One float32 array (..., D + SCALARS + N [+ extra]) so that one device->host copy returns a
    step."""
    scal = [
        reward,
        terminated,
        truncated,
        info["power"],
        info["normalized_power"],
        info["normalized_power_best"],
        info["action_nonfinite"],
    ]
    cols = (
        [obs]
        + [jnp.asarray(s, jnp.float32)[..., None] for s in scal]
        + [info["deltas_wl"]]
        + list(extra)
    )
    return jnp.concatenate([jnp.asarray(c, jnp.float32) for c in cols], axis=-1)


class FlatCodec:
    """Bit-exact round trip between a pytree of 32-bit arrays and one float32 vector."""

    def __init__(self, template):
        leaves, self.treedef = jax.tree.flatten(template)
        self.specs = [(tuple(x.shape), jnp.dtype(x.dtype)) for x in leaves]
        for _, dtype in self.specs:
            if jnp.dtype(dtype).itemsize != 4:
                raise TypeError(f"FlatCodec handles 32-bit leaves only, got {dtype}")
        self.sizes = [int(np.prod(shape)) for shape, _ in self.specs]
        self.size = sum(self.sizes)

    def flatten(self, tree):
        leaves = jax.tree.leaves(tree)
        cast = lambda x, dt: jax.lax.bitcast_convert_type(jnp.asarray(x, dt), jnp.float32).reshape(
            -1
        )
        return jnp.concatenate([cast(x, dt) for x, (_, dt) in zip(leaves, self.specs)])

    def unflatten(self, vec):
        out, i = [], 0
        for (shape, dtype), size in zip(self.specs, self.sizes):
            out.append(jax.lax.bitcast_convert_type(vec[i : i + size], dtype).reshape(shape))
            i += size
        return jax.tree.unflatten(self.treedef, out)


class Unpacked:
    """Views of a packed step (see ``pack``)."""

    def __init__(self, packed: np.ndarray, d: int, n: int):
        self.obs = packed[..., :d]
        self.reward = packed[..., d]
        self.terminated = packed[..., d + 1] != 0
        self.truncated = packed[..., d + 2] != 0
        self.power = packed[..., d + 3]
        self.normalized_power = packed[..., d + 4]
        self.normalized_power_best = packed[..., d + 5]
        self.action_nonfinite = packed[..., d + 6] != 0
        self.deltas_wl = packed[..., d + SCALARS : d + SCALARS + n]
        self.extra = packed[..., d + SCALARS + n :]
