"""Pictures of OPS: oscilloscope frames, animated episodes and the objective landscape.

All pictures use the exact field model (``physics.measure(model="field")``): intensity I(t) on the
0.5 ps grid, normalised to the peak of the ideal stacked pulse (``physics.peak_intensity``), the
2^N - 1 oscilloscope samples marked, and P / P_max of that measurement. matplotlib (Agg canvas,
no display needed) and Pillow are imported here only.

Command line (the policy episodes and their GIFs are ``python -m agents.episode``)::

    # P/Pmax along one stage's delay (one --stage: line plot; paper Fig. 2a is N=2, stage 1) ...
    python -m ops_jax.render landscape --stages 2 --stage 1 --out landscape_1d.png
    # ... or over two stages' delays (two --stage values: heat map, paper Fig. 2b)
    python -m ops_jax.render landscape --stages 3 --stage 1 2 --out landscape_2d.png

With the default "total" detector the LAST stage's carrier phase is invisible (physics.md section
4): a heat map over stages 1 and 2 at N = 2 is flat along stage 2, so the README uses N = 3 (or
``--detector polariser``). Stages are numbered from 1; landscape offsets span ``[-span, span]`` wl
(default 1) with the other stages at their optimal lengths.
"""

from __future__ import annotations

import argparse
import functools
import logging
import os
import sys
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np

from ops_jax import physics
from ops_jax.cli.parser import ArgumentParser, run
from ops_jax.env import make
from ops_jax.cli.progress import keep_ctrl_c

DEFAULT_FIGSIZE = (6.4, 3.4)  # inches
DEFAULT_DPI = 100
_NON_INTERACTIVE = {
    "agg",
    "pdf",
    "ps",
    "svg",
    "pgf",
    "cairo",
    "template",
    "module://matplotlib_inline.backend_inline",
}


@functools.lru_cache(maxsize=None)
def _measure_fn(stages: int, detector: str):
    """Jitted field measurement of a batch of offsets (B, N) -> (P / P_max (B,), I / I_peak (B, M))."""
    p_max = physics.p_max(stages, detector)
    peak = physics.peak_intensity(stages)

    @jax.jit
    def fn(deltas):
        m = physics.measure(deltas, stages=stages, model="field", detector=detector)
        return m.power / p_max, m.intensity / peak

    return fn


def measure_frames(deltas_wl, stages: int, detector: str = "total"):
    """Exact measurements of offsets ``deltas_wl`` (T, N) wl: (P / P_max (T,), I / I_peak (T, M))."""
    physics.check_stages(stages)
    physics._check_choice("detector", detector, physics.DETECTORS)
    x = np.asarray(deltas_wl, np.float32)
    if x.ndim != 2 or x.shape[1] != stages:
        raise ValueError(f"deltas_wl must have shape (T, {stages}), got {x.shape}")
    p, intensity = _measure_fn(stages, detector)(x)
    return np.asarray(p), np.asarray(intensity)


def _figure(figsize, dpi):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def _rgb(fig) -> np.ndarray:
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
        self.fig = _figure(figsize, dpi)
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
        return _rgb(self.fig)

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


_human = {}


def _headless() -> bool:
    return sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )


def show(frame: np.ndarray, title: str = "ops_jax") -> bool:
    """Show an RGB frame in a matplotlib window (``render_mode="human"``). On a machine without a
    display or with a non-interactive backend it logs one message (``logging``, not a warning, so
    warnings-as-errors test suites pass) and returns False."""
    if not _headless():
        import matplotlib.pyplot as plt

        if plt.get_backend().lower() not in _NON_INTERACTIVE:
            if "fig" not in _human or not plt.fignum_exists(_human["fig"].number):
                _human["fig"], ax = plt.subplots(num=title)
                ax.set_axis_off()
                _human["im"] = ax.imshow(frame)
                _human["fig"].tight_layout()
                plt.show(block=False)
            _human["im"].set_data(frame)
            plt.pause(0.001)
            return True
    if not _human.get("warned"):
        logging.getLogger("ops_jax").warning(
            "render_mode='human': no display or interactive matplotlib backend; frames are not shown "
            "(use render_mode='rgb_array')"
        )
        _human["warned"] = True
    return False


# -- episodes ---------------------------------------------------------------------------------


class Episode(NamedTuple):
    """deltas_wl (T + 1, N) after reset and after each step; normalized_power (T + 1,) exact."""

    deltas_wl: np.ndarray
    normalized_power: np.ndarray
    env_config: dict


def episode_frames(ep: Episode, every: int = 1, figsize=DEFAULT_FIGSIZE, dpi: int = 80) -> list:
    """Oscilloscope frames of every ``every``-th step of an episode (the last step always included)."""
    from ops_jax.cli.progress import progress

    env, _ = make(**ep.env_config)
    scope = Oscilloscope(env.config.stages, env.config.detector, figsize=figsize, dpi=dpi)
    idx = frame_steps(len(ep.deltas_wl), every)
    _, intensity = measure_frames(ep.deltas_wl[idx], env.config.stages, env.config.detector)
    frames = [
        scope.draw(intensity[j], float(ep.normalized_power[i]), i)
        for j, i in enumerate(progress(idx, desc="frames", unit="frame", leave=False))
    ]
    scope.close()
    return frames


def frame_steps(length: int, every: int = 1) -> list:
    """The steps that ``episode_frames`` draws from an episode of ``length`` offsets: every ``every``-th, and the last."""
    idx = list(range(0, length, every))
    return idx if idx[-1] == length - 1 else [*idx, length - 1]


def write_gif(frames, path, fps: float = 10.0, comment: str = "") -> Path:
    """Write RGB frames as an animated GIF (Pillow, one shared adaptive palette, looping; ``comment``: the
    file's comment, e.g. the frames' titles)."""
    from PIL import Image

    if len(frames) < 1:
        raise ValueError("frames must hold at least one frame")
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    images = [Image.fromarray(np.asarray(f, np.uint8)) for f in frames]
    palette = images[len(images) // 2].quantize(colors=64, method=Image.Quantize.MEDIANCUT)
    images = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in images]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(
        path,
        save_all=True,
        append_images=images[1:],
        duration=int(round(1000 / fps)),
        loop=0,
        optimize=True,
        comment=comment.encode(),
    )
    return path


# -- objective landscape -----------------------------------------------------------------------


def _check_stage(stage, stages):
    if (
        isinstance(stage, bool)
        or not isinstance(stage, (int, np.integer))
        or not 1 <= stage <= stages
    ):
        raise ValueError(f"stage must be an integer in [1, {stages}] (1-based), got {stage!r}")
    return int(stage) - 1


LANDSCAPE_CHUNK = 16_384  # offsets per field-model call of ``landscape``: its memory (the field grid of each) bounded


@functools.lru_cache(maxsize=None)
def _landscape_fn(stages: int, detector: str):
    p_max = physics.p_max(stages, detector)
    return jax.jit(
        lambda x: physics.measure(x, stages=stages, model="field", detector=detector).power / p_max
    )


def landscape(
    stages: int, stage_ids, offsets_wl, *, base_wl=None, detector: str = "total"
) -> np.ndarray:
    """P / P_max with the 1-based stages ``stage_ids`` (one or two) moved by ``offsets_wl`` (M,) wl
    from ``base_wl`` (N,) (default: the optimum), computed in one batched field-model call.
    One stage: shape (M,); two stages (a, b): shape (M, M), row i = offset i of stage b."""
    stages = physics.check_stages(stages)
    ids = [_check_stage(s, stages) for s in np.atleast_1d(stage_ids).tolist()]
    if len(ids) not in (1, 2) or len(set(ids)) != len(ids):
        raise ValueError(f"stage_ids must be one stage or two different stages, got {stage_ids!r}")
    x = np.asarray(offsets_wl, np.float32)
    if x.ndim != 1 or x.size < 1 or not np.all(np.isfinite(x)):
        raise ValueError("offsets_wl must be a non-empty 1-D array of finite offsets (wl)")
    base = np.zeros(stages, np.float32) if base_wl is None else np.asarray(base_wl, np.float32)
    if base.shape != (stages,):
        raise ValueError(f"base_wl must have shape ({stages},), got {base.shape}")
    if len(ids) == 1:
        deltas = np.tile(base, (x.size, 1))
        deltas[:, ids[0]] += x
    else:
        xa, xb = np.meshgrid(x, x)  # (M, M): column = stage a offset, row = stage b offset
        deltas = np.tile(base, (x.size**2, 1))
        deltas[:, ids[0]] += xa.ravel()
        deltas[:, ids[1]] += xb.ravel()
    fn, chunk = _landscape_fn(stages, detector), min(LANDSCAPE_CHUNK, len(deltas))
    padded = np.concatenate(
        [deltas, np.tile(base, (-len(deltas) % chunk, 1))]
    )  # whole chunks: one compilation
    p = np.concatenate(
        [np.asarray(fn(padded[i : i + chunk])) for i in range(0, len(padded), chunk)]
    )[: len(deltas)]
    return p if len(ids) == 1 else p.reshape(x.size, x.size)


def matplotlib_ticks(span: float, max_ticks: int = 5) -> np.ndarray:
    """Symmetric ticks on [-span, span] at a multiple of 0.25 wl (at most ``max_ticks``)."""
    step = 0.25
    while 2 * span / step + 1 > max_ticks:
        step *= 2
    k = np.floor(span / step)
    return np.arange(-k, k + 1) * step


def plot_landscape(
    stages: int,
    stage_ids,
    *,
    span: float = 1.0,
    points: int = 401,
    detector: str = "total",
    figsize=(5.6, 3.6),
    dpi: int = 120,
):
    """Figure of the landscape: a line plot (one stage) or a heat map (two stages)."""
    if not (np.isfinite(span) and span > 0):
        raise ValueError(f"span must be > 0 (wl), got {span}")
    if isinstance(points, bool) or not isinstance(points, (int, np.integer)) or points < 2:
        raise ValueError(f"points must be an integer >= 2, got {points!r}")
    ids = np.atleast_1d(stage_ids).tolist()
    x = np.linspace(-span, span, points)
    p = landscape(stages, ids, x, detector=detector)
    fig = _figure(figsize if len(ids) == 1 else (figsize[0], figsize[0] * 0.82), dpi)
    ax = fig.add_subplot()
    if len(ids) == 1:
        ax.plot(x, p, color="tab:blue", lw=1.4)
        ax.set_xlabel(f"stage {ids[0]} delay offset (wavelengths, 1 wl = 1030 nm)")
        ax.set_ylabel("P / Pmax")
        ax.set_ylim(0, 1.05)
        ax.set_xlim(-span, span)
        ax.grid(alpha=0.3)
        ax.set_title(
            f"P/Pmax along stage {ids[0]}'s delay (N = {stages}, other stages optimal), "
            f"max {p.max():.3f}",
            fontsize=10,
        )
    else:
        im = ax.imshow(
            p,
            origin="lower",
            extent=(-span, span, -span, span),
            cmap="viridis",
            vmin=0,
            vmax=1,
            aspect="equal",
            interpolation="bilinear",
        )
        ax.set_xlabel(f"stage {ids[0]} delay offset (wl)")
        ax.set_ylabel(f"stage {ids[1]} delay offset (wl)")
        ticks = matplotlib_ticks(span)
        ax.set_xticks(ticks)
        ax.set_yticks(ticks)
        fig.colorbar(im, ax=ax, label="P / Pmax", shrink=0.9)
        rest = "" if stages == 2 else ", other stages optimal"
        ax.set_title(
            f"P/Pmax over stages {ids[0]} and {ids[1]} (N = {stages}{rest}), max {p.max():.3f}",
            fontsize=10,
        )
    fig.tight_layout()
    return fig


# -- command line ------------------------------------------------------------------------------


def _parser():
    ap = ArgumentParser(
        prog="python -m ops_jax.render",
        description="The objective landscape of OPS as a picture (the "
        "oscilloscope frames and episode GIFs: python -m agents.episode).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("command", choices=("landscape",))
    ap.add_argument("--stages", type=int, default=5, help="number of stages N")
    ap.add_argument("--detector", default="total", choices=physics.DETECTORS)
    ap.add_argument("--stage", type=int, nargs="+", default=[1], help="1 or 2 stages (1-based)")
    ap.add_argument("--span", type=float, default=1.0, help="offsets in [-span, span] wl")
    ap.add_argument("--points", type=int, default=None, help="grid points per axis (401 / 201)")
    ap.add_argument("--dpi", type=int, default=120)
    ap.add_argument("--out", required=True, help="output PNG")
    return ap


def main(argv=None) -> Path:
    keep_ctrl_c()
    args = _parser().parse_args(argv)
    out = Path(args.out)
    points = args.points or (401 if len(args.stage) == 1 else 201)
    fig = plot_landscape(
        args.stages, args.stage, span=args.span, points=points, detector=args.detector, dpi=args.dpi
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, metadata={"Title": fig.axes[0].get_title()})
    print(f"wrote {out}")
    return out


if __name__ == "__main__":
    run("python -m ops_jax.render", main)
