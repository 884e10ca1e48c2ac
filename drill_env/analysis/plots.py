"""Figures of the bifurcation analysis in the style of the paper's Fig. 6, 8 and 9.

Stable branches are drawn solid, unstable ones dashed; the paper's points are labelled,
each label placed where it covers no curve or marker; a legend names every line and
marker style. Where a diagram reaches them, the rig's 5 V amplifier limit and the speed up
to which the brake friction was identified (12.6 rad/s) are drawn. matplotlib is imported
inside each function.

This module draws what the analysis computed and imports none of it: it reads the
attributes named by the protocols below, so that the result objects' ``.plot()`` methods
(:class:`~drill_env.analysis.diagram.BifurcationDiagram`,
:class:`~drill_env.analysis.shooting.LimitCycle`,
:class:`~drill_env.analysis.sweep.BruteForceCheck`) can call it without an import cycle.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from drill_env.outputs import save_figure
from drill_env.params import IDENTIFIED_SPEED_RAD_S, RIG_VOLTAGE_LIMIT

__all__ = [
    "AMPLIFIER_LIMIT_V",
    "IDENTIFIED_SPEED_RAD_S",
    "Label",
    "place_labels",
    "plot_equilibria",
    "plot_bifurcation",
    "plot_period",
    "plot_fig9",
    "plot_limit_cycles",
    "save_figures",
]


# -- what the figures read of the analysis' results -----------------------------------------


class LimitCycle(Protocol):
    """A periodic orbit (:class:`drill_env.analysis.shooting.LimitCycle`); read-only."""

    @property
    def u(self) -> float: ...  # [V]

    @property
    def period(self) -> float: ...  # [s]

    @property
    def x3_min(self) -> float: ...  # [rad/s]

    @property
    def x3_max(self) -> float: ...  # [rad/s]

    @property
    def stable(self) -> bool: ...

    @property
    def stick_slip(self) -> bool: ...

    def orbit(self, n: int = 400) -> Any: ...


class PeriodicSegment(Protocol):
    """A stretch of a periodic branch (:class:`drill_env.analysis.diagram.PeriodicSegment`);
    read-only, as the plots use it."""

    @property
    def name(self) -> str: ...

    @property
    def cycles(self) -> Sequence[LimitCycle]: ...

    @property
    def u(self) -> np.ndarray: ...

    @property
    def stable(self) -> np.ndarray: ...


class BifurcationDiagram(Protocol):
    """A bifurcation diagram (:class:`drill_env.analysis.diagram.BifurcationDiagram`);
    read-only, as the plots use it."""

    @property
    def preset(self) -> str: ...

    @property
    def u_min(self) -> float: ...  # [V]

    @property
    def u_max(self) -> float: ...  # [V]

    @property
    def equilibrium_branches(self) -> Sequence[Any]: ...

    @property
    def periodic_segments(self) -> Sequence[PeriodicSegment]: ...

    @property
    def points(self) -> Mapping[str, Any]: ...

    @property
    def hopf(self) -> Sequence[Any]: ...

    @property
    def branches(self) -> Sequence[Any]: ...

    def cycles_at(self, u: float) -> Sequence[LimitCycle]: ...

    def plot(self, kind: str = "fig8", ax: Any = None, **kwargs: Any) -> Any: ...


class BruteForceCheck(Protocol):
    """The simulation check of a diagram (:class:`drill_env.analysis.sweep.BruteForceCheck`)."""

    runs: list[Any]


_EQ_COLOR = "k"
_CYCLE_COLOR = "tab:blue"
_POINT_COLOR = "tab:red"
_LIMIT_COLOR = "tab:purple"
_SIM_COLOR = "tab:orange"

# The figures' size: drawn 724 px wide in the documentation (drill_env._figures' size rule),
# FIGURE_WIDTH inches show FONT-point text at 8.5 pt.
FIGURE_WIDTH = 8.0  # [in]
FONT = 9.0  # [pt] the smallest text of the figures (legends, labels, tick labels)
FIGURE_DPI = 130

AMPLIFIER_LIMIT_V = RIG_VOLTAGE_LIMIT  # [V] the rig's amplifier takes inputs in [-5, 5] V (Sec. 2.1)

POINT_MEANINGS = "A: start of motion, B, C: Hopf, D, E: stick-slip begins, ends, F: fold of cycles"
# How the brute-force check started each simulation (drill_env.analysis.sweep).
RUN_KINDS = {
    "small": ("o", 4, "started near the equilibrium"),
    "large": ("s", 3, "started with the lower disk at rest"),
    "forward": ("^", 4, "sweep of u upwards"),
    "backward": ("v", 4, "sweep of u downwards"),
}


def _style(stable: bool) -> str:
    return "-" if stable else "--"


def _hopf_ends(diagram: BifurcationDiagram, seg: PeriodicSegment) -> tuple[tuple | None, tuple | None]:
    """(u, x3) of the Hopf points a segment starts or ends at, so the curves meet the equilibria."""
    first = last = None
    for br in diagram.branches:
        if seg.cycles[0] is br.cycles[0]:
            first = (br.start.u, float(br.start.x_eq[2]))
        if seg.cycles[-1] is br.cycles[-1] and br.end_hopf_u is not None:
            h = min(diagram.hopf, key=lambda hh: abs(hh.u - br.end_hopf_u))
            last = (h.u, float(h.x_eq[2]))
    return first, last


def _segment_curves(diagram: BifurcationDiagram, seg: PeriodicSegment):
    u = [c.u for c in seg.cycles]
    lo = [c.x3_min for c in seg.cycles]
    hi = [c.x3_max for c in seg.cycles]
    first, last = _hopf_ends(diagram, seg)
    if first:
        u, lo, hi = [first[0], *u], [first[1], *lo], [first[1], *hi]
    if last:
        u, lo, hi = [*u, last[0]], [*lo, last[1]], [*hi, last[1]]
    return np.array(u), np.array(lo), np.array(hi)


def _segment_stable(seg: PeriodicSegment) -> bool:
    return bool(np.mean(seg.stable[1:-1] if len(seg.cycles) > 2 else seg.stable) > 0.5)


# -- labels placed clear of the data ----------------------------------------------------------


@dataclass
class Label:
    """A text to write next to the data point (x, y), placed by :func:`place_labels`."""

    text: str
    x: float
    y: float
    color: str = "k"
    fontsize: float = 9.0


_OFFSETS = [
    (dx, dy)
    for r in (5, 9, 14, 20, 28)
    for dx, dy in ((r, r), (-r, r), (r, -r), (-r, -r), (0, r), (0, -r), (r, 0), (-r, 0))
]


def _obstacles(ax) -> tuple[np.ndarray, np.ndarray]:
    """Display coordinates of every drawn line (densely sampled) and marker of ``ax``, with
    the radius [px] each occupies."""
    pts, rad = [], []
    px_per_pt = ax.figure.dpi / 72.0
    for line in ax.get_lines():
        if not line.get_visible():
            continue
        xy = line.get_transform().transform(np.column_stack(line.get_data()).astype(float))
        xy = xy[np.all(np.isfinite(xy), axis=1)]
        if xy.size == 0:
            continue
        if line.get_marker() not in (None, "None", "", " "):
            pts.append(xy)
            rad.append(np.full(len(xy), 0.5 * line.get_markersize() * px_per_pt + 1.0))
        if line.get_linestyle() not in ("None", "", " ") and len(xy) > 1:
            seg = np.diff(xy, axis=0)
            n = np.maximum(1, (np.hypot(seg[:, 0], seg[:, 1]) / 2.0).astype(int))
            dense = np.concatenate(
                [xy[i] + np.outer(np.arange(k) / k, seg[i]) for i, k in enumerate(n)] + [xy[-1:]]
            )
            pts.append(dense)
            rad.append(np.full(len(dense), 0.5 * line.get_linewidth() * px_per_pt + 1.0))
    for coll in ax.collections:  # vlines, scatter
        try:
            paths = coll.get_paths()
        except AttributeError:  # pragma: no cover
            continue
        if not coll.get_visible() or len(paths) > 5000:
            continue
        for path in paths:
            v = path.vertices
            if len(v) == 0 or len(v) > 200:
                continue  # a filled area, not a curve
            xy = coll.get_transform().transform(v)
            xy = xy[np.all(np.isfinite(xy), axis=1)]
            if len(xy) > 1:
                seg = np.diff(xy, axis=0)
                n = np.maximum(1, (np.hypot(seg[:, 0], seg[:, 1]) / 2.0).astype(int))
                xy = np.concatenate(
                    [xy[i] + np.outer(np.arange(k) / k, seg[i]) for i, k in enumerate(n)] + [xy[-1:]]
                )
            pts.append(xy)
            rad.append(np.full(len(xy), 1.5))
    if not pts:
        return np.zeros((0, 2)), np.zeros(0)
    return np.concatenate(pts), np.concatenate(rad)


# a light backing keeps a label readable even where no clear place was found
_LABEL_BOX = {"boxstyle": "square,pad=0.05", "fc": "white", "ec": "none", "alpha": 0.75}


def place_labels(ax, labels: Sequence[Label]) -> list:
    """Write each label next to its point where it covers the fewest lines, markers and
    other labels and stays inside the axes; returns the text artists. Call it after
    everything else is drawn and the axis limits and layout are final."""
    if not labels:
        return []
    from drill_env._figures import renderer as figure_renderer

    fig = ax.figure
    renderer = figure_renderer(fig)
    pts, rad = _obstacles(ax)
    box = ax.get_window_extent(renderer)
    placed: list = []
    out = []
    px_per_pt = fig.dpi / 72.0
    anchors = ax.transData.transform(np.array([(lab.x, lab.y) for lab in labels], dtype=float))
    for i, lab in enumerate(labels):
        anchor = anchors[i]
        if not np.all(np.isfinite(anchor)):
            continue
        txt = ax.annotate(
            lab.text,
            (lab.x, lab.y),
            textcoords="offset points",
            xytext=(0, 0),
            fontsize=lab.fontsize,
            color=lab.color,
            zorder=7,
            bbox=_LABEL_BOX,
            annotation_clip=False,
        )
        ext = txt.get_window_extent(renderer)
        w, h = ext.width, ext.height
        best, best_score = _OFFSETS[0], math.inf
        for k, (dx, dy) in enumerate(_OFFSETS):
            cx, cy = anchor[0] + dx * px_per_pt, anchor[1] + dy * px_per_pt
            x0 = cx - w if dx < 0 else cx - w / 2 if dx == 0 else cx
            y0 = cy - h if dy < 0 else cy - h / 2 if dy == 0 else cy
            x1, y1 = x0 + w, y0 + h
            hit = (
                (pts[:, 0] + rad > x0)
                & (pts[:, 0] - rad < x1)
                & (pts[:, 1] + rad > y0)
                & (pts[:, 1] - rad < y1)
            )
            score = float(hit.sum())
            score += sum(
                100.0
                * max(0.0, min(x1, b[2]) - max(x0, b[0]))
                * max(0.0, min(y1, b[3]) - max(y0, b[1]))
                / (w * h)
                for b in placed
            )
            if x0 < box.x0 or x1 > box.x1 or y0 < box.y0 or y1 > box.y1:
                score += 1000.0
            # a label must sit nearer its own point than any other labelled point
            centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
            d = np.hypot(*(anchors - centre).T)
            others = [j for j in range(len(labels)) if j != i and labels[j].text != lab.text]
            if others and np.nanmin(d[others]) < d[i]:
                score += 30.0
            score += 0.01 * k  # nearer offsets first among equals
            if score < best_score:
                best, best_score, best_box = (dx, dy), score, (x0, y0, x1, y1)
        dx, dy = best
        txt.set_position((dx, dy))
        txt.set_horizontalalignment("right" if dx < 0 else "center" if dx == 0 else "left")
        txt.set_verticalalignment("top" if dy < 0 else "center" if dy == 0 else "bottom")
        if max(abs(dx), abs(dy)) > 10:  # far from its point: a leader line says which
            txt.remove()
            txt = ax.annotate(
                lab.text,
                (lab.x, lab.y),
                textcoords="offset points",
                xytext=(dx, dy),
                ha="right" if dx < 0 else "center" if dx == 0 else "left",
                va="top" if dy < 0 else "center" if dy == 0 else "bottom",
                fontsize=lab.fontsize,
                color=lab.color,
                zorder=7,
                bbox=_LABEL_BOX,
                annotation_clip=False,
                arrowprops={"arrowstyle": "-", "lw": 0.6, "color": lab.color, "shrinkA": 0, "shrinkB": 3},
            )
        placed.append(best_box)
        out.append(txt)
    return out


# -- the rig's limits ---------------------------------------------------------------------------


def _draw_limits(ax, preset: str, u_max: float, y_max: float | None, handles: list) -> None:
    """The amplifier limit as a vertical line (the model only beyond it) when the u range
    reaches it, and the speed up to which the preset's friction was identified as a
    horizontal line when the plotted x3 reaches it (``y_max``: the largest x3 drawn)."""
    from matplotlib.lines import Line2D

    if u_max >= AMPLIFIER_LIMIT_V - 1e-9:
        ax.axvline(AMPLIFIER_LIMIT_V, color=_LIMIT_COLOR, lw=1.2, ls="-.", zorder=1)
        if u_max > AMPLIFIER_LIMIT_V + 1e-9:
            ax.axvspan(AMPLIFIER_LIMIT_V, u_max, color="0.5", alpha=0.08, lw=0, zorder=0)
        handles.append(
            Line2D(
                [],
                [],
                color=_LIMIT_COLOR,
                lw=1.2,
                ls="-.",
                label=f"rig's amplifier limit {AMPLIFIER_LIMIT_V:g} V"
                + (" (beyond: model only, shaded)" if u_max > AMPLIFIER_LIMIT_V + 1e-9 else ""),
            )
        )
    w = IDENTIFIED_SPEED_RAD_S.get(preset)
    if w is not None and y_max is not None and y_max >= w:
        ax.axhline(w, color="tab:brown", lw=1.0, ls=":", zorder=1)
        handles.append(
            Line2D(
                [], [], color="tab:brown", lw=1.0, ls=":", label=f"friction identified up to x3 = {w:g} rad/s"
            )
        )


def _set_u_range(ax, diagram: BifurcationDiagram) -> None:
    """The diagram's u range; a little more when it ends at the amplifier limit, so that
    the limit's line is not hidden under the frame."""
    hi = diagram.u_max
    if abs(hi - AMPLIFIER_LIMIT_V) < 1e-9:
        hi += 0.02 * (diagram.u_max - diagram.u_min)
    ax.set_xlim(diagram.u_min, hi)


def _style_handles(eq: set[bool], cyc: set[bool], points: bool) -> list:
    from matplotlib.lines import Line2D

    h = []
    for present, colour, what in (
        (eq, _EQ_COLOR, "equilibrium"),
        (cyc, _CYCLE_COLOR, "periodic orbit (max and min of x3)"),
    ):
        for st in (True, False):
            if st in present:
                label = f"{what}, {'stable' if st else 'unstable'}"
                h.append(Line2D([], [], color=colour, ls=_style(st), lw=1.5, label=label))
    if points:
        h.append(Line2D([], [], color=_POINT_COLOR, marker="o", ls="none", ms=4, label="the paper's points"))
    return h


def _room_for_labels(ax, frac: float = 0.06) -> None:
    """Widen the y range a little, so that a label fits beside a curve along an edge."""
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo - frac * (hi - lo), hi + frac * (hi - lo))


def _finish(
    ax,
    handles: list,
    labels: list[Label],
    own_figure: bool,
    *,
    legend_loc: str = "right",
    title: str | None = None,
) -> None:
    """Legend (below the figure on a figure of its own, else beside or below the axes),
    layout, then the labels placed clear of the data."""
    fig = ax.figure
    if handles and own_figure:
        legend_below(fig, handles, title=title)
    elif handles:
        if legend_loc == "right":
            ax.legend(
                handles=handles,
                fontsize=FONT,
                loc="upper left",
                bbox_to_anchor=(1.01, 1.0),
                borderaxespad=0.0,
                title=title,
                title_fontsize=FONT,
            )
        else:
            ax.legend(
                handles=handles,
                fontsize=FONT,
                loc="upper center",
                bbox_to_anchor=(0.5, -0.13),
                ncol=2,
                title=title,
                title_fontsize=FONT,
            )
    elif own_figure:
        fig.tight_layout()
    place_labels(ax, labels)


def legend_below(fig, handles: list, *, ncol: int = 2, title: str | None = None) -> Any:  # noqa: ANN401
    """One legend for the whole figure, centred below its axes, and the axes laid out above
    it (the legend's height measured, so that no entry covers an axis label)."""
    from drill_env._figures import renderer as figure_renderer

    leg = fig.legend(
        handles=handles,
        loc="lower center",
        bbox_to_anchor=(0.5, 0.005),
        ncol=min(ncol, len(handles)),
        fontsize=FONT,
        title=title,
        title_fontsize=FONT,
        frameon=False,
    )
    height = leg.get_window_extent(figure_renderer(fig)).height / (fig.dpi * fig.get_figheight())
    fig.tight_layout(rect=(0, min(0.6, height + 0.01), 1, 0.99 if fig.get_suptitle() else 1))
    return leg


def _own_figure(nrows: int, ncols: int, height: float, **kwargs: Any) -> Any:  # noqa: ANN401
    """Axes of a new figure FIGURE_WIDTH wide, their tick labels at FONT."""
    from drill_env._figures import user_subplots

    _, ax = user_subplots(nrows, ncols, figsize=(FIGURE_WIDTH, height), **kwargs)
    for a in np.atleast_1d(ax).flat:
        a.tick_params(labelsize=FONT)
    return ax


def plot_equilibria(diagram: BifurcationDiagram, ax=None):
    """Fig. 6: the equilibrium branches, twist x1 (a) and lower-disk speed x3 (b) against u."""
    from matplotlib.patches import Patch

    own = ax is None
    if own:
        ax = _own_figure(2, 1, 8.4)
    ax_a, ax_b = ax
    labels_a: list[Label] = []
    labels_b: list[Label] = []
    styles: set[bool] = set()
    stick = False
    for b in diagram.equilibrium_branches:
        st = bool(np.mean(b.stable) > 0.5)
        styles.add(st)
        if b.kind == "stick_set":
            stick = True
            ax_a.fill_between(b.u, b.x1_min, b.x1_max, color="0.85", lw=0)
            ax_a.plot(b.u, b.x1_min, _style(st), color=_EQ_COLOR, lw=1)
            ax_a.plot(b.u, b.x1_max, _style(st), color=_EQ_COLOR, lw=1)
        else:
            ax_a.plot(b.u, b.x1_min, _style(st), color=_EQ_COLOR, lw=1.5)
        ax_b.plot(b.u, b.x3, _style(st), color=_EQ_COLOR, lw=1.5)
        k = b.u.size // 2
        labels_b.append(Label(b.name, b.u[k], b.x3[k]))
        labels_a.append(
            Label(b.name, b.u[k], 0.5 * (b.x1_min[k] + b.x1_max[k]) if b.kind == "stick_set" else b.x1_max[k])
        )
    has_points = False
    for name in ("A", "B", "C"):
        pt = diagram.points.get(name)
        if pt is None:
            continue
        has_points = True
        x1 = pt.detail.get("x1", np.nan)
        x3 = pt.detail.get("x3", 0.0)
        for a, y, labs in ((ax_a, x1, labels_a), (ax_b, x3, labels_b)):
            a.plot([pt.u], [y], "o", color=_POINT_COLOR, ms=4, zorder=5)
            labs.append(Label(name, pt.u, y, _POINT_COLOR, 10))
    ax_a.set_xlabel("u = amplifier input [V]")
    ax_a.set_ylabel("x1 = twist at equilibrium [rad]")
    ax_b.set_xlabel("u = amplifier input [V]")
    ax_b.set_ylabel("x3 = lower-disk speed at equilibrium [rad/s]")
    ax_a.set_title(f"(a) twist at the equilibria, {diagram.preset}")
    ax_b.set_title(f"(b) lower-disk speed at the equilibria, {diagram.preset}")
    x3_top = max((float(np.max(b.x3)) for b in diagram.equilibrium_branches), default=0.0)
    handles = _style_handles(styles, set(), False)
    if has_points:
        from matplotlib.lines import Line2D

        handles.append(
            Line2D(
                [],
                [],
                color=_POINT_COLOR,
                marker="o",
                ls="none",
                ms=4,
                label=_points_legend(diagram, "ABC"),
            )
        )
    if stick:
        handles.append(Patch(color="0.85", label="stick set: every twist in the band is an equilibrium"))
    limit_handles: list = []
    _draw_limits(ax_a, diagram.preset, diagram.u_max, None, limit_handles)
    _draw_limits(ax_b, diagram.preset, diagram.u_max, x3_top, limit_handles)
    seen = set()
    for h in limit_handles:
        if h.get_label() not in seen:
            seen.add(h.get_label())
            handles.append(h)
    for a in ax:
        _set_u_range(a, diagram)
        a.grid(alpha=0.3)
        _room_for_labels(a)
    if own:
        legend_below(ax_a.figure, handles)
    else:
        ax_b.legend(handles=handles, fontsize=FONT, loc="best")
    place_labels(ax_a, labels_a)
    place_labels(ax_b, labels_b)
    return ax


def _check_runs(check) -> list:
    if check is None:
        return []
    return list(check.runs)


def plot_bifurcation(
    diagram: BifurcationDiagram,
    ax=None,
    check: BruteForceCheck | None = None,
    *,
    annotate: bool = True,
    legend: bool = True,
    limits: bool = True,
    lw: float = 1.5,
    alpha: float = 1.0,
):
    """Fig. 8: max and min of x3 on the periodic orbits and x3 at the equilibria against u.

    ``check``: the brute-force simulations, drawn as open markers (one marker style per
    way the simulation was started). ``annotate``: names of the branches and the paper's
    points; ``legend``: a legend beside the axes for every line and marker style;
    ``limits``: the amplifier limit and the identified speed range where the diagram
    reaches them; ``alpha``: opacity of the curves (below other data drawn on them). Returns the axes; the legend handles are in ``ax.diagram_handles``.
    """
    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    own = ax is None
    if own:
        ax = _own_figure(1, 1, 6.4)
    runs = _check_runs(check)
    labels, eq_styles, cyc_styles, y_top = _draw_x3(ax, diagram, runs, lw, alpha)
    handles = _style_handles(eq_styles, cyc_styles, False)
    if diagram.points:
        handles.append(
            Line2D([], [], color=_POINT_COLOR, marker="o", ls="none", ms=4, label=_points_legend(diagram))
        )
    if runs:
        handles.append(Line2D([], [], ls="none", label="simulations (steady max and min of x3):"))
    for kind, (m, size, what) in RUN_KINDS.items():
        if any(r.kind == kind for r in runs):
            handles.append(
                Line2D(
                    [], [], marker=m, mfc="none", mew=0.8, color=_SIM_COLOR, ms=size, ls="none", label=what
                )
            )
    if limits:
        _draw_limits(ax, diagram.preset, diagram.u_max, y_top, handles)
    _set_u_range(ax, diagram)
    ax.set_xlabel("u = amplifier input [V]")
    ax.set_ylabel("max and min of x3 = lower-disk speed [rad/s]")
    ax.set_title(f"bifurcation diagram, {diagram.preset}")
    ax.grid(alpha=0.3)
    ax.diagram_handles = handles
    zoom = _crowded_start(diagram) if annotate else None
    inset = None
    if zoom is not None:
        # the points near the start of motion crowd at this scale: an enlarged view
        inset = ax.inset_axes((0.04, 0.52, 0.26, 0.42))
        in_labels, *_ = _draw_x3(inset, diagram, runs, 1.0)
        inset.set_xlim(*zoom[0])
        inset.set_ylim(*zoom[1])
        inset.tick_params(labelsize=FONT)
        inset.xaxis.set_major_locator(MaxNLocator(3))
        inset.yaxis.set_major_locator(MaxNLocator(4))
        inset.grid(alpha=0.3)
        inset.set_title(f"enlarged: u = {zoom[0][0]:g} to {zoom[0][1]:g} V", fontsize=FONT)
        ax.indicate_inset_zoom(inset, edgecolor="0.4")
        names = {"A", "B", "D", "e1", "e2", "p1"}
        labels = [lab for lab in labels if not (lab.text in names and lab.x <= zoom[0][1])]
    if annotate:
        _room_for_labels(ax)
    if own or legend or annotate:
        _finish(ax, handles if legend else [], labels if annotate else [], own)
    if inset is not None and zoom is not None:
        place_labels(inset, [lab for lab in in_labels if lab.x <= zoom[0][1]])
    return ax


def _crowded_start(diagram: BifurcationDiagram) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """The (u, x3) window around A and B when they lie within 6 % of the u range of each
    other (too close to label at full scale), else None."""
    a, b = diagram.points.get("A"), diagram.points.get("B")
    span = diagram.u_max - diagram.u_min
    if a is None or b is None or b.u - diagram.u_min > 0.06 * span:
        return None
    u_hi = math.ceil(10.0 * (diagram.u_min + 2.5 * (b.u - diagram.u_min))) / 10.0
    ys = [0.0]
    for seg in diagram.periodic_segments:
        ys += [c.x3_max for c in seg.cycles if c.u <= u_hi] + [c.x3_min for c in seg.cycles if c.u <= u_hi]
    for br in diagram.equilibrium_branches:
        ys += list(br.x3[br.u <= u_hi])
    lo, hi = min(ys), max(ys)
    pad = 0.1 * (hi - lo or 1.0)
    return (diagram.u_min, u_hi), (lo - pad, hi + pad)


def _draw_x3(ax, diagram: BifurcationDiagram, runs: list, lw: float, alpha: float = 1.0):
    """The x3 curves of the diagram, its points and the simulation markers on ``ax``;
    returns (labels to place, equilibrium styles, cycle styles, largest x3 drawn)."""
    labels: list[Label] = []
    eq_styles: set[bool] = set()
    cyc_styles: set[bool] = set()
    y_top = 0.0
    for b in diagram.equilibrium_branches:
        st = bool(np.mean(b.stable) > 0.5)
        eq_styles.add(st)
        ax.plot(b.u, b.x3, _style(st), color=_EQ_COLOR, lw=lw, zorder=3, alpha=alpha)
        y_top = max(y_top, float(np.max(b.x3)))
        k = b.u.size // 2
        labels.append(Label(b.name, b.u[k], b.x3[k]))
    for seg in diagram.periodic_segments:
        st = _segment_stable(seg)
        cyc_styles.add(st)
        u, lo, hi = _segment_curves(diagram, seg)
        ax.plot(u, hi, _style(st), color=_CYCLE_COLOR, lw=lw, zorder=3, alpha=alpha)
        ax.plot(u, lo, _style(st), color=_CYCLE_COLOR, lw=lw, zorder=3, alpha=alpha)
        y_top = max(y_top, float(np.max(hi)))
        k = len(seg.cycles) // 2
        c = seg.cycles[k]
        labels.append(Label(seg.name, c.u, c.x3_max, _CYCLE_COLOR))
    for name, pt in diagram.points.items():
        if name == "A":
            y = [0.0]
        elif name in ("B", "C"):
            y = [pt.detail["x3"]]
        else:
            y = [pt.detail["x3_min"], pt.detail["x3_max"]]
        for yy in y:
            ax.plot([pt.u], [yy], "o", color=_POINT_COLOR, ms=4, zorder=5, alpha=alpha)
            labels.append(Label(name, pt.u, yy, _POINT_COLOR, 10))
    for kind, (m, size, _) in RUN_KINDS.items():
        rs = [r for r in runs if r.kind == kind]
        if not rs:
            continue
        uu = np.array([r.u for r in rs])
        for ys in ([r.x3_max for r in rs], [r.x3_min for r in rs]):
            ax.plot(uu, ys, m, mfc="none", mew=0.8, color=_SIM_COLOR, ms=size, zorder=2)
        y_top = max(y_top, max(r.x3_max for r in rs))
    return labels, eq_styles, cyc_styles, y_top


def _points_legend(diagram: BifurcationDiagram, names: str = "ABCDEF") -> str:
    """What the paper's points present in the diagram are, e.g. "A: start of motion, B, C: Hopf"."""
    groups = (
        ("A", "start of motion"),
        ("BC", "Hopf"),
        ("D", "stick-slip begins"),
        ("E", "stick-slip ends"),
        ("F", "fold of cycles"),
    )
    parts = []
    for keys, what in groups:
        present = [k for k in keys if k in diagram.points and k in names]
        if present:
            parts.append(f"{', '.join(present)}: {what}")
    lines = [", ".join(parts[i : i + 2]) for i in range(0, len(parts), 2)]
    return "the paper's points: " + ",\n".join(lines)


def plot_period(diagram: BifurcationDiagram, ax=None):
    """Period of the periodic orbits against u, with the linear period at the Hopf points."""
    from matplotlib.lines import Line2D

    own = ax is None
    if own:
        ax = _own_figure(1, 1, 5.0)
    labels: list[Label] = []
    styles: set[bool] = set()
    for seg in diagram.periodic_segments:
        st = _segment_stable(seg)
        styles.add(st)
        ax.plot(seg.u, [c.period for c in seg.cycles], _style(st), color=_CYCLE_COLOR, lw=1.5)
        k = len(seg.cycles) // 2
        labels.append(Label(seg.name, seg.u[k], seg.cycles[k].period, _CYCLE_COLOR))
    for name in ("B", "C", "D", "E", "F"):
        pt = diagram.points.get(name)
        if pt is not None:
            ax.plot([pt.u], [pt.detail["period"]], "o", color=_POINT_COLOR, ms=4, zorder=5)
            labels.append(Label(name, pt.u, pt.detail["period"], _POINT_COLOR, 10))
    handles = _style_handles(set(), styles, False)
    for h in handles:
        h.set_label(h.get_label().replace(" (max and min of x3)", ""))
    if any(k in diagram.points for k in "BCDEF"):
        handles.append(
            Line2D(
                [],
                [],
                color=_POINT_COLOR,
                marker="o",
                ls="none",
                ms=4,
                label=_points_legend(diagram, "BCDEF") + "\n(at B, C: the linear period 2π/ω)",
            )
        )
    _draw_limits(ax, diagram.preset, diagram.u_max, None, handles)
    _set_u_range(ax, diagram)
    ax.set_xlabel("u = amplifier input [V]")
    ax.set_ylabel("period [s]")
    ax.set_title(f"period of the limit cycles, {diagram.preset}")
    ax.grid(alpha=0.3)
    _room_for_labels(ax)
    _finish(ax, handles, labels, own)
    return ax


def plot_limit_cycles(cycles: Sequence[LimitCycle], axes=None, labels: Sequence[str] | None = None):
    """Projections of orbits on the planes x3 = 0 (x1, x2), x2 = 0 (x1, x3) and x1 = 0 (x2, x3).

    Without ``axes``: a figure of its own, the three projections in a 2 x 2 grid whose fourth
    cell holds the legend; returns the three axes."""
    own = axes is None
    if own:
        axes = _limit_cycle_axes()
    pairs = (("x1", "x2"), ("x1", "x3"), ("x2", "x3"))
    units = {"x1": "x1 = twist [rad]", "x2": "x2 = upper speed [rad/s]", "x3": "x3 = lower speed [rad/s]"}
    for i, c in enumerate(cycles):
        orb = c.orbit()
        lab = labels[i] if labels else f"u = {c.u:g} V" + (", stick-slip" if c.stick_slip else "")
        for a, (px, py) in zip(axes, pairs, strict=True):
            a.plot(getattr(orb, px), getattr(orb, py), _style(c.stable), lw=1.3, label=lab)
    titles = (
        "(a) projection on the (x1, x2) plane",
        "(b) on the (x1, x3) plane",
        "(c) on the (x2, x3) plane",
    )
    for a, (px, py), t in zip(axes, pairs, titles, strict=True):
        a.set_xlabel(units[px])
        a.set_ylabel(units[py])
        a.set_title(t, fontsize=FONT + 1)
        a.grid(alpha=0.3)
    if own:
        handles, texts = axes[0].get_legend_handles_labels()
        axes.legend_axes.legend(handles, texts, loc="center", fontsize=FONT, frameon=False)
        axes[0].figure.tight_layout()
    else:
        axes[0].legend(fontsize=FONT)
    return axes


class _CycleAxes(list):
    """The three projection axes of a limit-cycle figure, and the cell that holds its legend."""

    legend_axes: Any = None


def _limit_cycle_axes() -> _CycleAxes:
    grid = _own_figure(2, 2, 6.6)
    axes = _CycleAxes(grid.flat[:3])
    axes.legend_axes = grid[1, 1]
    axes.legend_axes.set_axis_off()
    return axes


def plot_fig9(diagram: BifurcationDiagram, ax=None, voltages: Sequence[float] = (1.0, 2.0)):
    """Fig. 9: the limit cycles of the diagram at the given voltages (default 1 V and 2 V)."""
    cycles, labels, none_at = [], [], []
    for u in voltages:
        found = diagram.cycles_at(u)
        if not found:
            none_at.append(u)
        for c in found:
            cycles.append(c)
            kind = "stick-slip" if c.stick_slip else "no stick-slip"
            labels.append(f"u = {u:g} V, {kind}, {'stable' if c.stable else 'unstable'}")
    if not cycles:
        if ax is None:
            ax = _limit_cycle_axes()
        ax[1].set_title(f"no limit cycle at u = {', '.join(f'{v:g}' for v in voltages)} V", fontsize=FONT + 1)
        return ax
    axes = plot_limit_cycles(cycles, axes=ax, labels=labels)
    title = f"limit cycles in state space, {diagram.preset}"
    if none_at:
        title += f"\n(no limit cycle at u = {', '.join(f'{v:g}' for v in none_at)} V)"
    fig = axes[1].figure
    fig.suptitle(title, fontsize=FONT + 2)
    if ax is None:
        fig.tight_layout()
    return axes


def save_figures(diagram: BifurcationDiagram, out_dir, check: BruteForceCheck | None = None) -> list:
    """Write the four figures as PNG files into ``out_dir``; returns their paths."""
    from pathlib import Path

    from drill_env._figures import offscreen

    out = Path(out_dir)
    paths = []
    for name, kind, kw in (
        ("fig6_equilibria.png", "fig6", {}),
        ("fig8_bifurcation.png", "fig8", {"check": check}),
        ("period.png", "period", {}),
        ("fig9_limit_cycles.png", "fig9", {}),
    ):
        with offscreen():
            ax = diagram.plot(kind, **kw)
        fig = (ax[0] if isinstance(ax, np.ndarray | list | tuple) else ax).figure
        save_figure(fig, out / name, dpi=FIGURE_DPI)
        paths.append(out / name)
    return paths
