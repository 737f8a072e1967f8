"""A resumable store of finished work units ("cells") for the sweep.

Each cell is one JSON file named by a readable label and a hash of its configuration, written
atomically (temporary file, then rename) the moment the cell finishes. A re-run finds the file,
checks that it parses and that its stored configuration equals the requested one, and skips the
work; a truncated or corrupt file is reported and recomputed; a file for another configuration
has another hash and is never mixed in. The label is a readable prefix only: a cell stored under
another label (its position in a plan that has since grown or been narrowed) is found by its hash.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Callable

from agents.io import read_json, write_json_atomic


def config_hash(config: dict) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


class CellStore:
    def __init__(self, folder: Path, log: Callable[[str], None] = print, meta: dict | None = None):
        """``meta``: keys written beside ``config`` and ``result`` in each cell computed here (e.g.
        where)."""
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.log = log
        self.meta = dict(meta or {})
        self.computed = 0
        self.reused = 0

    def path(self, label: str, config: dict) -> Path:
        safe = re.sub(r"[^A-Za-z0-9_.-]+", "-", label)
        return self.folder / f"{safe}-{config_hash(config)}.json"

    def load(self, label: str, config: dict, quiet: bool = False):
        """The stored result, or None when absent, corrupt or for another configuration (reported
        unless ``quiet``)."""
        path = self.path(label, config)
        if not path.exists():
            path = next(iter(sorted(self.folder.glob(f"*-{config_hash(config)}.json"))), None)
            if path is None:
                return None
        try:
            data = read_json(path)
            if data["config"] != json.loads(json.dumps(config, default=str)):
                raise ValueError("stored configuration differs")
            return data["result"]
        except (ValueError, KeyError, TypeError) as exc:
            if not quiet:
                self.log(f"cell {path.name} is unreadable ({exc}); recomputing")
            return None

    def get(self, label: str, config: dict, compute: Callable[[], dict]) -> dict:
        """Return the cell's result, computing and storing it if needed."""
        result = self.load(label, config)
        if result is not None:
            self.reused += 1
            return result
        result = compute()
        write_json_atomic(
            self.path(label, config), {"config": config, "result": result, **self.meta}
        )
        self.computed += 1
        return result
