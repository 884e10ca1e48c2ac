"""The docs teach today's environments: an out-of-date id (``DrillString-v1`` where v3 is
registered) appears only where a page tells the history -- a version-history section (its
heading says "version" or "history"), the history results page, or a table of what each
shipped policy was trained on (a header that says "trained on") -- never in a tutorial, an
example, the README or a page's running text."""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest
from doc_sources import doc_sources

ROOT = Path(__file__).resolve().parents[1]
ENV_ID = re.compile(r"\b(DrillString(?:NoBrake)?)-v(\d+)\b")
HISTORY_HEADING = re.compile(r"version|history", re.IGNORECASE)


def _latest_versions() -> dict[str, int]:
    import gymnasium

    import drill_env  # noqa: F401  (registers the environments)

    latest: dict[str, int] = {}
    for env_id in gymnasium.registry:
        m = ENV_ID.fullmatch(env_id)
        if m:
            latest[m[1]] = max(latest.get(m[1], -1), int(m[2]))
    return latest


def _out_of_date(line: str, latest: dict[str, int]) -> list[str]:
    return [m[0] for m in ENV_ID.finditer(line) if int(m[2]) < latest[m[1]]]


def _markdown_offences(path: Path, latest: dict[str, int]) -> list[str]:
    """Lines of a Markdown page naming an old id outside the places that tell the history."""
    offences = []
    heading = ""
    table_header: str | None = None
    in_code = False
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        stripped = line.strip()
        if stripped.startswith("```"):
            in_code = not in_code
        elif not in_code and stripped.startswith("#"):
            heading = stripped
        if stripped.startswith("|"):
            table_header = stripped if table_header is None else table_header
        else:
            table_header = None
        old = _out_of_date(line, latest)
        if not old:
            continue
        if HISTORY_HEADING.search(heading):
            continue
        if table_header is not None and table_header is not stripped and "trained on" in table_header:
            continue
        offences.append(f"{path.relative_to(ROOT)}:{number}: {', '.join(old)}")
    return offences


def _python_offences(path: Path, latest: dict[str, int]) -> list[str]:
    return [
        f"{path.relative_to(ROOT)}:{number}: {', '.join(old)}"
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1)
        if (old := _out_of_date(line, latest))
    ]


def test_the_registered_versions_are_found():
    latest = _latest_versions()
    assert latest["DrillString"] >= 3 and latest["DrillStringNoBrake"] == latest["DrillString"]


@pytest.mark.parametrize("page", doc_sources(), ids=lambda p: str(p.relative_to(ROOT)))
def test_a_page_names_an_old_env_version_only_in_its_history(page):
    latest = _latest_versions()
    if page.name == "history.md" and page.parent.name == "results":
        return  # the page of what was tried: it names the versions it tried
    assert _markdown_offences(page, latest) == []


def test_tutorials_examples_and_the_docs_build_use_todays_env():
    latest = _latest_versions()
    files = sorted((ROOT / "docs" / "tutorials_src").glob("*.py"))
    files += sorted((ROOT / "examples").glob("*.py")) + sorted((ROOT / "docs" / "_ext").glob("*.py"))
    offences = [o for f in files for o in _python_offences(f, latest)]
    assert offences == []


def test_the_env_docstring_names_old_versions_only_in_its_version_history():
    """The environment's reference page is generated from this docstring."""
    source = (ROOT / "drill_env" / "envs" / "drill_string.py").read_text(encoding="utf-8")
    (cls,) = [n for n in ast.parse(source).body if isinstance(n, ast.ClassDef) and n.name == "DrillStringEnv"]
    doc = ast.get_docstring(cls) or ""
    before_history, _, _ = doc.partition("## Version History")
    assert _out_of_date(before_history, _latest_versions()) == []


def test_the_rule_catches_an_old_id_in_running_text(tmp_path, monkeypatch):
    """The check itself: an old id in running text is found; in a version-history section or
    a trained-on table it is not."""
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    page = tmp_path / "page.md"
    page.write_text(
        "# Guide\n\nMake `DrillString-v1` here.\n\n"
        "| policy | env it was trained on |\n|---|---|\n| ppo | `DrillString-v2` |\n\n"
        "## Version history\n\n* v1: `DrillStringNoBrake-v1` added entries.\n",
        encoding="utf-8",
    )
    latest = {"DrillString": 3, "DrillStringNoBrake": 3}
    assert _markdown_offences(page, latest) == ["page.md:3: DrillString-v1"]
