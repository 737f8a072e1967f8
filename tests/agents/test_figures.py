"""The README's figures are what their commands draw: each command (collected from the README's
Pictures block) re-draws its figure's first frame here, and the title it prints must read as the
committed figure's (stored in the file: PNG text "Title", the GIF's comment, one line per frame)."""

import re
import shlex
from pathlib import Path

import pytest
from PIL import Image

from agents import episode
from ops_jax import render

REPO = Path(__file__).resolve().parents[2]


def picture_commands() -> list:
    """argv of every command in the README's Pictures block."""
    text = (REPO / "README.md").read_text()
    block = re.search(r"^## Pictures\n\n```bash\n(.*?)^```", text, re.S | re.M).group(1)
    return [shlex.split(line, comments=True) for line in block.splitlines() if line.strip()]


def first_title(path: Path) -> str:
    image = Image.open(path)
    return (
        image.info["comment"].decode().splitlines()[0]
        if path.suffix == ".gif"
        else image.text["Title"]
    )


def _option(argv, name):
    return argv[argv.index(name) + 1]


@pytest.mark.parametrize("argv", picture_commands(), ids=lambda a: Path(_option(a, "--out")).name)
def test_figure_title_reads_what_its_command_draws(argv, tmp_path):
    committed = REPO / _option(argv, "--out")
    assert committed.parent == REPO / "benchmarks" / "figures" and committed.exists(), committed
    args = argv[3:]
    args[args.index("--out") + 1] = str(tmp_path / committed.name)
    if argv[2] == "agents.episode" and "frame" not in args:
        # The GIF's first frame is the reset, before the policy acts: the zero policy draws it
        # without compiling the controller.
        args[args.index("--policy") + 1] = "zero"
        args[args.index("--steps") + 1] = "0"
    module = episode if argv[2] == "agents.episode" else render
    assert argv[:3] == ["python", "-m", module.__name__]
    module.main(args)
    redrawn = first_title(tmp_path / committed.name)
    assert re.search(r"(P/Pmax =|max) \d\.\d{3}$", redrawn), redrawn
    assert redrawn == first_title(committed), f"{committed.name}: re-draw with `{shlex.join(argv)}`"
