"""A mistyped option of the project's programs: two lines (the error, where the options are listed), exit 2."""

import pytest

from agents import cli, episode
from benchmarks import learning, throughput
from ops_jax import render


@pytest.mark.parametrize("main, argv, prog", [
    (cli.main, ["--algo", "td4"], "python -m agents.train"),
    (episode.main, ["frame", "--detector", "polarizer", "--out", "x.png"], "python -m agents.episode"),
    (learning.main, ["--algos", "td3", "--seedz", "2"], "python -m benchmarks.learning"),
    (throughput.main, ["--models", "fields"], "python -m benchmarks.throughput"),
    (render.main, ["landscap", "--out", "x.png"], "python -m ops_jax.render"),
])
def test_a_mistyped_option_is_two_lines(main, argv, prog, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 2
    assert len(err) == 2 and err[0].startswith(f"{prog}: error: ") and err[1] == f"the options: {prog} --help", err
