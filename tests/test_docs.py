"""The documentation site: its sources link to what exists, and the built site shows it.

Fast checks read the Markdown sources (``docs/**/*.md`` and ``README.md``): every internal
link and image points at a file that exists (or that the build generates from one that
does), every results report is shown by a page, and the documented columns of
``benchmark.csv`` are the committed file's. The slow check builds the site (``make docs``'s
command) and opens pages in headless Chromium: every image loaded, every internal link
points at a page or file of the site.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from urllib.parse import unquote, urlparse

import pytest
from doc_sources import doc_sources

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
BUILD = DOCS / "_build" / "html"

FENCE = re.compile(r"^```.*?^```", flags=re.M | re.S)
INLINE_CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
INCLUDE = re.compile(r"^```\{include\}\s+(\S+)", flags=re.M)


def links(text: str) -> list[str]:
    """Link and image targets of Markdown ``text``, outside code."""
    prose = INLINE_CODE.sub("", FENCE.sub("", text))
    return LINK.findall(prose)


def _results_pages_module():
    spec = importlib.util.spec_from_file_location("results_pages", DOCS / "_ext" / "results_pages.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def generated_files() -> set[str]:
    """What the build writes to ``docs/_generated/``, from the files it is made of."""
    names = {"env.md", "cli.md"}
    results = ROOT / "results"
    for md in results.rglob("*.md"):
        rel = md.relative_to(results)
        if rel != Path("README.md"):
            names.add("results/" + "_".join(rel.with_suffix("").parts) + ".md")
    readme = (results / "README.md").read_text(encoding="utf-8")
    for folder in _results_pages_module().readme_sections(readme):
        names.add(f"results/readme_{folder}.md")
    for ranking in results.rglob("ranking.json"):
        stem = "results/leaderboard_" + "_".join(ranking.parent.relative_to(results).parts)
        names.add(stem + ".md")
        if "headroom" in json.loads(ranking.read_text(encoding="utf-8")):  # a scenario suite's
            names.add(stem + "_suite.md")
    names.add("results/leaderboard_ranks.md")
    spec = importlib.util.spec_from_file_location("headlines", DOCS / "_ext" / "headlines.py")
    headlines = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(headlines)
    names |= {f"results/headline_{page}.md" for page in headlines.HEADLINES}
    return names


def _target_exists(source: Path, target: str) -> bool:
    path = (source.parent / unquote(target)).resolve()
    try:
        rel = path.relative_to(DOCS)
    except ValueError:
        return path.exists()
    if rel.parts and rel.parts[0] == "_generated":
        return Path(*rel.parts[1:]).as_posix() in generated_files()
    if rel.parts and rel.parts[0] == "tutorials" and rel.suffix in (".rst", ".html", ""):
        # a tutorial's page is built from its script
        return rel.stem == "index" or (DOCS / "tutorials_src" / f"{rel.stem}.py").is_file()
    return path.exists()


def test_the_sources_are_found():
    assert {"index.html", "reference/environment.html", "tutorials/t02_environment.html"} <= set(site_pages())
    names = {p.relative_to(ROOT).as_posix() for p in doc_sources()}
    assert {"README.md", "docs/index.md", "docs/reference/environment.md", "docs/results/history.md"} <= names


@pytest.mark.parametrize("source", doc_sources(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_internal_link_and_image_exists(source):
    text = source.read_text(encoding="utf-8")
    targets = links(text) + INCLUDE.findall(text)
    missing = []
    for target in targets:
        parsed = urlparse(target)
        if parsed.scheme or target.startswith("#"):
            continue
        if not _target_exists(source, parsed.path):
            missing.append(target)
    assert not missing, f"{source.relative_to(ROOT)}: links to nothing: {missing}"


def test_link_checker_catches_a_broken_link(tmp_path):
    page = DOCS / "howto" / "install.md"
    assert _target_exists(page, "../results/benchmark.md")
    assert not _target_exists(page, "../results/no_such_page.md")
    assert _target_exists(DOCS / "results" / "benchmark.md", "../_generated/results/benchmark_summary.md")
    assert not _target_exists(DOCS / "results" / "benchmark.md", "../_generated/results/no_such_summary.md")
    assert _target_exists(page, "../tutorials/t01_first_simulation.rst")
    assert not _target_exists(page, "../tutorials/t99_missing.rst")
    assert links("see [a](x.md) and `[b](y.md)` and ![c](z.png)\n```\n[d](w.md)\n```\n") == ["x.md", "z.png"]


def test_every_results_report_is_shown_by_a_page():
    """Nothing under results/ is lost from the site: each report is included by a page."""
    included = set()
    for md in doc_sources():
        included |= {Path(t).name for t in INCLUDE.findall(md.read_text(encoding="utf-8"))}
    reports = [
        p
        for p in (ROOT / "results").rglob("*.md")
        if p.name in ("summary.md", "confusion.md", "paper_case.md", "rig_comparison.md")
    ]
    assert len(reports) >= 12
    missing = []
    for report in reports:
        name = "_".join(report.relative_to(ROOT / "results").with_suffix("").parts) + ".md"
        if name not in included:
            missing.append(report.relative_to(ROOT).as_posix())
    assert not missing, f"results reports no page shows: {missing}"


def test_benchmark_columns_are_documented_as_the_file_has_them():
    with open(ROOT / "results" / "benchmark" / "benchmark.csv", newline="") as f:
        header = next(csv.reader(f))
    text = (DOCS / "reference" / "files.md").read_text(encoding="utf-8")
    section = text.split("## `benchmark.csv`", 1)[1].split("\n## ", 1)[0]
    documented = []
    for line in section.splitlines():
        if line.startswith("| `"):
            documented += re.findall(r"`([a-z0-9_]+)`", line.split("|")[1])
    assert documented == header


def test_the_policies_guide_names_the_environment_each_policy_was_trained_on():
    """The guide's table of the shipped policies is written by hand: each row's rig must be the
    env_id of the policy's committed config (and every shipped policy has a row)."""
    import yaml

    text = (DOCS / "guides" / "policies.md").read_text()
    rows = re.findall(r"^\| `([a-z_]+)` \| `[a-z_]+` \| [^|]*\(`([A-Za-z]+-v\d)`\) \|", text, re.M)
    shipped = sorted(p.parent.name for p in (ROOT / "results" / "agents").glob("*/config.yaml"))
    assert sorted(name for name, _ in rows) == shipped
    for name, env_id in rows:
        config = yaml.safe_load((ROOT / "results" / "agents" / name / "config.yaml").read_text())
        assert env_id == config["env_id"], name


def test_the_results_pages_show_the_regenerating_commands():
    """Each results page includes its folder's section of results/README.md (its command)."""
    sections = _results_pages_module().readme_sections((ROOT / "results" / "README.md").read_text())
    shown = set()
    for md in (DOCS / "results").glob("*.md"):
        shown |= set(re.findall(r"_generated/results/readme_(\w+)\.md", md.read_text()))
    assert set(sections) <= shown, (
        f"results/README.md sections no page shows: {sorted(set(sections) - shown)}"
    )


# Pages that are no result of one command: the policies' own cards and the variants not kept.
NOT_A_RESULTS_PAGE = {"agents", "history"}


@pytest.mark.parametrize(
    "page", sorted(p.stem for p in (DOCS / "results").glob("*.md") if p.stem not in NOT_A_RESULTS_PAGE)
)
def test_a_results_page_opens_with_a_figure_and_its_headline_table(page):
    """After the title: a figure, then the short table computed from the committed files, and
    that table renders from them (a column missing or a file moved fails here, not in the build)."""
    spec = importlib.util.spec_from_file_location("headlines", DOCS / "_ext" / "headlines.py")
    headlines = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(headlines)
    blocks = [
        b for b in (DOCS / "results" / f"{page}.md").read_text(encoding="utf-8").split("\n\n") if b.strip()
    ]
    assert blocks[0].startswith("# "), blocks[0]
    assert blocks[1].startswith("![") and "../../results/" in blocks[1], (
        f"{page}: no figure first: {blocks[1][:80]!r}"
    )
    assert blocks[2].strip() == f"```{{include}} ../_generated/results/headline_{page}.md\n```", blocks[2][
        :80
    ]
    table = headlines.HEADLINES[page](ROOT / "results")
    rows = [line for line in table.splitlines() if line.startswith("| ")]
    assert 2 <= len(rows) <= 25, f"{page}: a headline of {len(rows)} rows is no short table"


# -- the built site, in a browser ------------------------------------------------------------


def _chromium() -> tuple[str, str] | None:
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    driver = shutil.which("chromedriver")
    return (browser, driver) if browser and driver else None


@pytest.fixture(scope="module")
def built_site() -> Path:
    if os.environ.get("DRILL_ENV_DOCS_BUILT") != "1" or not (BUILD / "index.html").is_file():
        res = subprocess.run(
            [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-b", "html", "docs", str(BUILD)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=1800,
        )
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-5000:]
    return BUILD


@pytest.fixture(scope="module")
def browser():
    found = _chromium()
    if found is None:
        pytest.skip("needs chromium and chromedriver (Debian: apt-get install chromium chromium-driver)")
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = found[0]
    profile = tempfile.mkdtemp(prefix="drill-env-docs-chromium-")
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        f"--user-data-dir={profile}",
    ):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(found[1]), options=options)
    yield driver
    driver.quit()
    shutil.rmtree(profile, ignore_errors=True)


def site_pages() -> list[str]:
    """Every page the site is built from its sources: the Markdown pages and the tutorials."""
    pages = [
        md.relative_to(DOCS).with_suffix(".html").as_posix() for md in doc_sources() if md.parent != ROOT
    ]
    pages += [f"tutorials/{py.stem}.html" for py in sorted((DOCS / "tutorials_src").glob("*.py"))]
    return pages


PAGES = site_pages()


def page_problems(browser, path: Path) -> tuple[list[str], list[str], list[str]]:
    """Open ``path`` in the browser: images that did not load, internal links to nothing, and
    the sources of the images that did."""
    browser.get(path.as_uri())
    images = browser.execute_script(
        "return Array.from(document.images).map(i => [i.currentSrc || i.src, i.complete, i.naturalWidth]);"
    )
    broken = [src for src, complete, width in images if not complete or width == 0]
    hrefs = browser.execute_script(
        "return Array.from(document.querySelectorAll('a[href]')).map(a => a.href);"
    )
    dead = []
    for href in hrefs:
        url = urlparse(href)
        if url.scheme != "file":
            continue  # the site links nothing else of its own
        target = Path(unquote(url.path))
        if not target.exists():
            dead.append(href)
        elif url.fragment and target.suffix == ".html":
            if not re.search(
                rf"""id=["']{re.escape(url.fragment)}["']""", target.read_text(encoding="utf-8")
            ):
                dead.append(href)
    return broken, dead, [src for src, _, _ in images]


@pytest.mark.slow
def test_the_browser_check_finds_a_broken_image_and_link(browser, tmp_path):
    good = tmp_path / "good.html"
    good.write_text("<html><body><p id='here'>here</p></body></html>")
    page = tmp_path / "page.html"
    page.write_text(
        "<html><body><img src='missing.png'><a href='good.html#here'>ok</a>"
        "<a href='good.html#nowhere'>no anchor</a><a href='gone.html'>gone</a></body></html>"
    )
    broken, dead, _ = page_problems(browser, page)
    assert [Path(urlparse(b).path).name for b in broken] == ["missing.png"]
    assert sorted(Path(urlparse(d).path).name + "#" + urlparse(d).fragment for d in dead) == [
        "gone.html#",
        "good.html#nowhere",
    ]


@pytest.mark.slow
@pytest.mark.parametrize("page", PAGES)
def test_built_page_has_no_broken_image_or_link(built_site, browser, page):
    path = built_site / page
    assert path.is_file(), f"the build has no {page}"
    broken, dead, images = page_problems(browser, path)
    assert not broken, f"{page}: images that did not load: {broken}"
    assert not dead, f"{page}: internal links to nothing: {dead}"
    if page in ("index.html", "reference/environment.html", "results/benchmark.html"):
        assert images, f"{page} shows no image"
    if page.startswith("tutorials/") and page != "tutorials/t06_discrepancy.html":  # it draws nothing
        assert any("sphx_glr" in src for src in images), f"{page} shows no figure the tutorial drew"
    if page == "reference/environment.html":
        text = browser.find_element("tag name", "body").text
        for section in ("Action Space", "Observation Space", "Rewards", "Version History"):
            assert section in text
