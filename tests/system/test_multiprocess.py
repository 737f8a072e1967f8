"""A batched rollout sharded over 2 JAX processes (jax.distributed, gloo) equals the one-process
run."""

import numpy as np

from benchmarks.speed import multiprocess


def test_two_processes_match_one_process_instance_by_instance(this_build):
    r = multiprocess.check(processes=2, instances=8, steps=10, seed=3)
    assert r["devices"] == 2 and r["instances"] == 8
    assert r["equal"] and r["equal_instances"] == 8 and r["max_abs_diff"] == 0.0


def test_instances_differ_so_equality_is_not_trivial():
    npow = multiprocess.batched_rollout(instances=4, steps=10, seed=3)
    assert npow.shape == (4, 10) and np.all(np.isfinite(npow))
    assert len({row.tobytes() for row in npow}) == 4  # instance i's keys are folded by i
    assert not np.array_equal(npow, multiprocess.batched_rollout(instances=4, steps=10, seed=4))
