"""The packages import only downwards (ops_jax <- agents <- benchmarks) and no project modules
import each other in a cycle, counting every import statement (function-local ones included) and
every module named in a string (an import made at run time, e.g.
``importlib.import_module("agents.learners.offpolicy.td3")``)."""

import ast
import importlib
from pathlib import Path


REPO = Path(__file__).resolve().parents[1]
LAYERS = {"ops_jax": 0, "agents": 1, "benchmarks": 2}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict:
    """{module: {project modules it imports}}. ``from pkg import name`` counts as an import of
    ``pkg.name`` when that is a module, else of ``pkg``; a string that is a module's full name
    counts as an import of it (made at run time); an import under ``if TYPE_CHECKING:`` is none."""
    files = {module_name(p): p for layer in LAYERS for p in (REPO / layer).rglob("*.py")}
    graph = {}
    for name, path in files.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        edges, tree = set(), ast.parse(path.read_text(), str(path))
        logger_names = {
            id(a)
            for node in ast.walk(tree)
            if isinstance(node, ast.Call)  # a logger's name: no module
            and getattr(node.func, "attr", getattr(node.func, "id", "")) == "getLogger"
            for a in node.args
        }
        typing_only = {  # imports under ``if TYPE_CHECKING:``: never made at run time
            id(n)
            for node in ast.walk(tree)
            if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING"
            for stmt in node.body
            for n in ast.walk(stmt)
        }
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                targets = [node.value] if "." in node.value and node.value in files else []
                targets = [t for t in targets if id(node) not in logger_names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([node.module] if node.module else []))
                targets = [
                    f"{base}.{a.name}" if f"{base}.{a.name}" in files else base for a in node.names
                ]
            else:
                continue
            for target in targets:
                while target and target not in files:  # `import a.b.c` of a non-module: its package
                    target = target.rpartition(".")[0]
                if target and target != name:
                    edges.add(target)
        graph[name] = edges
    return graph


def cycles(graph: dict) -> list:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_graph_sees_function_local_imports():
    graph = import_graph()
    assert "benchmarks.sweep.report" in graph["benchmarks.sweep.units"]  # imported inside Sweep.run
    assert "ops_jax.render" in graph["ops_jax.adapters.gymnasium.shared"]  # in render_scope()
    assert (
        "agents.learners.offpolicy.td3" in graph["agents.algos"]
    )  # named in the registry's table, imported at run time
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_layers_import_only_downwards():
    upward = [
        (m, t)
        for m, targets in import_graph().items()
        for t in targets
        if LAYERS[t.split(".")[0]] > LAYERS[m.split(".")[0]]
    ]
    assert upward == []


def test_no_import_cycles():
    assert cycles(import_graph()) == []


def test_every_module_imports_and_hides_no_function_of_its_package():
    """Every module of the three packages imports (none refuses, none fails for want of a
    neighbour), and no package exports a name that is also one of its modules (``agents.train`` is
    the function; the training command line is ``python -m agents``)."""
    import agents

    assert agents.train is agents.api.train
    for name in sorted(import_graph()):
        if name.endswith("__main__"):
            continue
        package = importlib.import_module(name)
        modules = (
            {p.stem for p in Path(package.__file__).parent.glob("*.py")}
            if hasattr(package, "__path__")
            else set()
        )
        for exported in set(getattr(package, "__all__", ())) & modules:
            assert isinstance(getattr(package, exported), type(package)), (
                f"{name}.{exported} hides a module"
            )


def test_agents_names_no_preset_of_the_benchmarks():
    """The benchmarks' presets live in benchmarks/ (benchmarks/sweep/presets.py,
    benchmarks/budget/presets.py): no source under agents/ quotes the name of a sweep or lab-budget
    preset that is not also an algorithm's own preset name, holds a dict keyed by two or more of the
    sweep's preset names (an algorithm's part in them), or names their former registry fields."""
    import re

    from agents.registry import REGISTRY
    from benchmarks.budget.presets import PRESETS as BUDGET
    from benchmarks.sweep.presets import PRESETS as SWEEP

    from agents import TrimConfig

    own = {name for t in [*(a.config for a in REGISTRY.values()), TrimConfig] for name in t.PRESETS}
    theirs = (set(SWEEP) | set(BUDGET)) - own
    assert {"quick", "full", "frames-residual-history"} <= theirs  # what the scan looks for
    quoted = re.compile(r"""["'`](%s)["'`]""" % "|".join(map(re.escape, sorted(theirs))))
    fields = re.compile(r"\b(SweepPresets|lab_budget|reality_budgets)\b")
    found = []
    for path in sorted((REPO / "agents").rglob("*.py")):
        text = path.read_text()
        found += [f"{path.relative_to(REPO)}: {m.group(0)}" for m in quoted.finditer(text)]
        found += [f"{path.relative_to(REPO)}: {m.group(0)}" for m in fields.finditer(text)]
        for node in ast.walk(ast.parse(text)):
            keys = {k.value for k in getattr(node, "keys", []) if isinstance(k, ast.Constant)}
            if isinstance(node, ast.Dict) and len(keys & set(SWEEP)) >= 2:
                found.append(
                    f"{path.relative_to(REPO)}:{node.lineno}: a dict keyed by {sorted(keys)}"
                )
    assert found == []
