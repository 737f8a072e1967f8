"""``EnvSpec``: a frozen, hashable record of the ``ops_jax.make`` options, validated when it is
built.

    spec = ops_jax.EnvSpec(stages=5, mode="hard", model="phasor")  # or EnvSpec.from_options({...})
    env, params = spec.make()  # ops_jax.make(**spec.as_dict())
    spec.key  # stable: the same options, the same key

Its fields are ``stages``, ``mode`` (``make``'s defaults) and every option of
``ops_jax.env.option_names()`` (the one declaration: the ``EnvConfig`` and ``EnvParams`` fields and
the imperfection options), each None unless given: an option not given takes ``make``'s default (the
mode's, for the mode-dependent ones). Sequences and arrays are held as tuples, numpy scalars as
Python numbers. ``as_dict()`` is the given options as the keyword dict of ``make`` (``stages`` and
``mode`` always): the form stored in checkpoints and in the sweep's cell configurations.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
from typing import Any

import numpy as np

from ops_jax import env as _env


def _frozen(name: str, value):
    """``value`` as a hashable, JSON-ready value (tuples for sequences and arrays, Python
    numbers)."""
    if isinstance(value, (np.ndarray, list, tuple)):
        return tuple(
            _frozen(name, v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)
        )
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(
        f"{name} must be a number, a string, a bool or a sequence of numbers, got "
        f"{type(value).__name__}"
    )


_MAKE = inspect.signature(_env.make).parameters
_FIELDS = [
    ("stages", int, dataclasses.field(default=_MAKE["stages"].default)),
    ("mode", str, dataclasses.field(default=_MAKE["mode"].default)),
]
_FIELDS += [(name, Any, dataclasses.field(default=None)) for name in _env.option_names()]


def _post_init(self):
    for f in dataclasses.fields(self):
        object.__setattr__(self, f.name, _frozen(f.name, getattr(self, f.name)))
    _env.configure(
        **self.as_dict()
    )  # every check of ops_jax.make, without building the environment


def as_dict(self) -> dict:
    """The keyword arguments of ``ops_jax.make``: ``stages``, ``mode`` and the options given."""
    return {
        f.name: getattr(self, f.name)
        for f in dataclasses.fields(self)
        if f.name in ("stages", "mode") or getattr(self, f.name) is not None
    }


def _repr(self) -> str:
    return "EnvSpec(" + ", ".join(f"{k}={v!r}" for k, v in self.as_dict().items()) + ")"


def key(self) -> str:
    """A stable key of the options (16 hex digits): the same for equal specs in every process."""
    return hashlib.sha256(json.dumps(self.as_dict(), sort_keys=True).encode()).hexdigest()[:16]


def make(self):
    """``ops_jax.make(**self.as_dict())``: ``(env, params)``."""
    return _env.make(**self.as_dict())


def from_options(cls, options) -> "EnvSpec":
    """The spec of an ``ops_jax.make`` keyword dict (an ``EnvSpec`` is returned as it is). TypeError
    for anything else or an unknown option, ValueError for a value out of range, each naming the
    option."""
    if isinstance(options, cls):
        return options
    if not isinstance(options, dict):
        raise TypeError(
            f"env_config must be an ops_jax.EnvSpec or a dict of ops_jax.make keyword arguments, "
            f"got {type(options).__name__}"
        )
    unknown = set(options) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise TypeError(
            f"unknown option(s) {sorted(unknown)}; accepted: stages, mode, "
            f"{sorted(_env.option_names())}"
        )
    return cls(**options)


EnvSpec = dataclasses.make_dataclass(
    "EnvSpec",
    _FIELDS,
    frozen=True,
    namespace={
        "__post_init__": _post_init,
        "__repr__": _repr,
        "as_dict": as_dict,
        "key": property(key),
        "make": make,
        "from_options": classmethod(from_options),
    },
)
EnvSpec.__module__ = __name__  # pickles as ops_jax.spec.EnvSpec
EnvSpec.__doc__ = (
    "A frozen, hashable record of ``ops_jax.make``'s options, validated when built: ``stages``, "
    "``mode`` and every option (None: not given). ``make()``, ``as_dict()``, ``key``, "
    "``from_options(dict)``."
)
