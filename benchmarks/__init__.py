"""Benchmarks of ops-jax: throughput, learning, and the paper's sweep."""
