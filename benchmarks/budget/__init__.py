"""Learning on a lab's budget: score against env steps within 20k steps
(``python -m benchmarks.budget``)."""
