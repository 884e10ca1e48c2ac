"""Friction laws of the rig, eq. (12) (upper disk) and eq. (14) (lower disk).

Both laws are set-valued at zero speed: a static band, not a number. Away from
zero they are smooth, so the simulator integrates each slip branch on its own and
switches between branches at events; nothing here is smoothed.

The hump (Stribeck) part of eq. (14) and its slope are defined once, here, as
:func:`hump_law` and :func:`hump_slope_law`: compiled by numba for the kernels of
:mod:`drill_env.dynamics` (which call them on the flat parameter vector), and the very
same Python functions run on NumPy arrays for the functions below, which take
:class:`RigParams`, for users, plots, analysis and tests.

Note ``1 - 2/(1 + exp(beta w)) = tanh(beta w / 2)``: the law is written with the
paper's exponentials, cheaper than tanh in the kernels.
"""

from __future__ import annotations

import math
from typing import Protocol

import numba as nb
import numpy as np
from numpy.typing import ArrayLike

from drill_env._numba import INLINE


class RigParams(Protocol):
    """The friction parameters these laws read (:class:`drill_env.params.RigParams` has them):
    the laws are the lower layer, the validated parameter set is built on them. Read-only:
    a frozen dataclass has them."""

    @property
    def upper_static_pos(self) -> float: ...  # [N m] T_sup

    @property
    def upper_static_neg(self) -> float: ...  # [N m] T_sun

    @property
    def upper_viscous_pos(self) -> float: ...  # [N m s/rad] b_up

    @property
    def upper_viscous_neg(self) -> float: ...  # [N m s/rad] b_un

    @property
    def lower_static(self) -> float: ...  # [N m] T_sl

    @property
    def lower_viscous(self) -> float: ...  # [N m s/rad] b_l

    @property
    def lower_hump_1(self) -> float: ...  # [N m] T_1

    @property
    def lower_hump_rate_1(self) -> float: ...  # [s/rad] beta_1

    @property
    def lower_hump_2(self) -> float: ...  # [N m] T_2

    @property
    def lower_hump_rate_2(self) -> float: ...  # [s/rad] beta_2


__all__ = [
    "upper_slip_friction",
    "upper_static_band",
    "lower_slip_friction",
    "lower_static_band",
    "lower_friction_curve",
    "lower_friction_slope",
    "hump_torque",
    "hump_slope",
    "hump_derivatives",
    "hump_law",
    "hump_slope_law",
]


# -- the one definition of the hump part of eq. (14) ---------------------------------------
# Plain arithmetic and np.exp, so that numba compiles them for scalars and NumPy runs
# their .py_func on arrays: one source for both.


@nb.njit(**INLINE)
def hump_law(t1, beta1, t2, beta2, w):
    """T1 (1 - 2/(1 + exp(b1 w))) + T2 (1 - 2/(1 + exp(b2 w))) [N m], eq. (14).

    Odd in w; the lower friction takes it at w = |x3|. exp overflows to inf for large
    beta*w, which gives exactly 1.
    """
    return t1 * (1.0 - 2.0 / (1.0 + np.exp(beta1 * w))) + t2 * (1.0 - 2.0 / (1.0 + np.exp(beta2 * w)))


@nb.njit(**INLINE)
def hump_slope_law(t1, beta1, t2, beta2, w):
    """d/dw of :func:`hump_law`: T1 (b1/2) sech^2(b1 w/2) + T2 (b2/2) sech^2(b2 w/2) [N m s/rad].

    Even in w; sech^2 is written with exp(-|x|) so that it cannot overflow.
    """
    e1 = np.exp(-0.5 * beta1 * np.abs(w))
    e2 = np.exp(-0.5 * beta2 * np.abs(w))
    s1 = 2.0 * e1 / (1.0 + e1 * e1)
    s2 = 2.0 * e2 / (1.0 + e2 * e2)
    return 0.5 * t1 * beta1 * (s1 * s1) + 0.5 * t2 * beta2 * (s2 * s2)


def _hump_coefficients(params: RigParams) -> tuple[float, float, float, float]:
    return params.lower_hump_1, params.lower_hump_rate_1, params.lower_hump_2, params.lower_hump_rate_2


# -- NumPy forms on RigParams --------------------------------------------------------------


def upper_slip_friction(params: RigParams, speed: ArrayLike) -> np.ndarray:
    """T_fu on the slip branches of eq. (12) [N m]; NaN at exactly zero speed."""
    w = np.asarray(speed, dtype=float)
    out = np.where(
        w > 0,
        params.upper_static_pos + params.upper_viscous_pos * w,
        -params.upper_static_neg + params.upper_viscous_neg * w,
    )
    return np.where(w == 0, np.nan, out)


def upper_static_band(params: RigParams) -> tuple[float, float]:
    """The set T_fu(0) = [-T_sun, T_sup] [N m]."""
    return (-params.upper_static_neg, params.upper_static_pos)


def hump_torque(params: RigParams, speed: ArrayLike) -> np.ndarray:
    """The Stribeck/hump part T1 tanh(b1|w|/2) + T2 tanh(b2|w|/2) [N m] (zero at w = 0)."""
    a = np.abs(np.asarray(speed, dtype=float))
    with np.errstate(over="ignore"):  # exp(beta w) -> inf gives the limit 1 exactly
        return np.asarray(hump_law.py_func(*_hump_coefficients(params), a))


def hump_slope(params: RigParams, speed: ArrayLike) -> np.ndarray:
    """d/d|w| of :func:`hump_torque` at |speed| [N m s / rad]."""
    a = np.abs(np.asarray(speed, dtype=float))
    return np.asarray(hump_slope_law.py_func(*_hump_coefficients(params), a))


def lower_friction_curve(params: RigParams, speed: ArrayLike) -> np.ndarray:
    """T_l(w) of eq. (19): the magnitude of the slip friction at |w| [N m].

    ``T_l(0) = T_sl``; the lower-disk slip friction is ``T_l(|w|) sign(w)``.
    """
    a = np.abs(np.asarray(speed, dtype=float))
    return params.lower_static + hump_torque(params, a) + params.lower_viscous * a


def lower_slip_friction(params: RigParams, speed: ArrayLike) -> np.ndarray:
    """T_fl on the slip branches of eq. (14) [N m]; NaN at exactly zero speed."""
    w = np.asarray(speed, dtype=float)
    out = (params.lower_static + hump_torque(params, w)) * np.sign(w) + params.lower_viscous * w
    return np.where(w == 0, np.nan, out)


def lower_static_band(params: RigParams) -> tuple[float, float]:
    """The set T_fl(0) = [-T_sl, T_sl] [N m]."""
    return (-params.lower_static, params.lower_static)


def lower_friction_slope(params: RigParams, speed: ArrayLike) -> np.ndarray:
    """Friction damping d_l = dT_l/dx3 of eq. (24) at x3 = |speed| > 0 [N m s / rad]."""
    return hump_slope(params, speed) + params.lower_viscous


def hump_derivatives(params: RigParams, w: float) -> tuple[float, float, float, float]:
    """The hump part at w >= 0 and its first three derivatives in w (scalars).

    The value and slope are :func:`hump_law` and :func:`hump_slope_law`; the second and
    third derivatives (for the first Lyapunov coefficient of a Hopf point) follow from
    ``d/dx tanh = sech^2 = 1 - tanh^2`` with ``tanh(b w/2)`` the law of one term.
    """
    t1, b1, t2, b2 = _hump_coefficients(params)
    with np.errstate(over="ignore"):
        h = float(hump_law.py_func(t1, b1, t2, b2, w))
    d1 = float(hump_slope_law.py_func(t1, b1, t2, b2, w))
    d2 = d3 = 0.0
    for T, beta in ((t1, b1), (t2, b2)):
        k = 0.5 * beta
        th = math.tanh(k * w)
        s2 = 1.0 - th * th  # sech^2
        d2 += T * k * k * (-2.0 * s2 * th)
        d3 += T * k**3 * (-2.0) * (s2 * s2 - 2.0 * s2 * th * th)
    return h, d1, d2, d3
