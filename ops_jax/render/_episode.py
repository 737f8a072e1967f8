"""An episode's pictures: its oscilloscope frames (every k-th step and the last) and their animated
GIF (Pillow, imported only when a GIF is written)."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from ops_jax.env import make
from ops_jax.render._scope import DEFAULT_FIGSIZE, Oscilloscope, measure_frames


class Episode(NamedTuple):
    """deltas_wl (T + 1, N) after reset and after each step; normalized_power (T + 1,) exact."""

    deltas_wl: np.ndarray
    normalized_power: np.ndarray
    env_config: dict


def episode_frames(ep: Episode, every: int = 1, figsize=DEFAULT_FIGSIZE, dpi: int = 80) -> list:
    """Oscilloscope frames of every ``every``-th step of an episode (the last step always
    included)."""
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
    """The steps that ``episode_frames`` draws from an episode of ``length`` offsets: every
    ``every``-th, and the last."""
    idx = list(range(0, length, every))
    return idx if idx[-1] == length - 1 else [*idx, length - 1]


def write_gif(frames, path, fps: float = 10.0, comment: str = "") -> Path:
    """Write RGB frames as an animated GIF (Pillow, one shared adaptive palette, looping;
    ``comment``: the file's comment, e.g. the frames' titles)."""
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
