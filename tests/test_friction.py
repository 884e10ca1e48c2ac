"""Friction laws (12) and (14): slip branches, static bands, the slope d_l, and the
statements of the paper about them (condition (21), T_l(13 rad/s) ~ T_sl).

The hump part of eq. (14) has one definition (drill_env.friction.hump_law and its slope);
its compiled form (inside the simulator's right-hand side and the sensitivity flow's
Jacobian) and its NumPy form are checked here against an independent transcription of
the paper's formula and against central finite differences.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from drill_env import _layout as L
from drill_env.analysis.equilibria import equilibrium_jacobian
from drill_env.analysis.variational import jacobian as flow_jacobian
from drill_env.dynamics import hump, hump_slope, rhs
from drill_env.friction import hump_slope as hump_slope_numpy
from drill_env.friction import (
    hump_torque,
    lower_friction_curve,
    lower_friction_slope,
    lower_slip_friction,
    lower_static_band,
    upper_slip_friction,
    upper_static_band,
)

SPEEDS = np.concatenate([-np.logspace(-6, 1.7, 200)[::-1], np.logspace(-6, 1.7, 200)])


def paper_lower_friction(p, w):
    """Eq. (14) as printed, with the exponentials of the paper (not tanh)."""
    a = np.abs(w)
    stribeck = p.lower_hump_1 * (1 - 2 / (1 + np.exp(p.lower_hump_rate_1 * a))) + p.lower_hump_2 * (
        1 - 2 / (1 + np.exp(p.lower_hump_rate_2 * a))
    )
    return (p.lower_static + stribeck) * np.sign(w) + p.lower_viscous * w


@pytest.fixture(params=["brake", "no_brake"])
def params(request):
    return request.getfixturevalue(request.param)


def test_upper_slip_branches_are_eq_12(params):
    w = SPEEDS
    expected = np.where(
        w > 0,
        params.upper_static_pos + params.upper_viscous_pos * w,
        -params.upper_static_neg + params.upper_viscous_neg * w,
    )
    np.testing.assert_allclose(upper_slip_friction(params, w), expected, rtol=1e-15, atol=0)
    # The branches tend to the edges of the static band, not to a smoothed value.
    lo, hi = upper_static_band(params)
    assert (lo, hi) == (-params.upper_static_neg, params.upper_static_pos)
    assert upper_slip_friction(params, 1e-12) == pytest.approx(hi, abs=1e-11)
    assert upper_slip_friction(params, -1e-12) == pytest.approx(lo, abs=1e-11)


def test_lower_slip_branches_are_eq_14(params):
    np.testing.assert_allclose(
        lower_slip_friction(params, SPEEDS), paper_lower_friction(params, SPEEDS), rtol=1e-12, atol=1e-15
    )
    # Odd in the speed, and of the sign of the speed (dissipative, eq. 4).
    np.testing.assert_array_equal(lower_slip_friction(params, -SPEEDS), -lower_slip_friction(params, SPEEDS))
    assert np.all(np.sign(lower_slip_friction(params, SPEEDS)) == np.sign(SPEEDS))


def test_static_bands_and_no_value_at_zero(params):
    # At zero speed the friction is a set, so the slip functions have no value there.
    assert np.isnan(upper_slip_friction(params, 0.0))
    assert np.isnan(lower_slip_friction(params, 0.0))
    assert lower_static_band(params) == (-params.lower_static, params.lower_static)
    # The slip branches end on the band edges: a jump of 2 T_sl across zero, no smoothing.
    assert lower_slip_friction(params, 1e-13) == pytest.approx(params.lower_static, abs=1e-12)
    assert lower_slip_friction(params, -1e-13) == pytest.approx(-params.lower_static, abs=1e-12)


def test_friction_curve_of_eq_19(params):
    w = np.abs(SPEEDS)
    np.testing.assert_allclose(
        lower_friction_curve(params, w), np.abs(lower_slip_friction(params, w)), rtol=1e-15
    )
    np.testing.assert_array_equal(lower_friction_curve(params, -w), lower_friction_curve(params, w))
    assert lower_friction_curve(params, 0.0) == params.lower_static
    assert hump_torque(params, 0.0) == 0.0


def test_slope_is_the_derivative_of_the_curve(params):
    w = np.linspace(0.01, 40.0, 500)
    h = 1e-6
    fd = (lower_friction_curve(params, w + h) - lower_friction_curve(params, w - h)) / (2 * h)
    np.testing.assert_allclose(lower_friction_slope(params, w), fd, rtol=0, atol=1e-8)
    # At zero speed the slope is the sum of the linear terms of the humps plus b_l.
    d0 = 0.5 * (
        params.lower_hump_1 * params.lower_hump_rate_1 + params.lower_hump_2 * params.lower_hump_rate_2
    )
    assert lower_friction_slope(params, 0.0) == pytest.approx(d0 + params.lower_viscous, rel=1e-14)


def test_condition_21_one_slip_equilibrium_per_voltage(params):
    # Eq. (21): -b_up - dT_l/dx3 < 0 for all x3 > 0, so the second equation of (20),
    # km u - b_up x3 - T_sup - T_l(x3) = 0, is strictly decreasing in x3: one root.
    w = np.linspace(1e-6, 200.0, 400_001)
    assert np.max(-params.upper_viscous_pos - lower_friction_slope(params, w)) < 0.0
    g = -params.upper_viscous_pos * w - lower_friction_curve(params, w)
    assert np.all(np.diff(g) < 0)


def test_friction_damping_turns_negative_as_in_fig_7(params):
    # Fig. 7: d_l is positive at small speed, decreases, turns negative (the humped
    # curve) and rises again towards b_l at high speed.
    w = np.linspace(1e-6, 200.0, 200_001)
    d = lower_friction_slope(params, w)
    assert d[0] > 0
    assert d.min() < -0.00114  # below the stability threshold (23): Hopf point B exists
    assert d[-1] == pytest.approx(params.lower_viscous, rel=1e-3)


def test_brake_friction_returns_to_static_level_at_13_rad_s(brake):
    # Appendix: "T_l(13 rad/s) = T_sl" [Fig. 4(b)], and |T_l(x3)| > T_sl for |x3| < 13 rad/s.
    assert lower_friction_curve(brake, 13.0) == pytest.approx(brake.lower_static, rel=5e-3)
    crossing = brentq(lambda w: lower_friction_curve(brake, w) - brake.lower_static, 1.0, 40.0)
    assert crossing == pytest.approx(13.0, abs=0.5)  # the paper's two significant digits
    w = np.linspace(1e-6, 13.0, 100_001)
    assert np.all(lower_friction_curve(brake, w) > brake.lower_static)
    # Beyond it the brake friction drops below the static level.
    assert lower_friction_curve(brake, 20.0) < brake.lower_static


# -- one law, two forms ---------------------------------------------------------------------


def eq14_as_in_notes(p, w):
    """T_fl(w) = (T_sl + T1 tanh(b1|w|/2) + T2 tanh(b2|w|/2)) sign(w) + b_l w, w != 0."""
    a = abs(w)
    tl = (
        p.lower_static
        + p.lower_hump_1 * math.tanh(p.lower_hump_rate_1 * a / 2)
        + p.lower_hump_2 * math.tanh(p.lower_hump_rate_2 * a / 2)
    )
    return tl * (1.0 if w > 0 else -1.0) + p.lower_viscous * w


def central_difference(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h)


def compiled_lower_friction(p_vec, w, any_effect):
    """T_fl(w) as the simulator's right-hand side applies it: x1 = 0 (no string torque),
    the lower disk slipping at w, so Jl x3' = -T_fl(w). ``any_effect`` takes the general
    path (effects switched on, all of size zero) instead of the paper's short path."""
    p = p_vec.copy()
    p[L.ANY_EFFECT] = 1.0 if any_effect else 0.0
    y = np.zeros(L.NY)
    y[L.X3] = w
    y[L.WL] = abs(w)
    dy = np.zeros(L.NY)
    rhs(0.0, y, 0.0, p, 0, 1 if w > 0 else -1, dy)
    return -dy[L.X3] / p[L.INV_JL]


GRID = np.concatenate([-np.geomspace(1e-9, 60.0, 151)[::-1], np.geomspace(1e-9, 60.0, 151)])


def test_compiled_and_numpy_forms_are_eq_14(params):
    p_vec = params.as_array()
    paper = np.array([eq14_as_in_notes(params, w) for w in GRID])
    # round-off relative to the torques summed
    scale = params.lower_static + abs(params.lower_hump_1) + abs(params.lower_hump_2) + np.abs(paper)
    numpy_form = lower_slip_friction(params, GRID)
    np.testing.assert_array_less(np.abs(numpy_form - paper), 1e-14 * scale)
    for any_effect in (False, True):
        compiled = np.array([compiled_lower_friction(p_vec, w, any_effect) for w in GRID])
        np.testing.assert_array_less(np.abs(compiled - paper), 1e-14 * scale)
        np.testing.assert_array_less(np.abs(compiled - numpy_form), 1e-14 * scale)
    # the hump itself, compiled (at w = |x3|, as the kernel calls it) and NumPy, zero at rest
    hump_paper = np.array([eq14_as_in_notes(params, w) for w in np.abs(GRID)])
    hump_paper -= params.lower_static + params.lower_viscous * np.abs(GRID)
    hump_compiled = np.array([hump(p_vec, abs(w)) for w in GRID])
    tol = 1e-14 * (abs(params.lower_hump_1) + abs(params.lower_hump_2))
    np.testing.assert_array_less(np.abs(hump_compiled - hump_paper), tol)
    np.testing.assert_array_less(np.abs(hump_torque(params, GRID) - hump_paper), tol)
    assert hump(p_vec, 0.0) == 0.0
    assert hump(p_vec, 1e300) == params.lower_hump_1 + params.lower_hump_2


def test_compiled_and_numpy_slopes_are_central_differences_of_eq_14(params):
    p_vec = params.as_array()
    w = np.concatenate([np.linspace(0.005, 40.0, 400), [1e-4, 100.0]])
    h = 1e-5
    fd = np.array([central_difference(lambda v: eq14_as_in_notes(params, v), x, h) for x in w])
    fd_hump = fd - params.lower_viscous
    # truncation ~ h^2 |T'''| / 6 <= 1e-10 * 0.3 * 6.4^3 / 6, cancellation ~ 1e-16 * 0.4 / h
    atol = 2e-9
    np.testing.assert_allclose(lower_friction_slope(params, w), fd, rtol=0, atol=atol)
    np.testing.assert_allclose(hump_slope_numpy(params, w), fd_hump, rtol=0, atol=atol)
    compiled = np.array([hump_slope(p_vec, x) for x in w])
    np.testing.assert_allclose(compiled, fd_hump, rtol=0, atol=atol)
    # even in w (the kernel evaluates it at mode * x3), the same in both forms
    np.testing.assert_array_equal(np.array([hump_slope(p_vec, -x) for x in w]), compiled)
    np.testing.assert_allclose(hump_slope_numpy(params, w), compiled, rtol=1e-14, atol=1e-17)
    # far out the exponentials underflow to zero instead of overflowing
    assert hump_slope(p_vec, 1e300) == 0.0
    assert hump_slope_numpy(params, 1e300) == 0.0


def slip_field(p, x, u):
    """Eq. (36) on a slip branch of both disks, x = (x1, x2, x3), with eq. (14) as in NOTES."""
    x1, x2, x3 = x
    ts = p.string_stiffness * x1
    if x2 > 0:
        tfu = p.upper_static_pos + p.upper_viscous_pos * x2
    else:
        tfu = -p.upper_static_neg + p.upper_viscous_neg * x2
    return np.array(
        [
            x2 - x3,
            (p.motor_constant * u - ts - tfu) / p.upper_inertia,
            (ts - eq14_as_in_notes(p, x3)) / p.lower_inertia,
        ]
    )


def flow_jacobian_at(params, x2, x3):
    J = np.zeros((3, 4))
    flow_jacobian(x3, params.as_array(), int(np.sign(x2)), int(np.sign(x3)), J)
    return J


@pytest.mark.parametrize(
    "state", [(0.3, 1.5, 0.8), (-0.2, -0.7, -2.5), (1.0, 0.2, 6.0), (0.05, 3.0, -0.01), (-0.4, -1.0, 12.0)]
)
def test_slip_jacobian_is_the_central_difference_of_eq_36(params, state):
    x = np.array(state, dtype=float)
    u = 1.3
    J = flow_jacobian_at(params, x[1], x[2])
    fd = np.zeros((3, 4))
    h = 1e-6
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        fd[:, j] = (slip_field(params, x + e, u) - slip_field(params, x - e, u)) / (2 * h)
    fd[:, 3] = (slip_field(params, x, u + h) - slip_field(params, x, u - h)) / (2 * h)
    # entries up to |dT/dx3| / Jl ~ 10 s^-1; central differences good to ~1e-8 here
    np.testing.assert_allclose(J, fd, rtol=1e-7, atol=1e-7)


@pytest.mark.parametrize("x3", [0.4, 3.0, -1.2])
def test_equilibrium_jacobian_is_the_slip_jacobian(params, x3):
    # at a slip equilibrium both disks turn at x3: the analysis uses the flow's Jacobian
    np.testing.assert_array_equal(equilibrium_jacobian(params, x3), flow_jacobian_at(params, x3, x3)[:, :3])
