"""Atomic file writes shared by the training command line, the checkpoints and the benchmarks. What
they create gets the permissions of any new file or folder (0666 / 0777 less the umask), as its
neighbours.

Every JSON file the package writes is strict JSON (RFC 8259, readable by any tool): ``dumps_json``
writes a number that is not finite (NaN, +-inf) as ``null``, a dict's such number with a
neighbouring ``<key>_reason`` field saying why (the caller's reason for that key, else what the
number was; a list holding such numbers gets one too), and refuses anything else JSON has no form
for (``allow_nan=False``). ``read_json`` reads such a file back with those numbers as NaN (+-inf
where the reason says so), the reason fields dropped."""

from __future__ import annotations

import json
import math
import os
import secrets
import shutil
from pathlib import Path

import numpy as np


def _temp_name(parent: Path, name: str) -> Path:
    return parent / f"{name}.{secrets.token_hex(6)}.tmp"


def write_bytes_atomic(path: Path, blob: bytes) -> None:
    """Write ``blob`` to a temporary file in the same folder, then rename it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_name(path.parent, path.name)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(blob)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _what(x: float) -> str:
    """What a number that is not finite was, in words."""
    return "not a number (NaN)" if math.isnan(x) else f"{'+' if x > 0 else '-'}infinite"


def _plain(x):
    """``x`` with numpy/JAX numbers and arrays as Python ones (tuples as lists)."""
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, (np.ndarray, tuple)) or hasattr(x, "__array__"):
        return np.asarray(x).tolist() if not isinstance(x, tuple) else list(x)
    return x


def strict(data, reasons: dict | None = None):
    """``data`` as strict JSON values: numbers that are not finite as None, each a dict's value with
    ``<key>_reason`` beside it (``reasons[key]`` where given, else ``_what``); lists' entries just
    None."""
    reasons = reasons or {}
    data = _plain(data)
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, list):
        return [strict(v, reasons) for v in data]
    if not isinstance(data, dict):
        return data
    out = {}
    for key, value in data.items():
        value = _plain(value)
        if isinstance(value, float) and not math.isfinite(value):
            out[key], out[f"{key}_reason"] = None, reasons.get(key, _what(value))
            continue
        out[key] = strict(value, reasons)
        kinds = _unfinite(value) if isinstance(value, list) else set()
        if kinds:
            said = kinds.pop() if len(kinds) == 1 else "numbers that were not finite"
            out[f"{key}_reason"] = reasons.get(key, f"its nulls: {said}")
    return out


def _unfinite(values: list) -> set:
    """What the numbers that are not finite in the (nested) list ``values`` were (``_what``)."""
    kinds = set()
    for v in map(_plain, values):
        if isinstance(v, list):
            kinds |= _unfinite(v)
        elif isinstance(v, float) and not math.isfinite(v):
            kinds.add(_what(v))
    return kinds


def _restored(data):
    """``strict``'s inverse: each value with a ``<key>_reason`` beside it, its nulls as NaN (+-inf
    where the reason says so), the reason dropped."""
    if isinstance(data, list):
        return [_restored(v) for v in data]
    if not isinstance(data, dict):
        return data
    out = {}
    for key, value in data.items():
        reason = data.get(f"{key}_reason")
        if key.endswith("_reason") and key[: -len("_reason")] in data:
            continue
        if reason is not None:
            ends = {"+infinite": math.inf, "-infinite": -math.inf}
            number = next((x for end, x in ends.items() if str(reason).endswith(end)), math.nan)
            value = _nulls_as(value, number)
        out[key] = _restored(value)
    return out


def _nulls_as(value, number: float):
    """``value`` (None or a nested list) with its Nones as ``number``."""
    if value is None:
        return number
    return [_nulls_as(v, number) for v in value] if isinstance(value, list) else value


def read_json(path: Path):
    """A JSON file this package wrote (``write_json_atomic``), its non-finite numbers restored
    (``_restored``)."""
    return _restored(json.loads(Path(path).read_text()))


def dumps_json(data, reasons: dict | None = None, indent: int | None = 1) -> str:
    """``data`` as strict JSON text (``strict``; ValueError for what JSON cannot hold)."""
    return json.dumps(strict(data, reasons), indent=indent, allow_nan=False, default=float)


def write_json_atomic(path: Path, data, reasons: dict | None = None) -> None:
    """Write ``data`` as strict JSON (``dumps_json``, indented) atomically
    (``write_bytes_atomic``)."""
    write_bytes_atomic(path, dumps_json(data, reasons).encode())


def temp_dir(parent: Path, name: str) -> Path:
    """A new empty folder in ``parent`` (created there), to fill and then rename to
    ``parent / name``."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_name(parent, name)
    tmp.mkdir(0o777)
    return tmp


def replace_dir(tmp: Path, path: Path) -> None:
    """Put the filled folder ``tmp`` in place of ``path``: ``path`` renamed to ``PATH.old``, ``tmp``
    to ``path``, then ``PATH.old`` removed; a crash on the way leaves one of the two whole
    (``kept_dir``)."""
    path, old = Path(path), Path(f"{path}.old")
    if path.exists():
        shutil.rmtree(old, ignore_errors=True)
        os.replace(path, old)
    os.replace(tmp, path)
    shutil.rmtree(old, ignore_errors=True)


def kept_dir(path: Path) -> Path | None:
    """The folder ``replace_dir`` left: ``path``, else ``PATH.old``, else None."""
    path = Path(path)
    return next((p for p in (path, Path(f"{path}.old")) if p.is_dir()), None)
