"""The results pages' tables and commands, read from the committed files under ``results/``.

Nothing under ``results/`` is copied into the documentation by hand. Before the sources
are read, this writes Markdown copies of the result files the pages include into
``_generated/results/`` (excluded from the site's own pages, included by the pages of
``results/``):

* every ``results/**/*.md`` report (``summary.md``, ``confusion.md``, ...), its headings two
  levels down so that it sits under the including page's section, its figures pointed at the
  committed PNG files and its links to files that are no pages shown as file names;
* each section of ``results/README.md`` (``## benchmark/`` -> ``readme_benchmark.md``): the
  command that regenerates that folder and what it writes;
* the leaderboard, from every ``results/**/ranking.json`` (the paired statistics the
  benchmark writes): ``leaderboard_<folder>.md`` with each ranking's scores, intervals,
  ranks and differences to the leader, and ``leaderboard_ranks.md``, every controller's
  rank in every ranking side by side.

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


TOP_SCORE = 0.99  # the leading controllers: the leaderboard lists which of their pairs are resolved


def _num(x: float, digits: int = 4) -> str:
    t = f"{x:.{digits}f}"
    return t[1:] if t.startswith("-") and float(t) == 0.0 else t


def _span(r: dict) -> str:
    return str(r["best_rank"]) if r["best_rank"] == r["worst_rank"] else f"{r['best_rank']}-{r['worst_rank']}"


def leaderboard_tables(record: dict, folder: str) -> str:
    """The leaderboard section of one ``ranking.json``: per ranking, the controllers by rank with
    their score, interval, range of ranks and paired difference to the leader."""
    lines = []
    for rk in record["rankings"]:
        pct = f"{100 * rk['confidence']:g} %"
        lines += [
            f"### `{folder}`: {rk['title']}",
            "",
            f"Mean {rk['score']} over {rk['n_units']} paired units ({', '.join(rk['units'])}); {pct} "
            f"{rk['method']} bootstrap intervals ({rk['n_resamples']:,} joint resamples of the units).",
            "",
            f"| rank | controller | {rk['score']} | {pct} interval | ranks | leader - controller | interval | resolved |",
            "|---|---|---|---|---|---|---|---|",
        ]
        pairs = {(p["a"], p["b"]): p for p in rk["pairs"]}
        leader = rk["scores"][0]["controller"]
        for r in rk["scores"]:
            p = pairs.get((leader, r["controller"]))
            diff = (
                ("-", "-", "-")
                if p is None
                else (
                    _num(p["difference"], 5),
                    f"[{_num(p['low'], 5)}, {_num(p['high'], 5)}]",
                    "**yes**" if p["resolved"] else "no",
                )
            )
            lines.append(
                f"| {r['rank']} | {r['controller']} | {_num(r['score'])} | [{_num(r['low'])}, {_num(r['high'])}] | "
                f"{_span(r)} | " + " | ".join(diff) + " |"
            )
        n_res = sum(p["resolved"] for p in rk["pairs"])
        lines += ["", f"{n_res} of {len(rk['pairs'])} pairs resolved.", ""]
        score = {r["controller"]: r["score"] for r in rk["scores"]}
        top = [p for p in rk["pairs"] if min(score[p["a"]], score[p["b"]]) >= TOP_SCORE]
        if len(top) and rk["score"] == "suppression":
            res = [p for p in top if p["resolved"]]
            lines += [
                f"Among the controllers at {TOP_SCORE:g} or more ({sum(v >= TOP_SCORE for v in score.values())}), "
                f"{len(res)} of {len(top)} pairs are resolved"
                + (
                    ": "
                    + "; ".join(
                        f"{p['a']} > {p['b']} by {_num(p['difference'], 5)} "
                        f"[{_num(p['low'], 5)}, {_num(p['high'], 5)}]"
                        for p in res
                    )
                    if res
                    else ""
                )
                + ".",
                "",
            ]
    return "\n".join(lines)


def leaderboard_ranks(records: dict[str, dict]) -> str:
    """Every controller's rank (and the range the resolved differences allow) in every ranking."""
    columns = [(folder, rk) for folder, rec in records.items() for rk in rec["rankings"]]
    if not columns:
        return "No ranking has been committed.\n"
    names: list[str] = []
    for _, rk in columns:
        names += [r["controller"] for r in rk["scores"] if r["controller"] not in names]
    best = {
        name: min(
            (r["rank"] for _, rk in columns for r in rk["scores"] if r["controller"] == name), default=99
        )
        for name in names
    }
    names.sort(key=lambda n: (best[n], n))
    head = [f"`{folder}` {rk['key']}" for folder, rk in columns]
    lines = ["| controller | " + " | ".join(head) + " |", "|---|" + "---|" * len(columns)]
    for name in names:
        cells = []
        for _, rk in columns:
            r = next((r for r in rk["scores"] if r["controller"] == name), None)
            cells.append("-" if r is None else f"{r['rank']} ({_span(r)})")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


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
    import json

    records = {}
    for path in sorted(results.rglob("ranking.json")):
        folder = path.parent.relative_to(results).as_posix()
        records[folder] = json.loads(path.read_text(encoding="utf-8"))
        written[f"leaderboard_{folder.replace('/', '_')}.md"] = leaderboard_tables(records[folder], folder)
    written["leaderboard_ranks.md"] = leaderboard_ranks(records)
    for name, text in written.items():
        path = out / name
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")


def setup(app):  # noqa: ANN001, ANN201
    app.connect("builder-inited", write_results_pages)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
