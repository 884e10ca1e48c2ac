"""The benchmark report: ``summary.md`` (a table per preset, plant and regime, and the
suppression at every voltage) and the figures, from ``benchmark.csv``."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from drill_env.agents.evaluation.benchmark.figures import _figures, _plants_figure, worst_case_figure
from drill_env.agents.evaluation.benchmark.ranking import (
    RANKING_FILE as RANKING_FILE,
)
from drill_env.agents.evaluation.benchmark.ranking import (
    benchmark_rankings,
    ranking_summary_lines,
    write_rankings,
)
from drill_env.agents.evaluation.benchmark.runs import NOT_MADE, OPEN_LOOP_FLOOR
from drill_env.agents.evaluation.benchmark.store import load_results
from drill_env.agents.evaluation.episodes import IDENTIFIED_SPEED, STALL_SPEED_ERROR, STALL_STUCK_FRACTION
from drill_env.agents.evaluation.plants import NOMINAL
from drill_env.agents.evaluation.robustness import (
    REGIMES,
    ordered_controllers,
    robustness_figure,
    robustness_lines,
)
from drill_env.outputs import atomic_write_text
from drill_env.params import PRESETS

REGIME_TITLES = REGIMES  # regime -> the title of its table
# up to this many plants besides the nominal one get a suppression figure each; more are
# drawn as small multiples in one figure
SEPARATE_PLANT_FIGURES = 3
# the figures write_report makes (removed with the results by ``fresh``)
REPORT_FIGURES = (
    "ranking.md",
    "ranking_*.png",
    "bifurcation_*.png",
    "suppression_*.png",
    "robustness_*.png",
    "worst_case_*.png",
    "timeseries_*.png",
)


def _num(x: float, digits: int = 3) -> str:
    """Fixed-point text without a minus sign on a rounded zero."""
    t = f"{x:.{digits}f}"
    return t[1:] if t.startswith("-") and float(t) == 0.0 else t


def _plant_heading(preset: str, plant: str, info: Mapping[str, Any] | None) -> list[str]:
    if plant == NOMINAL:
        return [
            f"## {preset}, plant `{NOMINAL}`",
            "",
            "The preset's own model; open-loop reference: the bifurcation analysis where it is "
            "also the design model, else the open-loop run on it at the same voltage and seed.",
            "",
        ]
    info = info or {}
    effects = ", ".join(info.get("effects") or []) or "none"
    what = (
        f"The nominal `{preset}` model with {info['description']}"
        if info.get("description")
        else f"Rig `{info.get('source', plant)}`"
    )
    lines = [
        f"## {preset}, plant `{plant}`",
        "",
        f"{what} (effects: {effects}). The controllers keep their design on "
        "the design model, and the target speed and the regimes are the design model's; "
        "open-loop reference: the open-loop run on this plant at the same voltage and seed (no "
        f"cycle below {OPEN_LOOP_FLOOR:g} rad/s: suppression `-`), whose regime is the CSV's "
        "`plant_open_loop_regime`.",
        "",
    ]
    family = info.get("family")
    if family and family != preset:
        lines += [
            f"**Note:** this plant's lower-disk friction is closer to the `{family}` preset than to "
            f"`{preset}`, whose controllers run on it here.",
            "",
        ]
    return lines


def summary_tables(
    df,
    notes: Mapping[str, str] | None = None,
    plants: Mapping[str, Mapping[str, Any]] | None = None,
    starts: Mapping[str, str] | None = None,
    design: str | None = None,
    design_regimes: str | None = None,
) -> str:
    """The markdown of ``summary.md`` from the results DataFrame; ``notes``: the policy each
    learned controller ran per preset (``"<controller>/<preset>"`` -> ``"path on ENV-ID"``),
    ``starts``: how each started (same keys); ``design``: the design model's file when the
    controllers were built on one other than the preset's, ``design_regimes`` its regimes in
    one line (:func:`~drill_env.agents.evaluation.benchmark.grid.describe_regimes`)."""
    lines = [
        "# Controller benchmark",
        "",
        "Every controller at every operating point (nominal voltage u) and seed, switched on at a",
        "random phase of the open-loop behaviour after an open-loop warm-up; metrics of the lower-disk",
        "speed x3 over the last window of the episode, from the true state (see `agents/evaluation/episodes.py`).",
        "Suppression = 1 - amplitude / open-loop amplitude predicted by the bifurcation analysis",
        "(1: cycle removed, 0: as open loop, < 0: worse); it is defined only where the analysis",
        "predicts a cycle. Means over the runs of a regime, worst case in brackets; peak |u| is the",
        "largest over the runs. |u| and the time at the 5 V limit are over the whole closed-loop",
        "episode.",
        "",
        "Terms: *amplitude* = max - min of x3 over the window [rad/s]; *open-loop amplitude* = the",
        "same on the limit cycle the analysis predicts at u (0: a stable equilibrium); *stuck* = time",
        "fraction with the lower disk stuck; *severity* = (max - min) / (2 mean) of x3, the usual",
        "stick-slip severity (1 or more: the bit stops in each cycle); *RMS error* = RMS of x3 - w*,",
        "w* the target speed. The brake's friction model was identified up to 12.6 rad/s only",
        "(Sec. 4 of the paper): *beyond 12.6 rad/s* counts the runs whose |x3| exceeded that at any",
        "time of the closed-loop episode (CSV: `beyond_identified_range`, `x3_peak_abs`); their",
        "figures are outside what the model vouches for.",
        "",
        "*Stalled* runs failed to turn the lower disk at the target: stuck over more than "
        f"{100 * STALL_STUCK_FRACTION:g} % of the window, or the mean speed off the target by more "
        f"than {100 * STALL_SPEED_ERROR:g} % of it (CSV: `stalled`). A stopped disk has no cycle left, so "
        "its raw suppression is near 1; a stalled run is scored as a failure: its suppression is "
        "min(1 - amplitude / open-loop amplitude, 0), no better than the open loop, in every table.",
        "",
    ]
    if design:
        lines += [
            f"Design model: `{design}` (every controller built on it; target speeds and regimes are its own).",
            "",
        ]
        if design_regimes:
            lines += [f"Regimes of the design model (its own analysis): {design_regimes}.", ""]
    ok = df[df["error"] == ""]
    failed = df[df["error"] != ""]
    only_nominal = set(df["plant"]) <= {NOMINAL}
    sections = [
        (preset, plant)
        for preset in PRESETS
        if preset in set(df["preset"])
        for plant in _plants_in(df[df["preset"] == preset])
    ]
    for preset, plant in sections:
        sub = ok[(ok["preset"] == preset) & (ok["plant"] == plant)]
        names = _plants_in(df[df["preset"] == preset])
        if plant == names[0] and len(names) > 1:
            lines += robustness_lines(df, preset, plants)
        if only_nominal:
            lines += [f"## {preset}", ""]
        else:
            lines += _plant_heading(preset, plant, (plants or {}).get(plant))
        used = {k.split("/")[0]: v for k, v in (notes or {}).items() if k.endswith(f"/{preset}")}
        if used:
            lines.append(
                "Learned policies: "
                + "; ".join(
                    f"{c}: {_policy_note(v, (starts or {}).get(f'{c}/{preset}'))}" for c, v in used.items()
                )
                + "."
            )
            lines.append("")
        for regime, title in REGIME_TITLES.items():
            reg = sub[sub["regime"] == regime]
            if reg.empty:
                continue
            volts = sorted(set(reg["voltage"]))
            vtxt = ", ".join(f"{v:g}" for v in volts)
            lines.append(f"### {title} ({vtxt} V; {reg['seed'].nunique()} seed(s))")
            lines.append("")
            lines.append(
                "| controller | suppression | amplitude [rad/s] | open-loop amplitude [rad/s] | stuck [%] | "
                "severity | RMS error [rad/s] | mean \\|u\\| [V] | peak \\|u\\| [V] | at 5 V limit [%] | runs | "
                "stalled [runs] |"
                + (
                    f" beyond {IDENTIFIED_SPEED[preset]:g} rad/s [runs] |"
                    if preset in IDENTIFIED_SPEED
                    else ""
                )
            )
            lines.append(
                "|---|---|---|---|---|---|---|---|---|---|---|---|"
                + ("---|" if preset in IDENTIFIED_SPEED else "")
            )
            for c in ordered_controllers(reg["controller"]):
                r = reg[reg["controller"] == c]
                sup = r["suppression"].dropna()
                sup_txt = f"{_num(sup.mean())} ({_num(sup.min())})" if len(sup) else "-"
                cells = [
                    c,
                    sup_txt,
                    f"{_num(r['amplitude'].mean())} ({_num(r['amplitude'].max())})",
                    _num(r["open_loop_amplitude"].mean()),
                    f"{_num(100 * r['stick_fraction'].mean(), 1)} ({_num(100 * r['stick_fraction'].max(), 1)})",
                    _num(r["severity"].mean()),
                    f"{_num(r['rms_error'].mean())} ({_num(r['rms_error'].max())})",
                    _num(r["u_mean_abs"].mean(), 2),
                    _num(r["u_peak_abs"].max(), 2),
                    _num(100 * r["u_limit_fraction"].mean(), 1),
                    str(len(r)),
                    f"**{int(r['stalled'].sum())}**" if r["stalled"].any() else "0",
                ]
                if preset in IDENTIFIED_SPEED:
                    n_out = int(r["beyond_identified_range"].sum())
                    cells.append(f"**{n_out}**" if n_out else "0")
                lines.append("| " + " | ".join(cells) + " |")
            lines.append("")
        # suppression at every voltage
        cyc = sub[sub["open_loop_amplitude"] > 0]
        if not cyc.empty:
            volts = sorted(set(cyc["voltage"]))
            lines.append("### suppression at each voltage (mean over seeds)")
            lines.append("")
            lines.append("| controller | " + " | ".join(f"{v:g} V" for v in volts) + " |")
            lines.append("|---|" + "---|" * len(volts))
            for c in ordered_controllers(cyc["controller"]):
                r = cyc[cyc["controller"] == c]
                cells = []
                for v in volts:
                    s = r[r["voltage"] == v]["suppression"]
                    cells.append(_num(s.mean(), 2) if len(s) else "-")
                lines.append(f"| {c} | " + " | ".join(cells) + " |")
            lines.append("")
    not_made = failed["error"].astype(str).str.startswith(NOT_MADE)
    for title, rows in (("runs not made", failed[not_made]), ("runs that failed", failed[~not_made])):
        if rows.empty:
            continue
        lines.append(f"## {title}")
        lines.append("")
        for r in rows.to_dict("records"):
            on = "" if r["plant"] == NOMINAL else f" (plant {r['plant']})"
            error = r["error"][len(NOT_MADE) :] if r["error"].startswith(NOT_MADE) else r["error"]
            lines.append(
                f"- {r['controller']} {r['preset']}{on} {r['voltage']:g} V seed {int(r['seed'])}: {error}"
            )
        lines.append("")
    return "\n".join(lines)


def write_report(csv_path: str | Path, out_dir: str | Path) -> list[Path]:
    """``summary.md`` and the figures from a benchmark CSV."""
    df = load_results(csv_path)
    out = Path(out_dir)
    notes = starts = None
    design = regimes = None
    plants: dict[str, dict[str, Any]] = {}
    cfg_path = Path(csv_path).parent / "benchmark_config.json"
    if cfg_path.is_file():
        rec = json.loads(cfg_path.read_text())
        notes = rec.get("policies")
        starts = rec.get("policy_starts")
        plants = {p["name"]: p for p in rec.get("plant_notes", [])}
        design = (rec.get("design_model") or {}).get("source")
        regimes = rec.get("design_regimes")
    paths = [out / "summary.md"]
    rankings = benchmark_rankings(df)
    summary = summary_tables(df, notes, plants, starts, design, regimes)
    summary += "\n" + "\n".join(ranking_summary_lines(rankings))
    atomic_write_text(paths[0], summary + "\n")
    paths += write_rankings(rankings, out)
    for preset in [p for p in PRESETS if p in set(df["preset"])]:
        names = _plants_in(df[df["preset"] == preset])
        others = [q for q in names if q != NOMINAL]
        many = len(others) > SEPARATE_PLANT_FIGURES
        for plant in names if not many else [q for q in names if q == NOMINAL]:
            sel = (df["preset"] == preset) & (df["plant"] == plant) & (df["error"] == "")
            paths += _figures(df[sel], preset, out, plant)
        if many:
            paths.append(_plants_figure(df, preset, out, others))
        if len(names) > 1:
            paths.append(robustness_figure(df, preset, out))
            worst = worst_case_figure(df, preset, out)
            paths += [worst] if worst else []
    return paths


def _plants_in(df) -> list[str]:
    """The plants of a results frame, the nominal one first, then in order of appearance."""
    names = list(dict.fromkeys(df["plant"]))
    return sorted(names, key=lambda n: n != NOMINAL)


def _policy_note(text: str, start: str | None = None) -> str:
    """``path on ENV-ID`` -> ```path``` on ``ENV-ID`` (markdown), with how it started."""
    path, _, env_id = text.partition(" on ")
    note = f"`{path}` on `{env_id}`" if env_id else f"`{path}`"
    return f"{note} ({start})" if start else note
