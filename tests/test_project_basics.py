"""The project's basics: the version from the package metadata, ``python -m drill_env``,
the licence and citation files, the classifiers and the targets the Makefile promises."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from importlib.metadata import version
from pathlib import Path

import yaml
from typer.testing import CliRunner

import drill_env
from drill_env.cli import app

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def _python_m(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run(
        [sys.executable, "-m", "drill_env", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        cwd=ROOT,
    )


def test_version_is_the_package_metadata_s():
    res = CliRunner().invoke(app, ["--version"])
    assert res.exit_code == 0, res.output
    assert res.output == f"drill-env {version('drill-env')}\n"
    assert version("drill-env") == drill_env.__version__


def test_the_version_is_written_in_one_place():
    """``drill_env/__init__.py`` holds it; the build reads it from there (hatch), the
    citation and the changelog's newest release repeat it and are checked here."""
    assert "version" not in PYPROJECT["project"] and "version" in PYPROJECT["project"]["dynamic"]
    assert PYPROJECT["tool"]["hatch"]["version"]["path"] == "drill_env/__init__.py"
    init = (ROOT / "drill_env" / "__init__.py").read_text()
    assert init.count("__version__ = ") == 1
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["version"] == drill_env.__version__


def test_the_changelog_keeps_a_changelog():
    """Keep a Changelog 1.1: an Unreleased section, then each release ``## [X.Y.Z] - date``
    newest first, the newest being the package's version; each release lists each kind of
    change once; every section has its link at the end."""
    import re

    text = (ROOT / "CHANGELOG.md").read_text()
    sections = re.findall(r"^## \[([^\]]+)\](?: - (\d{4}-\d{2}-\d{2}))?$", text, flags=re.MULTILINE)
    assert sections[0] == ("Unreleased", "")
    releases = sections[1:]
    assert releases and releases[0][0] == drill_env.__version__
    assert all(date for _, date in releases)
    assert [d for _, d in releases] == sorted((d for _, d in releases), reverse=True)
    kinds = {"Added", "Changed", "Deprecated", "Removed", "Fixed", "Security", "Performance"}
    for body in re.split(r"^## ", text, flags=re.MULTILINE)[2:]:
        headings = re.findall(r"^### (.+)$", body, flags=re.MULTILINE)
        assert set(headings) <= kinds and len(headings) == len(set(headings)), headings
    for name, _ in sections:
        assert re.search(rf"^\[{re.escape(name)}\]: https://", text, flags=re.MULTILINE), name


def test_python_m_drill_env_runs_the_command_line():
    res = _python_m("--version")
    assert res.returncode == 0, res.stderr
    assert res.stdout == f"drill-env {drill_env.__version__}\n"
    res = _python_m("simulate", "--duration", "2", "--dt", "0.5", "--voltage", "1")
    assert res.returncode == 0, res.stderr
    assert "rig: brake, u = 1 V, 2 s simulated" in res.stdout
    res = _python_m("simulate", "--duration", "-1")
    assert (
        res.returncode == 2 and res.stderr.startswith("error: --duration") and "Traceback" not in res.stderr
    )
    assert "Usage: python -m drill_env" in _python_m("--help").stdout


def test_licence_and_classifiers_agree():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License\n\nCopyright (c) 2026 drill-env developers\n")
    project = PYPROJECT["project"]
    assert project["license"] == {"text": "MIT"}
    classifiers = set(project["classifiers"])
    assert {
        "License :: OSI Approved :: MIT License",
        "Operating System :: OS Independent",
        "Programming Language :: Python :: 3.11",
        "Programming Language :: Python :: 3.12",
        "Typing :: Typed",
    } <= classifiers
    assert project["requires-python"] == ">=3.11"
    assert (ROOT / "drill_env" / "py.typed").is_file()  # Typing :: Typed
    assert any(d.startswith("mypy") for d in project["optional-dependencies"]["dev"])


def test_citation_names_the_project_and_the_paper_it_models():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert cff["version"] == drill_env.__version__ and cff["license"] == "MIT"
    assert str(cff["date-released"]) and cff["repository-code"] == PYPROJECT["project"]["urls"]["Repository"]
    assert cff["authors"] == [{"name": "drill-env developers"}]
    (paper,) = cff["references"]
    assert paper["type"] == "article" and paper["doi"] == "10.1115/1.1850535"
    assert paper["year"] == 2004 and paper["volume"] == 126
    assert paper["journal"] == "Journal of Dynamic Systems, Measurement, and Control"
    assert [a["family-names"] for a in paper["authors"]] == [
        "Mihajlović",
        "van Veggel",
        "van de Wouw",
        "Nijmeijer",
    ]


def test_the_makefile_targets_do_what_they_say():
    make = (ROOT / "Makefile").read_text()
    targets = {
        line.split(":")[0] for line in make.splitlines() if line and not line[0].isspace() and ":" in line
    }
    assert {"test", "lint", "typecheck", "results", "results-quick"} <= targets
    res = subprocess.run(["make", "-s", "results"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    # every command of results/README.md, none run
    readme = (ROOT / "results" / "README.md").read_text()
    commands = [
        line
        for block in readme.split("```bash\n")[1:]
        for line in block.split("```")[0].splitlines()
        if line.startswith("drill-env ")
    ]
    assert len(commands) > 20
    for command in commands:
        assert f"  {command}\n" in res.stdout
    assert "## agents/" in res.stdout and "none is run" in res.stdout
    ci = (ROOT / ".ci" / "run").read_text()
    assert ci.index("-m pytest") < ci.index("-m mypy")
