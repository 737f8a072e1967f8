"""Progress reporting off a terminal: plain lines, no control codes, honest remaining time."""

import io
import subprocess
import sys

from ops_jax.cli import progress as prog


def test_plain_lines_without_control_codes_and_with_remaining_time():
    out = io.StringIO()
    bar = prog.progress(total=10, desc="cells", unit="cell", file=out, interval=0.0)
    assert isinstance(bar, prog.PlainProgress)
    for _ in range(4):
        bar.update(1)
    bar.set_postfix(P_Pmax="0.950")
    bar.close()
    bar.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 5  # one line per update at interval 0, and the final state once at close
    assert "\x1b" not in out.getvalue() and "\r" not in out.getvalue()
    assert (
        lines[-1].startswith("cells: 4/10 cell (40%)")
        and "remaining" in lines[-1]
        and "P_Pmax=0.950" in lines[-1]
    )


def test_lines_are_rate_limited_and_the_end_is_always_printed():
    out = io.StringIO()
    for _ in prog.progress(range(1000), desc="x", file=out, interval=3600.0):
        pass
    lines = out.getvalue().splitlines()
    assert len(lines) == 1 and lines[0].startswith("x: 1000/1000")


def test_weighted_total_gives_remaining_time_from_the_weighted_rate():
    bar = prog.PlainProgress(total=100.0, file=io.StringIO(), interval=3600.0)
    bar.start -= 10.0  # 10 s elapsed
    bar.update(25.0)  # a quarter of the weighted work in 10 s -> 30 s to go
    assert "~0:30 remaining" in bar.line()


def test_a_terminal_gets_tqdm():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    from tqdm import tqdm

    bar = prog.progress(total=3, file=Tty())
    assert isinstance(bar, tqdm)
    bar.close()


def test_format_seconds():
    assert prog.format_seconds(59.6) == "1:00"
    assert prog.format_seconds(3725) == "1:02:05"
    assert prog.format_seconds(-3) == "0:00"


def test_a_piped_command_writes_no_control_codes():
    code = (
        "from ops_jax.cli.progress import progress\nfor _ in progress(range(50), desc='w', "
        "interval=0.0): pass\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "\x1b" not in out.stderr and "\r" not in out.stderr
    assert out.stderr.splitlines()[-1].startswith("w: 50/50")
