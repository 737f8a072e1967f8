"""Atomic file writes shared by the training command line, the checkpoints and the benchmarks. What they
create gets the permissions of any new file or folder (0666 / 0777 less the umask), as its neighbours."""

from __future__ import annotations

import json
import os
import secrets
import shutil
from pathlib import Path


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


def write_json_atomic(path: Path, data) -> None:
    """Write JSON (indented, numpy numbers as floats) atomically (``write_bytes_atomic``)."""
    write_bytes_atomic(path, json.dumps(data, indent=1, default=float).encode())


def temp_dir(parent: Path, name: str) -> Path:
    """A new empty folder in ``parent`` (created there), to fill and then rename to ``parent / name``."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_name(parent, name)
    tmp.mkdir(0o777)
    return tmp


def replace_dir(tmp: Path, path: Path) -> None:
    """Put the filled folder ``tmp`` in place of ``path``: ``path`` renamed to ``PATH.old``, ``tmp`` to ``path``,
    then ``PATH.old`` removed; a crash on the way leaves one of the two whole (``kept_dir``)."""
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
