"""The dependency layers: what ``import ops_jax`` loads, the agents extra, brax on current JAX."""

import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from agents.learners.brax import compat as brax_compat

TIMEOUT_S = 120


def _python(code: str, **env) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        env={**os.environ, **env},
    )


def test_import_ops_jax_loads_no_learner_or_plotting_library():
    code = (
        "import sys, ops_jax, ops_jax.adapters.gymnasium.env, ops_jax.render; "
        "heavy = ('brax', 'flax', 'optax', 'matplotlib', 'gymnax', 'tensorboardX'); "
        "print(sorted(m for m in heavy if m in sys.modules))"
    )
    out = _python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_import_agents_loads_no_learner_or_plotting_library():
    """``import agents`` imports every algorithm's module (each declares its config and registry
    entry beside its code): their brax, flax and optax imports stay inside the functions that build
    and train the networks."""
    code = (
        "import sys, agents; "
        "heavy = ('brax', 'flax', 'optax', 'matplotlib', 'gymnax', 'tensorboardX'); "
        "print(sorted(m for m in heavy if m in sys.modules), "
        "all(a.module in sys.modules for a in agents.registry.REGISTRY.values()))"
    )
    out = _python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[] True"


def test_brax_adapter_without_brax_names_the_extra():
    # A finder that makes brax unimportable, as in an install without the agents extra.
    code = """
import importlib.abc, sys
class NoBrax(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "brax" or name.startswith("brax."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, NoBrax())
try:
    import ops_jax.adapters.brax
except ImportError as e:
    print("ImportError:", e)
"""
    out = _python(code)
    assert out.returncode == 0, out.stderr
    assert "ImportError:" in out.stdout and 'pip install -e ".[agents]"' in out.stdout


def test_agents_modules_print_nothing_on_import():
    out = _python(  # loaded as a program loads them (the registry imports brax quietly first)
        "import agents; [agents.api.algo_module(a) for a in ('ppo', 'sac', 'td3', 'droq')]; "
        "import brax.training.replay_buffers"
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout == ""


def test_device_put_replicated_stacks_one_slice_per_device():
    tree = {"w": np.arange(6.0, dtype=np.float32).reshape(2, 3), "b": np.float32(2.5)}
    devices = jax.local_devices()
    out = brax_compat.device_put_replicated(tree, devices)
    assert out["w"].shape == (len(devices), 2, 3) and out["b"].shape == (len(devices),)
    np.testing.assert_array_equal(np.asarray(out["w"])[0], tree["w"])
    assert {s.device for s in out["w"].addressable_shards} == set(devices)
    with pytest.raises(ValueError, match="devices"):
        brax_compat.device_put_replicated(tree, [])


def test_device_put_replicated_on_two_devices_feeds_pmap():
    code = """
import jax, numpy as np
from agents.learners.brax import compat as brax_compat
devs = jax.local_devices()
assert len(devs) == 2, devs
x = brax_compat.device_put_replicated(np.arange(3.0, dtype=np.float32), devs)
assert [s.device for s in x.addressable_shards] == devs, x.sharding
y = jax.pmap(lambda a: a * 2)(x)
print(np.asarray(y).tolist())
"""
    out = _python(code, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str([[0.0, 2.0, 4.0], [0.0, 2.0, 4.0]])


def test_ensure_is_a_no_op_where_jax_has_the_function(monkeypatch):
    sentinel = object()
    monkeypatch.setattr(jax, "device_put_replicated", sentinel, raising=False)
    assert brax_compat.ensure_device_put_replicated() is False
    assert jax.device_put_replicated is sentinel


def test_ensure_installs_the_function_where_jax_lacks_it(monkeypatch):
    monkeypatch.delattr(jax, "device_put_replicated", raising=False)
    assert brax_compat.ensure_device_put_replicated() is True
    assert jax.device_put_replicated is brax_compat.device_put_replicated
