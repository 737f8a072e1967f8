"""``render_mode="human"``: an RGB frame shown in a matplotlib window, or one logged message where
no display or interactive backend is there."""

from __future__ import annotations

import logging
import os
import sys

import numpy as np

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


_human_window = {}  # the window's figure and image, and whether the no-display message was logged


def _headless() -> bool:
    """Whether this is a Linux machine without an X or Wayland display."""
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
            if "fig" not in _human_window or not plt.fignum_exists(_human_window["fig"].number):
                _human_window["fig"], ax = plt.subplots(num=title)
                ax.set_axis_off()
                _human_window["im"] = ax.imshow(frame)
                _human_window["fig"].tight_layout()
                plt.show(block=False)
            _human_window["im"].set_data(frame)
            plt.pause(0.001)
            return True
    if not _human_window.get("warned"):
        logging.getLogger("ops_jax").warning(
            "render_mode='human': no display or interactive matplotlib backend; frames are not "
            "shown (use render_mode='rgb_array')"
        )
        _human_window["warned"] = True
    return False
