"""The scenario suite's report: ``runs.csv`` (one row per run), ``scenarios.csv`` (mean score
per controller and scenario, and the suite score), the rankings with paired statistics
(``ranking.json``, ``ranking.md``, ``ranking_suite.png``: the benchmark's code,
:mod:`~drill_env.agents.evaluation.benchmark.ranking`, on the units scenario x preset x seed),
``summary.md`` and the figures ``scores.png`` (the per-scenario table as a heat map) and
``set_point_steps_<preset>.png`` (the lower-disk speed of the leading controllers through the
set-point steps)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.agents.evaluation.scenarios import (
    REFERENCE,
    headroom,
    scenario_table,
    scenario_trajectory,
)
from drill_env.envs.scenarios import SCENARIOS
from drill_env.outputs import atomic_write_text, save_figure

__all__ = [
    "NOMINAL_TOP",
    "nominal_leaders",
    "read_nominal_ranking",
    "scores_figure",
    "set_point_figure",
    "suite_rankings",
    "write_report",
]

N_LEADERS = 3  # controllers drawn beside the open loop in the set-point figure
FIGURE_WIDTH, FIGURE_DPI, FONT = 8.0, 150, 9.0  # legible at the docs' width (drill_env._figures)
SUITE = "suite"  # the key of the suite's ranking (units: scenario, preset, seed)
SUITE_UNITS = ("scenario", "preset", "seed")
NOMINAL_TOP = 0.99  # the nominal benchmark's leaders: mean suppression at least this


def suite_rankings(runs: Any) -> list[tuple[str, str, Any]]:
    """(key, title, paired statistics) of the suite score (units: scenario, preset, seed; the
    mean over them is the suite score, every scenario having the same presets and seeds) and of
    each scenario's score (units: preset, seed), by
    :func:`~drill_env.agents.evaluation.benchmark.ranking.paired_ranking`: the benchmark's
    statistics, every controller on the same units. A failed run is in its unit at the score
    floor (never left out)."""
    from drill_env.agents.evaluation.benchmark.ranking import paired_ranking

    rows = runs[["controller", *SUITE_UNITS, "score"]]
    if rows["controller"].nunique() < 2:
        return []
    sizes = rows.groupby("scenario")[["preset", "seed"]].apply(lambda g: len(g.drop_duplicates()))
    if sizes.nunique() > 1:
        raise ValueError(
            f"runs: the scenarios have different numbers of preset x seed units ({sizes.to_dict()}); "
            "the suite score is their mean only on a balanced suite"
        )
    out = []
    if len(rows[list(SUITE_UNITS)].drop_duplicates()) >= 2:
        out.append(
            (
                SUITE,
                "scenario suite: every scenario, preset and seed",
                paired_ranking(rows, SUITE_UNITS, "score"),
            )
        )
    for name in [n for n in SCENARIOS if n in set(rows["scenario"])]:
        sub = rows[rows["scenario"] == name]
        if len(sub[["preset", "seed"]].drop_duplicates()) >= 2:
            out.append(
                (name, f"{name}: every preset and seed", paired_ranking(sub, ("preset", "seed"), "score"))
            )
    return out


def read_nominal_ranking(path: str | Path) -> dict[str, Any]:
    """The ranking of the nominal benchmark in ``path`` (its ``ranking.json``, or a folder
    holding one) that :func:`nominal_leaders` uses: the one over both presets (key ``all``),
    else the first; raises ValueError naming the file."""
    import json

    from drill_env.agents.evaluation.benchmark.ranking import RANKING_FILE

    p = Path(path)
    if p.is_dir():
        p = p / RANKING_FILE
    if not p.is_file():
        raise ValueError(f"--nominal-ranking: {str(path)!r} is no {RANKING_FILE} (nor a folder holding one)")
    try:
        record = json.loads(p.read_text(encoding="utf-8"))
        rankings = record["rankings"]
        chosen = next((r for r in rankings if r.get("key") == "all"), rankings[0])
        scores = {str(r["controller"]): float(r["score"]) for r in chosen["scores"]}
    except (OSError, UnicodeDecodeError, ValueError, KeyError, IndexError, TypeError) as exc:
        raise ValueError(
            f"--nominal-ranking: {str(p)!r} is not a benchmark's {RANKING_FILE} ({type(exc).__name__}: {exc})"
        ) from None
    return {
        "source": p.as_posix(),
        "key": str(chosen.get("key", "")),
        "score": str(chosen.get("score", "")),
        "scores": scores,
    }


def nominal_leaders(suite: Any, nominal: Mapping[str, Any], top: float = NOMINAL_TOP) -> dict[str, Any]:
    """Which pairs of the nominal benchmark's leaders (mean score at least ``top`` in
    ``nominal``, from :func:`read_nominal_ranking`) the suite's paired statistics ``suite``
    resolve: the controllers, the number of their pairs and of those resolved (per pair and
    with Holm's correction), and every pair with its difference and interval."""
    present = set(suite.scores["controller"])
    leaders = [
        c for c, v in sorted(nominal["scores"].items(), key=lambda kv: -kv[1]) if v >= top and c in present
    ]
    pairs = suite.pairs[suite.pairs["a"].isin(leaders) & suite.pairs["b"].isin(leaders)]
    return {
        "source": nominal["source"],
        "ranking": nominal["key"],
        "score": nominal["score"],
        "threshold": top,
        "controllers": {c: nominal["scores"][c] for c in leaders},
        "n_pairs": len(pairs),
        "resolved": int(pairs["resolved"].sum()),
        "resolved_holm": int(pairs["resolved_holm"].sum()),
        "pairs": [
            {k: (bool(v) if k.startswith("resolved") else v) for k, v in r.items()}
            for r in pairs[["a", "b", "difference", "low", "high", "resolved", "resolved_holm"]].to_dict(
                "records"
            )
        ],
    }


def _canvas(fig: Any) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)


def scores_figure(runs: Any, out: Path) -> Path:
    """``scores.png``: mean score per controller (rows, best suite score first) and scenario,
    each cell written to three decimals."""
    from matplotlib.figure import Figure

    table = scenario_table(runs)
    values = table.to_numpy(dtype=float)
    fig = Figure(figsize=(FIGURE_WIDTH, 0.36 * values.shape[0] + 2.0))
    _canvas(fig)
    ax = fig.add_subplot()
    im = ax.imshow(np.clip(values, -1.0, 1.0), cmap="RdYlGn", vmin=-1.0, vmax=1.0, aspect="auto")
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            v = values[i, j]
            ax.text(j, i, "-" if not np.isfinite(v) else f"{v:.3f}", ha="center", va="center", fontsize=FONT)
    # two short lines per column name ("set point\nsteps"): horizontal, clear of each other
    ax.set_xticks(range(values.shape[1]), [c.replace("_", "\n", 1).replace("_", " ") for c in table.columns])
    ax.set_yticks(range(values.shape[0]), list(table.index))
    ax.tick_params(labelsize=FONT)
    ax.set_title(
        "scenario suite: mean score over presets and seeds\n(1 = perfect, 0 = open loop)", fontsize=FONT + 1
    )
    bar = fig.colorbar(im, ax=ax, fraction=0.04, pad=0.02)
    bar.set_label("score [-]", fontsize=FONT)
    bar.ax.tick_params(labelsize=FONT)
    fig.tight_layout()
    path = out / "scores.png"
    save_figure(fig, path, dpi=FIGURE_DPI)
    return path


def set_point_figure(
    runs: Any, preset: str, out: Path, *, seed: int = 0, agents_dir: str | None = None
) -> Path | None:
    """``set_point_steps_<preset>.png``: lower-disk speed [rad/s] against time [s] through the
    set-point steps for the open loop and the :data:`N_LEADERS` best controllers by suite score,
    with the target speed; ``None`` if the runs have no set-point steps on ``preset``."""
    from matplotlib.figure import Figure

    from drill_env.agents.registry import controller_style

    sel = runs[(runs["scenario"] == "set_point_steps") & (runs["preset"] == preset)]
    if sel.empty:
        return None
    order = [c for c in scenario_table(runs).index if c != REFERENCE]
    names = [REFERENCE, *order[:N_LEADERS]]
    fig = Figure(figsize=(FIGURE_WIDTH, 4.4))
    _canvas(fig)
    ax = fig.add_subplot()
    target = None
    for name in names:
        rec = scenario_trajectory(name, "set_point_steps", preset, seed, agents_dir=agents_dir)
        st = controller_style(name)
        lw = 0.8 if name == REFERENCE else 1.3
        ax.plot(rec["t_fast"], rec["lower_speed"], color=st.colour, lw=lw, label=name)
        target = rec
    assert target is not None
    ax.step(target["t"], target["target"], where="pre", color="black", ls="--", lw=1.0, label="target speed")
    ax.set_xlabel("time since switch-on [s]", fontsize=FONT)
    ax.set_ylabel("lower-disk speed x3 [rad/s]", fontsize=FONT)
    ax.tick_params(labelsize=FONT)
    volts = " -> ".join(f"{v:g} V" for v in SCENARIOS["set_point_steps"].set_point_voltages(preset))
    ax.set_title(f"set-point steps, {preset} ({volts}), seed {seed}", fontsize=FONT + 1)
    ax.legend(loc="upper left", fontsize=FONT)
    fig.tight_layout()
    path = out / f"set_point_steps_{preset}.png"
    save_figure(fig, path, dpi=FIGURE_DPI)
    return path


def _markdown(table: Any, digits: int = 3) -> str:
    cols = [str(c) for c in table.columns]
    lines = ["| controller | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for name, row in table.iterrows():
        cells = ["-" if not np.isfinite(v) else f"{v:.{digits}f}" for v in row.to_numpy(dtype=float)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def headroom_records(runs: Any, rankings: Sequence[tuple[str, str, Any]] = ()) -> list[dict[str, Any]]:
    """Per scenario: the best controller (open loop left out), its mean score, the upper end of
    its interval in the scenario's ranking (if ranked) and the room left, 1 - score."""
    intervals = {
        key: {r["controller"]: (r["low"], r["high"]) for r in st.scores.to_dict("records")}
        for key, _title, st in rankings
    }
    out = []
    for name, r in headroom(runs).iterrows():
        low, high = intervals.get(str(name), {}).get(r.best_controller, (float("nan"), float("nan")))
        out.append(
            {
                "scenario": str(name),
                "best_controller": str(r.best_controller),
                "best_score": float(r.best_score),
                "low": float(low),
                "high": float(high),
                "room": 1.0 - float(r.best_score),
            }
        )
    return out


def _span(r: Mapping[str, Any]) -> str:
    b, w = int(r["best_rank"]), int(r["worst_rank"])
    return f"{b}" if b == w else f"{b}-{w}"


def _ranking_lines(rankings: Sequence[tuple[str, str, Any]], leaders: Mapping[str, Any] | None) -> list[str]:
    """The summary's ranking sections: the suite score with its interval and range of ranks, the
    rank of every controller on every scenario, and the nominal leaders' pairs."""
    by_key = {key: st for key, _title, st in rankings}
    suite = by_key.get(SUITE)
    if suite is None:
        return []
    pct = f"{100 * suite.confidence:g} %"
    n_res, n_holm = int(suite.pairs["resolved"].sum()), int(suite.pairs["resolved_holm"].sum())
    lines = [
        "## Suite score with paired intervals",
        "",
        f"Mean score over the {suite.n_units} paired units (scenario, preset, seed; every controller on "
        f"the same ones), {pct} {suite.method} bootstrap intervals from {suite.n_resamples:,} joint resamples "
        "of the units (`agents/evaluation/benchmark/statistics.py`, the benchmark's ranking code); *ranks*: "
        f"the range the resolved differences allow. {n_res} of {len(suite.pairs)} pairs resolved, {n_holm} "
        "with Holm's correction; every pair in `ranking.md`, as data in `ranking.json`.",
        "",
        f"| rank | controller | suite score | {pct} interval | ranks |",
        "|---|---|---|---|---|",
    ]
    for r in suite.scores.to_dict("records"):
        lines.append(
            f"| {r['rank']} | {r['controller']} | {r['score']:.3f} | [{r['low']:.3f}, {r['high']:.3f}] | {_span(r)} |"
        )
    scen = [k for k in SCENARIOS if k in by_key]
    if scen:
        lines += [
            "",
            "## Rank on each scenario",
            "",
            "Rank by the scenario's mean score (in brackets the range of ranks its paired intervals allow; "
            "units: preset, seed).",
            "",
            "| controller | " + " | ".join(scen) + " |",
            "|---" * (len(scen) + 1) + "|",
        ]
        ranks = {k: {r["controller"]: r for r in by_key[k].scores.to_dict("records")} for k in scen}
        for name in suite.scores["controller"]:
            cells = [
                f"{ranks[k][name]['rank']} ({_span(ranks[k][name])})" if name in ranks[k] else "-"
                for k in scen
            ]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    if leaders is not None:
        names = ", ".join(f"{c} ({v:.4f})" for c, v in leaders["controllers"].items())
        lines += [
            "",
            "## The nominal benchmark's leaders told apart",
            "",
            f"The controllers at {leaders['threshold']:g} or more mean {leaders['score']} in the nominal benchmark "
            f"(`{leaders['source']}`, ranking `{leaders['ranking']}`): {names or 'none'}. Of their "
            f"{leaders['n_pairs']} pairs the suite's paired intervals resolve **{leaders['resolved']}** "
            f"({leaders['resolved_holm']} with Holm's correction over all the suite's pairs).",
            "",
        ]
        if leaders["pairs"]:
            lines += [
                "| a | b | a - b | interval | resolved | resolved (Holm) |",
                "|---|---|---|---|---|---|",
            ]
            for q in leaders["pairs"]:
                lines.append(
                    f"| {q['a']} | {q['b']} | {q['difference']:.4f} | [{q['low']:.4f}, {q['high']:.4f}] | "
                    f"{'**yes**' if q['resolved'] else 'no'} | {'yes' if q['resolved_holm'] else 'no'} |"
                )
    lines.append("")
    return lines


def summary_text(
    runs: Any,
    meta: Mapping[str, Any],
    rankings: Sequence[tuple[str, str, Any]] = (),
    leaders: Mapping[str, Any] | None = None,
) -> str:
    """``summary.md``: what ran, the per-scenario table, the ranking with paired intervals, the
    headroom, the nominal leaders' pairs and the effort."""
    table = scenario_table(runs)
    head = headroom_records(runs, rankings)
    failed = runs[runs["error"].fillna("") != ""]
    effort = (
        runs[runs["scenario"] == "effort"]
        .groupby("controller")[["energy_ratio", "u_rms", "u_peak_abs", "du_dt_peak", "du_dt_rms"]]
        .mean()
    )
    effort = effort.loc[[c for c in table.index if c in effort.index]]
    lines = [
        "# Scenario suite",
        "",
        f"Command: `{meta.get('command', '')}`",
        "",
        f"Controllers {len(table)}, scenarios {runs['scenario'].nunique()}, presets "
        f"{', '.join(sorted(runs['preset'].unique()))}, seeds {runs['seed'].nunique()}: {len(runs)} runs "
        f"in {meta.get('wall_time_s', float('nan')):.0f} s wall time on {meta.get('workers', 1)} worker(s) "
        f"({runs['wall_time'].sum():.0f} s of run time); code version {meta.get('version', '?')}.",
        "",
        "Score per run: `max(-1, 1 - IAE / IAE_open_loop)` (the `effort` scenario times "
        "`min(1, E_ref / E)`); a controller's scenario score is the mean over presets and seeds, "
        "its suite score the mean of its scenario scores (see `docs/explanation/scenarios.md`).",
        "",
        "## Mean score per scenario (best suite score first)",
        "",
        _markdown(table),
        "",
        "## Headroom: the best controller on each scenario (open loop left out)",
        "",
        f"The best score is below 1 on {sum(h['best_score'] < 1 for h in head)} of {len(head)} scenarios, "
        f"the upper end of its interval below 0.99 on {sum(h['high'] < 0.99 for h in head)}.",
        "",
        "| scenario | best controller | best score | 95 % interval | room left (1 - score) |",
        "|---|---|---|---|---|",
        *[
            f"| {h['scenario']} | {h['best_controller']} | {h['best_score']:.3f} | "
            f"[{h['low']:.3f}, {h['high']:.3f}] | {h['room']:.3f} |"
            for h in head
        ],
        "",
        *_ranking_lines(rankings, leaders),
        "## Effort on the `effort` scenario (means over presets and seeds)",
        "",
        "energy_ratio: the motor's work over the equilibrium's; u_rms [V]; u_peak_abs [V]; "
        "du_dt_peak, du_dt_rms [V/s]",
        "",
        _markdown(effort, 2) if not effort.empty else "(not run)",
        "",
    ]
    if not failed.empty:
        lines += [
            "## Failed runs (scored -1)",
            "",
            *[
                f"- {r.controller} {r.scenario} {r.preset} seed {r.seed}: {r.error}"
                for r in failed.itertuples()
            ],
            "",
        ]
    return "\n".join(lines)


RANKING_INTRO = (
    "Paired bootstrap statistics of the scenario suite's scores (`agents/evaluation/benchmark/statistics.py`, "
    "the benchmark's ranking code): the suite's units (scenario, preset, seed) and each scenario's "
    "(preset, seed) resampled jointly for all controllers; a difference is *resolved* when its interval "
    "excludes 0."
)


def write_report(
    runs: Any,
    out: Path,
    meta: Mapping[str, Any],
    *,
    presets: Sequence[str],
    agents_dir: str | None = None,
    nominal: Mapping[str, Any] | None = None,
) -> list[Path]:
    """Write the CSVs, the rankings, ``summary.md`` and the figures into ``out``; returns the
    paths. ``nominal``: the nominal benchmark's ranking (:func:`read_nominal_ranking`), whose
    leaders' pairs the summary counts."""
    from drill_env.agents.evaluation.benchmark.ranking import write_rankings

    out.mkdir(parents=True, exist_ok=True)
    rankings = suite_rankings(runs)
    suite = next((st for key, _t, st in rankings if key == SUITE), None)
    leaders = nominal_leaders(suite, nominal) if nominal is not None and suite is not None else None
    paths = [out / "runs.csv", out / "scenarios.csv", out / "summary.md"]
    atomic_write_text(paths[0], runs.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(paths[1], scenario_table(runs).to_csv(float_format="%.6g"))
    atomic_write_text(paths[2], summary_text(runs, meta, rankings, leaders))
    extra: dict[str, Any] = {"headroom": headroom_records(runs, rankings)}
    if leaders is not None:
        extra["nominal_leaders"] = leaders
    paths += write_rankings(rankings, out, intro=RANKING_INTRO, figures=(SUITE,), extra=extra)
    paths.append(scores_figure(runs, out))
    for preset in presets:
        p = set_point_figure(runs, preset, out, agents_dir=agents_dir)
        if p is not None:
            paths.append(p)
    return paths
