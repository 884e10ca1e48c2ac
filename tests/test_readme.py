"""The README's and the documentation's code blocks run as printed.

Every ```python and ```bash block of README.md and of the documentation's Markdown sources
(``docs/**/*.md``) is run from the repository root, unless the line before it is
``<!-- excerpt -->`` (a fragment, or a command that regenerates a committed result and says
how long it takes). A block after ``<!-- slow -->`` runs only with ``-m slow``; the others
run in the default run and must be quick. What a block writes goes under ``runs/``
(ignored by git). ```yaml blocks are parsed.

Python blocks run in a fresh interpreter; the only change: training budgets
(``.learn(N)``) are cut to a few hundred steps, so that a block that trains shows that it
runs, not how well it learns. A bash block runs as a user runs it after the README's set-up:
whole, in a fresh ``bash -e`` at the repository root, with nothing of the installation on
``PATH`` (no virtual environment active, no ``PYTHONPATH``): a block that calls ``drill-env``
must put it there itself (``source .venv/bin/activate``), as a new shell must. The README's two fresh-machine commands (make a virtual
environment and install; run the tests) are the first lines of ``.ci/run``, which runs
them as printed; here they are checked to be there, not run inside the tests they start.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from doc_sources import doc_sources

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
BLOCK = re.compile(r"^(?:(<!--\s*(\w+)\s*-->)\n)?```(\w*)[^\n]*\n(.*?)^```", flags=re.S | re.M)
LEARN = re.compile(r"\.learn\(\s*[\d_]+\s*\)")
MARKERS = ("excerpt", "slow")
# Lines of a bash block that set up a machine or run the test suite itself: .ci/run runs them.
CI_LINE = re.compile(r"^(python3 -m venv |\.venv/bin/python -m pytest$|make (setup|test))")


@dataclass(frozen=True)
class Block:
    source: Path
    line: int
    language: str
    marker: str | None
    code: str

    @property
    def name(self) -> str:
        return f"{self.source.relative_to(ROOT).as_posix()}:{self.line}"


def blocks_of(path: Path) -> list[Block]:
    text = path.read_text(encoding="utf-8")
    found = []
    for m in BLOCK.finditer(text):
        marker = m.group(2)
        if marker is not None and marker not in MARKERS:
            raise ValueError(f"{path}: unknown marker <!-- {marker} --> (allowed: {MARKERS})")
        line = text.count("\n", 0, m.start(3)) + 1
        found.append(Block(path, line, m.group(3), marker, m.group(4)))
    return found


BLOCKS = [b for p in doc_sources() for b in blocks_of(p)]
RUNNABLE = [b for b in BLOCKS if b.language in ("python", "bash") and b.marker != "excerpt"]
README_BLOCKS = [b for b in BLOCKS if b.source.name == "README.md" and b.source.parent == ROOT]


def _params(language: str):
    return [
        pytest.param(b, id=b.name, marks=[pytest.mark.slow] if b.marker == "slow" else [])
        for b in RUNNABLE
        if b.language == language
    ]


def _needs(code: str) -> list[str]:
    """Third-party modules a block imports that are optional extras."""
    optional = ("sb3_contrib", "rl_zoo3", "ray")
    return [m for m in optional if re.search(rf"^\s*(from|import) {m}\b", code, flags=re.M)]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env.setdefault("MPLBACKEND", "Agg")
    return env


def bash_commands(code: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, comments and blank lines dropped."""
    commands, current = [], ""
    for raw in code.splitlines():
        line = raw.rstrip()
        if current:
            line = current + " " + line.lstrip()
            current = ""
        if line.endswith("\\"):
            current = line[:-1].rstrip()
            continue
        if line.strip() and not line.lstrip().startswith("#"):
            commands.append(line.strip())
    return commands


def test_the_readme_and_docs_have_runnable_blocks():
    assert len([b for b in README_BLOCKS if b.language == "python"]) >= 3
    assert all("import" in b.code for b in README_BLOCKS if b.language == "python")
    assert len(RUNNABLE) >= 8
    assert any(b.source.parent != ROOT for b in RUNNABLE), "no documentation page has a block that runs"


def test_blocks_are_parsed_with_their_markers(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("text\n\n<!-- excerpt -->\n```bash\nrm -rf /\n```\n\n```python\nimport x\n```\n")
    found = blocks_of(page)
    assert [(b.language, b.marker, b.line) for b in found] == [("bash", "excerpt", 4), ("python", None, 8)]
    assert bash_commands("a \\\n  --b c\n# note\n\nd") == ["a --b c", "d"]


def test_every_command_block_is_run_or_marked():
    """A shell or Python block in another language spelling would escape these tests."""
    loose = [b.name for b in BLOCKS if b.language in ("sh", "shell", "console", "py", "python3")]
    assert not loose, f"blocks neither run nor marked (write ```bash or ```python): {loose}"


def test_the_fresh_machine_commands_are_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text()
    ci_lines = [line.strip() for line in ci.splitlines()]
    fresh = [
        c for b in README_BLOCKS if b.language == "bash" for c in bash_commands(b.code) if CI_LINE.match(c)
    ]
    assert len(fresh) == 2, fresh
    for command in fresh:
        assert command in ci_lines, f".ci/run does not run the README's {command!r}"
    assert "-c constraints.txt" in fresh[0]


@pytest.mark.parametrize("block", _params("python"))
def test_python_block_runs_as_printed(block):
    for module in _needs(block.code):
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"needs the optional {module}")
    code = LEARN.sub(".learn(256)", block.code)
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=1200
    )
    assert res.returncode == 0, f"{block.name}:\n{code}\n{res.stderr[-3000:]}"


def _fresh_shell_env() -> dict[str, str]:
    """A new login shell's environment: this one without the virtual environment the tests run
    in (its bin folder off ``PATH``, no ``VIRTUAL_ENV``, no ``PYTHONPATH``)."""
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME")}
    ours = {Path(sys.executable).parent.resolve(), (ROOT / ".venv" / "bin").resolve()}
    path = [p for p in env.get("PATH", "").split(os.pathsep) if p and Path(p).resolve() not in ours]
    env["PATH"] = os.pathsep.join(path)
    env["MPLBACKEND"] = "Agg"
    return env


def test_a_fresh_shell_does_not_find_the_installation():
    res = subprocess.run(
        ["bash", "-c", "command -v drill-env || echo none"],
        env=_fresh_shell_env(),
        capture_output=True,
        text=True,
    )
    assert res.stdout.strip() == "none" or not res.stdout.strip().startswith(str(ROOT)), res.stdout


@pytest.mark.parametrize("block", _params("bash"))
def test_bash_block_runs_as_printed(block):
    commands = [c for c in bash_commands(block.code) if not CI_LINE.match(c)]
    if not commands:
        pytest.skip("the fresh-machine commands: .ci/run runs them")
    if not (ROOT / ".venv" / "bin" / "activate").is_file():
        pytest.skip("no .venv at the repository root: the README's set-up was not run here")
    for command in commands:
        assert "runs/" in command or "--out" not in command, f"{block.name}: writes outside runs/: {command}"
    script = "\n".join(commands)
    res = subprocess.run(
        ["bash", "-e", "-c", script],
        cwd=ROOT,
        env=_fresh_shell_env(),
        capture_output=True,
        text=True,
        timeout=3600,
    )
    assert res.returncode == 0, f"{block.name}:\n{script}\n{res.stdout[-2000:]}\n{res.stderr[-3000:]}"


@pytest.mark.parametrize("block", [b for b in BLOCKS if b.language == "yaml"], ids=lambda b: b.name)
def test_yaml_block_parses(block):
    yaml.safe_load(block.code)
