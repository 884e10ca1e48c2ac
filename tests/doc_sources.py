"""The documentation's Markdown sources the tests read: README.md and docs/**/*.md, without
what the docs build writes (``_build``, ``_generated``, the tutorials' pages and their ``runs``
folders), which may be half-written while a build runs beside the tests."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
GENERATED_DIRS = ("_build", "_generated", "tutorials")  # written by the build, not sources


def doc_sources(readme: bool = True) -> list[Path]:
    """README.md (unless ``readme`` is false), then every Markdown source under docs/, sorted."""
    files = [ROOT / "README.md"] if readme else []
    for md in sorted(DOCS.rglob("*.md")):
        rel = md.relative_to(DOCS)
        if rel.parts[0] in GENERATED_DIRS or "runs" in rel.parts:
            continue
        files.append(md)
    return files
