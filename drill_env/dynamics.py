"""Compiled right-hand side of the rig in each friction mode, and the switching rules.

Pure functions of (time, state, input voltage, parameter vector, modes); layouts in
:mod:`drill_env._layout`. Each disk is in one of three modes: slipping forward (+1),
slipping backward (-1) or stuck (0). In a slip mode the friction is the smooth slip
branch of eq. (12)/(14) for that direction; a stuck disk has speed exactly 0 and its
friction is whatever holds its torque balance. So within a mode the vector field is
smooth and the integrator sees no discontinuity; switching is the event logic's job.

Model (eq. 10 with the optional effects of :class:`drill_env.params.ModelEffects`)::

    x1' = x2 - x3
    Ju x2' = Tm - T_string - T_fu(x2)              T_string = k_theta x1 + b_theta (x2 - x3)
    Jl x3' = T_string + T_dist(t) - T_fl(x3)
    theta_l' = x3
    tau_m Tm' = km u - Tm        (Tm = km u when tau_m = 0)
    tau_f w' = |x3| - w          (w = |x3| when tau_f = 0: no friction memory)
    tau_th Th' = P - Th          P = T_fl x3 while the lower disk slips, 0 while it sticks

The thermal state Th [W] (friction heating, kappa != 0) is the power the lower friction
dissipates, lagged by the contact's thermal time constant; it scales the lower static +
Stribeck friction by 1 + kappa Th, in slip and in the static band alike.

Each slip branch is written as an analytic function (|x3| as mode*x3) so that it
extends smoothly past its own zero crossing; see :func:`hump`.
"""

from __future__ import annotations

import math

import numba as nb

from drill_env import _layout as L
from drill_env._numba import INLINE, JIT
from drill_env.friction import hump_law, hump_slope_law

# The compiled functions here never allocate (drill_env._numba.JIT); small helpers are
# inlined into the right-hand side: it is the innermost loop.
_JIT = JIT
_INLINE = INLINE


@nb.njit(**_INLINE)
def n_active(p):
    """Number of leading state components that evolve: 4, 6 with motor lag/friction memory,
    7 with friction heating (the thermal state)."""
    if p[L.HEAT] != 0.0:
        return L.NY
    if p[L.TAU_M] > 0.0 or p[L.TAU_F] > 0.0:
        return L.NY_LAG
    return 4


@nb.njit(**_INLINE)
def upper_scale(p, theta_u):
    """Position modulation of the upper static friction (1 when the effect is off)."""
    if p[L.POSU_A1] == 0.0 and p[L.POSU_A2] == 0.0:
        return 1.0
    return (
        1.0
        + p[L.POSU_A1] * math.cos(theta_u + p[L.POSU_P1])
        + p[L.POSU_A2] * math.cos(2.0 * theta_u + p[L.POSU_P2])
    )


@nb.njit(**_INLINE)
def lower_scale(p, t, theta_l):
    """Position and drift modulation of the lower static + Stribeck friction."""
    s = 1.0
    if p[L.POSL_A1] != 0.0 or p[L.POSL_A2] != 0.0:
        s = (
            1.0
            + p[L.POSL_A1] * math.cos(theta_l + p[L.POSL_P1])
            + p[L.POSL_A2] * math.cos(2.0 * theta_l + p[L.POSL_P2])
        )
    if p[L.DRIFT] != 0.0:
        s *= 1.0 + p[L.DRIFT] * t
    return s


@nb.njit(**_INLINE)
def thermal_scale(p, y):
    """Temperature modulation of the lower static + Stribeck friction, 1 + kappa Th."""
    if p[L.HEAT] == 0.0:
        return 1.0
    return 1.0 + p[L.HEAT] * y[L.TH]


@nb.njit(**_INLINE)
def hump(p, w):
    """Stribeck/hump part of eq. (14), :func:`drill_env.friction.hump_law`, for w = |x3| >= 0.

    Called with ``w = mode * x3``: on its own branch that is |x3|, and a step that
    overshoots the zero crossing (before the event is located) sees the analytic
    continuation of the branch instead of the kink of |x3|, so the error control of
    the integrator is not upset by it.
    """
    return hump_law(p[L.T1], p[L.BETA1], p[L.T2], p[L.BETA2], w)


@nb.njit(**_INLINE)
def hump_slope(p, w):
    """d/dw of :func:`hump`, :func:`drill_env.friction.hump_slope_law`."""
    return hump_slope_law(p[L.T1], p[L.BETA1], p[L.T2], p[L.BETA2], w)


@nb.njit(**_INLINE)
def motor_torque(p, y, u):
    if p[L.TAU_M] > 0.0:
        return y[L.TM]
    return p[L.KM] * u


@nb.njit(**_INLINE)
def string_torque(p, y):
    return p[L.KTH] * y[L.X1] + p[L.BTH] * (y[L.X2] - y[L.X3])


@nb.njit(**_INLINE)
def disturbance(p, t):
    if p[L.DIST_A] == 0.0:
        return 0.0
    return p[L.DIST_A] * math.sin(p[L.DIST_W] * t + p[L.DIST_P])


@nb.njit(**_INLINE)
def memory_speed(p, y, mode):
    """Speed at which the Stribeck part is evaluated on branch ``mode``: mode*x3 = |x3|,
    or its lagged value when friction has memory."""
    if p[L.TAU_F] > 0.0:
        return y[L.WL]
    return mode * y[L.X3]


@nb.njit(**_INLINE)
def upper_friction(p, y, mode):
    """Upper slip friction, eq. (12), on the branch ``mode`` (+1/-1)."""
    su = upper_scale(p, y[L.X1] + y[L.THL])
    if mode > 0:
        return su * p[L.TSUP] + p[L.BUP] * y[L.X2]
    return -su * p[L.TSUN] + p[L.BUN] * y[L.X2]


@nb.njit(**_INLINE)
def lower_friction(p, t, y, mode):
    """Lower slip friction, eq. (14), on the branch ``mode`` (+1/-1)."""
    sl = lower_scale(p, t, y[L.THL]) * thermal_scale(p, y)
    return mode * sl * (p[L.TSL] + hump(p, memory_speed(p, y, mode))) + p[L.BL] * y[L.X3]


@nb.njit(**_JIT)
def rhs(t, y, u, p, mode_u, mode_l, dy):
    """Vector field of the rig in modes (mode_u, mode_l); writes into ``dy``."""
    if p[L.ANY_EFFECT] == 0.0:
        _rhs_paper(y, u, p, mode_u, mode_l, dy)
        return
    ts = string_torque(p, y)
    dy[L.X1] = y[L.X2] - y[L.X3]
    if mode_u == 0:
        dy[L.X2] = 0.0
    else:
        dy[L.X2] = (motor_torque(p, y, u) - ts - upper_friction(p, y, mode_u)) / p[L.JU]
    power = 0.0  # dissipated by the lower friction: T_fl x3 = |T_fl x3| on the slip branch
    if mode_l == 0:
        dy[L.X3] = 0.0
    else:
        tfl = lower_friction(p, t, y, mode_l)
        dy[L.X3] = (ts + disturbance(p, t) - tfl) / p[L.JL]
        power = tfl * y[L.X3]
    dy[L.THL] = y[L.X3]
    if p[L.TAU_M] > 0.0:
        dy[L.TM] = (p[L.KM] * u - y[L.TM]) / p[L.TAU_M]
    else:
        dy[L.TM] = 0.0
    if p[L.TAU_F] > 0.0:
        dy[L.WL] = (mode_l * y[L.X3] - y[L.WL]) / p[L.TAU_F]  # mode_l * x3 = |x3| on the branch
    else:
        dy[L.WL] = 0.0
    if p[L.HEAT] != 0.0:
        dy[L.TH] = (power - y[L.TH]) / p[L.TAU_TH]
    else:
        dy[L.TH] = 0.0


@nb.njit(**_INLINE)
def _rhs_paper(y, u, p, mode_u, mode_l, dy):
    """Eq. (36) exactly, without the optional effects: the hot path."""
    ts = p[L.KTH] * y[L.X1]
    dy[L.X1] = y[L.X2] - y[L.X3]
    if mode_u == 0:
        dy[L.X2] = 0.0
    elif mode_u > 0:
        dy[L.X2] = (p[L.KM] * u - ts - p[L.TSUP] - p[L.BUP] * y[L.X2]) * p[L.INV_JU]
    else:
        dy[L.X2] = (p[L.KM] * u - ts + p[L.TSUN] - p[L.BUN] * y[L.X2]) * p[L.INV_JU]
    if mode_l == 0:
        dy[L.X3] = 0.0
    else:
        w = mode_l * y[L.X3]
        dy[L.X3] = (ts - mode_l * (p[L.TSL] + hump(p, w)) - p[L.BL] * y[L.X3]) * p[L.INV_JL]
    dy[L.THL] = y[L.X3]
    dy[L.TM] = 0.0
    dy[L.WL] = 0.0
    dy[L.TH] = 0.0


# -- switching: required torques and static bands ------------------------------------------


@nb.njit(**_JIT)
def upper_required(p, y, u):
    """Friction torque that holds the upper disk at zero speed."""
    return motor_torque(p, y, u) - (p[L.KTH] * y[L.X1] - p[L.BTH] * y[L.X3])


@nb.njit(**_JIT)
def lower_required(p, t, y):
    """Friction torque that holds the lower disk at zero speed."""
    return p[L.KTH] * y[L.X1] + p[L.BTH] * y[L.X2] + disturbance(p, t)


@nb.njit(**_JIT)
def upper_band(p, y):
    """(low, high) of the upper static band, [-T_sun, T_sup] scaled by position."""
    su = upper_scale(p, y[L.X1] + y[L.THL])
    return -su * p[L.TSUN], su * p[L.TSUP]


@nb.njit(**_JIT)
def lower_band_half(p, t, y):
    """Half-width of the lower static band, T_sl (scaled; widened by friction memory)."""
    sl = lower_scale(p, t, y[L.THL]) * thermal_scale(p, y)
    if p[L.TAU_F] > 0.0:
        # With memory the slip friction at zero speed is T_sl + S(w); the disk can only
        # break away once the load exceeds it, so the band covers it when S(w) > 0.
        return sl * (p[L.TSL] + max(hump(p, y[L.WL]), 0.0))
    return sl * p[L.TSL]


@nb.njit(**_JIT)
def decide_upper(p, y, u):
    """Mode of the upper disk at zero speed: stick if the load fits in the band (closed)."""
    need = upper_required(p, y, u)
    lo, hi = upper_band(p, y)
    if need > hi:
        return 1
    if need < lo:
        return -1
    return 0


@nb.njit(**_JIT)
def decide_lower(p, t, y):
    """Mode of the lower disk at zero speed: stick if the load fits in the band (closed)."""
    need = lower_required(p, t, y)
    half = lower_band_half(p, t, y)
    if need > half:
        return 1
    if need < -half:
        return -1
    return 0


# -- a stuck disk exactly on a band edge ----------------------------------------------------


@nb.njit(**_INLINE)
def _scale_rate(a1, p1, a2, p2, angle, angle_rate):
    """Time derivative of 1 + a1 cos(angle + p1) + a2 cos(2 angle + p2)."""
    if a1 == 0.0 and a2 == 0.0:
        return 0.0
    return -(a1 * math.sin(angle + p1) + 2.0 * a2 * math.sin(2.0 * angle + p2)) * angle_rate


@nb.njit(**_INLINE)
def _hump_rate(p, w):
    """d hump / d w."""
    e1 = math.exp(-p[L.BETA1] * w)  # sech^2(b w / 2) = 4 e / (1 + e)^2 with e = exp(-b w)
    e2 = math.exp(-p[L.BETA2] * w)
    return 2.0 * (p[L.T1] * p[L.BETA1] * e1 / (1.0 + e1) ** 2 + p[L.T2] * p[L.BETA2] * e2 / (1.0 + e2) ** 2)


@nb.njit(**_JIT)
def upper_edge_rate(p, y, u, dy):
    """Rate at which the stuck upper disk's load leaves its band (> 0) or enters it (< 0),
    when it sits exactly on one of its edges; ``dy`` is the state's time derivative.

    The rate of the held voltage is taken as zero (a zero-order hold, or a function of time
    whose derivative is not known): then only the higher derivatives decide (the caller's).
    """
    need = upper_required(p, y, u)
    lo, hi = upper_band(p, y)
    motor_rate = dy[L.TM] if p[L.TAU_M] > 0.0 else 0.0
    need_rate = motor_rate - p[L.KTH] * dy[L.X1] + p[L.BTH] * dy[L.X3]
    su_rate = _scale_rate(
        p[L.POSU_A1], p[L.POSU_P1], p[L.POSU_A2], p[L.POSU_P2], y[L.X1] + y[L.THL], dy[L.X1] + dy[L.THL]
    )
    if need - hi >= lo - need:
        return need_rate - su_rate * p[L.TSUP]
    return -su_rate * p[L.TSUN] - need_rate


@nb.njit(**_JIT)
def lower_edge_rate(p, t, y, dy):
    """Rate at which the stuck lower disk's load leaves its band (> 0) or enters it (< 0),
    when it sits exactly on one of its edges; ``dy`` is the state's time derivative."""
    need = lower_required(p, t, y)
    need_rate = p[L.KTH] * dy[L.X1] + p[L.BTH] * dy[L.X2]
    if p[L.DIST_A] != 0.0:
        need_rate += p[L.DIST_A] * p[L.DIST_W] * math.cos(p[L.DIST_W] * t + p[L.DIST_P])
    # half = s(theta_l) (1 + drift t) (1 + kappa Th) (T_sl + max(S(w), 0)): product rule
    pos = 1.0
    if p[L.POSL_A1] != 0.0 or p[L.POSL_A2] != 0.0:
        pos = (
            1.0
            + p[L.POSL_A1] * math.cos(y[L.THL] + p[L.POSL_P1])
            + p[L.POSL_A2] * math.cos(2.0 * y[L.THL] + p[L.POSL_P2])
        )
    pos_rate = _scale_rate(p[L.POSL_A1], p[L.POSL_P1], p[L.POSL_A2], p[L.POSL_P2], y[L.THL], dy[L.THL])
    drift = 1.0 + p[L.DRIFT] * t
    level = p[L.TSL]
    level_rate = 0.0
    if p[L.TAU_F] > 0.0 and hump(p, y[L.WL]) > 0.0:
        level += hump(p, y[L.WL])
        level_rate = _hump_rate(p, y[L.WL]) * dy[L.WL]
    half_rate = (pos_rate * drift + pos * p[L.DRIFT]) * level + pos * drift * level_rate
    if p[L.HEAT] != 0.0:
        heat = 1.0 + p[L.HEAT] * y[L.TH]
        half_rate = half_rate * heat + pos * drift * level * p[L.HEAT] * dy[L.TH]
    if need >= 0.0:
        return need_rate - half_rate
    return -half_rate - need_rate
