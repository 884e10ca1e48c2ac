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
  benchmark and the scenario suite write): ``leaderboard_<folder>.md`` with each ranking's
  scores, intervals, ranks and differences to the leader (of a scenario suite, the suite
  score's ranking), ``leaderboard_ranks.md``, every controller's rank in every ranking side
  by side, and for a scenario suite ``leaderboard_<folder>_suite.md``: the headroom, every
  controller's rank on every scenario and which pairs of the nominal benchmark's leaders the
  suite resolves.

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


SUITE_KEY = "suite"  # the suite score's ranking in a scenario suite's ranking.json
LEADERBOARD = ("benchmark", "plant_family", "scenarios")  # the folders the leaderboard page ranks


def _shown(record: dict) -> list[dict]:
    """The rankings of ``record`` the leaderboard shows: a scenario suite's suite score only
    (its scenarios' rankings are in its rank table), every ranking of a benchmark."""
    rankings = record["rankings"]
    suite = [rk for rk in rankings if rk["key"] == SUITE_KEY]
    return suite if "headroom" in record and suite else rankings


def suite_tables(record: dict, folder: str) -> str:
    """A scenario suite's ``ranking.json`` as the leaderboard shows it: the headroom (the best
    controller on each scenario with its interval), the pairs of the nominal benchmark's leaders
    the suite resolves, and every controller's rank on every scenario."""
    lines = [
        f"Headroom (`{folder}/ranking.json`): the best controller on each scenario, its mean score "
        "with its 95 % paired interval and the room left, 1 - score.",
        "",
        "| scenario | best controller | score | 95 % interval | room left |",
        "|---|---|---|---|---|",
    ]
    for h in record.get("headroom", []):
        lines.append(
            f"| {h['scenario']} | {h['best_controller']} | {_num(h['best_score'], 3)} | "
            f"[{_num(h['low'], 3)}, {_num(h['high'], 3)}] | {_num(h['room'], 3)} |"
        )
    lead = record.get("nominal_leaders")
    if lead:
        names = ", ".join(f"{c} ({_num(v)})" for c, v in lead["controllers"].items())
        res = [q for q in lead["pairs"] if q["resolved"]]
        lines += [
            "",
            f"The nominal benchmark's leaders at {lead['threshold']:g} or more mean {lead['score']} "
            f"(`{lead['source']}`, ranking `{lead['ranking']}`): {names}. Of their {lead['n_pairs']} pairs "
            f"the suite's paired intervals resolve **{lead['resolved']}** ({lead['resolved_holm']} with Holm's "
            "correction over all the suite's pairs)"
            + (
                ": " + "; ".join(f"{q['a']} > {q['b']} by {_num(q['difference'], 3)}" for q in res)
                if res
                else ""
            )
            + ".",
        ]
    by_key = {rk["key"]: rk for rk in record["rankings"]}
    suite = by_key.get(SUITE_KEY)
    scenarios = [rk["key"] for rk in record["rankings"] if rk["key"] != SUITE_KEY]
    if suite and scenarios:
        lines += [
            "",
            "Rank on each scenario (in brackets the range its paired intervals allow; units: preset, seed).",
            "",
            "| controller | suite | " + " | ".join(scenarios) + " |",
            "|---|---|" + "---|" * len(scenarios),
        ]
        ranks = {k: {r["controller"]: r for r in by_key[k]["scores"]} for k in [SUITE_KEY, *scenarios]}
        for r in suite["scores"]:
            cells = [
                f"{ranks[k][r['controller']]['rank']} ({_span(ranks[k][r['controller']])})"
                if r["controller"] in ranks[k]
                else "-"
                for k in [SUITE_KEY, *scenarios]
            ]
            lines.append(f"| {r['controller']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def leaderboard_tables(record: dict, folder: str) -> str:
    """The leaderboard section of one ``ranking.json``: per ranking, the controllers by rank with
    their score, interval, range of ranks and paired difference to the leader."""
    lines = []
    for rk in _shown(record):
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
    columns = [(folder, rk) for folder, rec in records.items() for rk in _shown(rec)]
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
        if "headroom" in records[folder]:
            written[f"leaderboard_{folder.replace('/', '_')}_suite.md"] = suite_tables(
                records[folder], folder
            )
    # the ranks table of the leaderboard page: the rankings it shows (the other folders' are on
    # their own pages)
    written["leaderboard_ranks.md"] = leaderboard_ranks(
        {f: r for f, r in records.items() if f in LEADERBOARD}
    )
    for name, text in written.items():
        path = out / name
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")


def setup(app):  # noqa: ANN001, ANN201
    app.connect("builder-inited", write_results_pages)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
