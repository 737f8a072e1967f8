"""Pictures of OPS: oscilloscope frames, animated episodes and the objective landscape.

All pictures use the exact field model (``physics.measure(model="field")``): intensity I(t) on the
0.5 ps grid, normalised to the peak of the ideal stacked pulse (``physics.peak_intensity``), the
2^N - 1 oscilloscope samples marked, and P / P_max of that measurement. matplotlib (Agg canvas,
no display needed) and Pillow are imported only when a picture is made.

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

from ops_jax.render._cli import main
from ops_jax.render._episode import Episode, episode_frames, frame_steps, write_gif
from ops_jax.render._landscape import (
    LANDSCAPE_CHUNK,
    landscape,
    matplotlib_ticks,
    plot_landscape,
)
from ops_jax.render._scope import (
    DEFAULT_DPI,
    DEFAULT_FIGSIZE,
    Oscilloscope,
    frame_title,
    measure_frames,
)
from ops_jax.render._window import show

__all__ = [
    "DEFAULT_DPI",
    "DEFAULT_FIGSIZE",
    "LANDSCAPE_CHUNK",
    "Episode",
    "Oscilloscope",
    "episode_frames",
    "frame_steps",
    "frame_title",
    "landscape",
    "main",
    "matplotlib_ticks",
    "measure_frames",
    "plot_landscape",
    "show",
    "write_gif",
]
