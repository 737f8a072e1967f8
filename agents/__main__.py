"""``python -m agents --algo ...``: train one controller from the command line (``agents.cli``)."""

from agents.cli import run

run()
