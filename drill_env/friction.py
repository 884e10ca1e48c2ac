"""Friction laws of the rig, eq. (12) (upper disk) and eq. (14) (lower disk).

Both laws are set-valued at zero speed: a static band, not a number. Away from
zero they are smooth, so the simulator integrates each slip branch on its own and
switches between branches at events; nothing here is smoothed.

Note ``1 - 2/(1 + exp(beta w)) = tanh(beta w / 2)``; the exponentials take |w|.

The functions here take :class:`RigParams` and NumPy arrays, for users, plots and
tests; the compiled kernels in :mod:`drill_env.dynamics` implement the same laws on
the flat parameter vector.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from drill_env.params import RigParams

__all__ = [
    "upper_slip_friction",
    "upper_static_band",
    "lower_slip_friction",
    "lower_static_band",
    "lower_friction_curve",
    "lower_friction_slope",
    "hump_torque",
]


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
    return params.lower_hump_1 * np.tanh(0.5 * params.lower_hump_rate_1 * a) + (
        params.lower_hump_2 * np.tanh(0.5 * params.lower_hump_rate_2 * a)
    )


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
    a = np.abs(np.asarray(speed, dtype=float))
    b1, b2 = params.lower_hump_rate_1, params.lower_hump_rate_2
    return (
        params.lower_hump_1 * 0.5 * b1 * _sech2(0.5 * b1 * a)
        + params.lower_hump_2 * 0.5 * b2 * _sech2(0.5 * b2 * a)
        + params.lower_viscous
    )


def _sech2(x: np.ndarray) -> np.ndarray:
    """sech(x)^2 for x >= 0, written with exp(-x) so that it cannot overflow."""
    e = np.exp(-x)
    return (2.0 * e / (1.0 + e * e)) ** 2
