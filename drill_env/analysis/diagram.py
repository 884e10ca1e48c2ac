"""The bifurcation diagram of the rig in the voltage u: Fig. 6 and Fig. 8 of the paper.

:func:`bifurcation_diagram` assembles

* the equilibrium branches: the stick set ``e1`` (eq. 26) up to point A, then the slip
  equilibria (eq. 20), split where their stability changes (``e2``, ``e3``, ``e4``);
* the periodic branches, continued from each Hopf point in the range until they return
  to an equilibrium (another Hopf point) or leave the range, split where the orbit
  starts or stops sticking or changes stability (``p1``, ``p2``, ...);
* the paper's points: A (start of motion), B and C (Hopf), D and E (the lower disk starts
  and stops sticking along the periodic branch: grazing, not bifurcations), F (fold of
  periodic orbits). A point outside the range is absent; other special points found on
  the way (a direction reversal appearing, further Hopf points, ...) are listed apart.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.analysis.continuation import (
    BranchEvent,
    ContinuationSettings,
    PeriodicBranch,
    continue_from_hopf,
    cycles_at,
)
from drill_env.analysis.equilibria import (
    Equilibrium,
    HopfPoint,
    critical_friction_slope,
    hopf_points,
    nominal_vector,
    slip_equilibrium,
    stick_set,
)
from drill_env.analysis.shooting import LimitCycle
from drill_env.params import RigParams

__all__ = [
    "EquilibriumBranch",
    "PeriodicSegment",
    "SpecialPoint",
    "BifurcationDiagram",
    "bifurcation_diagram",
    "POINT_TYPES",
]

POINT_TYPES = {
    "A": "start_of_motion",
    "D": "grazing_stick_onset",
    "E": "grazing_stick_end",
    "F": "fold_periodic",
}
_EVENT_TYPES = {
    "stick_onset": "grazing_stick_onset",
    "stick_end": "grazing_stick_end",
    "reversal_onset": "reversal_onset",
    "reversal_end": "reversal_end",
    "upper_stick_onset": "upper_stick_onset",
    "upper_stick_end": "upper_stick_end",
    "fold": "fold_periodic",
    "period_doubling": "period_doubling",
    "neimark_sacker": "neimark_sacker",
    "branch_point": "branch_point",
}


@dataclass
class EquilibriumBranch:
    """Equilibria over a range of u with one stability verdict each."""

    name: str
    kind: str  # "stick_set" or "slip"
    u: np.ndarray
    x1_min: np.ndarray
    x1_max: np.ndarray
    x3: np.ndarray
    stable: np.ndarray

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "kind": "equilibrium",
            "equilibrium_kind": self.kind,
            "stable": [bool(s) for s in self.stable],
            "u": self.u.tolist(),
            "x3_min": self.x3.tolist(),
            "x3_max": self.x3.tolist(),
            "x1_min": self.x1_min.tolist(),
            "x1_max": self.x1_max.tolist(),
        }


@dataclass
class PeriodicSegment:
    """A stretch of a periodic branch with one switching pattern and one stability."""

    name: str
    cycles: list[LimitCycle]

    @property
    def u(self) -> np.ndarray:
        return np.array([c.u for c in self.cycles])

    @property
    def stable(self) -> np.ndarray:
        return np.array([c.stable for c in self.cycles])

    @property
    def stick_slip(self) -> bool:
        inner = self.cycles[1:-1] or self.cycles
        return bool(np.mean([c.stick_slip for c in inner]) > 0.5)

    def to_dict(self) -> dict:
        cs = self.cycles
        return {
            "name": self.name,
            "kind": "periodic",
            "stable": [bool(c.stable) for c in cs],
            "u": [c.u for c in cs],
            "x3_min": [c.x3_min for c in cs],
            "x3_max": [c.x3_max for c in cs],
            "period": [c.period for c in cs],
            "multipliers": [[float(m.real) for m in c.multipliers] for c in cs],
            "multipliers_imag": [[float(m.imag) for m in c.multipliers] for c in cs],
            "trivial_multiplier_error": [c.trivial_multiplier_error for c in cs],
            "stick_fraction": [c.stick_fraction for c in cs],
            "x1_min": [c.x1_min for c in cs],
            "x1_max": [c.x1_max for c in cs],
            "section_x1": [float(c.xi[0]) for c in cs],
            "section_v": [float(c.xi[1]) for c in cs],
        }


@dataclass(frozen=True)
class SpecialPoint:
    name: str
    u: float
    type: str
    detail: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"u": self.u, "type": self.type, **self.detail}


@dataclass
class BifurcationDiagram:
    """Equilibria, periodic orbits and special points of the rig over [u_min, u_max]."""

    preset: str
    params: RigParams = field(repr=False)
    u_min: float
    u_max: float
    equilibrium_branches: list[EquilibriumBranch]
    periodic_segments: list[PeriodicSegment]
    points: dict[str, SpecialPoint]
    other_points: list[SpecialPoint]
    hopf: list[HopfPoint] = field(repr=False)
    branches: list[PeriodicBranch] = field(repr=False)
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def branch_names(self) -> list[str]:
        return [b.name for b in self.equilibrium_branches] + [s.name for s in self.periodic_segments]

    def segment(self, name: str) -> PeriodicSegment | EquilibriumBranch:
        stretches: list[PeriodicSegment | EquilibriumBranch] = [
            *self.equilibrium_branches,
            *self.periodic_segments,
        ]
        for b in stretches:
            if b.name == name:
                return b
        raise KeyError(name)

    def cycles_at(self, u: float) -> list[LimitCycle]:
        """Every periodic orbit of the diagram at voltage u (stable and unstable)."""
        _, p = nominal_vector(self.params)
        out: list[LimitCycle] = []
        for br in self.branches:
            for c in cycles_at(self.params, p, br, u):
                if not any(np.allclose(c.xi, o.xi, atol=1e-7) for o in out):
                    out.append(c)
        return out

    def stable_cycles_at(self, u: float) -> list[LimitCycle]:
        return [c for c in self.cycles_at(u) if c.stable]

    def checks(self) -> dict[str, Any]:
        """Self-checks over every orbit: the trivial Floquet multiplier, |mu - 1| and
        |M f - f| / |f|, and the periodicity residual |P(xi) - xi|; and whether the
        direction of each Hopf point's branch agrees with its first Lyapunov coefficient."""
        cycles = [c for br in self.branches for c in br.cycles]
        return {
            "orbits": len(cycles),
            "trivial_multiplier_max_deviation": max(
                (abs(c.multipliers[0] - 1.0) for c in cycles), default=None
            ),
            "trivial_eigenvector_max_error": max((c.trivial_multiplier_error for c in cycles), default=None),
            "periodicity_max_residual": max((c.residual for c in cycles), default=None),
            "hopf_direction_agrees_with_l1": {
                k: v.detail.get("branch_agrees_with_l1") for k, v in self.points.items() if k in ("B", "C")
            },
        }

    def to_dict(self) -> dict[str, Any]:
        return {
            "preset": self.preset,
            "u_range": [self.u_min, self.u_max],
            "points": {k: v.to_dict() for k, v in self.points.items()},
            "other_points": [{"name": o.name, **o.to_dict()} for o in self.other_points],
            "branches": [b.to_dict() for b in self.equilibrium_branches]
            + [s.to_dict() for s in self.periodic_segments],
            "critical_friction_slope": critical_friction_slope(self.params),
            "checks": self.checks(),
            "continuation": [
                {
                    "from_hopf_u": br.start.u,
                    "end": br.end_reason,
                    "orbits": len(br.cycles),
                    "newton_iterations": br.newton_iterations,
                    "flow_evaluations": br.flow_evaluations,
                }
                for br in self.branches
            ],
        }

    def save_json(self, path: str | Path) -> None:
        from drill_env.outputs import atomic_write_text

        atomic_write_text(path, json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n")

    def plot(self, kind: str = "fig8", ax=None, **kwargs):
        """Figures in the style of the paper: ``"fig6"``, ``"fig8"``, ``"period"``, ``"fig9"``."""
        from drill_env.analysis import plots

        makers = {
            "fig6": plots.plot_equilibria,
            "fig8": plots.plot_bifurcation,
            "period": plots.plot_period,
            "fig9": plots.plot_fig9,
        }
        if kind not in makers:
            raise ValueError(f"kind: expected one of {sorted(makers)}, got {kind!r}")
        return makers[kind](self, ax=ax, **kwargs)


# -- assembly -------------------------------------------------------------------------------


def _equilibrium_branches(
    params: RigParams, u_min: float, u_max: float, hopf: list[HopfPoint], n: int
) -> list[EquilibriumBranch]:
    out: list[EquilibriumBranch] = []
    # The stick set, eq. (26), over the part of range (25) inside [u_min, u_max].
    lo, hi = max(u_min, params.uc1_neg), min(u_max, params.uc1)
    if lo <= hi:
        us = np.linspace(lo, hi, max(3, n // 8))
        sets = [_stick_band(params, u) for u in us]
        out.append(
            EquilibriumBranch(
                name="e1",
                kind="stick_set",
                u=us,
                x1_min=np.array([s[0] for s in sets]),
                x1_max=np.array([s[1] for s in sets]),
                x3=np.zeros(us.size),
                stable=np.ones(us.size, dtype=bool),
            )
        )
    # Slip equilibria, forward (u > u_c1) and backward (u < -(T_sun + T_sl)/k_m).
    pieces = []
    if u_max > params.uc1:
        pieces.append((max(u_min, params.uc1), u_max, 1))
    if u_min < params.uc1_neg:
        pieces.append((u_min, min(u_max, params.uc1_neg), -1))
    count_fwd = 1
    count_bwd = 0
    for a, b, direction in pieces:
        cuts = sorted(h.u for h in hopf if a < h.u < b)
        us = np.unique(np.concatenate([np.linspace(a, b, n), cuts]))
        # The end at the stick range is approached but not taken (the speed is 0 there).
        eqs = []
        for u in us:
            uu = u
            if direction > 0 and u <= params.uc1:
                uu = params.uc1 + 1e-12 * max(1.0, abs(params.uc1))
            if direction < 0 and u >= params.uc1_neg:
                uu = params.uc1_neg - 1e-12 * max(1.0, abs(params.uc1_neg))
            eqs.append(_slip(params, uu))
        stable = np.array([e.stable for e in eqs])
        # A Hopf point belongs to both neighbouring stretches.
        bounds = [0]
        for c in cuts:
            bounds.append(int(np.flatnonzero(np.isclose(us, c, rtol=0, atol=1e-15))[0]))
        bounds.append(us.size - 1)
        for i0, i1 in zip(bounds[:-1], bounds[1:], strict=True):
            idx = np.arange(i0, i1 + 1)
            seg_stable = stable[idx].copy()
            inner = seg_stable[1:-1] if idx.size > 2 else seg_stable
            verdict = bool(np.mean(inner) > 0.5)
            seg_stable[:] = verdict
            if direction > 0:
                count_fwd += 1
                name = f"e{count_fwd}"
            else:
                count_bwd += 1
                name = f"e-{count_bwd}"
            out.append(
                EquilibriumBranch(
                    name=name,
                    kind="slip",
                    u=us[idx],
                    x1_min=np.array([eqs[i].x1_min for i in idx]),
                    x1_max=np.array([eqs[i].x1_max for i in idx]),
                    x3=np.array([eqs[i].x3 for i in idx]),
                    stable=seg_stable,
                )
            )
    return out


_SPLITTING = ("stick_onset", "stick_end", "fold", "period_doubling", "neimark_sacker", "branch_point")


def _segments(branches: list[PeriodicBranch]) -> list[PeriodicSegment]:
    """Split the branches where the lower disk starts/stops sticking or the stability changes.

    The located orbit of each such point ends one segment and starts the next.
    """
    out: list[PeriodicSegment] = []
    k = 0
    for br in branches:
        splits: dict[int, list[BranchEvent]] = {}
        for e in br.events:
            if e.kind in _SPLITTING:
                splits.setdefault(e.index, []).append(e)
        current: list[LimitCycle] = [br.cycles[0]]
        for i in range(1, len(br.cycles)):
            for ev in sorted(splits.get(i, []), key=lambda e: abs(e.u - br.cycles[i - 1].u)):
                current.append(ev.cycle)
                k += 1
                out.append(PeriodicSegment(name=f"p{k}", cycles=current))
                current = [ev.cycle]
            current.append(br.cycles[i])
        if len(current) > 1:
            k += 1
            out.append(PeriodicSegment(name=f"p{k}", cycles=current))
    return out


def _event_point(name: str, ev: BranchEvent) -> SpecialPoint:
    c = ev.cycle
    detail = {
        "x3_min": c.x3_min,
        "x3_max": c.x3_max,
        "period": c.period,
        "stick_fraction": c.stick_fraction,
        "multipliers_real": [float(m.real) for m in c.multipliers],
        "multipliers_imag": [float(m.imag) for m in c.multipliers],
    }
    if ev.kind == "fold":
        detail["multiplier_near_1"] = ev.detail.get("multiplier_near_1")
    if ev.kind in ("stick_onset", "stick_end"):
        detail["note"] = "grazing of x3 = 0 by the periodic orbit; not a bifurcation"
    return SpecialPoint(name=name, u=ev.u, type=_EVENT_TYPES[ev.kind], detail=detail)


def _stick_band(params: RigParams, u: float) -> tuple[float, float]:
    """The stick set at a voltage inside its range (25)."""
    band = stick_set(params, u)
    assert band is not None, u
    return band


def _slip(params: RigParams, u: float) -> Equilibrium:
    """The slip equilibrium at a voltage outside the stick range."""
    eq = slip_equilibrium(params, u)
    assert eq is not None, u
    return eq


def _hopf_point(params: RigParams, name: str, h: HopfPoint, branches: list[PeriodicBranch]) -> SpecialPoint:
    detail: dict[str, Any] = {
        "x1": float(h.x_eq[0]),
        "x3": float(h.x_eq[2]),
        "omega": h.omega,
        "period": h.period,
        "l1": h.l1,
        "crossing_speed": h.crossing_speed,
        "friction_slope": h.friction_slope,
    }
    # The direction of the emerging branch: cycles where the equilibrium is unstable
    # make the Hopf point supercritical, cycles where it is stable subcritical.
    side = None
    for br in branches:
        if br.start is h and len(br.cycles) > 1:
            side = br.cycles[1].u
        elif br.end_hopf_u is not None and abs(br.end_hopf_u - h.u) < 1e-9 and len(br.cycles) > 1:
            side = br.cycles[-1].u
    if side is not None and side != h.u:
        eq = _slip(params, side)
        by_branch = "hopf_supercritical" if not eq.stable else "hopf_subcritical"
        detail["type_from_branch"] = by_branch
        detail["branch_agrees_with_l1"] = by_branch == h.kind
    return SpecialPoint(name=name, u=h.u, type=h.kind, detail=detail)


def bifurcation_diagram(
    params: RigParams | str,
    u_max: float = 5.0,
    u_min: float = 0.0,
    *,
    n_equilibria: int = 400,
    settings: ContinuationSettings | None = None,
    on_point: Callable[[LimitCycle], None] | None = None,
) -> BifurcationDiagram:
    """The bifurcation diagram of the paper's model in u over [u_min, u_max] [V].

    ``on_point`` is called with each orbit found along the continuation (for progress
    displays).
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    preset = params if isinstance(params, str) else getattr(params, "name", "custom")
    params, p = nominal_vector(params)
    if not (math.isfinite(u_min) and math.isfinite(u_max) and u_max > u_min):
        raise ValueError(f"u range: need finite u_min < u_max, got [{u_min!r}, {u_max!r}]")
    settings = settings or ContinuationSettings()
    hopf = hopf_points(params, u_min, u_max)
    eq_branches = _equilibrium_branches(params, u_min, u_max, hopf, n_equilibria)
    timings["equilibria"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    branches: list[PeriodicBranch] = []
    reached: list[float] = []
    hopf_us = [h.u for h in hopf]
    for h in hopf:
        if any(abs(h.u - r) < 1e-9 for r in reached):
            continue
        br = continue_from_hopf(params, p, h, u_min, u_max, hopf_us, settings, on_point)
        branches.append(br)
        reached.append(h.u)
        if br.end_hopf_u is not None:
            reached.append(br.end_hopf_u)
    timings["continuation"] = time.perf_counter() - t1
    segments = _segments(branches)

    points: dict[str, SpecialPoint] = {}
    other: list[SpecialPoint] = []
    if u_min <= params.uc1 <= u_max:
        s = _stick_band(params, params.uc1)
        points["A"] = SpecialPoint(
            name="A",
            u=params.uc1,
            type=POINT_TYPES["A"],
            detail={
                "x1": s[0],
                "x3": 0.0,
                "note": "the stick set shrinks to a point; no change of stability",
            },
        )
    forward = [h for h in hopf if h.x_eq[2] > 0]
    for i, h in enumerate(forward):
        name = "B" if i == 0 else "C" if i == 1 else f"H{i + 1}"
        sp = _hopf_point(params, name, h, branches)
        if name in ("B", "C"):
            points[name] = sp
        else:
            other.append(sp)
    for i, h in enumerate(x for x in hopf if x.x_eq[2] < 0):
        other.append(_hopf_point(params, f"H-{i + 1}", h, branches))
    for br in branches:
        for ev in br.events:
            letter = {"stick_onset": "D", "stick_end": "E", "fold": "F"}.get(ev.kind)
            if letter is not None and letter not in points:
                points[letter] = _event_point(letter, ev)
            else:
                other.append(_event_point(ev.kind, ev))
    order = "ABCDEF"
    points = {k: points[k] for k in sorted(points, key=order.index)}
    timings["total"] = time.perf_counter() - t0
    return BifurcationDiagram(
        preset=str(preset),
        params=params,
        u_min=float(u_min),
        u_max=float(u_max),
        equilibrium_branches=eq_branches,
        periodic_segments=segments,
        points=points,
        other_points=other,
        hopf=hopf,
        branches=branches,
        timings=timings,
    )
