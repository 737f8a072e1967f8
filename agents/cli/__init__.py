"""The training command line, ``python -m agents`` / ``ops-train`` (``command``), and what a run
writes besides its checkpoint (``outputs``)."""

from agents.cli.command import RUN_FILES, main, parse_set, parser, run

__all__ = ["RUN_FILES", "main", "parse_set", "parser", "run"]
