"""The oscilloscope frame of an N-stage output: the exact field measurement of offsets and its
picture (intensity I(t) / I_peak on the 0.5 ps grid, the 2^N - 1 samples marked, P / P_max in the
title), drawn on a matplotlib Agg canvas (no display needed; matplotlib imported only when a figure
is made)."""

from __future__ import annotations

import functools

import jax
import numpy as np

from ops_jax import physics

DEFAULT_FIGSIZE = (6.4, 3.4)  # inches
DEFAULT_DPI = 100


@functools.lru_cache(maxsize=None)
def _measure_fn(stages: int, detector: str):
    """Jitted field measurement of a batch of offsets (B, N) -> (P / P_max (B,), I / I_peak (B,
    M))."""
    p_max = physics.p_max(stages, detector)
    peak = physics.peak_intensity(stages)

    @jax.jit
    def fn(deltas):
        m = physics.measure(deltas, stages=stages, model="field", detector=detector)
        return m.power / p_max, m.intensity / peak

    return fn


def measure_frames(deltas_wl, stages: int, detector: str = "total"):
    """Exact measurements of offsets ``deltas_wl`` (T, N) wl: (P / P_max (T,), I / I_peak (T,
    M))."""
    physics.check_stages(stages)
    physics._check_choice("detector", detector, physics.DETECTORS)
    x = np.asarray(deltas_wl, np.float32)
    if x.ndim != 2 or x.shape[1] != stages:
        raise ValueError(f"deltas_wl must have shape (T, {stages}), got {x.shape}")
    p, intensity = _measure_fn(stages, detector)(x)
    return np.asarray(p), np.asarray(intensity)


def agg_figure(figsize, dpi):
    """A matplotlib figure (size in inches, dpi) on an Agg canvas: drawn without a display."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def figure_pixels(fig) -> np.ndarray:
    """The drawn figure as (H, W, 3) uint8 RGB."""
    fig.canvas.draw()
    return np.array(fig.canvas.buffer_rgba())[..., :3]


class Oscilloscope:
    """Reusable oscilloscope plot of an N-stage output: ``frame(deltas_wl (N,), step)`` -> (H, W, 3)
    uint8 RGB. The x axis is time in ps over the 2^N x 20 ps window, the y axis I(t) / I_peak."""

    def __init__(
        self, stages: int, detector: str = "total", figsize=DEFAULT_FIGSIZE, dpi: int = DEFAULT_DPI
    ):
        self.stages = physics.check_stages(stages)
        self.detector = physics._check_choice("detector", detector, physics.DETECTORS)
        g = physics.grid(stages)
        self.t = g.t
        self.sample_idx = np.arange(1, 2**stages) * physics.POINTS_PER_PERIOD
        self.fig = agg_figure(figsize, dpi)
        ax = self.fig.add_subplot()
        (self.line,) = ax.plot(
            self.t, np.zeros_like(self.t), color="tab:blue", lw=1.2, label="I(t)"
        )
        (self.dots,) = ax.plot(
            self.t[self.sample_idx],
            np.zeros(self.sample_idx.size),
            "o",
            ms=3.5,
            color="tab:red",
            label="oscilloscope samples",
        )
        ax.set_xlim(self.t[0], self.t[-1])
        ax.set_ylim(-0.02, 1.1)
        ax.axhline(1.0, color="0.6", lw=0.8, ls="--")
        ax.set_xlabel("time (ps)")
        ax.set_ylabel("intensity / ideal stacked peak")
        ax.legend(loc="upper left", fontsize=8, frameon=False)
        ax.grid(alpha=0.3)
        self.title = ax.set_title(" ")
        self.fig.tight_layout()

    def draw(self, intensity, normalized_power: float, step=None) -> np.ndarray:
        """Draw a precomputed normalised intensity (M,) and P / P_max; returns the RGB frame."""
        self.line.set_ydata(intensity)
        self.dots.set_ydata(np.asarray(intensity)[self.sample_idx])
        self.title.set_text(frame_title(self.stages, normalized_power, step))
        return figure_pixels(self.fig)

    def frame(self, deltas_wl, step=None) -> np.ndarray:
        """The frame for offsets ``deltas_wl`` (N,) wl (exact field model)."""
        p, intensity = measure_frames(
            np.reshape(deltas_wl, (1, self.stages)), self.stages, self.detector
        )
        return self.draw(intensity[0], float(p[0]), step)

    def frames(self, deltas_wl, steps=None) -> list:
        """Frames for a sequence of offsets (T, N), measured in one batched call."""
        p, intensity = measure_frames(deltas_wl, self.stages, self.detector)
        steps = range(len(p)) if steps is None else steps
        return [self.draw(i, float(q), s) for i, q, s in zip(intensity, p, steps)]

    def close(self):
        self.fig.clear()


def frame_title(stages: int, normalized_power: float, step=None) -> str:
    """The title of an oscilloscope frame: N, the step and P / P_max."""
    head = f"N = {stages}" + ("" if step is None else f",  step {step}")
    return f"{head},  P/Pmax = {normalized_power:.3f}"
