"""Equilibria, their stability and the Hopf points against the paper's equations.

The references here are the paper's formulas evaluated with the friction laws of
:mod:`drill_env.friction` (a separate implementation from the analysis' own), and
numerical derivatives.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import drill_env
from drill_env import _layout as L
from drill_env.analysis import (
    critical_friction_slope,
    equilibria,
    hopf_points,
    routh_hurwitz,
    slip_equilibrium,
    stick_set,
)
from drill_env.analysis import variational as V
from drill_env.analysis.equilibria import _hump_derivatives, equilibrium_jacobian
from drill_env.dynamics import rhs
from drill_env.friction import hump_torque, lower_friction_curve, lower_friction_slope

PRESETS = ("brake", "no_brake")


@pytest.mark.parametrize("preset", PRESETS)
def test_stick_set_is_eq_26_within_range_25(preset):
    p = drill_env.load_params(preset)
    k, km = p.string_stiffness, p.motor_constant
    lo_u = -(p.upper_static_neg + p.lower_static) / km
    hi_u = (p.upper_static_pos + p.lower_static) / km
    for u in np.linspace(lo_u, hi_u, 41):
        lo, hi = stick_set(p, u)
        assert lo == pytest.approx(max(-p.lower_static / k, (km * u - p.upper_static_pos) / k), abs=1e-14)
        assert hi == pytest.approx(min(p.lower_static / k, (km * u + p.upper_static_neg) / k), abs=1e-14)
        assert lo <= hi
        (eq,) = equilibria(p, u)
        assert eq.kind == "stick_set" and eq.stable and eq.x3 == 0.0
    # Point A: the set shrinks to one twist, T_sl / k_theta, and is gone just above.
    lo, hi = stick_set(p, hi_u)
    assert hi - lo == pytest.approx(0.0, abs=1e-12)
    assert lo == pytest.approx(p.lower_static / k, rel=1e-12)
    assert stick_set(p, hi_u * (1 + 1e-9)) is None
    assert stick_set(p, lo_u * (1 + 1e-9)) is None
    assert p.uc1 == pytest.approx(hi_u, rel=1e-15)


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("u", [0.15, 0.3, 0.7, 1.0, 2.0, 4.9, 12.0, -0.2, -1.5, -4.0])
def test_slip_equilibrium_solves_eq_20_and_22(preset, u):
    p = drill_env.load_params(preset)
    if p.uc1_neg <= u <= p.uc1:
        pytest.skip("inside the stick range")
    eq = slip_equilibrium(p, u)
    x3 = eq.x3
    tl = float(lower_friction_curve(p, x3))
    if u > 0:
        assert x3 > 0 and eq.kind == "slip_forward"
        residual = p.motor_constant * u - p.upper_viscous_pos * x3 - p.upper_static_pos - tl  # eq. (20)
        assert eq.x1 == pytest.approx(tl / p.string_stiffness, rel=1e-13)
    else:
        assert x3 < 0 and eq.kind == "slip_backward"
        residual = p.motor_constant * u - p.upper_viscous_neg * x3 + p.upper_static_neg + tl  # eq. (22)
        assert eq.x1 == pytest.approx(-tl / p.string_stiffness, rel=1e-13)
    assert abs(residual) < 1e-12 * max(1.0, abs(u))
    # It is a rest point of the vector field the simulator integrates.
    y = np.zeros(L.NY)
    y[:3] = eq.state
    dy = np.empty(L.NY)
    m = 1 if x3 > 0 else -1
    rhs(0.0, y, u, p.as_array(), m, m, dy)
    assert np.max(np.abs(dy[:3])) < 1e-11


@pytest.mark.parametrize("preset", PRESETS)
def test_condition_21_one_slip_equilibrium_per_voltage(preset):
    """Statement 2: -b_up - dT_l/dx3 < 0 for all x3 > 0, so u(x3) is increasing."""
    p = drill_env.load_params(preset)
    w = np.linspace(1e-6, 60.0, 200001)
    assert np.all(-p.upper_viscous_pos - lower_friction_slope(p, w) < 0)
    us = np.linspace(p.uc1 + 1e-6, 20.0, 300)
    x3 = np.array([slip_equilibrium(p, u).x3 for u in us])
    assert np.all(np.diff(x3) > 0)


def test_brake_friction_at_13_rad_s_equals_static_level():
    """Statement 3 (the Appendix): T_l(13 rad/s) is about T_sl for the brake."""
    p = drill_env.load_params("brake")
    assert float(lower_friction_curve(p, 13.0)) == pytest.approx(p.lower_static, rel=0.01)
    w = np.linspace(1e-3, 12.9, 2000)
    assert np.all(lower_friction_curve(p, w) > p.lower_static)


def test_critical_friction_slope_is_eq_23():
    """Statement 1: the slip equilibrium is stable iff d_l > -0.00114 N m s/rad."""
    for preset in PRESETS:
        assert critical_friction_slope(preset) == pytest.approx(-0.00114, abs=5e-6)


@pytest.mark.parametrize("preset", PRESETS)
def test_stability_eigenvalues_agree_with_routh_hurwitz_and_eq_23(preset):
    p = drill_env.load_params(preset)
    dcrit = critical_friction_slope(p)
    dcrit_neg = critical_friction_slope(p, direction=-1)
    us = np.concatenate([np.linspace(p.uc1 + 1e-4, 16.0, 400), np.linspace(-16.0, p.uc1_neg - 1e-4, 200)])
    verdicts = []
    for u in us:
        eq = slip_equilibrium(p, u)
        margin = eq.friction_slope - (dcrit if u > 0 else dcrit_neg)
        if abs(margin) < 1e-9:
            continue
        assert eq.stable == eq.routh_hurwitz == (margin > 0), u
        verdicts.append(eq.stable)
    assert any(verdicts) and not all(verdicts)  # both stable and unstable equilibria occur


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("x3", [0.3, 0.9, 2.0, 7.0, -0.5, -3.0])
def test_routh_hurwitz_coefficients_are_the_characteristic_polynomial(preset, x3):
    p = drill_env.load_params(preset)
    _, (a2, a1, a0) = routh_hurwitz(p, x3)
    coeffs = np.poly(equilibrium_jacobian(p, x3))
    np.testing.assert_allclose(coeffs, [1.0, a2, a1, a0], rtol=1e-12, atol=1e-14)


def test_jacobian_matches_finite_differences_and_field_matches_simulator():
    p = drill_env.load_params("brake").as_array()
    J = np.zeros((3, 4))
    y = np.zeros(L.NY)
    dy = np.empty(L.NY)
    rng = np.random.default_rng(3)
    for mu, ml in itertools.product((-1, 0, 1), repeat=2):
        for _ in range(5):
            x = rng.normal(size=3) * [2.0, 3.0, 3.0]
            u = rng.uniform(-5, 5)
            f = np.array(V.field(x[0], x[1], x[2], u, p, mu, ml))
            y[:3] = x
            rhs(0.0, y, u, p, mu, ml, dy)
            np.testing.assert_allclose(f, dy[:3], rtol=1e-14, atol=1e-15)
            V.jacobian(x[2], p, mu, ml, J)
            fd = np.zeros((3, 4))
            for j in range(4):
                h = 1e-6
                a = np.append(x, u).astype(float)
                b = a.copy()
                a[j] += h
                b[j] -= h
                fd[:, j] = (
                    np.array(V.field(*a[:3], a[3], p, mu, ml)) - np.array(V.field(*b[:3], b[3], p, mu, ml))
                ) / (2 * h)
            np.testing.assert_allclose(J, fd, rtol=1e-7, atol=1e-7)


@pytest.mark.parametrize("preset", PRESETS)
def test_hump_derivatives(preset):
    p = drill_env.load_params(preset)
    for w in (0.1, 0.8, 2.4, 10.0):
        h, d1, d2, d3 = _hump_derivatives(p, w)
        e = 1e-4
        vals = [float(hump_torque(p, w + k * e)) for k in (-2, -1, 0, 1, 2)]
        assert h == pytest.approx(vals[2], rel=1e-13)
        assert d1 == pytest.approx((vals[3] - vals[1]) / (2 * e), rel=1e-6, abs=1e-9)
        assert d2 == pytest.approx((vals[3] - 2 * vals[2] + vals[1]) / e**2, rel=1e-4, abs=1e-6)
        fd3 = (vals[4] - 2 * vals[3] + 2 * vals[1] - vals[0]) / (2 * e**3)
        assert d3 == pytest.approx(fd3, rel=1e-3, abs=1e-3)
        assert d1 + p.lower_viscous == pytest.approx(float(lower_friction_slope(p, w)), rel=1e-12)


# Values from the closed-form condition (23) solved by root-finding; the tolerances are
# those of the root-finders. The paper's Fig. 8 puts B near 0.5 V (both presets) and C
# near 1.4 V (no brake).
HOPF = {"no_brake": (0.488922958, 1.429598608), "brake": (0.582998547, 13.128517497)}


@pytest.mark.parametrize("preset", PRESETS)
def test_hopf_points_where_d_l_is_critical_and_a_pair_crosses(preset):
    p = drill_env.load_params(preset)
    hs = hopf_points(p, 0.0, 20.0)
    assert [h.u for h in hs] == pytest.approx(HOPF[preset], abs=1e-8)
    dcrit = critical_friction_slope(p)
    for h in hs:
        assert h.friction_slope == pytest.approx(dcrit, abs=1e-13)
        ev = np.linalg.eigvals(equilibrium_jacobian(p, h.x_eq[2]))
        pair = ev[np.abs(ev.imag) > 0.1]
        assert pair.size == 2 and np.max(np.abs(pair.real)) < 1e-10
        assert h.omega == pytest.approx(abs(pair[0].imag), rel=1e-12)
        # The real part of the pair changes sign across u_H, at the computed speed.
        re = []
        for du in (-1e-4, 1e-4):
            e = slip_equilibrium(p, h.u + du)
            re.append(e.eigenvalues[np.argmax(np.abs(e.eigenvalues.imag))].real)
        assert re[0] * re[1] < 0
        assert (re[1] - re[0]) / 2e-4 == pytest.approx(h.crossing_speed, rel=1e-3)
        # The linear period is close to that of the string resonance (Sec. 4).
        assert h.period == pytest.approx(2 * np.pi / p.resonance_rad_s, rel=0.01)
    # B supercritical, C subcritical (statement 5): the sign of l1.
    assert hs[0].l1 < 0 and hs[0].kind == "hopf_supercritical"
    assert hs[1].l1 > 0 and hs[1].kind == "hopf_subcritical"
