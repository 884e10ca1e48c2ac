"""How each controller holds up across plants: the nominal, mean and worst case of a
benchmark run on several plants (``drill-env benchmark --plants family`` or ``--plant``).

Per preset, regime (the design model's, at each voltage) and controller:

* *nominal*: the mean over the runs on the nominal plant;
* *mean*: the mean over plants of each plant's mean (every plant weighs the same);
* *worst*: the worst single run over all plants, voltages and seeds, with where it was.

And per voltage, the worst case over the plants (:func:`worst_by_voltage`): the worst single
run over every plant and seed at that voltage, the envelope a controller guarantees across the
family. A robust policy (``<name>_robust``) is set against its nominal-trained counterpart
(``<name>``) on it (:func:`robust_pairs`, :func:`worst_case_verdict`).

Suppression counts only runs whose plant has an open-loop cycle at that voltage and seed; a
stalled run (:func:`drill_env.agents.evaluation.episodes.is_stalled`) has its suppression scored
as a failure, min(., 0), so a disk that stops never ranks as a suppressed one.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from drill_env.agents.evaluation.plants import NOMINAL
from drill_env.agents.registry import CONTROLLERS, controller_style
from drill_env.outputs import save_figure

__all__ = [
    "COLORS",
    "METRICS",
    "ordered_controllers",
    "robustness_figure",
    "robustness_lines",
    "robustness_rows",
    "robust_pairs",
    "worst_by_voltage",
    "worst_case_lines",
    "worst_case_verdict",
]

ROBUST_SUFFIX = "_robust"

# metric column, heading, unit, whether larger is worse, scale to print
METRICS: tuple[tuple[str, str, str, bool, float], ...] = (
    ("suppression", "suppression", "-", False, 1.0),
    ("stick_fraction", "stuck", "%", True, 100.0),
    ("rms_error", "RMS speed error", "rad/s", True, 1.0),
)
REGIMES = {
    "equilibrium": "stable equilibrium",
    "limit_cycle": "Hopf cycle without stick",
    "stick_slip": "stick-slip",
}


def ordered_controllers(names) -> list[str]:
    names = set(names)
    return [c for c in CONTROLLERS if c in names] + sorted(names - set(CONTROLLERS))


def robustness_rows(df, preset: str) -> list[dict[str, Any]]:
    """One dict per (regime, controller, metric) with ``nominal``, ``mean``, ``worst``,
    ``worst_plant``, ``worst_voltage`` and ``per_plant`` (plant -> mean)."""
    ok = df[(df["error"] == "") & (df["preset"] == preset)]
    rows = []
    for regime in REGIMES:
        reg = ok[ok["regime"] == regime]
        for c in ordered_controllers(reg["controller"]):
            r = reg[reg["controller"] == c]
            for col, _, _, worse_high, _ in METRICS:
                if col == "suppression" and c == "open_loop":
                    continue  # the reference itself: 0 by definition
                vals = r[["plant", "voltage", col]].dropna()
                if vals.empty:
                    continue
                per_plant = vals.groupby("plant", sort=False)[col].mean()
                i = vals[col].idxmax() if worse_high else vals[col].idxmin()
                nominal = per_plant.get(NOMINAL, math.nan)
                rows.append(
                    {
                        "regime": regime,
                        "controller": c,
                        "metric": col,
                        "nominal": float(nominal),
                        "mean": float(per_plant.mean()),
                        "worst": float(vals.at[i, col]),
                        "worst_plant": str(vals.at[i, "plant"]),
                        "worst_voltage": float(vals.at[i, "voltage"]),
                        # every run alike: no plant to name
                        "spread": bool(vals[col].max() - vals[col].min() > 1e-9),
                        "per_plant": {str(k): float(v) for k, v in per_plant.items()},
                        "n_plants": int(per_plant.size),
                    }
                )
    return rows


def _cell(x: float, scale: float, digits: int) -> str:
    if not math.isfinite(x):
        return "-"
    t = f"{scale * x:.{digits}f}"
    return t[1:] if t.startswith("-") and float(t) == 0.0 else t


def robustness_lines(df, preset: str, plants: Mapping[str, Mapping[str, Any]] | None = None) -> list[str]:
    """The markdown section of ``summary.md`` for one preset run on several plants."""
    names = list(dict.fromkeys(df[df["preset"] == preset]["plant"]))
    lines = [
        f"## {preset}: robustness across {len(names)} plants",
        "",
        "Every controller keeps its design on the design model. Per regime of the design model:",
        "*nominal* = mean over the runs on the nominal plant, *mean* = mean over plants of each",
        "plant's mean, *worst* = the worst single run over all plants, voltages and seeds (plant,",
        "voltage). Suppression counts only runs whose plant has an open-loop cycle there "
        f"(figure: `robustness_{preset}.png`).",
        "",
    ]
    if plants:
        lines += ["| plant | what differs from the nominal model |", "|---|---|"]
        for n in names:
            info = plants.get(n) or {}
            what = info.get("description") or (
                "the preset's own model" if n == NOMINAL else f"rig `{info.get('source', n)}`"
            )
            lines.append(f"| `{n}` | {what} |")
        lines.append("")
    rows = robustness_rows(df, preset)
    for regime, title in REGIMES.items():
        reg = [r for r in rows if r["regime"] == regime]
        if not reg:
            continue
        lines += [f"### {title}", ""]
        head = ["controller"]
        for col, label, unit, _, _ in METRICS:
            if any(r["metric"] == col for r in reg):
                u = "" if unit == "-" else f" [{unit}]"
                head += [f"{label}{u}: nominal", "mean", "worst (plant, V)"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for c in ordered_controllers({r["controller"] for r in reg}):
            cells = [c]
            for col, _, _, _, scale in METRICS:
                if not any(r["metric"] == col for r in reg):
                    continue
                m = next((r for r in reg if r["controller"] == c and r["metric"] == col), None)
                if m is None:
                    cells += ["-", "-", "-"]
                    continue
                digits = 1 if scale == 100.0 else 3
                cells += [
                    _cell(m["nominal"], scale, digits),
                    _cell(m["mean"], scale, digits),
                    f"{_cell(m['worst'], scale, digits)} ({m['worst_plant']}, {m['worst_voltage']:g})"
                    if m["spread"]
                    else f"{_cell(m['worst'], scale, digits)} (every run)",
                ]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return lines + worst_case_lines(df, preset)


def worst_by_voltage(df, preset: str) -> dict[str, dict[float, tuple[float, str]]]:
    """controller -> voltage -> (the worst suppression of a single run over every plant and
    seed at that voltage, the plant of that run); runs without an open-loop cycle, whose
    suppression is undefined, are left out, and so is a voltage where no plant has a cycle."""
    ok = df[(df["error"] == "") & (df["preset"] == preset) & (df["controller"] != "open_loop")]
    ok = ok.dropna(subset=["suppression"])
    out: dict[str, dict[float, tuple[float, str]]] = {}
    for c in ordered_controllers(ok["controller"]):
        r = ok[ok["controller"] == c]
        worst = r.loc[r.groupby("voltage")["suppression"].idxmin()]
        out[c] = {
            float(v): (float(s), str(p))
            for v, s, p in zip(worst["voltage"], worst["suppression"], worst["plant"], strict=True)
        }
    return out


def robust_pairs(names) -> list[tuple[str, str]]:
    """(robust policy, its nominal-trained counterpart) for each ``<name>_robust`` whose
    ``<name>`` is among ``names``."""
    names = set(names)
    return [
        (c, c.removesuffix(ROBUST_SUFFIX))
        for c in ordered_controllers(names)
        if c.endswith(ROBUST_SUFFIX) and c.removesuffix(ROBUST_SUFFIX) in names
    ]


def worst_case_verdict(worst: Mapping[str, Mapping[float, tuple[float, str]]], robust: str, nominal: str):
    """The robust policy's worst case over the plants against the nominal-trained one's at
    each voltage both have: ``{"voltages", "at_least", "behind" (voltage -> margin < 0),
    "smallest" (margin, voltage)}``, margin = robust - nominal."""
    volts = sorted(set(worst.get(robust, {})) & set(worst.get(nominal, {})))
    margin = {v: worst[robust][v][0] - worst[nominal][v][0] for v in volts}
    smallest = min(((m, v) for v, m in margin.items()), default=(math.nan, math.nan))
    return {
        "voltages": len(volts),
        "at_least": sum(m >= 0 for m in margin.values()),
        "behind": {v: m for v, m in margin.items() if m < 0},
        "smallest": smallest,
    }


def worst_case_lines(df, preset: str) -> list[str]:
    """The markdown of the worst case over the plants at each voltage, and each robust
    policy's worst case against its nominal-trained counterpart's."""
    worst = worst_by_voltage(df, preset)
    if not worst:
        return []
    volts = sorted({v for w in worst.values() for v in w})
    lines = [
        "### worst case over the plants at each voltage",
        "",
        "The worst single run's suppression at each voltage over every plant and seed with an "
        "open-loop cycle there (stalled runs scored as failures), and after the slash the largest "
        f"RMS speed error [rad/s] of a run there, the tracking (figure: `worst_case_{preset}.png`); "
        "`(stalled)`: the worst run stalled.",
        "",
    ]
    rms = worst_rms_by_voltage(df, preset)
    stalled = _stalled_worst(df, preset, worst)
    for robust, nominal in robust_pairs(worst):
        v = worst_case_verdict(worst, robust, nominal)
        if not v["voltages"]:
            continue
        m, at = v["smallest"]
        text = (
            f"- `{robust}` against `{nominal}`: its worst case is at least `{nominal}`'s at "
            f"{v['at_least']} of {v['voltages']} voltages"
        )
        if v["behind"]:
            text += "; behind at " + ", ".join(f"{u:g} V by {-d:.4f}" for u, d in sorted(v["behind"].items()))
        else:
            text += f"; smallest margin {m:+.4f} at {at:g} V"
        lines.append(text + ".")
    if lines[-1] != "":
        lines.append("")
    lines += [
        "| controller | " + " | ".join(f"{v:g} V" for v in volts) + " |",
        "|---|" + "---|" * len(volts),
    ]
    for c, w in worst.items():
        cells = []
        for v in volts:
            if v not in w:
                cells.append("-")
                continue
            e = rms.get(c, {}).get(v, math.nan)
            cells.append(
                _cell(w[v][0], 1.0, 3)
                + (" (stalled)" if (c, v) in stalled else "")
                + f" / {_cell(e, 1.0, 3)}"
            )
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    lines.append("")
    return lines


def worst_rms_by_voltage(df, preset: str) -> dict[str, dict[float, float]]:
    """controller -> voltage -> the largest RMS speed error [rad/s] of a single run over every
    plant and seed at that voltage (the tracking beside the worst suppression)."""
    ok = df[(df["error"] == "") & (df["preset"] == preset) & (df["controller"] != "open_loop")]
    ok = ok.dropna(subset=["rms_error"])
    return {
        c: {float(v): float(e) for v, e in g.groupby("voltage")["rms_error"].max().items()}
        for c, g in ok.groupby("controller")
    }


def _stalled_worst(df, preset: str, worst) -> set[tuple[str, float]]:
    """(controller, voltage) whose worst run of :func:`worst_by_voltage` stalled."""
    if "stalled" not in df:
        return set()
    ok = df[(df["error"] == "") & (df["preset"] == preset) & df["stalled"].astype(bool)]
    out = set()
    for c, w in worst.items():
        for v, (s, plant) in w.items():
            r = ok[(ok["controller"] == c) & (ok["voltage"] == v) & (ok["plant"] == plant)]
            if len(r) and (r["suppression"] == s).any():
                out.add((c, v))
    return out


# Each controller's colour in every figure, from the registry (drill_env.agents.registry.STYLES).
COLORS = {c: controller_style(c).colour for c in CONTROLLERS}
SUPPRESSION_FLOOR = -1.0  # [-] values below are drawn at the floor
RMS_FLOOR = 1e-4  # [rad/s] log axis floor


def robustness_figure(df, preset: str, out: str | Path) -> Path:
    """``robustness_<preset>.png``: per regime (rows) and metric (columns), each controller's
    per-plant means (dots), their mean (bar), the nominal plant (diamond) and the worst run
    (cross; its plant and voltage are in the robustness table of ``summary.md``). Drawn 8 in
    wide with 9 pt text: legible at the docs' width (:mod:`drill_env._figures`)."""
    from drill_env._figures import subplots

    rows = robustness_rows(df, preset)
    regimes = [g for g in REGIMES if any(r["regime"] == g for r in rows)]
    ctrls = ordered_controllers({r["controller"] for r in rows})
    n_plants = max((r["n_plants"] for r in rows), default=0)
    font = 9.0
    fig, axes = subplots(
        len(regimes),
        len(METRICS),
        figsize=(8.0, 1.3 + len(regimes) * (1.05 + 0.24 * len(ctrls))),
        squeeze=False,
        sharey=True,
    )
    for i, regime in enumerate(regimes):
        for j, (col, label, unit, _, scale) in enumerate(METRICS):
            ax = axes[i][j]
            reg = {r["controller"]: r for r in rows if r["regime"] == regime and r["metric"] == col}
            if not reg:
                ax.text(0.5, 0.5, "no cycle to suppress", ha="center", va="center", transform=ax.transAxes)
                ax.set_yticks([])
                ax.set_xticks([])
                ax.set_title(f"{REGIMES[regime]}:\n{label}", fontsize=font)
                continue

            def shown(x: float, col: str = col, scale: float = scale) -> float:
                if col == "suppression":
                    return max(x, SUPPRESSION_FLOOR)
                if col == "rms_error":
                    return max(x, RMS_FLOOR)
                return scale * x

            for k, c in enumerate(ctrls):
                y = len(ctrls) - 1 - k
                r = reg.get(c)
                if r is None:
                    continue
                col_c = controller_style(c).colour
                vals = [shown(v) for v in r["per_plant"].values()]
                ax.plot(vals, [y] * len(vals), "o", color="0.55", ms=2.5, alpha=0.7, zorder=2)
                ax.plot([shown(r["mean"])] * 2, [y - 0.35, y + 0.35], "-", color=col_c, lw=2.0, zorder=3)
                if math.isfinite(r["nominal"]):
                    ax.plot(shown(r["nominal"]), y, "D", color=col_c, ms=4.5, mec="black", mew=0.6, zorder=4)
                if not r["spread"] or r["worst_plant"] == NOMINAL:
                    continue  # the worst run is on the nominal plant, or all alike
                ax.plot(shown(r["worst"]), y, "x", color="tab:red", ms=5, mew=1.5, zorder=5)
            ax.set_yticks(range(len(ctrls)))
            ax.set_yticklabels(ctrls[::-1], fontsize=font)
            ax.tick_params(labelsize=font)
            ax.set_ylim(-0.8, len(ctrls) - 0.4)
            u = "" if unit == "-" else f" [{unit}]"
            if col == "suppression":
                ax.set_xlim(SUPPRESSION_FLOOR - 0.05, 1.05)
                ax.axvline(1.0, color="gray", lw=0.8, ls=":")
                ax.axvline(0.0, color="gray", lw=0.8)
                xl = f"suppression{u}\n(below {SUPPRESSION_FLOOR:g} drawn at it)"
            elif col == "rms_error":
                ax.set_xscale("log")
                xl = f"RMS error of x3{u}\n(log; below {RMS_FLOOR:g} at it)"
            else:
                top = max([5.0] + [scale * r["worst"] for r in reg.values()])
                ax.set_xlim(-0.03 * top, 1.1 * top)
                xl = f"lower disk stuck{u}"
            ax.set_xlabel(xl, fontsize=font)
            ax.set_title(f"{REGIMES[regime]}:\n{label}", fontsize=font)
            ax.grid(alpha=0.3, axis="x")
    from matplotlib.lines import Line2D

    handles = [
        Line2D(
            [],
            [],
            color="0.55",
            marker="o",
            ls="none",
            ms=3,
            alpha=0.7,
            label="one plant: mean over its runs",
        ),
        Line2D([], [], color="0.2", marker="|", ls="none", ms=10, mew=2.5, label="mean over plants"),
        Line2D(
            [],
            [],
            color="0.5",
            marker="D",
            ls="none",
            ms=6,
            mec="black",
            label="nominal plant (the design model)",
        ),
        Line2D(
            [],
            [],
            color="tab:red",
            marker="x",
            ls="none",
            ms=7,
            mew=2,
            label="worst single run (not on the nominal plant; its plant and voltage: summary.md)",
        ),
    ]
    for h in handles:
        h.set_label(textwrap.fill(h.get_label(), 44, break_on_hyphens=False))
    fig.legend(handles=handles, loc="lower center", ncol=2, fontsize=font, frameon=False)
    fig.suptitle(
        f"{preset}: every controller on {n_plants} plants, designed on the nominal model\n"
        "(per regime of the nominal model; colour: controller)",
        fontsize=font + 1,
    )
    fig.tight_layout(rect=(0, 0.85 / fig.get_figheight(), 1, 1), h_pad=0.8, w_pad=0.3)
    path = Path(out) / f"robustness_{preset}.png"
    save_figure(fig, path, dpi=150)
    return path
