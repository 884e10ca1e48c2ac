"""The benchmark's rankings: the paired statistics
(:mod:`~drill_env.agents.evaluation.benchmark.statistics`) of the suppression per preset and
over both, as ``ranking.json`` (every score, interval and pair, read by the docs'
leaderboard), ``ranking.md`` (the tables) and ``ranking_<key>.png`` (each controller's
shortfall 1 - suppression on a log scale and its difference to the best with the paired
interval: the leading controllers told apart where their suppression all reads 0.99)."""

from __future__ import annotations

import json
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.agents.evaluation.benchmark.statistics import (
    PairedStatistics,
    _num,
    paired_bootstrap,
    ranking_lines,
)
from drill_env.agents.registry import controller_style
from drill_env.outputs import atomic_write_text, save_figure

__all__ = [
    "N_RESAMPLES",
    "RANKING_FILE",
    "RANKING_REPORT",
    "SCORE",
    "benchmark_rankings",
    "paired_ranking",
    "ranking_figure",
    "ranking_record",
    "ranking_summary_lines",
    "write_rankings",
]

SCORE = "suppression"
RANKING_FILE = "ranking.json"  # the paired statistics of every ranking (read by the docs' leaderboard)
RANKING_REPORT = "ranking.md"
N_RESAMPLES = 10_000
CONFIDENCE = 0.95
METHOD = "BCa"
SEED = 0
SHORTFALL_FLOOR = 1e-4  # [-] a shortfall 1 - suppression below this is drawn at it
LINEAR_BELOW = 1e-4  # [-] the difference axis is linear within +-this, logarithmic beyond
SHOWN_ABOVE = 0.01  # [-] the figure draws the controllers whose mean score is above this


def paired_ranking(rows: Any, units: Sequence[str], score: str = SCORE) -> PairedStatistics:
    """The paired statistics of ``score`` over ``units`` with the rankings' settings
    (:data:`CONFIDENCE`, :data:`N_RESAMPLES`, :data:`METHOD`, :data:`SEED`): one code path for
    the benchmark's rankings and the scenario suite's."""
    units = tuple(units)
    return paired_bootstrap(
        rows[["controller", *units, score]],
        score=score,
        units=units,
        confidence=CONFIDENCE,
        n_resamples=N_RESAMPLES,
        method=METHOD,
        seed=SEED,
    )


def benchmark_rankings(df: Any) -> list[tuple[str, str, PairedStatistics]]:
    """(key, title, statistics) of the suppression per preset (units: plant, voltage, seed)
    and, with more than one preset, over all (units: preset, plant, voltage, seed); the
    failed runs count as missing scores (their units are left out and counted)."""
    from drill_env.params import PRESETS

    out = []
    presets = [p for p in PRESETS if p in set(df["preset"])]
    cols = ["controller", "preset", "plant", "voltage", "seed", SCORE]
    rows = df[cols].copy()
    rows.loc[df["error"] != "", SCORE] = np.nan
    if rows["controller"].nunique() < 2:
        return []
    groups = [(p, f"{p}: every operating point with a cycle", rows[rows["preset"] == p]) for p in presets]
    if len(presets) > 1:
        groups.append(("all", "both presets: every operating point with a cycle", rows))
    for key, title, sub in groups:
        units = ("plant", "voltage", "seed") if key != "all" else ("preset", "plant", "voltage", "seed")
        if sub[SCORE].notna().groupby([sub[u] for u in units]).any().sum() < 2:
            continue
        out.append((key, title, paired_ranking(sub, units)))
    return out


def ranking_record(key: str, title: str, st: PairedStatistics) -> dict[str, Any]:
    """One ranking as JSON data."""
    return {
        "key": key,
        "title": title,
        **st.record(),
        "scores": json.loads(st.scores.to_json(orient="records")),
        "pairs": json.loads(st.pairs.to_json(orient="records")),
    }


BENCHMARK_SUMMARY_INTRO = (
    "Every controller ran on the same units (operating point, seed, plant), so the rankings pair "
    "them; the differences of every pair with their intervals are in `ranking.md`, the "
    "figures in `ranking_<preset>.png`."
)
BENCHMARK_REPORT_INTRO = (
    "Paired bootstrap statistics of the suppression (`agents/evaluation/benchmark/statistics.py`): "
    "the units (plant, operating point, seed) resampled jointly for all controllers; a difference is "
    "*resolved* when its interval excludes 0."
)


def ranking_summary_lines(
    rankings: Sequence[tuple[str, str, PairedStatistics]], *, intro: str = BENCHMARK_SUMMARY_INTRO
) -> list[str]:
    """The ranking section of ``summary.md``: the score table of each ranking (the pairs are
    in ``ranking.md``) under ``intro``."""
    if not rankings:
        return []
    lines = ["## Ranking (paired bootstrap)", "", intro, ""]
    for _key, title, st in rankings:
        body = ranking_lines(st, title=title)
        cut = next((i for i, line in enumerate(body) if line.startswith("Paired differences")), len(body))
        lines += body[:cut]
        n_res = int(st.pairs["resolved"].sum()) if len(st.pairs) else 0
        lines += [f"{n_res} of {len(st.pairs)} pairs resolved.", ""]
    return lines


def write_rankings(
    rankings: Sequence[tuple[str, str, PairedStatistics]],
    out: Path,
    *,
    intro: str = BENCHMARK_REPORT_INTRO,
    figures: Sequence[str] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> list[Path]:
    """``ranking.json`` (the rankings and the entries of ``extra``), ``ranking.md`` (``intro``,
    then every ranking) and ``ranking_<key>.png`` for each ranking in ``figures`` (default:
    all) in ``out``; the paths."""
    for stale in (out / RANKING_FILE, out / RANKING_REPORT, *out.glob("ranking_*.png")):
        if stale.is_file():
            stale.unlink()
    if not rankings:
        return []
    paths = [out / RANKING_FILE, out / RANKING_REPORT]
    record = {"rankings": [ranking_record(k, t, st) for k, t, st in rankings], **(extra or {})}
    atomic_write_text(paths[0], json.dumps(record, indent=2) + "\n")
    lines = ["# Controller ranking", "", intro, ""]
    for key, title, st in rankings:
        lines += ranking_lines(st, title=title, level=2)
        if figures is None or key in figures:
            lines += [f"![ranking {key}](ranking_{key}.png)", ""]
            paths.append(ranking_figure(st, title, out / f"ranking_{key}.png"))
    atomic_write_text(paths[1], "\n".join(lines) + "\n")
    return paths


MAX_DECADE_TICKS = 7  # labelled ticks of the difference axis at the most (labels clear of each other)


def _symlog_ticks(low: float, high: float) -> list[float]:
    """Ticks of the symmetric log axis from ``low`` to ``high``: 0 and the powers of ten beyond
    :data:`LINEAR_BELOW` on each side, every k-th decade so that at most
    :data:`MAX_DECADE_TICKS` are labelled."""
    e0 = int(np.floor(np.log10(LINEAR_BELOW) + 1e-9))
    pos = [10.0**e for e in range(e0, 3) if 10.0**e <= high]
    neg = [-(10.0**e) for e in range(e0, 3) if -(10.0**e) >= low]
    step = max(1, -(-(len(pos) + len(neg)) // (MAX_DECADE_TICKS - 1)))
    if step > 1:  # a crowded axis: the largest decades kept, none at +-LINEAR_BELOW beside 0
        pos, neg = pos[::-1][::step][::-1], neg[::-1][::step][::-1]
        pos, neg = [x for x in pos if x > LINEAR_BELOW * 1.5], [x for x in neg if x < -LINEAR_BELOW * 1.5]
    return sorted([0.0, *pos, *neg])


def ranking_figure(st: PairedStatistics, title: str, path: Path) -> Path:
    """Two panels, one row per controller whose mean score is above :data:`SHOWN_ABOVE` (better
    than open loop), by rank:
    (a) the shortfall 1 - mean score on a log scale with its interval, (b) the paired
    difference to the best controller with its interval (symmetric log scale, linear within
    +-:data:`LINEAR_BELOW`); resolved differences filled, unresolved ones open. The
    controllers left out are named with their score under the panels."""
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

    from drill_env._figures import subplots

    rows = st.scores.to_dict("records")
    shown = [r for r in rows if r["score"] > SHOWN_ABOVE] or rows[:1]
    left_out = [r for r in rows if r not in shown]
    k = len(shown)
    best = rows[0]["controller"]
    font = 9.0  # 8 in wide, 9 pt: legible at the docs' width (drill_env._figures)
    fig, (ax1, ax2) = subplots(1, 2, figsize=(8.0, 0.34 * k + 2.6), sharey=True)
    y = np.arange(k)[::-1]
    pairs = {(r["a"], r["b"]): r for r in st.pairs.to_dict("records")}
    widest = LINEAR_BELOW
    lowest = -LINEAR_BELOW  # the most negative end of an interval (a pair not resolved)
    shortfalls: list[float] = []
    for yi, r in zip(y, shown, strict=True):
        c = r["controller"]
        style = controller_style(c)
        short = max(1.0 - r["score"], SHORTFALL_FLOOR)
        lo = max(1.0 - r["high"], SHORTFALL_FLOOR)
        hi = max(1.0 - r["low"], SHORTFALL_FLOOR)
        shortfalls += [lo, hi]
        ax1.errorbar(
            short,
            yi,
            xerr=[[short - lo], [hi - short]],
            fmt=style.marker,
            color=style.colour,
            ms=7,
            capsize=3,
        )
        if c == best:
            ax2.plot(0.0, yi, style.marker, color=style.colour, ms=7)
            continue
        p = pairs[(best, c)]
        widest = max(widest, p["high"])
        lowest = min(lowest, p["low"])
        ax2.errorbar(
            p["difference"],
            yi,
            xerr=[[p["difference"] - p["low"]], [p["high"] - p["difference"]]],
            fmt=style.marker,
            color=style.colour,
            mfc=style.colour if p["resolved"] else "white",
            ms=7,
            capsize=3,
        )
    ax1.set_yticks(y, [f"{r['rank']}. {r['controller']}" for r in shown])
    for a in (ax1, ax2):
        a.tick_params(labelsize=font)
    ax1.set_xscale("log")
    # better to the right in both panels
    ax1.set_xlim(min(1.0, 2.0 * max(shortfalls)), max(SHORTFALL_FLOOR, min(shortfalls)) / 2.0)
    ax1.set_xlabel(f"shortfall 1 - mean {st.score} [-]\n(log; 0.99 -> 1e-2, 0.999 -> 1e-3)", fontsize=font)
    # labelled ticks as numbers (0.001): at each decade, unlabelled ones at 2 and 5 of it (labels
    # that do not overlap at the docs' width); on an axis of less than two decades at 1, 2 and 5
    lo_x, hi_x = sorted(ax1.get_xlim())
    narrow = np.log10(hi_x / lo_x) < 2.0
    every = [m * 10.0**e for e in range(-5, 1) for m in (1, 2, 5)]
    decades = [10.0**e for e in range(-5, 1)]
    ax1.xaxis.set_major_locator(FixedLocator(every if narrow else decades))
    ax1.xaxis.set_minor_locator(FixedLocator([] if narrow else [t for t in every if t not in decades]))
    ax1.xaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    ax1.xaxis.set_minor_formatter(NullFormatter())
    ax1.grid(alpha=0.3, which="both")
    ax2.axvline(0.0, color="gray", lw=0.8)
    ax2.set_xscale("symlog", linthresh=LINEAR_BELOW, linscale=0.5)
    ax2.set_xlim(2.0 * widest, 2.0 * lowest)
    ax2.xaxis.set_major_locator(FixedLocator(_symlog_ticks(2.0 * lowest, 2.0 * widest)))
    ax2.set_xlabel(
        f"{best} - controller [-]: paired difference\nof mean {st.score} (linear within +-{LINEAR_BELOW:g})",
        fontsize=font,
    )
    ax2.grid(alpha=0.3, which="both")
    handles = [
        Line2D([], [], marker="o", ls="none", color="0.3", label="resolved: interval excludes 0"),
        Line2D([], [], marker="o", ls="none", color="0.3", mfc="white", label="not resolved"),
    ]
    ax2.legend(handles=handles, fontsize=font, loc="upper left")
    pct = f"{100 * st.confidence:g} %"
    fig.suptitle(
        f"{title}:\n{st.n_units} paired units, {pct} {st.method} bootstrap intervals", fontsize=font + 1
    )
    if left_out:
        note = textwrap.fill(
            f"not drawn (mean {st.score} at most {SHOWN_ABOVE:g}, as open loop or worse): "
            + ", ".join(f"{r['controller']} {_num(r['score'])}" for r in left_out),
            100,
        )
        fig.text(0.01, 0.01, note, fontsize=font)
    n_note = len(note.splitlines()) if left_out else 0
    fig.tight_layout(rect=(0, (0.05 + 0.17 * n_note) / fig.get_figheight(), 1, 1))
    save_figure(fig, path, dpi=150)
    return path
