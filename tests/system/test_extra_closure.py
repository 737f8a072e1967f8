"""What an install of ``ops-jax[lab]`` alone holds is all the bench's commands without a learner
import: the IOC, the template, the check and a frozen controller's run, each a real subprocess in
which every installed distribution outside the closure of ``ops-jax[lab]``'s requirements is made
unimportable (as in a fresh environment with that extra only)."""

import json
import os
import re
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement

pytest.importorskip("caproto")
pytest.importorskip("ophyd")
pytest.importorskip("bluesky")

from benchmarks.lab import Process, ca_env  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
START_S = 240  # an IOC or runner start-up on a loaded 2-core machine (JAX import and compile)
PREFIX = "LX:"
BLOCKER = """import os, sys
for name in os.environ["BLOCK_MODULES"].split(","):
    sys.modules[name] = None  # `import name` then raises ModuleNotFoundError
"""


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def closure(distribution: str, extras: set) -> set:
    """The canonical names of ``distribution`` with ``extras`` and of everything it requires, at
    any depth, on this interpreter."""
    todo, seen = [(distribution, frozenset(extras))], set()
    while todo:
        name, wanted = todo.pop()
        if (_canonical(name), wanted) in seen:
            continue
        seen.add((_canonical(name), wanted))
        try:
            requirements = metadata.distribution(name).requires or []
        except metadata.PackageNotFoundError:
            continue
        for text in requirements:
            requirement = Requirement(text)
            marker = requirement.marker
            if marker is None or any(marker.evaluate({"extra": e}) for e in wanted or {""}):
                todo.append((requirement.name, frozenset(requirement.extras)))
    return {name for name, _ in seen}


def blocked_modules(allowed: set) -> list:
    """The top-level modules installed here that no distribution in ``allowed`` provides."""
    provided = metadata.packages_distributions()
    return sorted(
        module
        for module, dists in provided.items()
        if module.isidentifier() and not any(_canonical(d) in allowed for d in dists)
    )


def test_the_closure_of_the_lab_extra_holds_the_lab_stack_and_no_learner():
    allowed = closure("ops-jax", {"lab"})
    assert {"caproto", "ophyd", "bluesky", "event-model", "jax", "numpy"} <= allowed, allowed
    assert not {"brax", "flax", "optax", "ray", "pytest"} & allowed, allowed
    blocked = blocked_modules(allowed)
    installed = set(metadata.packages_distributions())
    assert {"brax", "flax", "ray", "pytest"} & installed <= set(blocked), blocked
    assert "pytest" in blocked and "caproto" not in blocked and "jax" not in blocked, blocked


def _env_with_only(extras: set, site: Path) -> dict:
    """Channel Access on a fresh localhost port, and a ``sitecustomize`` that makes everything
    outside ``ops-jax[extras]`` unimportable."""
    (site / "sitecustomize.py").write_text(BLOCKER)
    modules = blocked_modules(closure("ops-jax", extras))
    return {
        **ca_env(),
        "BLOCK_MODULES": ",".join(modules),
        "PYTHONPATH": f"{site}{os.pathsep}{REPO}",
    }


def _bench(name: str, args: list, env: dict, tmp_path: Path) -> None:
    proc = Process("agents.bench", args, env, tmp_path / f"{name}.log")
    rc, log = proc.wait(START_S), proc.text()
    assert rc == 0 and "ModuleNotFoundError" not in log, (name, log)


TINY_DROQ = [f"--set={k}" for k in ("hidden=[16,16]", "critic_hidden=[16,16]", "batch_size=16")]
TINY_DROQ += ["--set=learning_starts=20", "--set=utd_ratio=1.0", "--steps", "40", "--rate", "50"]


@pytest.mark.parametrize(
    "extras, learn",
    [({"lab"}, None), ({"lab", "agents"}, ["--learn", "droq", *TINY_DROQ])],
    ids=["lab", "lab+agents"],
)
def test_the_extras_the_readme_names_are_all_the_bench_commands_need(extras, learn, tmp_path):
    """``.[lab]``: the IOC, the template, the check and the physics controller's run; ``.[lab,
    agents]``: DroQ learning on the bench (the README's bench block names these extras)."""
    for module in ("flax", "optax", "brax") if "agents" in extras else ():
        pytest.importorskip(module)  # an environment with the lab extra only runs the first case
    env = _env_with_only(extras, tmp_path)
    ioc_args = ["--prefix", PREFIX, "--stages", "3", "--mode", "hard", "--rate", "100"]
    ioc_args += ["--observe-lengths", "False"]
    ioc = Process("ops_jax.ioc", ioc_args, env, tmp_path / "ioc.log")
    mapping, out = tmp_path / "mapping.json", tmp_path / "out"
    try:
        ioc.wait_for("serving", START_S)
        if learn is None:
            args = ["--out", mapping, "--prefix", PREFIX, "--stages", "3", "--no-lengths"]
            _bench("template", ["template", *args], env, tmp_path)
            _bench("check", ["check", "--mapping", mapping], env, tmp_path)
            run = ["--mapping", mapping, "--controller", "physics", "--seconds", "3"]
        else:
            run = ["--prefix", PREFIX, "--stages", "3", "--no-lengths", *learn]
        _bench("run", [*run, "--stale-s", "5", "--out", out], env, tmp_path)
        summary = json.loads((out / "summary.json").read_text())
        assert summary.get("steps", summary.get("env_steps_total", 0)) > 0, summary
    finally:
        ioc.kill()
