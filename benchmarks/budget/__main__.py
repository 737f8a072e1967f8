"""``python -m benchmarks.budget``: learning on a lab's budget (``benchmarks.budget.plan``)."""

from benchmarks.budget.command import main

main()
