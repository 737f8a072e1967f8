"""The objective landscape: P / P_max (exact field model) with one or two stages moved from the
optimum, as numbers (``landscape``) and as a figure (``plot_landscape``: a line plot or a heat
map)."""

from __future__ import annotations

import functools

import jax
import numpy as np

from ops_jax import physics
from ops_jax.render._scope import agg_figure


def _check_stage(stage, stages):
    if (
        isinstance(stage, bool)
        or not isinstance(stage, (int, np.integer))
        or not 1 <= stage <= stages
    ):
        raise ValueError(f"stage must be an integer in [1, {stages}] (1-based), got {stage!r}")
    return int(stage) - 1


# offsets per field-model call of ``landscape``: its memory (the field grid of each) bounded
LANDSCAPE_CHUNK = 16_384


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
    fig = agg_figure(figsize if len(ids) == 1 else (figsize[0], figsize[0] * 0.82), dpi)
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
