"""The suite's own tooling: the run's persistent XLA cache, shared with the processes the tests
start, and the ``compiles`` counter, which counts a program loaded from that cache as a
compilation."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

pytest.importorskip(
    "filelock", reason="the suite shares its XLA cache where filelock is installed (the dev extra)"
)


def test_a_program_loaded_from_the_cache_counts_as_a_compilation(compiles):
    keep = jax.config.jax_persistent_cache_min_compile_time_secs
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    loaded = []
    listen = lambda event, **kwargs: loaded.append(event == "/jax/compilation_cache/cache_hits")  # noqa: E731
    jax.monitoring.register_event_listener(listen)
    try:
        f = jax.jit(lambda x: jnp.sin(x) * 3.0 - x)
        x = jnp.ones(7, jnp.float32)
        with compiles() as n:
            f(x).block_until_ready()
        assert n[0] == 1
        jax.clear_caches()  # the in-memory programs gone: the next call loads it from the folder
        del loaded[:]
        with compiles() as n:
            f(x).block_until_ready()
        assert n[0] == 1 and sum(loaded) == 1
        with compiles() as n:
            f(x).block_until_ready()
        assert n[0] == 0
    finally:
        jax.monitoring.unregister_event_listener(listen)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", keep)


def test_started_processes_share_the_runs_cache_folder():
    folder = os.environ["JAX_COMPILATION_CACHE_DIR"]
    assert os.path.isdir(folder) and os.environ["OPS_JAX_CACHE"] == folder
    assert not Path(folder).is_relative_to(
        Path.home() / ".cache"
    )  # never the user's ~/.cache/ops-jax
    code = "import jax; print(jax.config.jax_compilation_cache_dir)"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert out.stdout.strip() == folder
