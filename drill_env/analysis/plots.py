"""Figures of the bifurcation analysis in the style of the paper's Fig. 6, 8 and 9.

Stable branches are drawn solid, unstable ones dashed; the paper's points are labelled.
matplotlib is imported inside each function.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from drill_env.analysis.diagram import BifurcationDiagram, PeriodicSegment
    from drill_env.analysis.shooting import LimitCycle
    from drill_env.analysis.sweep import BruteForceCheck

__all__ = [
    "plot_equilibria",
    "plot_bifurcation",
    "plot_period",
    "plot_fig9",
    "plot_limit_cycles",
    "save_figures",
]

_EQ_COLOR = "k"
_CYCLE_COLOR = "tab:blue"
_POINT_COLOR = "tab:red"


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


def _label_point(ax, name: str, u: float, y: float) -> None:
    ax.plot([u], [y], "o", color=_POINT_COLOR, ms=4, zorder=5)  # above curves and markers
    ax.annotate(name, (u, y), textcoords="offset points", xytext=(4, 4), color=_POINT_COLOR, fontsize=10)


def _equilibrium_x3_at(diagram: BifurcationDiagram, u: float) -> float:
    from drill_env.analysis.equilibria import equilibria

    return float(equilibria(diagram.params, u)[0].x3)


def plot_equilibria(diagram: BifurcationDiagram, ax=None):
    """Fig. 6: the equilibrium branches, twist x1 (a) and lower-disk speed x3 (b) against u."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax_a, ax_b = ax
    for b in diagram.equilibrium_branches:
        st = bool(np.mean(b.stable) > 0.5)
        if b.kind == "stick_set":
            ax_a.fill_between(b.u, b.x1_min, b.x1_max, color="0.85", lw=0)
            ax_a.plot(b.u, b.x1_min, _style(st), color=_EQ_COLOR, lw=1)
            ax_a.plot(b.u, b.x1_max, _style(st), color=_EQ_COLOR, lw=1)
        else:
            ax_a.plot(b.u, b.x1_min, _style(st), color=_EQ_COLOR, lw=1.5)
        ax_b.plot(b.u, b.x3, _style(st), color=_EQ_COLOR, lw=1.5)
        k = b.u.size // 2
        ax_b.annotate(b.name, (b.u[k], b.x3[k]), textcoords="offset points", xytext=(0, 6), fontsize=9)
        ax_a.annotate(b.name, (b.u[k], b.x1_max[k]), textcoords="offset points", xytext=(0, 6), fontsize=9)
    for name in ("A", "B", "C"):
        pt = diagram.points.get(name)
        if pt is None:
            continue
        x1 = pt.detail.get("x1", np.nan)
        x3 = pt.detail.get("x3", 0.0)
        _label_point(ax_a, name, pt.u, x1)
        _label_point(ax_b, name, pt.u, x3)
    ax_a.set_xlabel("u [V]")
    ax_a.set_ylabel("x1 = twist at equilibrium [rad]")
    ax_b.set_xlabel("u [V]")
    ax_b.set_ylabel("x3 = lower-disk speed at equilibrium [rad/s]")
    ax_a.set_title(f"(a) equilibria, {diagram.preset}")
    ax_b.set_title("(b) solid: stable, dashed: unstable")
    for a in ax:
        a.set_xlim(diagram.u_min, diagram.u_max)
        a.grid(alpha=0.3)
    return ax


def plot_bifurcation(diagram: BifurcationDiagram, ax=None, check: BruteForceCheck | None = None):
    """Fig. 8: max and min of x3 on the periodic orbits and x3 at the equilibria against u."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(8, 5))
    for b in diagram.equilibrium_branches:
        st = bool(np.mean(b.stable) > 0.5)
        ax.plot(b.u, b.x3, _style(st), color=_EQ_COLOR, lw=1.5, zorder=3)
        k = b.u.size // 2
        ax.annotate(b.name, (b.u[k], b.x3[k]), textcoords="offset points", xytext=(0, -12), fontsize=9)
    for seg in diagram.periodic_segments:
        st = bool(np.mean(seg.stable[1:-1] if len(seg.cycles) > 2 else seg.stable) > 0.5)
        u, lo, hi = _segment_curves(diagram, seg)
        ax.plot(u, hi, _style(st), color=_CYCLE_COLOR, lw=1.5, zorder=3)
        ax.plot(u, lo, _style(st), color=_CYCLE_COLOR, lw=1.5, zorder=3)
        k = len(seg.cycles) // 2
        c = seg.cycles[k]
        ax.annotate(
            seg.name,
            (c.u, c.x3_max),
            textcoords="offset points",
            xytext=(0, 6),
            fontsize=9,
            color=_CYCLE_COLOR,
        )
    for name, pt in diagram.points.items():
        if name == "A":
            y = [0.0]
        elif name in ("B", "C"):
            y = [pt.detail["x3"]]
        else:
            y = [pt.detail["x3_min"], pt.detail["x3_max"]]
        for yy in y:
            _label_point(ax, name, pt.u, yy)
    if check is not None:
        marks = {"small": ("o", 4), "large": ("s", 3), "forward": ("^", 4), "backward": ("v", 4)}
        for kind, (m, size) in marks.items():
            rs = [r for r in check.runs if r.kind == kind]
            if not rs:
                continue
            uu = np.array([r.u for r in rs])
            ax.plot(
                uu,
                [r.x3_max for r in rs],
                m,
                mfc="none",
                mew=0.8,
                color="tab:orange",
                ms=size,
                zorder=2,
                label=f"simulation: {kind}",
            )
            ax.plot(uu, [r.x3_min for r in rs], m, mfc="none", mew=0.8, color="tab:orange", ms=size, zorder=2)
        ax.legend(fontsize=8, loc="upper left")
    ax.set_xlim(diagram.u_min, diagram.u_max)
    ax.set_xlabel("u [V]")
    ax.set_ylabel("max / min of x3 = lower-disk speed [rad/s]")
    ax.set_title(f"bifurcation diagram, {diagram.preset} (solid: stable, dashed: unstable)")
    ax.grid(alpha=0.3)
    return ax


def plot_period(diagram: BifurcationDiagram, ax=None):
    """Period of the periodic orbits against u, with the linear period at the Hopf points."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(8, 4))
    for seg in diagram.periodic_segments:
        st = bool(np.mean(seg.stable[1:-1] if len(seg.cycles) > 2 else seg.stable) > 0.5)
        ax.plot(seg.u, [c.period for c in seg.cycles], _style(st), color=_CYCLE_COLOR, lw=1.5)
        k = len(seg.cycles) // 2
        ax.annotate(
            seg.name, (seg.u[k], seg.cycles[k].period), textcoords="offset points", xytext=(0, 6), fontsize=9
        )
    for name in ("B", "C"):
        pt = diagram.points.get(name)
        if pt is not None:
            _label_point(ax, name, pt.u, pt.detail["period"])
    for name in ("D", "E", "F"):
        pt = diagram.points.get(name)
        if pt is not None:
            _label_point(ax, name, pt.u, pt.detail["period"])
    ax.set_xlim(diagram.u_min, diagram.u_max)
    ax.set_xlabel("u [V]")
    ax.set_ylabel("period [s]")
    ax.set_title(f"period of the limit cycles, {diagram.preset}")
    ax.grid(alpha=0.3)
    return ax


def plot_limit_cycles(cycles: Sequence[LimitCycle], axes=None, labels: Sequence[str] | None = None):
    """Projections of orbits on the planes x3 = 0 (x1, x2), x2 = 0 (x1, x3) and x1 = 0 (x2, x3)."""
    import matplotlib.pyplot as plt

    if axes is None:
        _, axes = plt.subplots(1, 3, figsize=(13, 4))
    pairs = (("x1", "x2"), ("x1", "x3"), ("x2", "x3"))
    units = {"x1": "x1 = twist [rad]", "x2": "x2 = upper speed [rad/s]", "x3": "x3 = lower speed [rad/s]"}
    for i, c in enumerate(cycles):
        orb = c.orbit()
        lab = labels[i] if labels else f"u = {c.u:g} V" + (", stick-slip" if c.stick_slip else "")
        for a, (px, py) in zip(axes, pairs, strict=True):
            a.plot(getattr(orb, px), getattr(orb, py), _style(c.stable), lw=1.3, label=lab)
    for a, (px, py), t in zip(
        axes, pairs, ("(a) plane x3 = 0", "(b) plane x2 = 0", "(c) plane x1 = 0"), strict=True
    ):
        a.set_xlabel(units[px])
        a.set_ylabel(units[py])
        a.set_title(t)
        a.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
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
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(1, 3, figsize=(13, 4))
        ax[1].set_title(f"no limit cycle at u = {', '.join(f'{v:g}' for v in voltages)} V")
        return ax
    axes = plot_limit_cycles(cycles, axes=ax, labels=labels)
    title = f"limit cycles in state space, {diagram.preset}"
    if none_at:
        title += f" (no limit cycle at u = {', '.join(f'{v:g}' for v in none_at)} V)"
    axes[1].figure.suptitle(title)
    return axes


def save_figures(diagram: BifurcationDiagram, out_dir, check: BruteForceCheck | None = None) -> list:
    """Write the four figures as PNG files into ``out_dir``; returns their paths."""
    from pathlib import Path

    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    paths = []
    for name, kind, kw in (
        ("fig6_equilibria.png", "fig6", {}),
        ("fig8_bifurcation.png", "fig8", {"check": check}),
        ("period.png", "period", {}),
        ("fig9_limit_cycles.png", "fig9", {}),
    ):
        ax = diagram.plot(kind, **kw)
        fig = (ax[0] if isinstance(ax, np.ndarray | list | tuple) else ax).figure
        fig.tight_layout()
        fig.savefig(out / name, dpi=130)
        plt.close(fig)
        paths.append(out / name)
    return paths
