"""A control loop as a Bluesky flyer: ``kickoff`` starts it in its own thread, ``collect_pages``
hands back its events as event pages, ``next_page`` says when one is due, ``complete`` finishes when
the loop ends (fails with the loop's exception)."""

from __future__ import annotations

import asyncio
import collections
import threading
import time
from concurrent.futures import Future, InvalidStateError

from ophyd.status import Status


class LoopFlyer:
    """Runs ``start()`` then ``step() -> (data, timestamps)`` until ``done()`` in a thread of its
    own; each step is one event of the stream ``stream`` described by ``data_keys``. Nothing of the
    loop goes through the RunEngine: it sees the events only when it collects them. A page is due
    after the step that ends ``page_s`` s since the last one, and when the loop ends."""

    def __init__(
        self,
        name: str,
        data_keys: dict,
        start,
        step,
        done,
        *,
        page_s: float,
        stream: str = "primary",
    ):
        self.name, self.parent, self.stream = name, None, stream
        self._data_keys, self._start, self._step, self._done = data_keys, start, step, done
        self.page_s = page_s
        self._events: collections.deque = collections.deque()
        self._page: Future = Future()  # done when a page is due
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
            due = time.monotonic() + self.page_s
            while not self._done():
                data, timestamps = self._step()
                self._events.append({"data": data, "timestamps": timestamps})
                if (now := time.monotonic()) >= due:
                    due = now + self.page_s
                    self._page_due(last=False)
        except BaseException as exc:  # handed to the plan through the completion status
            self.error = exc
            self._complete.set_exception(exc)
        else:
            self._complete.set_finished()
        finally:
            self._page_due(last=True)

    def _page_due(self, last: bool):
        page = self._page
        if not last:
            self._page = Future()
        try:
            page.set_result(None)
        except InvalidStateError:  # done already, or cancelled by the RunEngine (a halt)
            pass

    def next_page(self):
        """An awaitable (in the RunEngine's event loop) done when a page is due: collected then, the
        page's work falls in the loop's wait for its next frame rather than in the middle of a
        step."""
        return asyncio.wrap_future(self._page)

    def complete(self) -> Status:
        """Finishes when the loop has ended."""
        return self._complete

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def describe_collect(self) -> dict:
        return {self.stream: self._data_keys}

    def collect_pages(self):
        """The events recorded since the last call as one partial event page (none if there are
        none)."""
        events = [self._events.popleft() for _ in range(len(self._events))]
        if events:
            yield {
                "data": {k: [_plain(e["data"][k]) for e in events] for k in self._data_keys},
                "timestamps": {k: [e["timestamps"][k] for e in events] for k in self._data_keys},
            }


def fly(flyer):
    """Plan stub: kick ``flyer`` off and collect its events whenever a page is due until it
    completes; if it fails, collect what it recorded, then re-raise (bluesky's ``FailedStatus``)."""
    import bluesky.plan_stubs as bps
    from bluesky.utils import FailedStatus, short_uid

    yield from bps.kickoff(flyer, wait=True)
    group = short_uid("complete")
    complete = yield from bps.complete(flyer, group=group, wait=False)
    try:
        done = False
        while not done:
            yield from bps.wait_for([flyer.next_page])
            # read before collecting: a loop that ends meanwhile leaves its last steps for once more
            done = complete.done
            yield from bps.collect(flyer, return_payload=False)
        yield from bps.wait(group=group)
    except FailedStatus:
        yield from bps.collect(flyer, return_payload=False)
        raise


def _plain(value):
    """``value`` as built-in Python types (numpy arrays and scalars by their ``tolist``): a page
    that needs no ``sanitize_doc`` before JSON."""
    return value.tolist() if hasattr(value, "tolist") else value
