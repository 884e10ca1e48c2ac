"""The results pages' tables and commands, read from the committed files under ``results/``.

Nothing under ``results/`` is copied into the documentation by hand. Before the sources
are read, this writes Markdown copies of the result files the pages include into
``_generated/results/`` (excluded from the site's own pages, included by the pages of
``results/``):

* every ``results/**/*.md`` report (``summary.md``, ``confusion.md``, ...), its headings two
  levels down so that it sits under the including page's section, its figures pointed at the
  committed PNG files and its links to files that are no pages shown as file names;
* each section of ``results/README.md`` (``## benchmark/`` -> ``readme_benchmark.md``): the
  command that regenerates that folder and what it writes.

The pages of ``results/`` include them with MyST's ``{include}``, so a rebuilt site shows
the numbers of the files as committed.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

HEADING = re.compile(r"^(#{1,5}) ", flags=re.M)
IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")
LINK = re.compile(r"(?<!!)\[([^\]]*)\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", flags=re.M | re.S)


def _outside_fences(text: str, fn) -> str:  # noqa: ANN001
    """Apply ``fn`` to the parts of ``text`` outside fenced code blocks."""
    parts, last = [], 0
    for m in FENCE.finditer(text):
        parts += [fn(text[last : m.start()]), m.group(0)]
        last = m.end()
    parts.append(fn(text[last:]))
    return "".join(parts)


def rewrite(text: str, source: Path, page_dir: Path, shift: int = 1) -> str:
    """``text`` of the result file ``source`` as the pages in ``page_dir`` include it."""

    def fix(chunk: str) -> str:
        chunk = HEADING.sub(lambda m: "#" * (len(m.group(1)) + shift) + " ", chunk) if shift else chunk

        def image(m: re.Match) -> str:
            target = m.group(2)
            if "://" in target:
                return m.group(0)
            path = (source.parent / target).resolve()
            return f"![{m.group(1)}]({Path(os.path.relpath(path, page_dir)).as_posix()})"

        def link(m: re.Match) -> str:
            target = m.group(2)
            if "://" in target or target.startswith("#"):
                return m.group(0)
            return f"{m.group(1)} (`{Path(os.path.relpath(source.parent / target, source.parents[0])).as_posix()}`)"

        return LINK.sub(link, IMAGE.sub(image, chunk))

    return _outside_fences(text, fix)


def readme_sections(text: str) -> dict[str, str]:
    """The ``## folder/`` sections of ``results/README.md``, by folder name."""
    sections: dict[str, str] = {}
    matches = list(re.finditer(r"^## (\S+?)/?\s*$", text, flags=re.M))
    for i, m in enumerate(matches):
        end = matches[i + 1].start() if i + 1 < len(matches) else len(text)
        sections[m.group(1)] = text[m.end() : end].strip() + "\n"
    return sections


def write_results_pages(app) -> None:  # noqa: ANN001 (Sphinx application)
    src = Path(app.srcdir)
    results = src.parent / "results"
    page_dir = src / "results"
    out = src / "_generated" / "results"
    out.mkdir(parents=True, exist_ok=True)
    written = {}
    for md in sorted(results.rglob("*.md")):
        if md.name == "README.md" and md.parent == results:
            continue
        rel = md.relative_to(results)
        name = "_".join(rel.with_suffix("").parts) + ".md"
        written[name] = rewrite(md.read_text(encoding="utf-8"), md, page_dir, shift=2)
    for folder, body in readme_sections((results / "README.md").read_text(encoding="utf-8")).items():
        written[f"readme_{folder}.md"] = rewrite(body, results / "README.md", page_dir, shift=2)
    for name, text in written.items():
        path = out / name
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")


def setup(app):  # noqa: ANN001, ANN201
    app.connect("builder-inited", write_results_pages)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
