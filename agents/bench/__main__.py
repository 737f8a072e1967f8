"""``python -m agents.bench``: a controller on a bench (``agents.bench.runner``)."""

from agents.bench.runner import run

run()
