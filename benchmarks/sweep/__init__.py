"""The paper's experiments as one resumable command (``python -m benchmarks.sweep``)."""
