"""Which optional extra of ops-jax installs a missing module, and the one-line message that the
project's command-line programs print instead of a traceback when it is missing (or when a Ctrl-C
reaches the top of one: ``interrupted: ...``, exit status 130)."""

from __future__ import annotations

import importlib.metadata
import os
import re
import sys

PACKAGES = ("ops_jax", "agents", "benchmarks")  # whose ``python -m`` programs get the short message
_REQUIREMENT = re.compile(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*).*?extra\s*==\s*['\"]([\w-]+)['\"]")


def install_command(extra: str) -> str:
    """The command that installs ``extra`` into a clone's environment."""
    return f'pip install -e ".[{extra}]"'


def _extras() -> list:
    """(top-level module name, extra) of every requirement of an extra of ops-jax, in pyproject
    order."""
    try:
        requirements = importlib.metadata.requires("ops-jax") or []
    except importlib.metadata.PackageNotFoundError:
        return []
    found = []
    for requirement in requirements:
        match = _REQUIREMENT.match(requirement)
        if match:
            found.append(
                (match.group(1).lower().replace("-", "_").replace(".", "_"), match.group(2))
            )
    return found


def extra_of(module: str) -> str | None:
    """The first extra (in pyproject order) whose requirements install top-level ``module``; None if
    none does."""
    return next((extra for name, extra in _extras() if name == module), None)


def modules_of(extra: str) -> list:
    """The top-level names of what ``extra`` installs itself (not through the extras it names)."""
    return [name for name, e in _extras() if e == extra and name != "ops_jax"]


def missing_module(exc: BaseException) -> str | None:
    """The top-level name of the module whose absence raised ``exc`` (or its cause); None
    otherwise."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, ModuleNotFoundError) and exc.name:
            return exc.name.split(".")[0]
        exc = exc.__cause__ or exc.__context__
    return None


def program() -> str | None:
    """``python -m NAME`` when the running program is one of this project's modules, its name when
    it is one of its commands (``ops-train``, ...: ``[project.scripts]``), else None."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    name = getattr(spec, "name", None) or ""
    if (
        not name and started_as_program()
    ):  # the package still imports: the module named on the command line
        name = sys.orig_argv[sys.orig_argv.index("-m") + 1]
    if name.split(".")[0] in PACKAGES:
        return f"python -m {name.removesuffix('.__main__')}"
    script = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    return script if spec is None and script in scripts() else None


def scripts() -> set:
    """The names of ops-jax's commands (its console scripts)."""
    try:
        points = importlib.metadata.distribution("ops-jax").entry_points
    except importlib.metadata.PackageNotFoundError:
        return set()
    return {p.name for p in points if p.group == "console_scripts"}


_previous_hook = sys.excepthook


def _excepthook(kind, exc, tb):
    prog = program()
    if prog is not None and issubclass(kind, KeyboardInterrupt):
        from ops_jax.cli.progress import exit_interrupted

        exit_interrupted(f"{prog} stopped before it finished")
    module = missing_module(exc)
    extra = extra_of(module) if module else None
    if prog is None or extra is None:
        return _previous_hook(kind, exc, tb)
    others = [m for m in modules_of(extra) if m != module]
    also = f" (with {', '.join(others)})" if others else ""
    print(
        f"{prog} needs {module}, which the {extra} extra installs{also}: {install_command(extra)}",
        file=sys.stderr,
    )


def install_excepthook() -> None:
    """Print one line naming the install command, not a traceback, when one of the project's
    programs stops on a module that an extra installs, and one line with exit status 130 when a
    Ctrl-C stops it where the program does not say what it kept (other programs keep their
    traceback)."""
    global _previous_hook
    if sys.excepthook is not _excepthook:
        _previous_hook, sys.excepthook = sys.excepthook, _excepthook
    if (
        started_as_program()
    ):  # a Ctrl-C landing in JAX's gc callback while the program imports stops it too
        from ops_jax.cli.progress import keep_ctrl_c

        keep_ctrl_c()


def started_as_program() -> bool:
    """Whether this interpreter was started as ``python -m`` one of this project's modules (known
    while the package still imports, before ``program`` can tell)."""
    argv = list(getattr(sys, "orig_argv", ()))
    return "-m" in argv[:-1] and argv[argv.index("-m") + 1].split(".")[0] in PACKAGES
