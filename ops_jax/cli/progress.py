"""Progress reporting for long commands: a tqdm bar on a terminal, plain lines anywhere else.

``progress(iterable=None, total=..., desc=..., unit=...)`` returns an object with tqdm's methods
that the project uses (``update``, ``set_postfix``, ``set_postfix_str``, ``write``, ``close``,
iteration, ``with``). When the stream is not a terminal (a CI log, ``nohup``, a cluster job's
stdout), it prints one plain line at most every ``interval`` seconds (and one at the end): what is
done, the rate, and the remaining time from that rate; no cursor-control codes. ``total`` and
``update(n)`` may count weighted work (e.g. the estimated seconds of each unit), so the remaining
time follows the measured cost rather than the count.
"""

from __future__ import annotations

import _thread
import contextlib
import os
import signal
import sys
import threading
import time

INTERVAL_ENV = "OPS_JAX_PROGRESS_INTERVAL"
DEFAULT_INTERVAL_S = 30.0


def format_seconds(s: float) -> str:
    """``s`` seconds as H:MM:SS (or M:SS under an hour)."""
    s = int(round(max(0.0, s)))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


def is_terminal(stream) -> bool:
    """True when ``stream`` is an interactive terminal."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


class PlainProgress:
    """tqdm's interface as periodic plain lines (for streams that are not terminals)."""

    def __init__(
        self,
        iterable=None,
        *,
        total=None,
        desc: str = "",
        unit: str = "it",
        file=None,
        interval: float | None = None,
        unit_scale: bool = False,
        remaining: bool = True,
        **_ignored,
    ):
        self.iterable = iterable
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)
        self.total = total
        self.desc = desc
        self.unit = unit
        self.file = file if file is not None else sys.stderr
        if interval is None:
            interval = float(os.environ.get(INTERVAL_ENV, DEFAULT_INTERVAL_S))
        self.interval = interval
        self.remaining = remaining  # False: the caller says the remaining time (``StepProgress``)
        self.n = 0
        self.postfix = ""
        self.start = time.monotonic()
        self._last_print = self.start
        self._printed_state = None
        self._closed = False

    def __iter__(self):
        for item in self.iterable:
            yield item
            self.update(1)
        self.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def line(self) -> str:
        """The status line: done/total, rate, elapsed and remaining time, postfix."""
        elapsed = time.monotonic() - self.start
        rate = self.n / elapsed if elapsed > 0 else 0.0
        done = (
            f"{self.n:g}/{self.total:g} {self.unit} ({100 * self.n / self.total:.0f}%)"
            if self.total
            else f"{self.n:g} {self.unit}"
        )
        parts = [
            f"{self.desc}: {done}" if self.desc else done,
            f"{rate:.3g} {self.unit}/s",
            f"{format_seconds(elapsed)} elapsed",
        ]
        if self.total and rate > 0 and self.remaining:
            parts.append(f"~{format_seconds((self.total - self.n) / rate)} remaining")
        if self.postfix:
            parts.append(self.postfix)
        return ", ".join(parts)

    def _emit(self):
        print(self.line(), file=self.file, flush=True)
        self._last_print = time.monotonic()
        self._printed_state = (self.n, self.postfix)

    def update(self, n: float = 1) -> None:
        self.n += n
        if time.monotonic() - self._last_print >= self.interval:
            self._emit()

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self.postfix = s

    def set_postfix(self, ordered_dict=None, refresh: bool = True, **kwargs) -> None:
        items = dict(ordered_dict or {}, **kwargs)
        self.postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def set_description(self, desc: str = "", refresh: bool = True) -> None:
        self.desc = desc

    def write(self, s: str) -> None:
        print(s, file=self.file, flush=True)

    def refresh(self) -> None:
        self._emit()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self._printed_state != (self.n, self.postfix):
                self._emit()


def progress(
    iterable=None, *, total=None, desc: str = "", unit: str = "it", file=None, **tqdm_kwargs
):
    """A tqdm bar when ``file`` (default stderr) is a terminal, else ``PlainProgress``."""
    stream = file if file is not None else sys.stderr
    if is_terminal(stream):
        from tqdm import tqdm

        return tqdm(
            iterable,
            total=total,
            desc=desc,
            unit=unit,
            file=stream,
            dynamic_ncols=True,
            **tqdm_kwargs,
        )
    tqdm_kwargs.pop("bar_format", None)
    tqdm_kwargs.pop("leave", None)
    tqdm_kwargs.pop("position", None)
    tqdm_kwargs.pop("dynamic_ncols", None)
    return PlainProgress(iterable, total=total, desc=desc, unit=unit, file=stream, **tqdm_kwargs)


class StepProgress:
    """A training's progress as a ``progress_fn(step, metrics)``: env steps done, the latest
    evaluation P/Pmax, "compiling" until the first report (the compilation and warm-up before it are
    timed and said), then the remaining time from the rate since the second report: the trainers
    compile their training step after the first report (brax's report step 0 first, the off-policy
    learners the end of their warm-up), so the first interval holds a compilation that the rest of
    the run does not repeat. ``close()`` ends the bar; ``n`` is the steps reported."""

    def __init__(self, total: int | None, desc: str, file=None):
        self.total = total or None
        eta = {
            "remaining": False,
            "bar_format": "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]",
        }
        self.bar = progress(
            total=self.total, unit="step", unit_scale=True, desc=desc, file=file, **eta
        )
        self.bar.set_postfix_str("compiling", refresh=True)
        self.start = time.monotonic()
        self.first = None  # (time, step) of the first report
        self.base = None  # (time, step) of the second: the rate is measured from there

    @property
    def n(self) -> int:
        return int(self.bar.n)

    def __call__(self, step: int, metrics: dict) -> None:
        now, step = time.monotonic(), int(step)
        said = (
            [f"P/Pmax {metrics['normalized_power']:.3f}"] if "normalized_power" in metrics else []
        )
        if self.first is None:
            self.first = (now, step)
            said.append(f"{format_seconds(now - self.start)} compiling and warming up")
        elif self.base is None:
            self.base = (now, step)
        elif now > self.base[0] and step > self.base[1]:
            rate = (step - self.base[1]) / (now - self.base[0])
            said.append(f"{rate:.3g} step/s")
            if self.total:
                said.append(f"~{format_seconds((self.total - step) / rate)} remaining")
        self.bar.set_postfix_str(", ".join(said), refresh=False)
        done = min(step, self.total or step)  # the last chunk may pass the total
        self.bar.update(max(0, done - self.bar.n))

    def close(self) -> None:
        self.bar.close()


@contextlib.contextmanager
def reporting(show: bool | None, progress_fn, total: int | None, desc: str):
    """A training's ``progress_fn``: ``progress_fn`` (may be None) and, with ``show`` (None: when
    stderr is a terminal), a ``StepProgress`` bar, closed on the way out; None when neither."""
    if show is None:
        show = is_terminal(sys.stderr)
    if not show:
        yield progress_fn
        return
    bar = StepProgress(total, desc)

    def both(step, metrics):
        bar(step, metrics)
        if progress_fn is not None:
            progress_fn(step, metrics)

    try:
        yield both
    finally:
        bar.close()


@contextlib.contextmanager
def stop_signals(handler):
    """While inside: ``handler(signum, frame)`` handles SIGINT and SIGTERM; the previous handlers
    are restored after."""
    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, kept in previous.items():
            signal.signal(s, kept)


def keep_ctrl_c() -> None:
    """Make a Ctrl-C that lands in a garbage-collector callback (JAX registers one) or a ``__del__``
    stop the program: Python reports a ``KeyboardInterrupt`` raised there as unraisable and goes on;
    this hook has it raised again 5 ms later, once the callback has returned. Other unraisable
    errors are reported as before. Idempotent; for command-line programs that end on
    ``KeyboardInterrupt``."""
    if getattr(sys.unraisablehook, "keeps_ctrl_c", False):
        return
    previous = sys.unraisablehook

    def hook(unraisable):
        if not issubclass(unraisable.exc_type, KeyboardInterrupt):
            previous(unraisable)
            return
        while True:
            try:
                threading.Thread(target=_interrupt_main_soon, daemon=True).start()
                return
            except KeyboardInterrupt:  # a delivery landed in this hook: it is lost, so send another
                continue

    hook.keeps_ctrl_c = True
    sys.unraisablehook = hook


def _interrupt_main_soon() -> None:
    """Simulate a SIGINT in the main thread after 5 ms (nothing when SIGINT is ignored)."""
    time.sleep(0.005)
    _thread.interrupt_main(signal.SIGINT)


def exit_interrupted(line: str, status: int = 130) -> None:
    """Ctrl-C: print ``line`` (what was kept) and exit at once with ``status``, 130 (128 + SIGINT,
    as a shell reports it; 143 for SIGTERM). ``os._exit``: XLA may be mid-computation in its own
    threads, and the normal interpreter teardown then can crash."""
    sys.stdout.flush()
    print(f"interrupted: {line}", file=sys.stderr, flush=True)
    os._exit(status)
