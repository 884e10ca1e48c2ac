"""Pseudo-arclength continuation of the rig's periodic orbits in the voltage u.

Unknowns ``X = (x1, v, u)``: the section point of the orbit (see
:mod:`drill_env.analysis.shooting`) and the voltage. The orbit condition
``G(X) = P(x1, v; u) - (x1, v) = 0`` has two equations, so the solutions form a curve;
it is followed with a tangent predictor and a Newton corrector on the hyperplane
orthogonal to the tangent, with step-size control from the corrector's effort.

A branch starts at a Hopf point: the linear eigenvector gives the direction of a
small cycle on the section, and the first orbit is solved with its distance from the
equilibrium fixed (the amplitude, not u, is the parameter there). It ends where its
amplitude shrinks back to zero (at another Hopf point), where u leaves the range, or
when the step size collapses.

Along the branch, between consecutive orbits, the following are detected and
located by bisection along the chord (each intermediate orbit solved exactly):

* a change of the orbit's switching pattern: the lower disk starts to stick (grazing
  of x3 = 0, the paper's point D) or stops sticking (E), a direction reversal appears or
  disappears, the upper disk sticks; these are not bifurcations;
* a fold (the tangent's u component changes sign; a Floquet multiplier passes +1),
  the paper's point F;
* any other change of stability (a multiplier through -1 or a complex pair through
  the unit circle), reported as period doubling or Neimark-Sacker.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drill_env.analysis.equilibria import HopfPoint
from drill_env.analysis.shooting import (
    LimitCycle,
    SectionReturn,
    ShootingError,
    make_cycle,
    section_return,
    solve_periodic,
)
from drill_env.params import RigParams

__all__ = ["BranchEvent", "PeriodicBranch", "continue_from_hopf", "ContinuationSettings"]


@dataclass(frozen=True)
class ContinuationSettings:
    ds_initial: float = 0.02  # first arclength step in (x1 [rad], v [rad/s], u [V])
    ds_min: float = 1e-6
    ds_max: float | None = None  # default 0.03 per 2.5 V of the range
    start_amplitude: float = 0.01  # distance of the first orbit's section point from the equilibrium
    end_amplitude: float = 0.02  # a branch whose x3 amplitude falls below this ends at a Hopf point
    newton_tol: float = 1e-10
    newton_max_iter: int = 8
    max_points: int = 3000
    locate_tol_u: float = 1e-9  # [V] bisection of special points
    max_turn_cos: float = 0.95  # reject a step whose tangent turns more than ~18 degrees


@dataclass(frozen=True)
class BranchEvent:
    """A special point on a periodic branch, located between orbits ``index - 1`` and ``index``."""

    kind: str  # e.g. "stick_onset", "stick_end", "fold", "period_doubling", ...
    u: float
    index: int
    cycle: LimitCycle
    detail: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"type": self.kind, "u": self.u, **self.detail}


@dataclass
class PeriodicBranch:
    """Orbits along one continuation run, in continuation order."""

    start: HopfPoint
    cycles: list[LimitCycle] = field(default_factory=list)
    tangents: list[np.ndarray] = field(default_factory=list)
    events: list[BranchEvent] = field(default_factory=list)
    end_reason: str = ""
    end_hopf_u: float | None = None  # u of the Hopf point the branch returned to, if any
    newton_iterations: int = 0
    flow_evaluations: int = 0

    @property
    def u(self) -> np.ndarray:
        return np.array([c.u for c in self.cycles])


def _signature(c: LimitCycle) -> tuple[int, int, int]:
    """The switching pattern of an orbit: (lower disk sticks, reverses, upper disk sticks)."""
    return (int(c.stick_fraction > 0.0), int(c.reversals > 0), int(c.upper_stick_fraction > 0.0))


def _n_unstable(c: LimitCycle) -> int:
    return int(np.sum(np.abs(c.multipliers[1:]) > 1.0))


class _Solver:
    """Residual, Jacobian and corrector of the orbit condition for one parameter vector."""

    def __init__(self, params: RigParams, p: np.ndarray, settings: ContinuationSettings):
        self.params = params
        self.p = p
        self.s = settings
        self.flows = 0
        self.iterations = 0

    def ret(self, X: np.ndarray) -> SectionReturn:
        self.flows += 1
        return section_return(self.p, float(X[2]), X[:2])

    @staticmethod
    def jac(r: SectionReturn) -> np.ndarray:
        return np.column_stack([r.dP_dxi - np.eye(2), r.dP_du])

    @staticmethod
    def tangent(DG: np.ndarray, orient: np.ndarray) -> np.ndarray:
        t = np.cross(DG[0], DG[1])
        t /= np.linalg.norm(t)
        return t if t @ orient >= 0 else -t

    def correct(
        self, X0: np.ndarray, normal: np.ndarray, anchor: np.ndarray
    ) -> tuple[np.ndarray, SectionReturn]:
        """Newton on G(X) = 0, normal . (X - anchor) = 0 from X0."""
        X = X0.copy()
        for _ in range(self.s.newton_max_iter):
            r = self.ret(X)
            self.iterations += 1
            H = np.concatenate([r.residual, [normal @ (X - anchor)]])
            Jm = np.vstack([self.jac(r), normal])
            dX = np.linalg.solve(Jm, -H)
            X = X + dX
            if np.linalg.norm(dX) <= self.s.newton_tol * (1.0 + np.linalg.norm(X)):
                r = self.ret(X)
                if np.linalg.norm(r.residual) <= 1e3 * self.s.newton_tol * (1.0 + np.linalg.norm(X)):
                    return X, r
        raise ShootingError("corrector did not converge")

    def cycle(self, r: SectionReturn) -> LimitCycle:
        return make_cycle(self.params, self.p, r)


def _first_orbit(
    solver: _Solver, hopf: HopfPoint, eps: float
) -> tuple[np.ndarray, SectionReturn, np.ndarray]:
    """The small cycle next to the Hopf point, its distance from the equilibrium on the
    section fixed to ``eps``; returns (X, return, direction of growing amplitude)."""
    q = hopf.eigenvector
    c = q[1] - q[2]
    phase = 0.5 * math.pi - math.atan2(c.imag, c.real)
    r_vec = np.real(q * np.exp(1j * phase))  # on the section (r_vec[1] == r_vec[2]), x1 at its maximum
    d_un = np.array([r_vec[0], r_vec[2]])
    d = d_un / np.linalg.norm(d_un)
    xi_h = np.array([hopf.x_eq[0], hopf.x_eq[2]])
    radius = eps / (2.0 * np.linalg.norm(d_un))
    du = hopf.amplitude_offset(float(radius))
    normal = np.array([d[0], d[1], 0.0])
    anchor = np.array([xi_h[0] + eps * d[0], xi_h[1] + eps * d[1], hopf.u])
    X0 = anchor.copy()
    X0[2] += du
    X, r = solver.correct(X0, normal, anchor)
    return X, r, normal


def _bisect(
    solver: _Solver,
    Xa: np.ndarray,
    Xb: np.ndarray,
    side_of: Callable[[np.ndarray, SectionReturn], bool],
    tol_u: float,
) -> tuple[np.ndarray, SectionReturn]:
    """Bisection along the chord Xa -> Xb for the change of ``side_of`` (False at a, True at b)."""
    chord = Xb - Xa
    a, b = 0.0, 1.0
    Xbest: np.ndarray | None = None
    rbest: SectionReturn | None = None
    for _ in range(80):
        m = 0.5 * (a + b)
        anchor = Xa + m * chord
        try:
            X, r = solver.correct(anchor, chord, anchor)
        except ShootingError:
            break
        if side_of(X, r):
            b = m
            Xbest, rbest = X, r
        else:
            a = m
        if abs(chord[2]) * (b - a) <= tol_u and np.linalg.norm(chord) * (b - a) <= 1e3 * tol_u:
            break
    if Xbest is None or rbest is None:  # set together
        anchor = Xa + b * chord
        Xbest, rbest = solver.correct(anchor, chord, anchor)
    return Xbest, rbest


def continue_from_hopf(
    params: RigParams,
    p: np.ndarray,
    hopf: HopfPoint,
    u_min: float,
    u_max: float,
    hopf_us: list[float] | None = None,
    settings: ContinuationSettings | None = None,
    on_point: Callable[[LimitCycle], None] | None = None,
) -> PeriodicBranch:
    """Follow the periodic orbits born at ``hopf`` while u stays in [u_min, u_max]."""
    s = settings or ContinuationSettings()
    solver = _Solver(params, p, s)
    branch = PeriodicBranch(start=hopf)
    X, r, grow = _first_orbit(solver, hopf, s.start_amplitude)
    t = solver.tangent(solver.jac(r), grow)
    cyc = solver.cycle(r)
    branch.cycles.append(cyc)
    branch.tangents.append(t)
    if on_point:
        on_point(cyc)
    ds = s.ds_initial
    ds_max = s.ds_max if s.ds_max is not None else 0.03 * max(1.0, (u_max - u_min) / 2.5)
    hopf_us = list(hopf_us or [])
    while True:
        if len(branch.cycles) >= s.max_points:
            branch.end_reason = "maximum number of points"
            break
        if ds < s.ds_min:
            branch.end_reason = f"step size fell below {s.ds_min:g} at u = {X[2]:.6g} V"
            break
        Xp = X + ds * t
        boundary = None
        if Xp[2] > u_max or Xp[2] < u_min:
            boundary = u_max if Xp[2] > u_max else u_min
        it0 = solver.iterations
        try:
            if boundary is not None:
                # The last orbit exactly on the boundary of the range.
                frac = (boundary - X[2]) / (Xp[2] - X[2])
                Xg = X + frac * (Xp - X)
                e_u = np.array([0.0, 0.0, 1.0])
                Xn, rn = solver.correct(Xg, e_u, Xg)
            else:
                Xn, rn = solver.correct(Xp, t, Xp)
            n_it = solver.iterations - it0
        except (ShootingError, np.linalg.LinAlgError):
            ds *= 0.5
            continue
        tn = solver.tangent(solver.jac(rn), t)
        if tn @ t < s.max_turn_cos and ds > 4 * s.ds_min:
            ds *= 0.5
            continue
        try:
            cn = solver.cycle(rn)
        except np.linalg.LinAlgError:
            ds *= 0.5
            continue
        _detect(solver, branch, X, r, t, Xn, rn, tn, cn, s)
        X, r, t = Xn, rn, tn
        branch.cycles.append(cn)
        branch.tangents.append(tn)
        if on_point:
            on_point(cn)
        if boundary is not None:
            branch.end_reason = f"u reached the end of the range ({boundary:g} V)"
            break
        amp = cn.amplitude
        shrinking = len(branch.cycles) > 3 and amp < branch.cycles[-2].amplitude
        if shrinking and amp < s.end_amplitude:
            near = [h for h in hopf_us if abs(h - cn.u) < 0.05 * max(1.0, abs(h))]
            branch.end_hopf_u = min(near, key=lambda h: abs(h - cn.u)) if near else None
            branch.end_reason = (
                f"amplitude fell below {s.end_amplitude:g} rad/s next to the Hopf point at u = {branch.end_hopf_u:.6g} V"
                if near
                else f"amplitude fell below {s.end_amplitude:g} rad/s at u = {cn.u:.6g} V (no Hopf point near)"
            )
            break
        # Step-size control from the corrector's effort.
        ds = min(ds_max, ds * (1.5 if n_it <= 2 else 1.1 if n_it <= 4 else 0.7))
    branch.newton_iterations = solver.iterations
    branch.flow_evaluations = solver.flows
    return branch


def _detect(
    solver: _Solver,
    branch: PeriodicBranch,
    Xa: np.ndarray,
    ra: SectionReturn,
    ta: np.ndarray,
    Xb: np.ndarray,
    rb: SectionReturn,
    tb: np.ndarray,
    cb: LimitCycle,
    s: ContinuationSettings,
) -> None:
    ca = branch.cycles[-1]
    index = len(branch.cycles)
    sig_a, sig_b = _signature(ca), _signature(cb)
    fold = (ta[2] > 0) != (tb[2] > 0)
    names = (
        ("stick_onset", "stick_end"),
        ("reversal_onset", "reversal_end"),
        ("upper_stick_onset", "upper_stick_end"),
    )
    for k in range(3):
        if sig_a[k] == sig_b[k]:
            continue

        def side(X, r, k=k):
            return _signature(solver.cycle(r))[k] == sig_b[k]

        X, r = _bisect(solver, Xa, Xb, side, s.locate_tol_u)
        c = solver.cycle(r)
        kind = names[k][0] if sig_b[k] else names[k][1]
        branch.events.append(
            BranchEvent(
                kind=kind,
                u=float(X[2]),
                index=index,
                cycle=c,
                detail={
                    "x3_min": c.x3_min,
                    "x3_max": c.x3_max,
                    "period": c.period,
                    "stable_before": ca.stable,
                    "stable_after": cb.stable,
                },
            )
        )
    if fold:
        chord = Xb - Xa

        def side_fold(X, r):
            tt = solver.tangent(solver.jac(r), chord)
            return (tt[2] > 0) == (tb[2] > 0)

        X, r = _bisect(solver, Xa, Xb, side_fold, s.locate_tol_u)
        c = solver.cycle(r)
        near1 = c.multipliers[1:][np.argmin(np.abs(c.multipliers[1:] - 1.0))]
        branch.events.append(
            BranchEvent(
                kind="fold",
                u=float(X[2]),
                index=index,
                cycle=c,
                detail={
                    "x3_min": c.x3_min,
                    "x3_max": c.x3_max,
                    "period": c.period,
                    "multiplier_near_1": float(near1.real),
                    "stable_before": ca.stable,
                    "stable_after": cb.stable,
                },
            )
        )
    if _n_unstable(ca) != _n_unstable(cb) and not fold and sig_a == sig_b:
        # A smooth loss of stability away from a fold: which multiplier crossed?
        crossing = cb.multipliers[1:][np.argmax(np.abs(cb.multipliers[1:]))]
        if abs(crossing.imag) > 1e-9:
            kind = "neimark_sacker"
        elif crossing.real < 0:
            kind = "period_doubling"
        else:
            kind = "branch_point"
        na = _n_unstable(ca)

        def side_stab(X, r):
            return _n_unstable(solver.cycle(r)) != na

        X, r = _bisect(solver, Xa, Xb, side_stab, s.locate_tol_u)
        c = solver.cycle(r)
        branch.events.append(
            BranchEvent(
                kind=kind,
                u=float(X[2]),
                index=index,
                cycle=c,
                detail={
                    "multipliers_real": [float(m.real) for m in c.multipliers],
                    "multipliers_imag": [float(m.imag) for m in c.multipliers],
                },
            )
        )


def cycles_at(params: RigParams, p: np.ndarray, branch: PeriodicBranch, u: float) -> list[LimitCycle]:
    """All orbits of the branch at voltage u, each solved by Newton from the nearest orbit."""
    us = branch.u
    out: list[LimitCycle] = []
    for i in range(len(us) - 1):
        lo, hi = sorted((us[i], us[i + 1]))
        if not (lo <= u <= hi) or hi == lo:
            continue
        a, b = branch.cycles[i], branch.cycles[i + 1]
        w = (u - a.u) / (b.u - a.u)
        xi0 = (1 - w) * a.xi + w * b.xi
        try:
            _, ret, _ = solve_periodic(p, u, xi0)
        except ShootingError:
            continue
        c = make_cycle(params, p, ret)
        if not any(np.allclose(c.xi, o.xi, atol=1e-7) for o in out):
            out.append(c)
    return out
