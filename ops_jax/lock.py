"""A controller scored as optics papers score a lock: time to lock, RMS power noise after lock, and
the spectrum of what is left.

    # trace: P / P_max (or P / P_best), shape (..., steps)
    figures = lock_figures(trace, rate_hz=100.0)

``trace[..., k]`` is the power after control step ``k + 1`` (as ``agents.evaluate`` records it). Per
trace:

- **held level**: the median of the trace's last half (its locked level, if it locks).
- **lock step**: the control steps made when P enters, for good, the band
  ``|P - held| <= band x held`` (``band`` relative, default 2 %): ``k + 1`` for the first index
  ``k`` from which every later reading is in the band. The lock must last at least ``hold`` of the
  trace (default 10 %, at least 2 readings); a trace whose last excursion out of the band comes
  later, or whose held level is not positive, never locked: its figures are NaN (``None`` with a
  reason in ``to_json`` and ``episode_summary``). A trace that starts in the band locks at step 1.
  Seconds to lock: the lock step over ``rate_hz`` (control steps per second).
- **RMS after lock**: std / mean of P from the lock on (the readings in the band; population std).
- **PSD after lock**: the one-sided power spectral density of P's relative fluctuation
  ``P / mean - 1`` from the lock on, by Welch's method: Hann windows of ``segment`` readings, 50 %
  overlap, each segment's mean removed, periodograms averaged. Units 1/Hz at frequencies in Hz with
  ``rate_hz``, else per cycle per step at cycles per step; its integral over frequency is the
  relative variance (the RMS squared, less what the segments' means held). ``segment`` default: the
  largest power of two <= 256 that every locked trace's post-lock readings fill; a trace with fewer
  post-lock readings than ``segment`` has a NaN spectrum.

``episode_summary(traces)`` gives the figures over episodes (the medians of those that locked), as
``agents.evaluate``'s summary reports them; ``trace_json(trace, rate_hz)`` one run's, as
``agents.bench``'s summary.json holds them. The figures do not change when the trace is scaled (P /
P_max and P / P_best give the same ones). Numpy only.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

DEFAULT_BAND = 0.02  # relative half-width of the lock band
DEFAULT_HOLD = 0.1  # least fraction of the trace a lock lasts
MAX_SEGMENT = 256  # longest default Welch segment (readings)
MIN_STEPS = 4  # shortest trace scored (readings)


@dataclasses.dataclass(frozen=True)
class LockFigures:
    """The lock figures of traces (..., steps): per trace (shape ``(...)``) ``held_level`` (the
    trace's unit), ``lock_step`` (control steps, NaN: never locked), ``lock_s`` (s; None without a
    rate), ``rms_after_lock`` (relative, NaN: never locked) and ``psd`` (..., F) at ``frequency``
    (F,) (1/Hz at Hz, or per cycle per step at cycles per step without a rate); the settings
    ``band``, ``hold``, ``segment`` and ``rate_hz``."""

    band: float
    hold: float
    segment: int
    rate_hz: float | None
    held_level: np.ndarray
    lock_step: np.ndarray
    lock_s: np.ndarray | None
    rms_after_lock: np.ndarray
    frequency: np.ndarray
    psd: np.ndarray

    @property
    def locked(self) -> np.ndarray:
        """Whether each trace locked (bool, shape ``(...)``)."""
        return np.isfinite(self.lock_step)

    def reason(self) -> str:
        """Why a trace has no lock figures (the same words for every such trace)."""
        return (
            f"never stayed within {self.band:.0%} of its held level (the median of its last half) "
            f"for the last {self.hold:.0%} of the trace, or that level is not positive"
        )

    def to_json(self) -> dict:
        """The figures as JSON-able values (per trace, nested lists for a batch): a never-locked
        trace's lock step, seconds and RMS are ``None`` and its ``lock_reason`` says why (``None``
        where it locked)."""
        locked = self.locked
        return dict(
            lock_band=self.band,
            held_level=_json(self.held_level),
            lock_step=_json(self.lock_step, integer=True),
            lock_s=None if self.lock_s is None else _json(self.lock_s),
            rms_after_lock=_json(self.rms_after_lock),
            lock_reason=np.where(locked, None, self.reason()).tolist(),
        )

    def episode_summary(self) -> dict:
        """Over the traces (episodes): the median lock step and RMS after lock of those that locked
        (``None`` with ``lock_reason`` where none did), the fraction that locked and the band."""
        locked = self.locked
        some = bool(locked.any())
        return dict(
            lock_band=self.band,
            fraction_locked=float(locked.mean()),
            lock_step_median=float(np.median(self.lock_step[locked])) if some else None,
            rms_after_lock_median=float(np.median(self.rms_after_lock[locked])) if some else None,
            lock_reason=None if some else "no episode locked: every one " + self.reason(),
        )


def _too_short(traces: np.ndarray) -> str | None:
    """Why ``traces`` are too short to score (fewer than ``MIN_STEPS`` readings), or None."""
    if traces.ndim >= 1 and (steps := traces.shape[-1]) < MIN_STEPS:
        return f"traces of {steps} steps are too short to score (at least {MIN_STEPS})"
    return None


def episode_summary(traces, rate_hz=None, *, band=DEFAULT_BAND, hold=DEFAULT_HOLD) -> dict:
    """``LockFigures.episode_summary`` of ``traces`` (episodes, steps); traces of fewer than
    ``MIN_STEPS`` readings are too short to score: ``None`` figures, and ``lock_reason`` says so."""
    traces = np.asarray(traces)
    short = _too_short(traces)
    if short is None:
        return lock_figures(traces, rate_hz, band=band, hold=hold).episode_summary()
    none = dict(fraction_locked=None, lock_step_median=None, rms_after_lock_median=None)
    return dict(lock_band=float(band), **none, lock_reason=short)


def trace_json(trace, rate_hz=None, *, band=DEFAULT_BAND, hold=DEFAULT_HOLD) -> dict:
    """``LockFigures.to_json`` of one ``trace`` (steps,) (a run's); one of fewer than ``MIN_STEPS``
    readings is too short to score: ``None`` figures, and ``lock_reason`` says so."""
    trace = np.asarray(trace)
    short = _too_short(trace)
    if short is None:
        return lock_figures(trace, rate_hz, band=band, hold=hold).to_json()
    none = dict(held_level=None, lock_step=None, lock_s=None, rms_after_lock=None)
    return dict(lock_band=float(band), **none, lock_reason=short)


def _json(values: np.ndarray, integer: bool = False):
    """``values`` as (nested lists of) floats, ``None`` where not finite; whole numbers as int."""
    as_value = (lambda v: int(v)) if integer else float
    cast = np.vectorize(lambda v: as_value(v) if math.isfinite(v) else None, otypes=[object])
    return cast(np.asarray(values, np.float64)).tolist()


def lock_figures(
    trace,
    rate_hz: float | None = None,
    *,
    band: float = DEFAULT_BAND,
    hold: float = DEFAULT_HOLD,
    segment: int | None = None,
) -> LockFigures:
    """The ``LockFigures`` of ``trace`` (..., steps) of P per control step at ``rate_hz`` control
    steps per second (None: per step); see the module docstring. Non-finite readings count as out of
    the band."""
    trace = _checked(trace, rate_hz, band, hold, segment)
    steps = trace.shape[-1]
    with warnings.catch_warnings():  # an all-NaN last half: NaN, never locked
        warnings.simplefilter("ignore", RuntimeWarning)
        held = np.nanmedian(trace[..., steps // 2 :], axis=-1)
    start = _lock_index(trace, held, band, max(2, math.ceil(hold * steps)))
    locked = start < steps
    after = np.arange(steps) >= start[..., None]
    count = after.sum(-1)
    mean = np.where(after, trace, 0.0).sum(-1) / np.maximum(count, 1)
    spread = np.where(after, (trace - mean[..., None]) ** 2, 0.0).sum(-1) / np.maximum(count, 1)
    rms = np.where(locked, np.sqrt(spread) / np.where(locked, mean, 1.0), np.nan)
    lock_step = np.where(locked, start + 1.0, np.nan)
    if segment is None:
        shortest = int((steps - start[locked]).min()) if locked.any() else MIN_STEPS
        segment = 2 ** int(math.log2(min(MAX_SEGMENT, max(shortest, MIN_STEPS))))
    fs = 1.0 if rate_hz is None else float(rate_hz)
    flat, flat_start = trace.reshape(-1, steps), start.reshape(-1)
    spectra = [
        _welch(row[s:] / row[s:].mean() - 1.0, segment, fs)
        if s < steps
        else np.full(segment // 2 + 1, np.nan)
        for row, s in zip(flat, flat_start)
    ]
    return LockFigures(
        band=float(band),
        hold=float(hold),
        segment=int(segment),
        rate_hz=None if rate_hz is None else float(rate_hz),
        held_level=np.asarray(held, np.float64),
        lock_step=lock_step,
        lock_s=None if rate_hz is None else lock_step / float(rate_hz),
        rms_after_lock=rms,
        frequency=np.fft.rfftfreq(segment, 1.0 / fs),
        psd=np.stack(spectra).reshape(*trace.shape[:-1], segment // 2 + 1),
    )


def _checked(trace, rate_hz, band, hold, segment) -> np.ndarray:
    """``trace`` as float64, or ValueError naming the parameter and its accepted range."""
    trace = np.asarray(trace, np.float64)
    if trace.ndim < 1 or trace.shape[-1] < MIN_STEPS or 0 in trace.shape:
        raise ValueError(
            f"trace must have shape (..., steps) with steps >= {MIN_STEPS} and no empty axis, "
            f"got shape {trace.shape}"
        )
    if not 0.0 < float(band) < 1.0:
        raise ValueError(f"band must lie in (0, 1) (relative to the held level), got {band!r}")
    if not 0.0 < float(hold) <= 1.0:
        raise ValueError(f"hold must lie in (0, 1] (a fraction of the trace), got {hold!r}")
    if rate_hz is not None and not (math.isfinite(float(rate_hz)) and float(rate_hz) > 0):
        raise ValueError(
            f"rate_hz must be a finite number > 0 (control steps/s) or None, got {rate_hz!r}"
        )
    if segment is not None and (
        isinstance(segment, bool)
        or not isinstance(segment, (int, np.integer))
        or not MIN_STEPS <= segment <= trace.shape[-1]
    ):
        raise ValueError(
            f"segment must be an integer in [{MIN_STEPS}, steps = {trace.shape[-1]}] or None, got "
            f"{segment!r}"
        )
    return trace


def _lock_index(trace: np.ndarray, held, band: float, least: int) -> np.ndarray:
    """Per trace, the first index from which every reading is in the band around ``held``; ``steps``
    where that run is shorter than ``least`` readings or ``held`` is not a positive number (never
    locked)."""
    steps = trace.shape[-1]
    held = np.asarray(held)[..., None]
    with np.errstate(invalid="ignore"):
        inside = np.abs(trace - held) <= band * held
    outside = ~inside
    last_out = np.where(outside.any(-1), steps - 1 - outside[..., ::-1].argmax(-1), -1)
    start = last_out + 1
    good = (steps - start >= least) & np.isfinite(held[..., 0]) & (held[..., 0] > 0)
    return np.where(good, start, steps)


def _welch(x: np.ndarray, segment: int, fs: float) -> np.ndarray:
    """One-sided Welch PSD of ``x`` (Hann, 50 % overlap, segment means removed; x's unit squared per
    Hz of ``fs``); NaN where ``x`` is shorter than ``segment``."""
    if x.size < segment:
        return np.full(segment // 2 + 1, np.nan)
    step = segment - segment // 2  # overlap: half a segment, rounded down
    starts = np.arange(0, x.size - segment + 1, step)
    parts = x[starts[:, None] + np.arange(segment)]
    parts = parts - parts.mean(-1, keepdims=True)
    window = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(segment) / segment)  # periodic Hann
    power = np.abs(np.fft.rfft(parts * window, axis=-1)) ** 2 / (fs * np.sum(window**2))
    power[:, 1 : segment // 2 + segment % 2] *= 2  # one-sided: negative frequencies folded in
    return power.mean(0)


def draw_psd(ax, figures: LockFigures, label: str | None = None) -> None:
    """Plot the median PSD after lock of ``figures``' locked traces on the matplotlib axes ``ax``
    (log-log; no matplotlib import here), or say on it that nothing locked."""
    unit = "Hz" if figures.rate_hz is not None else "cycles / step"
    ax.set(xlabel=f"frequency ({unit})", ylabel=f"PSD of P / mean - 1 (per {unit})")
    rows = figures.psd[figures.locked] if figures.psd.ndim > 1 else figures.psd[None]
    rows = rows[np.isfinite(rows).all(-1)] if rows.size else rows
    if not rows.size:
        ax.text(0.5, 0.5, "not locked", transform=ax.transAxes, ha="center", va="center")
        return
    ax.loglog(figures.frequency[1:], np.median(rows, 0)[1:], lw=1, label=label)
    ax.set_title(f"after lock (band {figures.band:.0%})")
    ax.grid(alpha=0.3, which="both")
