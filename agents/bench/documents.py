"""``documents.jsonl``: the Bluesky documents of a run on the bench, one a line as they are emitted
(``{"name": ..., "doc": ...}``; an event page as its events), each strict JSON (``agents.io``: a
number that is not finite as ``null`` with a ``<key>_reason`` beside it)."""

from __future__ import annotations

import json
from pathlib import Path

from agents.io import dumps_json

NAME = "documents.jsonl"


def _line(name: str, doc: dict) -> str:
    """One document as a line of strict JSON."""
    return dumps_json({"name": name, "doc": doc}, indent=None) + "\n"


def writer(out: Path):
    """The RunEngine's document callback: every document a line of ``out/documents.jsonl``,
    appended as it comes (an event page as its events, one open per page)."""
    from event_model import sanitize_doc, unpack_event_page

    path = Path(out) / NAME

    def write(name: str, doc: dict) -> None:
        if name == "event_page":  # plain types already
            lines = [_line("event", event) for event in unpack_event_page(doc)]
        else:
            lines = [_line(name, sanitize_doc(doc))]
        with open(path, "a") as f:
            f.writelines(lines)

    return write


def mend(path: Path) -> None:
    """End the last line of ``path`` (documents.jsonl) before a resumed run appends: a whole
    document a kill left without its newline gets it, a half-written one is cut."""
    if path.exists() and (size := path.stat().st_size):
        with open(path, "rb+") as f:
            f.seek(max(0, size - (1 << 20)))
            tail = f.read()
            if tail.endswith(b"\n"):
                return
            start = tail.rfind(b"\n") + 1
            try:
                json.loads(tail[start:])
                f.write(b"\n")
            except ValueError:
                f.truncate(size - len(tail) + start)


def begin(out: Path, resume: bool) -> None:
    """Before a run: a resumed learning run appends to the documents (their last line mended), any
    other starts them afresh."""
    if resume:
        mend(Path(out) / NAME)
    else:
        (Path(out) / NAME).unlink(missing_ok=True)
