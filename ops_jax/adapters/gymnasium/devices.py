"""The JAX process state of the Gymnasium adapters (``ops_jax.adapters.gymnasium.env``): the guard
against running in a process forked after JAX started, and the device an adapter's state lives
on."""

from __future__ import annotations

import os

import jax

FORK_ERROR = (
    "ops_jax/OPS-v0 cannot run in a process forked after JAX started in its parent (JAX is "
    "multithreaded; "
    "the child would deadlock). Fixes: gymnasium.make_vec(..., "
    'vectorization_mode="vector_entry_point") (one process, all instances in one jitted call), or '
    'keep "async" with vector_kwargs={"context": "forkserver"} (or "spawn"); plain "async" with '
    "the default fork "
    "works when the parent has not run JAX yet."
)


def jax_running() -> bool:
    """Whether JAX's backends (and their threads) have started in this process; no lock taken."""
    try:
        from jax._src import xla_bridge
    except ImportError:
        return True
    backends = getattr(xla_bridge, "_backends", None)
    if isinstance(backends, dict):
        return bool(backends)
    check = getattr(xla_bridge, "backends_are_initialized", None)
    return bool(check()) if check is not None else True


_FORKED_AFTER_JAX = False


def _after_fork_in_child() -> None:
    global _FORKED_AFTER_JAX
    _FORKED_AFTER_JAX = _FORKED_AFTER_JAX or jax_running()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def refuse_after_fork() -> None:
    """Raise ``RuntimeError(FORK_ERROR)`` in a process forked after JAX started (instead of
    deadlocking)."""
    if _FORKED_AFTER_JAX:
        raise RuntimeError(FORK_ERROR)


def check_device(device):
    """Validate ``device`` (None, a platform name or a jax.Device) without starting JAX; resolve it
    now (availability checked) only where JAX already runs."""
    if device is not None and not isinstance(device, (str, jax.Device)):
        raise TypeError(
            f"device must be None, a platform name such as 'cpu' or a jax.Device, got {device!r}"
        )
    if jax_running() and not _FORKED_AFTER_JAX:
        resolve_device(device)
    return device


def resolve_device(device):
    if device is None:
        return None
    if isinstance(device, jax.Device):
        return device
    platform, index = (
        device if isinstance(device, tuple) else (device, None)
    )  # tuple: a pickled jax.Device
    try:
        found = [d for d in jax.devices(platform) if index is None or d.id == index]
    except RuntimeError as exc:
        raise ValueError(f"device {device!r} is not available: {exc}") from exc
    if not found:
        raise ValueError(
            f"device {device!r} is not available: no {platform} device with id {index}"
        )
    return found[0]


def picklable_device(device):
    """A jax.Device as (platform, id) (devices do not pickle); other values unchanged."""
    return (device.platform, device.id) if isinstance(device, jax.Device) else device
