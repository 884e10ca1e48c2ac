"""Periodic orbits of the nonsmooth rig by shooting on a Poincare section.

The section is ``x2 = x3`` crossed downwards: the instant of maximal twist x1, when the
lower disk has just overtaken the upper one. Every cycle of the rig crosses it once per
period, with or without stick phases (while the lower disk sticks, ``x2 - x3 = x2 > 0``),
and transversally as long as the twist has a proper maximum. A point on the section
is ``xi = (x1, v)`` with ``x2 = x3 = v``.

The Poincare map ``P(xi, u)`` and its derivatives come from one integration of the
state and its sensitivity (:mod:`drill_env.analysis.variational`), saltation matrices
included; Newton's method on ``P(xi) - xi`` converges quadratically on smooth and on
stick-slip cycles alike. Floquet multipliers are the eigenvalues of the monodromy
matrix ``M = d x(T) / d x(0)``; one of them is the trivial multiplier 1 (the flow
direction, ``M f(x*) = f(x*)``), and a cycle with a stick phase has a multiplier 0 (the
stuck speed forgets its perturbation).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drill_env.analysis import variational as V
from drill_env.analysis.equilibria import nominal_vector
from drill_env.params import RigParams

__all__ = [
    "ShootingError",
    "SectionReturn",
    "LimitCycle",
    "section_return",
    "solve_periodic",
    "limit_cycle",
    "orbit_from_section",
    "SHOOTING_RTOL",
    "SHOOTING_ATOL",
]

SHOOTING_RTOL = 1e-11
SHOOTING_ATOL = 1e-13
H_MAX = 0.1  # [s] cap on the step: the section must not be crossed twice within a step
EVENT_CAPACITY = 64


class ShootingError(RuntimeError):
    """The flow did not return to the section, or Newton's method did not converge."""


def section_state(xi: np.ndarray) -> np.ndarray:
    """Full state (x1, v, v) of the section point xi = (x1, v)."""
    return np.array([xi[0], xi[1], xi[1]])


@dataclass(frozen=True)
class SectionReturn:
    """One pass of the Poincare map from xi at voltage u, with its derivatives."""

    u: float
    xi: np.ndarray  # start (x1, v)
    xi_next: np.ndarray  # P(xi, u)
    period: float  # return time [s]
    monodromy: np.ndarray  # d x(T) / d x(0), 3 x 3, at fixed time T
    dx_du: np.ndarray  # d x(T) / du at fixed time (3,)
    dP_dxi: np.ndarray  # 2 x 2
    dP_du: np.ndarray  # (2,)
    dT_dxi: np.ndarray  # (2,)
    dT_du: float
    info: np.ndarray = field(repr=False)
    events_t: np.ndarray = field(repr=False)
    events_kind: np.ndarray = field(repr=False)

    @property
    def residual(self) -> np.ndarray:
        return self.xi_next - self.xi

    @property
    def x3_min(self) -> float:
        return float(self.info[V.I_X3MIN])

    @property
    def x3_max(self) -> float:
        return float(self.info[V.I_X3MAX])

    @property
    def lower_stick_time(self) -> float:
        return float(self.info[V.I_STICK_L])

    @property
    def upper_stick_time(self) -> float:
        return float(self.info[V.I_STICK_U])


def _modes(x: np.ndarray, u: float, p: np.ndarray) -> np.ndarray:
    z = V.augmented_initial(x)
    mu, ml = V.initial_modes(z, u, p)
    return np.array([mu, ml], dtype=np.int64)


def section_return(
    p: np.ndarray,
    u: float,
    xi: np.ndarray,
    *,
    rtol: float = SHOOTING_RTOL,
    atol: float = SHOOTING_ATOL,
    t_max: float = 200.0,
) -> SectionReturn:
    """Integrate from the section point ``xi`` at voltage ``u`` back to the section."""
    x0 = section_state(xi)
    z = V.augmented_initial(x0)
    modes = _modes(x0, u, p)
    info = np.zeros(V.N_INFO)
    ev_t = np.zeros(EVENT_CAPACITY)
    ev_k = np.zeros(EVENT_CAPACITY, dtype=np.int64)
    status = V.flow(z, float(u), p, modes, t_max, True, rtol, atol, H_MAX, 10_000_000, info, ev_t, ev_k)
    if status != 0:
        raise ShootingError(f"section_return at u = {u:.6g}, xi = {xi}: {V.FLOW_STATUS[status]}")
    x, S = V.split_augmented(z)
    f = np.array(V.field(x[0], x[1], x[2], float(u), p, int(modes[0]), int(modes[1])))
    n = V.SECTION_NORMAL
    nf = float(n @ f)
    Sx = S[:, :3]
    Su = S[:, 3]
    E = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 1.0]])  # d x(0) / d xi
    proj = np.eye(3) - np.outer(f, n) / nf  # slide to the section along the flow
    pick = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # (x1, x3) of a section point
    n_ev = min(int(info[V.I_EVENTS]), EVENT_CAPACITY)
    return SectionReturn(
        u=float(u),
        xi=np.asarray(xi, dtype=float).copy(),
        xi_next=np.array([x[0], x[2]]),
        period=float(info[V.I_T]),
        monodromy=Sx,
        dx_du=Su,
        dP_dxi=pick @ proj @ Sx @ E,
        dP_du=pick @ proj @ Su,
        dT_dxi=-(n @ Sx @ E) / nf,
        dT_du=float(-(n @ Su) / nf),
        info=info.copy(),
        events_t=ev_t[:n_ev].copy(),
        events_kind=ev_k[:n_ev].copy(),
    )


def solve_periodic(
    p: np.ndarray,
    u: float,
    xi0: np.ndarray,
    *,
    tol: float = 1e-10,
    max_iter: int = 20,
    rtol: float = SHOOTING_RTOL,
    atol: float = SHOOTING_ATOL,
) -> tuple[np.ndarray, SectionReturn, int]:
    """Newton's method on P(xi, u) - xi = 0 at fixed u; returns (xi, return, iterations)."""
    xi = np.asarray(xi0, dtype=float).copy()
    for it in range(1, max_iter + 1):
        r = section_return(p, u, xi, rtol=rtol, atol=atol)
        res = r.residual
        step = np.linalg.solve(r.dP_dxi - np.eye(2), -res)
        # Damp steps that would leave the side of the section the orbit leaves on.
        lam = 1.0
        xi_new = xi + step
        while lam > 1e-3 and not _leaves_downwards(p, u, xi_new):
            lam *= 0.5
            xi_new = xi + lam * step
        xi = xi_new
        if np.linalg.norm(step) <= tol * (1.0 + np.linalg.norm(xi)):
            r = section_return(p, u, xi, rtol=rtol, atol=atol)
            return xi, r, it
    raise ShootingError(f"Newton did not converge at u = {u:.6g} (last step {np.linalg.norm(step):.3g})")


def _leaves_downwards(p: np.ndarray, u: float, xi: np.ndarray) -> bool:
    x = section_state(xi)
    m = _modes(x, u, p)
    f = V.field(x[0], x[1], x[2], float(u), p, int(m[0]), int(m[1]))
    return f[1] - f[2] < 0.0


def floquet(ret: SectionReturn, p: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Floquet multipliers (trivial first, then by decreasing modulus), the error of the
    trivial one ``|M f - f| / |f|`` at the start point, and the nontrivial ones."""
    x0 = section_state(ret.xi)
    m = _modes(x0, ret.u, p)
    f0 = np.array(V.field(x0[0], x0[1], x0[2], ret.u, p, int(m[0]), int(m[1])))
    M = ret.monodromy
    triv_err = float(np.linalg.norm(M @ f0 - f0) / np.linalg.norm(f0))
    mu_all = np.linalg.eigvals(M)
    nontrivial = np.linalg.eigvals(ret.dP_dxi)
    # The trivial multiplier: the eigenvalue of M left after removing the two of dP/dxi.
    rest = list(mu_all)
    for mu in nontrivial:
        k = int(np.argmin([abs(r - mu) for r in rest]))
        rest.pop(k)
    trivial = rest[0]
    nontrivial = nontrivial[np.argsort(-np.abs(nontrivial))]
    return np.concatenate([[trivial], nontrivial]), triv_err, nontrivial


@dataclass(frozen=True)
class LimitCycle:
    """A periodic orbit of the rig at constant voltage ``u``.

    ``xi`` = (x1, v) is the point of maximal twist (x2 = x3 = v). ``multipliers`` are the
    Floquet multipliers, the trivial one first; ``stable`` when all others lie inside
    the unit circle.
    """

    u: float  # [V]
    xi: np.ndarray
    period: float  # [s]
    x3_min: float  # [rad/s]
    x3_max: float  # [rad/s]
    x1_min: float  # [rad]
    x1_max: float  # [rad]
    x2_min: float  # [rad/s]
    x2_max: float  # [rad/s]
    stick_fraction: float  # fraction of the period with the lower disk stuck [-]
    upper_stick_fraction: float  # [-]
    stick_phases: int  # lower-disk stick phases per period
    reversals: int  # direction reversals per period
    multipliers: np.ndarray  # complex (3,)
    trivial_multiplier_error: float  # |M f - f| / |f|
    residual: float  # |P(xi) - xi|
    params: Any = field(repr=False, default=None)

    @property
    def amplitude(self) -> float:
        """Peak-to-peak lower-disk speed, max x3 - min x3 [rad/s]."""
        return self.x3_max - self.x3_min

    @property
    def frequency(self) -> float:
        return 1.0 / self.period

    @property
    def stick_slip(self) -> bool:
        return self.stick_fraction > 0.0

    @property
    def stable(self) -> bool:
        return bool(np.all(np.abs(self.multipliers[1:]) < 1.0))

    @property
    def state(self) -> np.ndarray:
        return section_state(self.xi)

    def orbit(self, n: int = 400):
        """One period sampled at n + 1 points by the event-driven simulator."""
        return orbit_from_section(self.params, self.u, self.xi, self.period, n)

    def to_dict(self) -> dict:
        return {
            "u": self.u,
            "x1": float(self.xi[0]),
            "v": float(self.xi[1]),
            "period": self.period,
            "frequency": self.frequency,
            "x3_min": self.x3_min,
            "x3_max": self.x3_max,
            "amplitude": self.amplitude,
            "x1_min": self.x1_min,
            "x1_max": self.x1_max,
            "stick_fraction": self.stick_fraction,
            "upper_stick_fraction": self.upper_stick_fraction,
            "stick_phases": self.stick_phases,
            "reversals": self.reversals,
            "stable": self.stable,
            "multipliers_real": [float(m.real) for m in self.multipliers],
            "multipliers_imag": [float(m.imag) for m in self.multipliers],
            "trivial_multiplier_error": self.trivial_multiplier_error,
            "residual": self.residual,
        }

    def plot(self, axes=None):
        """Projections of the orbit on the planes of Fig. 9 (matplotlib)."""
        from drill_env.analysis.plots import plot_limit_cycles

        return plot_limit_cycles([self], axes=axes)


def make_cycle(params: RigParams, p: np.ndarray, ret: SectionReturn) -> LimitCycle:
    """A :class:`LimitCycle` from the return of a converged section point."""
    mult, triv_err, _ = floquet(ret, p)
    info = ret.info
    T = ret.period
    return LimitCycle(
        u=ret.u,
        xi=ret.xi.copy(),
        period=T,
        x3_min=float(info[V.I_X3MIN]),
        x3_max=float(info[V.I_X3MAX]),
        x1_min=float(info[V.I_X1MIN]),
        x1_max=float(info[V.I_X1MAX]),
        x2_min=float(info[V.I_X2MIN]),
        x2_max=float(info[V.I_X2MAX]),
        stick_fraction=float(info[V.I_STICK_L]) / T,
        upper_stick_fraction=float(info[V.I_STICK_U]) / T,
        stick_phases=int(info[V.I_STICK_PHASES_L]),
        reversals=int(info[V.I_REVERSALS]),
        multipliers=mult,
        trivial_multiplier_error=triv_err,
        residual=float(np.linalg.norm(ret.residual)),
        params=params,
    )


def orbit_from_section(params: RigParams, u: float, xi: np.ndarray, period: float, n: int = 400):
    """The orbit through the section point xi over one period, by :func:`drill_env.simulate`."""
    from drill_env.simulator import simulate

    return simulate(params, float(u), float(period), x0=section_state(xi), dt=period / n)


def _section_crossings(t: np.ndarray, x1: np.ndarray, x2: np.ndarray, x3: np.ndarray) -> list[np.ndarray]:
    """Section points (x1, v) interpolated at the downward crossings of x2 - x3 in samples."""
    h = x2 - x3
    idx = np.flatnonzero((h[:-1] > 0) & (h[1:] <= 0))
    out = []
    for i in idx:
        a = h[i] / (h[i] - h[i + 1])
        x1c = x1[i] + a * (x1[i + 1] - x1[i])
        vc = x3[i] + a * (x3[i + 1] - x3[i])
        out.append(np.array([x1c, vc]))
    return out


def limit_cycle(
    params: RigParams | str,
    u: float,
    guess: np.ndarray | LimitCycle | None = None,
    *,
    settle: float = 1500.0,
    tol: float = 1e-10,
) -> LimitCycle | None:
    """The limit cycle of the rig at constant voltage ``u`` [V], or None if there is none.

    Without a guess, the attracting cycle is found by the event-driven simulator from
    a large perturbation of the equilibrium (the lower disk held at rest while the upper
    one turns at the equilibrium speed), then from a small one, over ``settle`` seconds;
    if both settle on the equilibrium there is no stable cycle and None is returned.
    The last crossing of the section seeds Newton's method. With a ``guess`` (a section
    point ``(x1, v)`` or a :class:`LimitCycle`), Newton starts there, and unstable cycles
    are found as well.
    """
    from drill_env.analysis.equilibria import equilibria
    from drill_env.simulator import simulate

    params, p = nominal_vector(params)
    u = float(u)
    if guess is not None:
        xi0 = guess.xi if isinstance(guess, LimitCycle) else np.asarray(guess, dtype=float)
        xi, ret, _ = solve_periodic(p, u, xi0, tol=tol)
        return make_cycle(params, p, ret)
    eqs = equilibria(params, u)
    if not eqs or eqs[0].kind == "stick_set":
        return None
    eq = eqs[0]
    starts = [
        np.array([eq.x1, eq.x3, 0.0]),  # lower disk held, then released: large
        np.array([eq.x1 + 1e-3 * max(1.0, abs(eq.x1)), eq.x3, eq.x3]),  # small
    ]
    for x0 in starts:
        res = simulate(params, u, settle, x0=x0, dt=0.01)
        tail = res.t >= settle - 60.0
        x3 = res.x3[tail]
        if np.ptp(x3) < 1e-6 * max(1.0, abs(eq.x3)):
            continue
        cross = _section_crossings(res.t[tail], res.x1[tail], res.x2[tail], x3)
        if not cross:
            continue
        xi, ret, _ = solve_periodic(p, u, cross[-1], tol=tol)
        return make_cycle(params, p, ret)
    return None
