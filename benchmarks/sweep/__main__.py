"""``python -m benchmarks.sweep``: the paper's experiments (``benchmarks.sweep.command``)."""

from benchmarks.sweep.command import main

main()
