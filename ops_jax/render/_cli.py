"""The command line ``python -m ops_jax.render landscape ...``: the objective landscape as a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from ops_jax import physics
from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import keep_ctrl_c
from ops_jax.render._landscape import plot_landscape


def _parser():
    """The argument parser of ``python -m ops_jax.render``."""
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
    """Run ``python -m ops_jax.render`` with ``argv``: write the landscape PNG; returns its path."""
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
