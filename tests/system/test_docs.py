"""Every command and snippet in README.md and docs/*.md at least starts, collected from the markdown
so that none rots: each ``python -m MODULE ...`` / ``python SCRIPT ...`` (fenced ``bash`` blocks and
inline code) parses its arguments and imports (run with ``--help`` appended), ``pip install`` names
existing extras, YAML blocks parse, and each ``python`` block runs in a fresh interpreter (with the
sizes in ``SHRINK`` made small). A few long-running commands (``STARTED``) run for real until their
first output. Skip rule: a command or snippet that stops on a module that an extra of ops-jax
installs, and that extra is not installed here, is skipped naming the extra."""

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ops_jax.cli import extras

REPO = Path(__file__).resolve().parents[2]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]  # docs/decisions/ too
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
INLINE = re.compile(r"(?<!`)`((?:python\s+(?:-m\s|examples/)|pip\s+install\s)[^`]+)`")
# Placeholders of inline commands in prose, and a value each takes here.
PLACEHOLDERS = {"ALGO": "td3", "ADDRESS": "auto", "PORT": "6379", "X": "out", "...": "out"}
# Sizes in python blocks that would take minutes, and what they become here (each must occur
# somewhere).
SHRINK = {
    "total_steps=300_000": "total_steps=5_000",
    "episodes=50": "episodes=2",
    "1024, 200)": "64, 20)",
    "total_steps=20_000": "total_steps=1_000",
}  # the last: DroQ's budget run cut to its random warm-up
# Long-running commands that run for real (in a temporary folder) until their output shows this
# text.
STARTED = {"python -m agents --algo td3 --stages 5 --mode hard --out runs/td3": " step"}
TIMEOUT_S = 240


def _where(path: Path, text: str, pos: int) -> str:
    return f"{path.relative_to(REPO)}:{text.count(chr(10), 0, pos) + 1}"


def fenced(lang: str) -> list:
    """(where, body) of every fenced block of ``lang`` in the docs."""
    out = []
    for path in DOCS:
        text = path.read_text()
        out += [
            (_where(path, text, m.start()), m.group(2))
            for m in FENCE.finditer(text)
            if m.group(1) == lang
        ]
    return out


def shell_commands() -> list:
    """(where, argv) of every simple command in bash blocks (comments dropped, ``&&`` split) and
    inline code."""
    found = []
    for where, body in fenced("bash"):
        for line in body.replace("\\\n", " ").splitlines():
            words, part = shlex.split(line, comments=True), []
            for word in [*words, "&&"]:
                if word == "&&":
                    found += [(where, part)] if part else []
                    part = []
                else:
                    part.append(word)
    for path in DOCS:
        text = path.read_text()
        for m in INLINE.finditer(text):
            argv = [PLACEHOLDERS.get(w, w) for w in shlex.split(" ".join(m.group(1).split()))]
            found.append((_where(path, text, m.start()), argv))
    return found


def python_commands() -> list:
    return [
        (where, argv)
        for where, argv in shell_commands()
        if argv[0] == "python" and argv[1:2] != ["-c"] and not argv[1:3] == ["-m", "venv"]
    ]


def _name(argv) -> str:
    return " ".join(argv)


RUNNER = r"""
import contextlib, io, json, runpy, sys
results = {}
for argv in json.loads(sys.argv[1]):
    out = io.StringIO()
    code = None
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            module = argv[1] == "-m"
            sys.argv = [argv[2] if module else argv[1], *argv[3 if module else 2:], "--help"]
            if module:
                runpy.run_module(argv[2], run_name="__main__", alter_sys=True)
            else:
                runpy.run_path(argv[1], run_name="__main__")
    except SystemExit as e:
        code = e.code or 0
    except BaseException as e:
        from ops_jax.cli.extras import missing_module
        code = "missing" if missing_module(e) else f"{type(e).__name__}: {e}"
        out = io.StringIO(missing_module(e) or out.getvalue())
    results[" ".join(argv)] = [code, out.getvalue()[:2000]]
print(json.dumps(results))
"""


@pytest.fixture(scope="module")
def help_outputs():
    """``--help`` of every documented python command, all in one fresh interpreter (imports paid
    once)."""
    argvs = sorted({_name(argv): argv for _, argv in python_commands()}.values())
    out = subprocess.run(
        [sys.executable, "-c", RUNNER, json.dumps(argvs)],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _skip_if_extra_missing(module: str) -> None:
    extra = extras.extra_of(module)
    if extra is not None:
        pytest.skip(
            f"needs {module} from the {extra} extra, not installed here: "
            f"{extras.install_command(extra)}"
        )


def _prose(path: Path) -> str:
    """The page's text without its fenced blocks (a ``#`` there is a comment, a ``](`` code)."""
    return re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)


def _anchors(path: Path) -> set:
    """The anchors GitHub gives the page's headings: lower case, punctuation dropped, spaces to
    dashes, repeats -1, -2."""
    seen, out = {}, set()
    for m in re.finditer(r"^#{1,6} (.+)$", _prose(path), re.M):
        slug = re.sub(r"[^\w\- ]", "", m.group(1).replace("`", "").strip().lower()).replace(
            " ", "-"
        )
        out.add(f"{slug}-{seen[slug]}" if slug in seen else slug)
        seen[slug] = seen.get(slug, 0) + 1
    return out


@pytest.mark.parametrize("path", DOCS, ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_and_anchor_resolves(path):
    """A link to a moved or renamed page or section: GitHub shows the page's top, or a 404."""
    broken = []
    for m in re.finditer(r"\]\(([^)\s]+)\)", _prose(path)):
        target, _, anchor = m.group(1).partition("#")
        if re.match(r"[a-z]+:", target):
            continue
        page = (path.parent / target).resolve() if target else path
        if not page.exists() or (anchor and page.suffix == ".md" and anchor not in _anchors(page)):
            broken.append(m.group(1))
    assert not broken, f"{path.relative_to(REPO)}: {broken}"


def test_the_readme_index_links_every_docs_page():
    index = (
        REPO.joinpath("README.md").read_text().split("## Documentation", 1)[1].split("\n## ", 1)[0]
    )
    pages = {p.relative_to(REPO).as_posix() for p in (REPO / "docs").glob("*.md")}
    assert pages and pages <= set(re.findall(r"\]\((docs/[\w.]+\.md)\)", index)), pages


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_every_table_has_as_many_columns_in_its_separator_as_in_its_header(path):
    """A separator row of another width than its header's: GitHub shows the table as text."""
    lines = path.read_text().splitlines()
    split = lambda line: re.split(r"(?<!\\)\|", line.strip().strip("|"))  # noqa: E731  (cells; an escaped \| inside one)
    for i, line in enumerate(lines[1:], 1):
        if re.fullmatch(r"\|(\s*:?-+:?\s*\|)+", line.strip()) and lines[i - 1].lstrip().startswith(
            "|"
        ):
            assert len(split(line)) == len(split(lines[i - 1])), (
                f"{path.name}:{i + 1}: {lines[i - 1]}"
            )


def test_the_docs_hold_the_commands_this_test_expects():
    names = {_name(argv) for _, argv in python_commands()}
    assert "python -m benchmarks.sweep" in names and "python -m pytest -q -n 2" in names
    assert set(STARTED) <= names, set(STARTED) - names
    python = "".join(body for _, body in fenced("python"))
    assert all(big in python for big in SHRINK), [big for big in SHRINK if big not in python]


@pytest.mark.parametrize(
    "where, argv", python_commands(), ids=lambda v: v if isinstance(v, str) else _name(v)
)
def test_documented_command_parses(where, argv, help_outputs):
    code, output = help_outputs[_name(argv)]
    if code == "missing":
        _skip_if_extra_missing(output)
    assert code == 0 and "usage" in output.lower(), (
        f"{where}: {_name(argv)} --help -> {code}\n{output}"
    )


@pytest.mark.parametrize(
    "where, argv",
    [(w, a) for w, a in shell_commands() if a[:2] == ["pip", "install"]],
    ids=lambda v: v if isinstance(v, str) else _name(v),
)
def test_documented_pip_install_names_existing_extras(where, argv):
    """Each requirement of the command is the project (a clone ``.`` or ``ops-jax``) with extras it
    declares, or another package's name (with extras and versions): every case asserts on every word
    it installs."""
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    declared = set(project["optional-dependencies"])
    requirements = [word for word in argv[2:] if not word.startswith("-")]
    assert requirements, f"{where}: {_name(argv)} installs nothing"
    for word in requirements:
        ours = re.fullmatch(r"(?:\.|ops-jax)(?:\[([\w,-]+)\])?(?: @ .+)?", word, re.S)
        if ours:
            extras_named = set(filter(None, (ours.group(1) or "").split(",")))
            assert extras_named <= declared, f"{where}: {word}; extras are {sorted(declared)}"
            assert project["name"] == "ops-jax"
        else:
            other = re.fullmatch(r"[A-Za-z0-9][\w.-]*(\[[\w,-]+\])?([<>=!~]=?[\w.*]+)?", word)
            assert other and not word.startswith(("ops-jax", "ops_jax", ".")), (
                f"{where}: {word!r} is no requirement"
            )


@pytest.mark.parametrize(
    "where, body", fenced("yaml"), ids=lambda v: v if isinstance(v, str) and ".md:" in v else ""
)
def test_documented_yaml_parses(where, body):
    yaml = pytest.importorskip("yaml")
    assert isinstance(yaml.safe_load(body), dict), where


@pytest.mark.parametrize(
    "where, body", fenced("python"), ids=lambda v: v if isinstance(v, str) and ".md:" in v else ""
)
def test_documented_python_block_runs(where, body, tmp_path, this_build):
    for big, small in SHRINK.items():
        body = body.replace(big, small)
    out = subprocess.run(
        [sys.executable, "-c", body],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    missing = re.search(r"ModuleNotFoundError: No module named '([\w]+)", out.stderr)
    if out.returncode and missing:
        _skip_if_extra_missing(missing.group(1))
    assert out.returncode == 0, f"{where}:\n{out.stderr[-3000:]}"


@pytest.mark.parametrize("command", sorted(STARTED))
def test_long_running_command_starts(command, tmp_path, this_build):
    """Runs for real in a temporary folder until its first progress output, then is stopped (process
    group)."""
    log = tmp_path / "output.log"
    with open(log, "w") as f:
        proc = subprocess.Popen(
            shlex.split(command),
            executable=sys.executable,
            stdout=f,
            stderr=subprocess.STDOUT,
            cwd=tmp_path,
            start_new_session=True,
            env={**os.environ, "PYTHONPATH": str(REPO), "OPS_JAX_PROGRESS_INTERVAL": "1"},
        )
    deadline = time.monotonic() + TIMEOUT_S
    try:
        while STARTED[command] not in log.read_text():
            assert proc.poll() is None, (
                f"{command} exited {proc.returncode}:\n{log.read_text()[-3000:]}"
            )
            assert time.monotonic() < deadline, (
                f"{command}: no {STARTED[command]!r} in {TIMEOUT_S} s"
            )
            time.sleep(0.2)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
