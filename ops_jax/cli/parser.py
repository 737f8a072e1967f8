"""The argument parser of the project's command-line programs: a mistyped option is reported in two
lines (the error and where the options are listed), not under a screenful of usage; ``run``: a
picture program's values out of range and its Ctrl-C in one line each."""

from __future__ import annotations

import argparse
import sys

from ops_jax.cli.progress import exit_interrupted, keep_ctrl_c


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose errors are two lines on stderr, exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\nthe options: {self.prog} --help\n")

    def check_least(self, args, **least) -> None:
        """A parser error for the first of the options ``least`` names whose value lies under its
        least (an option left unset, None, passes): ``check_least(args, steps=0, episodes=1)``."""
        for name, low in least.items():
            value = getattr(args, name)
            if value is not None and value < low:
                self.error(f"--{name.replace('_', '-')} must be >= {low}, got {value}")


def run(prog: str, main) -> None:
    """Run a picture-making program's ``main()``, which computes from its arguments alone: a
    ``ValueError`` (a value out of its range, named by the function that refused it) is one line on
    stderr, exit status 2; a Ctrl-C one line, exit status 130."""
    keep_ctrl_c()
    try:
        main()
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr, flush=True)
        sys.exit(2)
    except KeyboardInterrupt:
        exit_interrupted("nothing written")
