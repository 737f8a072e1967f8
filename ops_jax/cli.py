"""The argument parser of the project's command-line programs: a mistyped option is reported in two
lines (the error and where the options are listed), not under a screenful of usage."""

from __future__ import annotations

import argparse


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose errors are two lines on stderr, exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\nthe options: {self.prog} --help\n")

