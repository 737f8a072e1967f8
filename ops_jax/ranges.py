"""Accepted ranges of numeric options, declared as dataclass field metadata: one validation for the
environment's ``EnvConfig`` / ``EnvParams``, the lab ``Imperfections`` and the algorithms' configs.

    drift_cap: ArrayLike = ranged(Range(0.0, 10.0), 0.0)
    check_fields(params)      # ValueError "drift_cap must be a finite number in [0, 10], got ..."
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np


@dataclasses.dataclass(frozen=True)
class Range:
    """Numbers in [lo, hi] (``lo_open`` / ``hi_open``: an open end; an infinite ``hi`` is open
    unless ``inf_ok``, which accepts +inf itself), whole numbers when ``integer``; ``unit`` for
    messages. Array leaves: ``shape`` "stage" (one value per stage, (N,), a scalar broadcast) or
    "resonance" (one per resonance); ``scaled``: an error magnitude multiplied by
    ``imperfection_scale``."""

    lo: float
    hi: float = math.inf
    integer: bool = False
    lo_open: bool = False
    hi_open: bool = False
    inf_ok: bool = False
    unit: str = ""
    shape: str = "scalar"
    scaled: bool = False

    def __str__(self):
        fmt = lambda v: (
            "inf" if v == math.inf else (str(int(v)) if float(v).is_integer() else f"{v:g}")
        )
        right = ")" if self.hi_open or (self.hi == math.inf and not self.inf_ok) else "]"
        what = "an integer" if self.integer else ("a number" if self.inf_ok else "a finite number")
        return f"{what} in {'(' if self.lo_open else '['}{fmt(self.lo)}, {fmt(self.hi)}{right}" + (
            f" {self.unit}" if self.unit else ""
        )

    def contains(self, value) -> bool:
        """Whether every entry of ``value`` (a number or an array) is accepted."""
        v = np.asarray(value)
        if v.dtype == bool or not np.issubdtype(v.dtype, np.number) or np.any(np.isnan(v)):
            return False
        if not np.all(np.isfinite(v)) and not (
            self.inf_ok and np.all((v == math.inf) | np.isfinite(v))
        ):
            return False
        above = v > self.lo if self.lo_open else v >= self.lo
        below = v < self.hi if self.hi_open else v <= self.hi
        return bool(
            np.all(above & below)
            and (not self.integer or np.all(v[np.isfinite(v)] == np.round(v[np.isfinite(v)])))
        )

    def __call__(self, name: str, v):
        """A Python scalar option: the accepted value as int / float, else ValueError naming
        ``name`` (booleans and, for an integer range, non-integer types are refused)."""
        kinds = (int, np.integer) if self.integer else (int, float, np.integer, np.floating)
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, kinds) or not self.contains(v):
            raise ValueError(f"{name} must be {self}, got {v!r}")
        return int(v) if self.integer else float(v)


def ranged(accepted: Range, default=dataclasses.MISSING, **kw):
    """A dataclass field with the accepted ``Range`` as its metadata (``check_fields``)."""
    return dataclasses.field(default=default, metadata={"range": accepted}, **kw)


def ranges(cls) -> dict:
    """{field name: Range} of a dataclass (type or instance) with ``ranged`` fields."""
    return {f.name: f.metadata["range"] for f in dataclasses.fields(cls) if "range" in f.metadata}


def check_fields(obj) -> None:
    """ValueError naming the first ``ranged`` field of ``obj`` outside its range."""
    for name, accepted in ranges(obj).items():
        value = getattr(obj, name)
        if not accepted.contains(value):
            raise ValueError(f"{name} must be {accepted}, got {value!r}")
