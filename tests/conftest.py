import contextlib
import gc
import importlib.util
import json
import os
import shutil
import tempfile
from pathlib import Path

import jax
import numpy as np
import pytest

REFERENCE_DIR = Path(__file__).resolve().parents[1] / "benchmarks" / "reference"


def _compile_unoptimised():
    """This process compiles at XLA's backend optimisation level 0 (as
    ``benchmarks.sweep --quick``): the suite's time is mostly compilation. The level is read once,
    when the backend starts (here); XLA_FLAGS is then restored, so that the processes the tests
    start (the bench, the IOC, the sweep) run the optimised build; a test that compares this
    process's numbers with a started process's bit for bit uses ``this_build``. Returns the
    XLA_FLAGS of this process."""
    flags = os.environ.get("XLA_FLAGS")
    if "xla_backend_optimization_level" in (flags or ""):
        return flags
    here = os.environ["XLA_FLAGS"] = f"{flags or ''} --xla_backend_optimization_level=0".strip()
    try:
        jax.devices()
    finally:
        if flags is None:
            del os.environ["XLA_FLAGS"]
        else:
            os.environ["XLA_FLAGS"] = flags
    return here


XLA_FLAGS_HERE = _compile_unoptimised()


def _share_compilations():
    """One persistent XLA cache for the run, a temporary folder (not the user's
    ``~/.cache/ops-jax``) made by the first pytest process and inherited by xdist's workers and by
    every process the tests start (IOCs, bench runners, learners, snippets, sweeps): a program one
    of them compiled, another loads. Programs that compile in under 0.5 s are not kept. Only where
    the filelock package is installed: the cache's size limit turns its file lock on, and several
    processes write to it. ``compiles`` counts a program loaded from it as a compilation. Returns
    the folder this process made and removes at the end (None: none, inherited, or set outside)."""
    if "JAX_COMPILATION_CACHE_DIR" in os.environ or not importlib.util.find_spec("filelock"):
        return None  # inherited or set outside (jax read it when imported), or no file lock
    folder = Path(tempfile.mkdtemp(prefix="ops-jax-tests-xla-"))
    settings = {
        "jax_compilation_cache_dir": str(folder),
        "jax_persistent_cache_min_compile_time_secs": 0.5,
        "jax_compilation_cache_max_size": 4 << 30,
    }
    for name, value in settings.items():
        jax.config.update(name, value)  # this process's jax is imported already
        os.environ[name.upper()] = str(
            value
        )  # the processes started later read it when they import jax
    os.environ["OPS_JAX_CACHE"] = str(folder)  # the sweep's cache
    return folder


SHARED_XLA_CACHE = _share_compilations()


def pytest_unconfigure(config):
    if SHARED_XLA_CACHE is not None:  # the first pytest process, after every worker has ended
        shutil.rmtree(SHARED_XLA_CACHE, ignore_errors=True)


@pytest.fixture
def this_build(monkeypatch):
    """XLA_FLAGS set to this process's while the test runs: the processes it starts compile the same
    build (to compare with it bit for bit, or to compile faster where a process's speed does not
    matter)."""
    monkeypatch.setenv("XLA_FLAGS", XLA_FLAGS_HERE)


@pytest.fixture(scope="session")
def reference():
    """The paper implementation's numbers (benchmarks/reference, or OPS_REFERENCE_DIR): physics
    arrays and constants."""
    ref = Path(os.environ.get("OPS_REFERENCE_DIR") or REFERENCE_DIR)
    assert (ref / "ops_reference_physics.npz").exists(), f"reference data not found in {ref}"
    physics = dict(np.load(ref / "ops_reference_physics.npz"))
    constants = json.loads((ref / "ops_reference_constants.json").read_text())["stages"]
    return physics, constants


@contextlib.contextmanager
def _count_compiles():
    n = [0]

    def listen(
        event, duration, **kwargs
    ):  # also fired for a program loaded from the persistent cache
        n[0] += event == "/jax/core/compile/backend_compile_duration"

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield n
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


@pytest.fixture
def compiles():
    """``with compiles() as n:`` counts the XLA compilations inside the block in ``n[0]``, programs
    loaded from the persistent cache included (``jax.monitoring``'s events): a check that nothing is
    traced or compiled again."""
    return _count_compiles


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop each test module's compiled programs when it ends: one process compiles hundreds of XLA
    programs over the suite, and their code mappings would otherwise add up to the kernel's
    per-process map limit."""
    yield
    jax.clear_caches()
    gc.collect()
