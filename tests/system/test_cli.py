"""A mistyped option of the project's programs: two lines (the error, where the options are listed),
exit 2; a value out of its range: one line, exit 2."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from agents import cli, episode
from benchmarks import learning
from benchmarks.sweep import command as sweep
from benchmarks.speed import throughput
from ops_jax import ioc, render


@pytest.mark.parametrize(
    "main, argv, prog",
    [
        (cli.main, ["--algo", "td4"], "python -m agents"),
        (
            episode.main,
            ["frame", "--detector", "polarizer", "--out", "x.png"],
            "python -m agents.episode",
        ),
        (learning.main, ["--algos", "td3", "--seedz", "2"], "python -m benchmarks.learning"),
        (throughput.main, ["--models", "fields"], "python -m benchmarks.speed.throughput"),
        (render.main, ["landscap", "--out", "x.png"], "python -m ops_jax.render"),
        (sweep.main, ["--quikc"], "python -m benchmarks.sweep"),
        (
            sweep.main,
            ["--quick", "--seeds", "1"],
            "python -m benchmarks.sweep",
        ),  # a value out of range, before any work
        (ioc.main, ["--rate", "-1"], "python -m ops_jax.ioc"),
        (ioc.main, ["--mode", "bogus"], "python -m ops_jax.ioc"),
    ],
)
def test_a_mistyped_option_is_two_lines(main, argv, prog, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2
    assert (
        len(err) == 2
        and err[0].startswith(f"{prog}: error: ")
        and err[1] == f"the options: {prog} --help"
    ), err


REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    "argv, words",
    [
        (
            ["-m", "ops_jax.render", "landscape", "--stages", "2", "--stage", "3"],
            "stage must be an integer in [1, 2]",
        ),
        (
            ["-m", "agents.episode", "episode", "--policy", "foo"],
            "policy must be zero, random, one of",
        ),
    ],
)
def test_a_value_out_of_range_is_one_line(argv, words, tmp_path):
    """The picture programs, as run from a shell: the refusing function's message, one line, no
    traceback."""
    out = subprocess.run(
        [sys.executable, *argv, "--out", str(tmp_path / "x.png")],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    prog = f"python -m {argv[1]}"
    assert out.returncode == 2 and out.stderr.splitlines() == [out.stderr.strip()], out.stderr
    assert out.stderr.startswith(f"{prog}: error: {words}") and not (tmp_path / "x.png").exists(), (
        out.stderr
    )
