"""A control loop as a Bluesky flyer: ``kickoff`` starts it in its own thread, ``collect_pages`` hands back its
events as event pages, ``complete`` finishes when the loop ends (fails with the loop's exception)."""

from __future__ import annotations

import collections
import threading

from ophyd.status import Status


class LoopFlyer:
    """Runs ``start()`` then ``step() -> (data, timestamps)`` until ``done()`` in a thread of its own; each
    step is one event of the stream ``stream`` described by ``data_keys``. Nothing of the loop goes through
    the RunEngine: it sees the events only when it collects them."""

    def __init__(self, name: str, data_keys: dict, start, step, done, stream: str = "primary"):
        self.name, self.parent, self.stream = name, None, stream
        self._data_keys, self._start, self._step, self._done = data_keys, start, step, done
        self._events: collections.deque = collections.deque()
        self._thread: threading.Thread | None = None
        self._complete: Status | None = None
        self.error: BaseException | None = None

    def kickoff(self) -> Status:
        """Start the loop; done at once."""
        self._complete = Status(obj=self)
        self._thread = threading.Thread(target=self._run, name=f"{self.name}-loop", daemon=True)
        self._thread.start()
        status = Status(obj=self)
        status.set_finished()
        return status

    def _run(self):
        try:
            self._start()
            while not self._done():
                data, timestamps = self._step()
                self._events.append({"data": data, "timestamps": timestamps})
        except Exception as exc:  # handed to the plan through the completion status
            self.error = exc
            self._complete.set_exception(exc)
        else:
            self._complete.set_finished()

    def complete(self) -> Status:
        """Finishes when the loop has ended."""
        return self._complete

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def describe_collect(self) -> dict:
        return {self.stream: self._data_keys}

    def collect_pages(self):
        """The events recorded since the last call as one partial event page (none if there are none)."""
        events = [self._events.popleft() for _ in range(len(self._events))]
        if events:
            yield {"data": {k: [_plain(e["data"][k]) for e in events] for k in self._data_keys},
                   "timestamps": {k: [e["timestamps"][k] for e in events] for k in self._data_keys}}


def fly(flyer, flush_s: float):
    """Plan stub: kick ``flyer`` off and collect its events every ``flush_s`` s until it completes; if it fails,
    collect what it recorded, then re-raise (bluesky's ``FailedStatus``)."""
    import bluesky.plan_stubs as bps
    from bluesky.utils import FailedStatus, short_uid

    yield from bps.kickoff(flyer, wait=True)
    group = short_uid("complete")
    yield from bps.complete(flyer, group=group, wait=False)
    try:
        done = False
        while not done:
            done = yield from bps.wait(group=group, timeout=flush_s, error_on_timeout=False)
            yield from bps.collect(flyer, return_payload=False)
    except FailedStatus:
        yield from bps.collect(flyer, return_payload=False)
        raise


def _plain(value):
    """``value`` as built-in Python types (numpy arrays and scalars by their ``tolist``): a page that needs no
    ``sanitize_doc`` before JSON."""
    return value.tolist() if hasattr(value, "tolist") else value
