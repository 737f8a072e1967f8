"""Compatibility of brax 0.14's trainers with current JAX.

brax 0.14.2's PPO and SAC trainers (``brax.training.agents.{ppo,sac}.train``) and
``brax.training.pmap`` call ``jax.device_put_replicated``, which JAX 0.10 removed (brax issue
#671). ``ensure_device_put_replicated()`` provides it again, built on ``jax.device_put`` with a
``NamedSharding`` over a one-axis ``Mesh`` of the given devices: every leaf is stacked once per
device along a new leading axis, one slice per device, which is what ``jax.pmap`` expects as a
replicated argument. It changes nothing on JAX versions that still have the function.

The mesh axis is named ``PMAP_AXIS`` = brax's own pmap axis name (``"i"``): on JAX 0.10 ``pmap``
returns arrays sharded over a mesh axis of that name, and a jitted function (brax's evaluation
unroll, its training step) compiles anew for every distinct input sharding; with any other name each
of them compiles once for the replicated start state and again for the trained state.

Importing this module imports brax through ``ops_jax.adapters.brax``, which keeps mujoco's
optional-backend messages ("Failed to import warp") off stdout: the agents modules that use
brax import this module first. ``prepare_brax()`` is what the trainers call before running
brax's training code.
"""

from __future__ import annotations

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

import ops_jax.adapters.brax  # noqa: F401  (the first, quiet import of brax)

PMAP_AXIS = "i"  # brax.training.agents.{ppo,sac}.train._PMAP_AXIS_NAME


def device_put_replicated(x, devices):
    """``x`` (a pytree) stacked ``len(devices)`` times on a new leading axis, slice i on
    devices[i]."""
    devices = list(devices)
    if not devices:
        raise ValueError("devices must name at least one device")
    sharding = NamedSharding(Mesh(np.array(devices), (PMAP_AXIS,)), PartitionSpec(PMAP_AXIS))

    def put(leaf):
        leaf = np.asarray(leaf) if not isinstance(leaf, jax.Array) else leaf
        stacked = jax.numpy.broadcast_to(leaf, (len(devices),) + tuple(leaf.shape))
        return jax.device_put(stacked, sharding)

    return jax.tree.map(put, x)


def ensure_device_put_replicated() -> bool:
    """Install ``jax.device_put_replicated`` if this JAX lacks it; returns True when it installed
    it."""
    if hasattr(jax, "device_put_replicated"):
        return False
    jax.device_put_replicated = device_put_replicated
    return True


def prepare_brax() -> None:
    """Make brax's trainers runnable on this JAX (call before running them; idempotent)."""
    ensure_device_put_replicated()
