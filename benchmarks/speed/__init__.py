"""How fast ops-jax runs: throughput, the step's breakdown, the device, the learners, Gymnasium's
modes."""
