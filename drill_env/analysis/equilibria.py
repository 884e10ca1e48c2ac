"""Equilibria of the rig at a constant voltage, their stability, and the Hopf points.

Sec. 3.1 of Mihajlovic et al. (2004):

* for ``-(T_sun + T_sl)/k_m <= u <= (T_sup + T_sl)/k_m`` both disks stand still and the
  equilibria form the *stick set* E of eq. (26), an interval of twists;
* above that range the disks turn together at the speed ``x3`` solving eq. (20),
  ``k_m u - b_up x3 - T_sup - T_l(x3) = 0``; below it at the speed solving eq. (22).

The stability of a slip equilibrium follows from the eigenvalues of the Jacobian of
eq. (36) there, cross-checked by the Routh-Hurwitz conditions on its characteristic
polynomial (which reduce to eq. 23, ``d_l > -0.00114``, for the paper's parameters).
A Hopf point is where a complex pair of eigenvalues crosses the imaginary axis; its
direction (super- or subcritical) comes from the first Lyapunov coefficient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

from drill_env.friction import hump_derivatives, lower_friction_curve, lower_friction_slope
from drill_env.params import RigParams, resolve_params

__all__ = [
    "Equilibrium",
    "HopfPoint",
    "equilibria",
    "slip_equilibrium",
    "stick_set",
    "equilibrium_jacobian",
    "routh_hurwitz",
    "critical_friction_slope",
    "hopf_points",
    "first_lyapunov_coefficient",
    "nominal_vector",
]


def nominal_vector(params: RigParams | str) -> tuple[RigParams, np.ndarray]:
    """Parameters and their flat vector, checking that the model is the paper's."""
    params = resolve_params(params)
    if params.effects.active:
        raise ValueError(
            "the bifurcation analysis covers the paper's model only; switch off "
            f"the effects {list(params.effects.active)}"
        )
    return params, params.as_array()


# -- friction of the lower disk on its slip branch, with its derivatives ------------------


_hump_derivatives = hump_derivatives


def _lower_curve(params: RigParams, w: float) -> float:
    """T_l(w) of eq. (19) for w >= 0 [N m]."""
    return float(lower_friction_curve(params, w))


def _lower_slope(params: RigParams, w: float) -> float:
    """d_l = dT_l/dx3 at |x3| = w, eq. (24) [N m s / rad]."""
    return float(lower_friction_slope(params, w))


def _voltage_of_speed(params: RigParams, x3: float) -> float:
    """The voltage at which x3 != 0 is the equilibrium speed, eq. (20) / (22) [V]."""
    if x3 > 0:
        return (params.upper_static_pos + params.upper_viscous_pos * x3 + _lower_curve(params, x3)) / (
            params.motor_constant
        )
    w = -x3
    return (-params.upper_static_neg - params.upper_viscous_neg * w - _lower_curve(params, w)) / (
        params.motor_constant
    )


# -- result objects ------------------------------------------------------------------------


@dataclass(frozen=True)
class Equilibrium:
    """An equilibrium (or the stick set) at voltage ``u``.

    For the stick set ``x1_min < x1_max`` bound the interval (26) of twists and
    ``x2 = x3 = 0``; for a slip equilibrium ``x1_min == x1_max`` is its twist.
    """

    u: float  # [V]
    kind: str  # "stick_set", "slip_forward" or "slip_backward"
    x1_min: float  # [rad]
    x1_max: float  # [rad]
    x3: float  # common speed of both disks [rad/s]
    stable: bool
    eigenvalues: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))
    routh_hurwitz: bool | None = None  # the Routh-Hurwitz verdict (slip equilibria)
    friction_slope: float = math.nan  # d_l at |x3| [N m s / rad] (slip equilibria)

    @property
    def x1(self) -> float:
        """Twist [rad] (the midpoint of the interval for the stick set)."""
        return 0.5 * (self.x1_min + self.x1_max)

    @property
    def state(self) -> np.ndarray:
        return np.array([self.x1, self.x3, self.x3])

    def to_dict(self) -> dict:
        return {
            "u": self.u,
            "kind": self.kind,
            "x1_min": self.x1_min,
            "x1_max": self.x1_max,
            "x3": self.x3,
            "stable": self.stable,
            "eigenvalues_real": [float(v.real) for v in self.eigenvalues],
            "eigenvalues_imag": [float(v.imag) for v in self.eigenvalues],
            "routh_hurwitz": self.routh_hurwitz,
            "friction_slope": None if math.isnan(self.friction_slope) else self.friction_slope,
        }


@dataclass(frozen=True)
class HopfPoint:
    """A Hopf point of the slip equilibria: a complex pair crosses the imaginary axis."""

    u: float  # [V]
    x_eq: np.ndarray  # equilibrium state (x1, x2, x3)
    omega: float  # imaginary part of the critical pair [rad/s]
    eigenvector: np.ndarray  # q with J q = i omega q (complex, 3)
    l1: float  # first Lyapunov coefficient (Kuznetsov's normalisation)
    crossing_speed: float  # d Re(lambda)/du at the point [1/(V s)]
    friction_slope: float  # d_l there [N m s / rad]

    @property
    def supercritical(self) -> bool:
        return self.l1 < 0.0

    @property
    def kind(self) -> str:
        return "hopf_supercritical" if self.supercritical else "hopf_subcritical"

    @property
    def period(self) -> float:
        """Period of the emerging cycle, 2 pi / omega [s]."""
        return 2.0 * math.pi / self.omega

    def amplitude_offset(self, radius: float) -> float:
        """Normal-form prediction of u - u_H for a cycle of radius ``radius``.

        In ``x = x_eq + z q + conj(z q)``, ``|q| = 1``, the normal form
        ``r' = r (Re(lambda)'(u) (u - u_H) + omega l1 r^2)`` has its cycle at
        ``u - u_H = -omega l1 r^2 / Re(lambda)'``.
        """
        return -self.omega * self.l1 * radius * radius / self.crossing_speed

    def to_dict(self) -> dict:
        return {
            "u": self.u,
            "type": self.kind,
            "x1": float(self.x_eq[0]),
            "x3": float(self.x_eq[2]),
            "omega": self.omega,
            "period": self.period,
            "l1": self.l1,
            "crossing_speed": self.crossing_speed,
            "friction_slope": self.friction_slope,
        }


# -- the equilibria --------------------------------------------------------------------------


def stick_set(params: RigParams | str, u: float) -> tuple[float, float] | None:
    """Interval of twists x1 of the stick set E, eq. (26), or None outside range (25)."""
    params = resolve_params(params)
    k = params.string_stiffness
    lo = max(-params.lower_static / k, (params.motor_constant * u - params.upper_static_pos) / k)
    hi = min(params.lower_static / k, (params.motor_constant * u + params.upper_static_neg) / k)
    if lo > hi:
        # at the ends of range (25) the set is one point; rounding may put lo an ulp above hi
        if lo - hi > 1e-12 * max(1.0, abs(lo)):
            return None
        lo = hi = 0.5 * (lo + hi)
    return lo, hi


def equilibrium_jacobian(params: RigParams | str, x3: float) -> np.ndarray:
    """Jacobian of eq. (36) at a slip equilibrium with speed x3 != 0 (3 x 3)."""
    from drill_env.analysis.variational import jacobian

    params, p = nominal_vector(params)
    mode = 1 if x3 > 0 else -1
    J = np.zeros((3, 4))
    jacobian(x3, p, mode, mode, J)
    return J[:, :3]


def critical_friction_slope(params: RigParams | str, direction: int = 1) -> float:
    """The friction slope d_l at which a slip equilibrium loses stability, eq. (23).

    From the Routh-Hurwitz condition ``a2 a1 > a0`` on ``lambda^3 + a2 lambda^2 + a1 lambda
    + a0`` with ``alpha = b_u/J_u``, ``delta = d_l/J_l``, ``k_u = k_theta/J_u``,
    ``k_l = k_theta/J_l``: ``a2 a1 - a0 = alpha delta (alpha + delta) + alpha k_u +
    delta k_l``, zero at the root of ``alpha delta^2 + (alpha^2 + k_l) delta + alpha k_u``
    nearest zero [N m s / rad].
    """
    params = resolve_params(params)
    b = params.upper_viscous_pos if direction > 0 else params.upper_viscous_neg
    alpha = b / params.upper_inertia
    ku = params.string_stiffness / params.upper_inertia
    kl = params.string_stiffness / params.lower_inertia
    disc = (alpha * alpha + kl) ** 2 - 4.0 * alpha * alpha * ku
    delta = (-(alpha * alpha + kl) + math.sqrt(disc)) / (2.0 * alpha)
    return delta * params.lower_inertia


def routh_hurwitz(params: RigParams | str, x3: float) -> tuple[bool, tuple[float, float, float]]:
    """Routh-Hurwitz verdict for the slip equilibrium at speed x3, and (a2, a1, a0).

    Closed-form coefficients of the characteristic polynomial (independent of the
    eigenvalue computation), stable iff a2 > 0, a0 > 0 and a2 a1 > a0.
    """
    params = resolve_params(params)
    b = params.upper_viscous_pos if x3 > 0 else params.upper_viscous_neg
    alpha = b / params.upper_inertia
    delta = _lower_slope(params, abs(x3)) / params.lower_inertia
    ku = params.string_stiffness / params.upper_inertia
    kl = params.string_stiffness / params.lower_inertia
    a2 = alpha + delta
    a1 = alpha * delta + ku + kl
    a0 = ku * delta + kl * alpha
    return (a2 > 0 and a0 > 0 and a2 * a1 > a0), (a2, a1, a0)


def _speed_at(params: RigParams, u: float) -> float:
    """Equilibrium speed x3 at voltage u outside the stick range (eq. 20 / 22)."""
    direction = 1.0 if u > params.uc1 else -1.0
    # The voltage grows monotonically with the speed, condition (21); bracket and solve.
    hi = 1.0
    while (_voltage_of_speed(params, direction * hi) - u) * direction < 0:
        hi *= 2.0
        if hi > 1e9:
            raise ValueError(f"no slip equilibrium found at u = {u!r}")
    f = lambda w: (_voltage_of_speed(params, direction * w) - u) * direction  # noqa: E731
    w = brentq(f, 0.0, hi, xtol=1e-15, rtol=4 * np.finfo(float).eps, maxiter=500)
    return direction * w


def _slip_equilibrium_at_speed(params: RigParams, x3: float, u: float | None = None) -> Equilibrium:
    w = abs(x3)
    sign = 1.0 if x3 > 0 else -1.0
    x1 = sign * _lower_curve(params, w) / params.string_stiffness
    eig = np.linalg.eigvals(equilibrium_jacobian(params, x3))
    eig = eig[np.argsort(-eig.real)]
    rh, _ = routh_hurwitz(params, x3)
    return Equilibrium(
        u=_voltage_of_speed(params, x3) if u is None else float(u),
        kind="slip_forward" if x3 > 0 else "slip_backward",
        x1_min=x1,
        x1_max=x1,
        x3=x3,
        stable=bool(np.all(eig.real < 0)),
        eigenvalues=eig,
        routh_hurwitz=rh,
        friction_slope=_lower_slope(params, w),
    )


def slip_equilibrium(params: RigParams | str, u: float) -> Equilibrium | None:
    """The slip equilibrium at voltage u (eq. 20 for u > u_c1, eq. 22 below the stick range)."""
    params, _ = nominal_vector(params)
    if params.uc1_neg <= u <= params.uc1:
        return None
    return _slip_equilibrium_at_speed(params, _speed_at(params, float(u)), u)


def equilibria(params: RigParams | str, u: float) -> list[Equilibrium]:
    """All equilibria at voltage u: the stick set (26) within range (25), else one slip equilibrium.

    By condition (21) there is one slip equilibrium per voltage outside range (25), and
    none inside it (its speed would have to be 0). The stick set is locally
    asymptotically stable (the paper's Appendix).
    """
    params, _ = nominal_vector(params)
    s = stick_set(params, u)
    if s is not None:
        return [Equilibrium(u=float(u), kind="stick_set", x1_min=s[0], x1_max=s[1], x3=0.0, stable=True)]
    eq = slip_equilibrium(params, u)
    return [] if eq is None else [eq]


# -- Hopf points -------------------------------------------------------------------------------


def first_lyapunov_coefficient(params: RigParams | str, x3: float) -> tuple[float, float, np.ndarray]:
    """First Lyapunov coefficient l1 at a Hopf point of the slip equilibrium with speed x3.

    Kuznetsov's formula (Elements of Applied Bifurcation Theory, eq. 3.20) with
    ``A q = i omega q``, ``A^T p = -i omega p``, ``<p, q> = 1``; the only nonlinearity is
    the lower-disk friction, so B and C act on the third component only. Returns
    (l1, omega, q). l1 < 0: supercritical.
    """
    params = resolve_params(params)
    A = equilibrium_jacobian(params, x3)
    ev, vecs = np.linalg.eig(A)
    k = int(np.argmax(ev.imag))
    omega = float(ev[k].imag)
    q = vecs[:, k]
    q = q / np.linalg.norm(q)
    evl, vecl = np.linalg.eig(A.T)
    kl = int(np.argmin(np.abs(evl - (-1j * omega))))
    pv = vecl[:, kl]
    pv = pv / np.conj(np.vdot(pv, q))  # <p, q> = conj(p) . q = 1
    m = 1.0 if x3 > 0 else -1.0
    _, _, h2, h3 = _hump_derivatives(params, abs(x3))
    jl = params.lower_inertia
    b2 = -m * h2 / jl  # d^2 f3 / dx3^2
    b3 = -h3 / jl  # d^3 f3 / dx3^3

    def Bf(x, y):
        return np.array([0.0, 0.0, b2 * x[2] * y[2]], dtype=complex)

    def Cf(x, y, z):
        return np.array([0.0, 0.0, b3 * x[2] * y[2] * z[2]], dtype=complex)

    qb = np.conj(q)
    t1 = np.vdot(pv, Cf(q, q, qb))
    t2 = np.vdot(pv, Bf(q, np.linalg.solve(A, Bf(q, qb))))
    t3 = np.vdot(pv, Bf(qb, np.linalg.solve(2j * omega * np.eye(3) - A, Bf(q, q))))
    l1 = float(np.real(t1 - 2.0 * t2 + t3) / (2.0 * omega))
    return l1, omega, q


def _rh_margin(params: RigParams, x3: float) -> float:
    _, (a2, a1, a0) = routh_hurwitz(params, x3)
    return a2 * a1 - a0


def hopf_points(
    params: RigParams | str, u_min: float = -math.inf, u_max: float = math.inf, max_speed: float = 200.0
) -> list[HopfPoint]:
    """Hopf points of the slip equilibria with ``u_min <= u <= u_max``, in increasing u.

    Located where the Routh-Hurwitz margin ``a2 a1 - a0`` changes sign (a complex pair
    on the imaginary axis), scanning the equilibrium speed up to ``max_speed``.
    """
    params, _ = nominal_vector(params)
    found: list[HopfPoint] = []
    for direction in (1.0, -1.0):
        w = np.concatenate([np.linspace(1e-6, 5.0, 20001)[:-1], np.linspace(5.0, max_speed, 20001)])
        g = np.array([_rh_margin(params, direction * x) for x in w])
        for i in np.flatnonzero(np.sign(g[1:]) != np.sign(g[:-1])):
            ws = brentq(
                lambda x, d=direction: _rh_margin(params, d * x), w[i], w[i + 1], xtol=1e-14, rtol=1e-15
            )
            x3 = direction * ws
            u = _voltage_of_speed(params, x3)
            if not (u_min <= u <= u_max):
                continue
            _, (a2, a1, a0) = routh_hurwitz(params, x3)
            if a1 <= 0:  # a real root through zero, not a Hopf point
                continue
            l1, omega, q = first_lyapunov_coefficient(params, x3)
            # d Re(lambda)/du by central differences along the equilibrium branch.
            dw = 1e-6 * max(1.0, ws)
            re = []
            for s in (-1.0, 1.0):
                xs = direction * (ws + s * dw)
                ev = np.linalg.eigvals(equilibrium_jacobian(params, xs))
                re.append(ev[np.argmin(np.abs(ev.imag - omega))].real)
            du = _voltage_of_speed(params, direction * (ws + dw)) - _voltage_of_speed(
                params, direction * (ws - dw)
            )
            x1 = direction * _lower_curve(params, ws) / params.string_stiffness
            found.append(
                HopfPoint(
                    u=float(u),
                    x_eq=np.array([x1, x3, x3]),
                    omega=omega,
                    eigenvector=q,
                    l1=l1,
                    crossing_speed=float((re[1] - re[0]) / du),
                    friction_slope=_lower_slope(params, ws),
                )
            )
    found.sort(key=lambda h: h.u)
    return found
