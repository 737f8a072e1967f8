"""A missing extra: the project's programs stop with one line naming the install command, in a real
subprocess whose ``sitecustomize`` makes the module unimportable (as in an install without the
extra)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from ops_jax.cli import extras

REPO = Path(__file__).resolve().parents[2]
TIMEOUT_S = 180
BLOCKER = """import os, sys
for name in os.environ["BLOCK_MODULES"].split(","):
    sys.modules[name] = None  # `import name` then raises ModuleNotFoundError
"""


def _run_without(modules, args, tmp_path) -> subprocess.CompletedProcess:
    (tmp_path / "sitecustomize.py").write_text(BLOCKER)
    env = {
        **os.environ,
        "BLOCK_MODULES": ",".join(modules),
        "PYTHONPATH": f"{tmp_path}{os.pathsep}{REPO}",
    }
    return subprocess.run(
        [sys.executable, *args],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        env=env,
        cwd=tmp_path,
    )


def test_the_agents_extra_installs_what_the_sweep_and_learners_import():
    for module in ("ray", "brax", "flax", "optax", "scipy"):
        assert extras.extra_of(module) == "agents", module
    assert extras.extra_of("pytest") == "dev"
    assert extras.extra_of("no_such_module") is None


@pytest.mark.parametrize(
    "modules, args",
    [
        (["ray"], ["-m", "benchmarks.sweep", "--quick", "--out", "out"]),
        (
            ["ray", "brax", "flax", "optax", "scipy"],
            ["-m", "benchmarks.sweep", "--quick", "--out", "out"],
        ),
        (
            ["flax"],
            ["-m", "agents", "--algo", "td3", "--stages", "2", "--steps", "1000", "--out", "run"],
        ),
        (["brax"], ["-m", "benchmarks.learning", "--algos", "sac", "--seeds", "1", "--out", "out"]),
    ],
)
def test_a_program_without_its_extra_names_the_install_command(modules, args, tmp_path):
    out = _run_without(modules, args, tmp_path)
    assert out.returncode == 1, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    assert lines[0].startswith(f"python -m {args[1]} needs ") and lines[0].endswith(
        'pip install -e ".[agents]"'
    )


def test_other_programs_keep_their_traceback(tmp_path):
    out = _run_without(["ray"], ["-c", "import ops_jax, ray"], tmp_path)
    assert out.returncode == 1 and "Traceback" in out.stderr and "ModuleNotFoundError" in out.stderr


def test_the_benchs_learner_without_the_agents_extra_names_it_and_what_it_installs(tmp_path):
    """``.[lab]`` alone: learning on the bench (DroQ: flax networks, optax optimisers, brax's replay
    buffer) stops with a last line naming the agents extra and the modules it brings."""
    learn = ["--prefix", "NOONE:", "--stages", "3", "--learn", "droq", "--steps", "100"]
    out = _run_without(
        ["brax", "flax", "optax", "scipy", "ray"],
        ["-m", "agents.bench", *learn, "--out", "o"],
        tmp_path,
    )
    assert out.returncode == 1 and "Traceback" not in out.stderr, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert re.fullmatch(
        r"python -m agents\.bench needs (brax|flax|optax), which the agents extra installs \(with "
        r"[a-z, ]+\): "
        r'pip install -e "\.\[agents\]"',
        last,
    ), last
    assert all(m in last for m in ("brax", "flax", "optax")), last
    assert not (tmp_path / "o").exists()
