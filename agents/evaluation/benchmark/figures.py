"""The benchmark figures: each controller's steady min/max of x3 on the bifurcation diagram
(``bifurcation_<preset>.png``) and its suppression of the open-loop cycle
(``suppression_<preset>.png``), per plant or as small multiples."""

from __future__ import annotations

import functools
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from drill_env.agents.evaluation.episodes import EpisodeSettings
from drill_env.agents.evaluation.plants import NOMINAL
from drill_env.agents.evaluation.robustness import REGIMES, ordered_controllers
from drill_env.agents.registry import CONTROLLERS, controller_style
from drill_env.outputs import save_figure

Y_FLOOR = -2.0  # suppression below this is drawn at the floor with its value written
# Each controller's marker in every figure, from the registry (drill_env.agents.registry.STYLES).
_MARKERS = {c: controller_style(c).marker for c in CONTROLLERS}


def _figures(df, preset: str, out: Path, plant: str = NOMINAL) -> list[Path]:
    """The bifurcation figure (nominal plant only: the analysis is of the nominal model) and
    the suppression figure of one preset and plant."""

    if df.empty:
        return []
    ctrls = ordered_controllers(df["controller"])
    if plant != NOMINAL:
        return _suppression_figure(df, preset, out, plant, ctrls)
    return [bifurcation_figure(df, preset, out)] + _suppression_figure(df, preset, out, plant, ctrls)


def bifurcation_figure(df, preset: str, out: Path) -> Path:
    """``bifurcation_<preset>.png``: a grid of panels, one per controller, each with the
    nominal model's bifurcation diagram (faded) and, at its exact voltage, every run's steady
    min and max of x3 joined by a bar. Runs beyond the common scale end in a triangle at the
    panel's edge; their range is written under the panel's title. Legible at the docs' width
    (:data:`drill_env._figures.MAX_WIDTH_IN`)."""

    fig = draw_bifurcation_figure(df, preset)
    p = out / f"bifurcation_{preset}.png"
    save_figure(fig, p, dpi=FIGURE_DPI)
    return p


FIGURE_WIDTH = 8.0  # [in] the benchmark's figures, drawn 724 px wide in the docs
FIGURE_DPI = 150
FONT = 9.0  # [pt] the smallest text of the benchmark's figures (8.5 pt as shown in the docs)
GRID_COLUMNS = 4
LEGEND_WRAP = 30  # [characters] per line of a legend entry in the grid figures


def _grid(n: int, ncol: int = GRID_COLUMNS) -> tuple[int, int, int]:
    """Rows and columns of a grid of ``n`` panels and the empty slots left in its last row."""
    nrow = -(-n // ncol)
    return nrow, ncol, nrow * ncol - n


def draw_bifurcation_figure(df, preset: str, diagram=None):
    """The figure of :func:`bifurcation_figure` (``diagram``: the nominal model's to 5 V,
    computed if not given); returns the matplotlib figure."""
    from matplotlib.lines import Line2D

    from drill_env._figures import subplots
    from drill_env.analysis import bifurcation_diagram
    from drill_env.analysis.plots import plot_bifurcation

    ctrls = ordered_controllers(df["controller"])
    diagram = diagram if diagram is not None else bifurcation_diagram(preset, u_max=5.0)
    tops = [float(np.max([c.x3_max for c in seg.cycles])) for seg in diagram.periodic_segments]
    tops += [float(np.max(b.x3)) for b in diagram.equilibrium_branches]
    y_hi = 1.15 * max(tops + [1.0])
    y_lo = -0.08 * y_hi
    nrow, ncol, spare = _grid(len(ctrls))
    legend_below = spare < 2  # the legend takes the empty slots of the last row, or a band below
    height = 1.85 * nrow + 0.75 + (1.3 if legend_below else 0.0)
    fig, axes = subplots(nrow, ncol, figsize=(FIGURE_WIDTH, height), sharex=True, sharey=True, squeeze=False)
    flat = [a for row in axes for a in row]
    handles: list = []
    for ax, c in zip(flat, ctrls, strict=False):
        plot_bifurcation(diagram, ax, annotate=False, legend=False, lw=0.9, alpha=0.5)
        handles = handles or list(ax.diagram_handles)
        r = df[df["controller"] == c]
        u = r["voltage"].to_numpy(dtype=float)
        hi, lo = r["x3_max"].to_numpy(dtype=float), r["x3_min"].to_numpy(dtype=float)
        col, m = controller_style(c).colour, controller_style(c).marker
        inside_hi, inside_lo = hi <= y_hi, lo >= y_lo
        both = inside_hi & inside_lo  # a run beyond the scale gets no bar across the panel
        ax.vlines(u[both], lo[both], hi[both], color=col, lw=0.9, alpha=0.8, zorder=4)
        ax.plot(u[inside_hi], hi[inside_hi], m, color=col, ms=3.5, mfc="white", mew=0.8, zorder=5)
        ax.plot(u[inside_lo], lo[inside_lo], m, color=col, ms=3.5, mfc="white", mew=0.8, zorder=5)
        for beyond, y_edge, m_edge in ((~inside_hi, y_hi, "^"), (~inside_lo, y_lo, "v")):
            if beyond.any():  # on the frame, unclipped (an empty unclipped line would stretch
                # the layout to the figure's corner)
                ax.plot(
                    u[beyond],
                    np.full(beyond.sum(), y_edge),
                    m_edge,
                    color=col,
                    ms=4.5,
                    clip_on=False,
                    zorder=6,
                )
        title = c
        off = ~(inside_hi & inside_lo)
        if off.any():
            vs = u[off]
            title += (
                f"\n{int(off.sum())} runs off scale ({vs.min():g}-{vs.max():g} V):"
                f"\nx3 {lo[off].min():.1f} to {hi[off].max():.1f} rad/s"
            )
        # an off-scale note clears the triangles on the frame
        ax.set_title(
            title, fontsize=FONT, color=col if c != "open_loop" else "black", pad=6 if off.any() else 3
        )
        ax.set_xlabel("")
        ax.set_ylabel("")
        ax.tick_params(labelsize=FONT, length=2.5, pad=2)
    for ax in flat[len(ctrls) :]:
        ax.axis("off")
    for row in axes:
        row[0].set_ylabel("x3 [rad/s]", fontsize=FONT)
    for k, ax in enumerate(flat[: len(ctrls)]):
        if k + ncol >= len(ctrls):  # the lowest panel of its column
            ax.tick_params(labelbottom=True)
            ax.set_xlabel("nominal u [V]", fontsize=FONT)
    ax0 = flat[0]
    ax0.set_ylim(y_lo, y_hi)
    ax0.set_xlim(0.0, 5.1)
    ax0.set_xticks([0, 1, 2, 3, 4, 5])
    handles = [h for h in handles if "simulation" not in h.get_label()]
    handles += [
        Line2D(
            [],
            [],
            color="0.3",
            marker="o",
            mfc="white",
            ms=3.5,
            lw=0.9,
            label="a run's steady min and max of x3",
        ),
        Line2D(
            [], [], color="0.3", marker="^", ls="none", ms=4.5, label="run off scale (range under the title)"
        ),
    ]
    for h in handles:  # two columns of the width of the empty slots
        h.set_label(textwrap.fill(h.get_label(), LEGEND_WRAP, break_on_hyphens=False))
    fig.suptitle(
        f"{preset}: each controller's runs (one per seed; steady min and max of x3 over the last "
        f"{EpisodeSettings().window:g} s)\non the nominal model's bifurcation diagram (faded)",
        fontsize=FONT + 1,
    )
    if legend_below:
        fig.tight_layout(rect=(0, 1.3 / height, 1, 1), h_pad=0.6, w_pad=0.4)
        fig.legend(handles=handles, loc="lower center", fontsize=FONT, ncol=2, frameon=False)
    else:
        fig.tight_layout(h_pad=0.6, w_pad=0.4)
        empty = flat[len(ctrls) :]
        x0 = min(a.get_position().x0 for a in empty)
        x1 = max(a.get_position().x1 for a in empty)
        y0 = min(a.get_position().y0 for a in empty)
        y1 = max(a.get_position().y1 for a in empty)
        fig.legend(
            handles=handles,
            loc="center",
            bbox_to_anchor=(x0, y0 - 0.03, x1 - x0, y1 - y0 + 0.03),
            fontsize=FONT,
            ncol=2 if spare >= 3 else 1,
            frameon=False,
        )
    return fig


def _regime_handles(preset: str) -> list:
    """Legend entries of the regime shading of the suppression figures."""
    from matplotlib.patches import Patch

    present = {name for name, _, _ in _regime_spans(preset)}
    return [
        Patch(color=_REGIME_SHADES[name], alpha=0.15, label=f"nominal model: {REGIMES[name]}")
        for name in ("limit_cycle", "stick_slip")
        if name in present
    ]


_REGIME_SHADES = {"limit_cycle": "tab:orange", "stick_slip": "tab:red"}
FLOOR_BAND = 0.45  # [-] height of the band under the floor where off-scale means are written
FLOOR_LABEL_WIDTH = 0.42  # [in] room for one written mean ("-33.8") in that band


LEADING = 0.95  # [-] controllers whose mean suppression is at least this at every voltage ...
LEADERS_COLOUR = "0.45"  # ... are drawn as one band on the linear scale (told apart on the log one)


def leading_controllers(df, ctrls, threshold: float = LEADING) -> list[str]:
    """The controllers of ``ctrls`` whose mean suppression over seeds is at least ``threshold``
    at every voltage with an open-loop cycle (none unless at least two): on a linear scale they
    would lie on one line at 1, so the suppression panels draw them as one band."""
    cyc = df[df["open_loop_amplitude"] > 0]
    out = []
    for c in ctrls:
        g = cyc[cyc["controller"] == c].groupby("voltage")["suppression"].mean()
        if len(g) and bool((g >= threshold).all()):
            out.append(c)
    return out if len(out) >= 2 else []


def _draw_suppression(ax, df, preset: str, ctrls, *, small: bool = False, group: bool = True) -> list[str]:
    """Suppression against voltage of each controller (mean over seeds, seed range as bars),
    every marker at its run's voltage. Means below the floor are drawn on it and written in
    a band beneath it (only when not ``small``). With ``group``, the
    :func:`leading_controllers` are drawn as one band from the lowest to the highest of their
    means at each voltage (returned), not as lines on top of each other."""
    cyc = df[df["open_loop_amplitude"] > 0]
    for name, lo, hi in _regime_spans(preset):
        if name in _REGIME_SHADES:
            ax.axvspan(lo, hi, color=_REGIME_SHADES[name], alpha=0.15, lw=0, zorder=0)
    leaders = leading_controllers(df, ctrls) if group else []
    if leaders:
        means = cyc[cyc["controller"].isin(leaders)].groupby(["voltage", "controller"])["suppression"].mean()
        band = means.groupby(level="voltage").agg(["min", "max"])
        v = band.index.to_numpy(dtype=float)
        ax.fill_between(
            v, band["min"], band["max"], color=LEADERS_COLOUR, alpha=0.5, lw=0, zorder=2,
            label=f"grey band: the {len(leaders)} controllers at {LEADING:g} or more at every voltage "
            "(lowest to highest mean; told apart below)",
        )  # fmt: skip
        ax.plot(v, band["min"], "-", color=LEADERS_COLOUR, lw=1.2 if small else 2.0, zorder=2.1)
    floored: list[tuple[float, float, str]] = []
    for c in ctrls:
        r = cyc[cyc["controller"] == c]
        if r.empty or c in leaders:
            continue
        g = r.groupby("voltage")["suppression"]
        v = np.array(sorted(g.groups))
        mean, lo, hi = g.mean().loc[v].to_numpy(), g.min().loc[v].to_numpy(), g.max().loc[v].to_numpy()
        shown = np.maximum(mean, Y_FLOOR)
        ax.errorbar(
            v,
            shown,
            yerr=[shown - np.maximum(lo, Y_FLOOR), np.maximum(hi, Y_FLOOR) - shown],
            fmt=controller_style(c).marker + "-",
            color=controller_style(c).colour,
            mfc="none",
            mew=1.0,
            ms=3 if small else 6,
            lw=0.8 if small else 1,
            capsize=0 if small else 2,
            label=c,
        )
        floored += [(float(vv), float(mm), c) for vv, mm in zip(v, mean, strict=True) if mm < Y_FLOOR]
    ax.axhline(0.0, color="gray", lw=0.8)
    ax.axhline(1.0, color="gray", lw=0.8, ls=":")
    from drill_env.analysis.plots import AMPLIFIER_LIMIT_V

    ax.axvline(AMPLIFIER_LIMIT_V, color="tab:purple", lw=1.0, ls="-.", zorder=1)
    lo_y = (
        min(-0.5, float(np.nanmin(cyc["suppression"])) - 0.05) if cyc["suppression"].notna().any() else -0.5
    )
    bottom = max(lo_y, Y_FLOOR - 0.1)
    if floored and not small:
        bottom = Y_FLOOR - FLOOR_BAND
        ax.axhspan(bottom, Y_FLOOR - 0.04, color="white", zorder=2.5)  # a band clear of lines
        ax.axhline(Y_FLOOR - 0.04, color="0.5", lw=0.6, ls="--", zorder=2.6)
        ends: list[float] = []  # per row of labels: the voltage where its last label ends
        gap = FLOOR_LABEL_WIDTH * 5.1 / max(ax.get_position().width * ax.figure.get_figwidth(), 1e-9)
        for vv, mm, c in sorted(floored):
            k = next((i for i, end in enumerate(ends) if vv - end >= gap), len(ends))
            if k == len(ends):
                ends.append(vv)
            ends[k] = vv
            ax.annotate(
                f"{mm:.1f}",
                (vv, Y_FLOOR - 0.04),
                xytext=(0, -3 - 11 * k),
                textcoords="offset points",
                fontsize=FONT,
                color=controller_style(c).colour,
                ha="center",
                va="top",
                zorder=3,
            )
    ax.set_ylim(bottom, 1.1)
    ax.set_xlim(0.0, 5.1)
    ax.grid(alpha=0.3)
    return leaders


SHORTFALL_FLOOR = 1e-4  # [-] a mean shortfall 1 - suppression below this is drawn at it
SHORTFALL_ABOVE = 0.01  # [-] the shortfall panel draws the means of suppression above this


def _draw_shortfall(ax, df, preset: str, ctrls) -> bool:
    """The shortfall 1 - suppression (mean over seeds) against voltage on a log scale, where the
    controllers that all read 0.99-1.00 on the linear scale are told apart (0.99 -> 1e-2,
    0.999 -> 1e-3); a mean suppression of at most :data:`SHORTFALL_ABOVE` (as open loop or
    worse) is left to the panel above,
    a shortfall below :data:`SHORTFALL_FLOOR` drawn at it. Returns whether anything was drawn."""
    cyc = df[df["open_loop_amplitude"] > 0]
    for name, lo, hi in _regime_spans(preset):
        if name in _REGIME_SHADES:
            ax.axvspan(lo, hi, color=_REGIME_SHADES[name], alpha=0.15, lw=0, zorder=0)
    drawn = False
    for c in ctrls:
        r = cyc[cyc["controller"] == c]
        if r.empty:
            continue
        g = r.groupby("voltage")["suppression"].mean()
        short = 1.0 - g
        keep = short < 1.0 - SHORTFALL_ABOVE
        if not keep.any():
            continue
        v = np.asarray(short.index[keep], dtype=float)
        y = np.maximum(short[keep].to_numpy(), SHORTFALL_FLOOR)
        style = controller_style(c)
        ax.plot(
            v,
            y,
            style.marker + "-",
            color=style.colour,
            mfc="none",
            ms=6,
            lw=1,
            label=c,
        )
        drawn = True
    ax.set_yscale("log")
    ax.set_ylim(SHORTFALL_FLOOR * 0.7, 1.0)
    ax.set_xlim(0.0, 5.1)
    from drill_env.analysis.plots import AMPLIFIER_LIMIT_V

    ax.axvline(AMPLIFIER_LIMIT_V, color="tab:purple", lw=1.0, ls="-.", zorder=1)
    ax.grid(alpha=0.3, which="both")
    return drawn


def _suppression_figure(df, preset: str, out: Path, plant: str, ctrls) -> list[Path]:
    """``suppression_<preset>[_<plant>].png``: the suppression against voltage (mean, seed
    range) above and the shortfall 1 - suppression on a log scale below, where the leading
    controllers are told apart."""
    from matplotlib.lines import Line2D

    from drill_env._figures import subplots

    fig, (ax, ax_log) = subplots(2, 1, figsize=(FIGURE_WIDTH, 9.6), sharex=True)
    _draw_suppression(ax, df, preset, ctrls)
    _draw_shortfall(ax_log, df, preset, ctrls)
    ax_log.set_xlabel("nominal voltage u [V]", fontsize=FONT)
    ax.set_ylabel("suppression [-]\n1 - amplitude / open-loop amplitude", fontsize=FONT)
    ax_log.set_ylabel("shortfall 1 - suppression [-]\n(mean over seeds, log scale)", fontsize=FONT)
    on = "" if plant == NOMINAL else f" on plant {plant}\n(reference: the open-loop run on it)"
    ax.set_title(f"{preset}{on}: suppression of the open-loop cycle", fontsize=FONT + 1)
    ax_log.set_title(
        f"the same means as shortfall: 0.99 -> 1e-2, 0.999 -> 1e-3\n(below {SHORTFALL_FLOOR:g} drawn at it; "
        f"means at or below {SHORTFALL_ABOVE:g} only above)",
        fontsize=FONT,
    )
    for a in (ax, ax_log):
        a.tick_params(labelsize=FONT)
    handles, _ = ax_log.get_legend_handles_labels()
    seen = {h.get_label() for h in handles}
    handles += [h for h in ax.get_legend_handles_labels()[0] if h.get_label() not in seen]
    handles = sorted(
        handles, key=lambda h: CONTROLLERS.index(h.get_label()) if h.get_label() in CONTROLLERS else 99
    )
    handles += [
        Line2D([], [], color="gray", lw=0.8, ls=":", label="1: cycle removed"),
        Line2D([], [], color="gray", lw=0.8, label="0: amplitude as open loop"),
        Line2D([], [], color="tab:purple", lw=1.0, ls="-.", label="amplifier limit 5 V"),
        *_regime_handles(preset),
    ]
    if any(t.get_text() for t in ax.texts if t.get_text()[:1] in "-0123456789"):
        handles.append(
            Line2D(
                [], [], color="0.5", lw=0.6, ls="--",
                label=f"below {Y_FLOOR:g}: drawn at {Y_FLOOR:g}, mean written under the dashed line",
            )
        )  # fmt: skip
    for h in handles:
        h.set_label(textwrap.fill(h.get_label(), 34, break_on_hyphens=False))
    ncol = 3
    rows = sum(-(-len(h.get_label().splitlines()) // 1) for h in handles) / ncol
    legend_in = 0.21 * rows + 0.3
    fig.tight_layout(rect=(0, legend_in / fig.get_figheight(), 1, 1))
    fig.legend(
        handles=handles, loc="lower center", fontsize=FONT, ncol=ncol, frameon=False,
        title="mean over seeds (bar: seed range)", title_fontsize=FONT,
    )  # fmt: skip
    p = out / (f"suppression_{preset}.png" if plant == NOMINAL else f"suppression_{preset}_{plant}.png")
    save_figure(fig, p, dpi=FIGURE_DPI)
    return [p]


def _plants_figure(df, preset: str, out: Path, plants: Sequence[str]) -> Path:
    """``suppression_<preset>_plants.png``: the suppression figure of every plant other than
    the nominal one as small multiples (one panel per plant, shared axes)."""
    from matplotlib.lines import Line2D

    from drill_env._figures import subplots

    ok = df[(df["preset"] == preset) & (df["error"] == "")]
    ctrls = ordered_controllers(ok["controller"])
    ncol = GRID_COLUMNS
    n_legend_slots = 3
    nrow = -(-(len(plants) + n_legend_slots) // ncol)  # the legend takes the last slots
    fig, axes = subplots(
        nrow, ncol, figsize=(FIGURE_WIDTH, 1.75 * nrow + 0.8), sharex=True, sharey=True, squeeze=False
    )
    flat = [a for row in axes for a in row]
    for k, plant in enumerate(plants):
        ax = flat[k]
        _draw_suppression(ax, ok[ok["plant"] == plant], preset, ctrls, small=True)
        ax.set_title(plant, fontsize=FONT, pad=3)
        ax.set_ylim(Y_FLOOR - 0.1, 1.1)
        ax.tick_params(labelsize=FONT, length=2.5, pad=2)
        if k % ncol == 0:
            ax.set_ylabel("suppression [-]", fontsize=FONT)
        if k + ncol >= len(plants):  # the lowest panel of its column
            ax.set_xlabel("nominal u [V]", fontsize=FONT)
            ax.tick_params(labelbottom=True)
    for ax in flat[len(plants) :]:
        ax.axis("off")
    from matplotlib.patches import Patch

    # every controller (a panel draws its leaders as one band: which ones differs by plant)
    handles = [
        Line2D(
            [], [], marker=controller_style(c).marker, color=controller_style(c).colour, mfc="none", label=c
        )
        for c in ctrls
    ]
    handles.append(
        Patch(
            color=LEADERS_COLOUR,
            alpha=0.5,
            label=f"band: those at {LEADING:g}+ everywhere",
        )
    )
    regimes = _regime_handles(preset)
    for h in regimes:  # short: the legend fits the empty slots
        h.set_label(h.get_label().replace("nominal model: ", "").replace(" without stick", ""))
    handles += [
        Line2D([], [], color="gray", lw=0.8, ls=":", label="1: removed"),
        Line2D([], [], color="gray", lw=0.8, label="0: as open loop"),
        Line2D([], [], color="tab:purple", lw=1.0, ls="-.", label="5 V limit"),
        *regimes,
    ]
    fig.suptitle(
        f"{preset}: suppression on each plant, controllers designed on the nominal model\n"
        f"(reference: the open-loop run on the same plant; means below {Y_FLOOR:g} drawn at {Y_FLOOR:g})",
        fontsize=FONT + 1,
    )
    fig.tight_layout(h_pad=0.6, w_pad=0.4)
    # after the layout, which would otherwise shrink every panel to the legend's width: in the
    # empty slots of the last rows
    empty = flat[len(plants) :]
    x0, x1 = min(a.get_position().x0 for a in empty), max(a.get_position().x1 for a in empty)
    y0, y1 = min(a.get_position().y0 for a in empty), max(a.get_position().y1 for a in empty)
    for h in handles:
        h.set_label(textwrap.fill(h.get_label(), 22, break_on_hyphens=False))
    fig.legend(
        handles=handles, loc="center", bbox_to_anchor=(x0, y0 - 0.01, x1 - x0, y1 - y0), fontsize=FONT,
        frameon=False, ncol=3, handlelength=1.4, columnspacing=0.8, labelspacing=0.25, borderaxespad=0.0,
        title="mean over seeds (bar: seed range); shaded: the nominal model's regimes", title_fontsize=FONT,
    )  # fmt: skip
    p = out / f"suppression_{preset}_plants.png"
    save_figure(fig, p, dpi=FIGURE_DPI)
    return p


@functools.lru_cache(maxsize=8)
def _regime_spans(preset: str) -> list[tuple[str, float, float]]:
    from drill_env.envs.task import operating_regimes
    from drill_env.params import load_params

    return list(operating_regimes(load_params(preset)).intervals)


RATIO_FLOOR = 1e-3  # [-] amplitude ratios below are drawn at the floor


def worst_case_figure(df, preset: str, out: Path) -> Path | None:
    """``worst_case_<preset>.png``: each controller's worst run over every plant and seed at
    each voltage (left, as the residual amplitude 1 - suppression on a log axis, so that 0.99
    and 0.999 are told apart), and each robust policy's worst suppression less its
    nominal-trained counterpart's (right: above 0, the robust policy's guarantee across the
    plants is the better one at that voltage). None where no controller has a suppression
    (the open loop alone, or no cycle on any plant)."""
    from matplotlib.lines import Line2D

    from drill_env._figures import subplots
    from drill_env.agents.evaluation.robustness import robust_pairs, worst_by_voltage

    worst = worst_by_voltage(df, preset)
    if not worst:
        return None
    pairs = robust_pairs(worst)
    n_plants = df[(df["preset"] == preset) & (df["error"] == "")]["plant"].nunique()
    volts = [v for w in worst.values() for v in w]
    pad = 0.05 * (max(volts) - min(volts)) + 0.05
    xlim = (min(volts) - pad, max(volts) + pad)
    # one panel above the other (the second: each robust policy against its counterpart)
    fig, axes = subplots(2 if pairs else 1, 1, figsize=(FIGURE_WIDTH, 8.4 if pairs else 5.0), squeeze=False)
    ax = axes[0][0]
    for name, lo, hi in _regime_spans(preset):
        if name in _REGIME_SHADES:
            ax.axvspan(lo, hi, color=_REGIME_SHADES[name], alpha=0.15, lw=0, zorder=0)
    for c, w in worst.items():
        v = np.array(sorted(w))
        s = np.array([w[x][0] for x in v])
        style = controller_style(c)
        ax.plot(
            v,
            np.maximum(1.0 - s, RATIO_FLOOR),
            style.marker + "-",
            color=style.colour,
            mfc="none",
            ms=5,
            lw=1.0,
            label=c,
        )
    ax.set_yscale("log")
    ax.axhline(1.0, color="gray", lw=0.8)
    ax.axhline(0.1, color="gray", lw=0.8, ls="--")
    ax.set_xlim(*xlim)
    ax.grid(alpha=0.3, which="both")
    ax.set_xlabel("nominal voltage u [V]", fontsize=FONT)
    ax.set_ylabel("1 - suppression = worst amplitude\n/ open-loop amplitude [-] (log)", fontsize=FONT)
    ax.tick_params(labelsize=FONT)
    ax.set_title(
        f"{preset}: worst run over {n_plants} plants and every seed, at each voltage", fontsize=FONT + 1
    )
    handles, _ = ax.get_legend_handles_labels()
    handles += [
        Line2D([], [], color="gray", lw=0.8, label="1: as open loop"),
        Line2D([], [], color="gray", lw=0.8, ls="--", label="0.1: suppression 0.9"),
        *_regime_handles(preset),
    ]
    ncol = 4
    for h in handles:
        h.set_label(textwrap.fill(h.get_label(), 24, break_on_hyphens=False))
    fig.legend(handles=handles, loc="lower center", ncol=ncol, fontsize=FONT, frameon=False)
    legend_lines = sum(len(h.get_label().splitlines()) for h in handles)
    if pairs:
        from drill_env.agents.evaluation.robustness import worst_case_verdict

        ax = axes[1][0]
        margins: list[float] = []
        for robust, nominal in pairs:
            vs = sorted(set(worst[robust]) & set(worst[nominal]))
            margin = np.array([worst[robust][v][0] - worst[nominal][v][0] for v in vs])
            verdict = worst_case_verdict(worst, robust, nominal)
            style = controller_style(robust)
            ax.plot(
                vs,
                margin,
                style.marker + "-",
                color=style.colour,
                mfc="none",
                ms=5,
                label=f"{robust} - {nominal}: >= 0 at {verdict['at_least']} of {verdict['voltages']} voltages",
            )
            ax.plot(np.array(vs)[margin < 0], margin[margin < 0], "x", color="tab:red", ms=8, mew=2)
            margins += margin.tolist()
        ax.axhline(0.0, color="black", lw=1.0)
        ax.set_yscale("symlog", linthresh=0.01)
        ax.set_xlim(*xlim)
        ax.set_ylim(min([-0.01, *(1.5 * m for m in margins)]), max([0.01, *(1.5 * m for m in margins)]))
        from matplotlib.ticker import SymmetricalLogLocator

        ax.yaxis.set_minor_locator(SymmetricalLogLocator(base=10, linthresh=0.01, subs=range(2, 10)))
        ax.grid(alpha=0.3, which="both")
        ax.set_xlabel("nominal voltage u [V]", fontsize=FONT)
        ax.set_ylabel("difference of worst\nsuppression [-] (symlog)", fontsize=FONT)
        ax.tick_params(labelsize=FONT)
        ax.set_title(
            "robust policy less its nominal-trained counterpart (worst runs, above)", fontsize=FONT + 1
        )
        handles, _ = ax.get_legend_handles_labels()
        if any(m < 0 for m in margins):
            handles.append(Line2D([], [], color="tab:red", marker="x", ls="none", mew=2, label="behind"))
        ax.legend(handles=handles, fontsize=FONT, loc="upper right")
    legend_rows = -(-legend_lines // ncol) + 1
    fig.tight_layout(rect=(0, (0.15 + 0.19 * legend_rows) / fig.get_figheight(), 1, 1))
    p = out / f"worst_case_{preset}.png"
    save_figure(fig, p, dpi=FIGURE_DPI)
    return p
