"""Friction laws (12) and (14): slip branches, static bands, the slope d_l, and the
statements of the paper about them (condition (21), T_l(13 rad/s) ~ T_sl)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

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
