"""The env's operating points and regimes come from the analysis and are those they were
before it did: the boundaries of Fig. 8, the Routh-Hurwitz threshold against the closed
form of the cubic's Hurwitz determinant, and the equilibrium speed against eq. (20)."""

from __future__ import annotations

import math

import pytest

from drill_env.envs import task
from drill_env.envs.equilibrium import stable_at_speed
from drill_env.params import load_params


def _hurwitz_threshold(params) -> float:
    """Larger root in d of a2 a1 - a0 for s^3 + a2 s^2 + a1 s + a0 with a2 = b/Ju + d/Jl,
    a1 = k/Ju + k/Jl + b d/(Ju Jl), a0 = k (b + d)/(Ju Jl) (expanded by hand)."""
    ju, jl = params.upper_inertia, params.lower_inertia
    k, b = params.string_stiffness, params.upper_viscous_pos
    c2 = b / (ju * jl * jl)
    c1 = (k / ju + k / jl) / jl + b * b / (ju * ju * jl) - k / (ju * jl)
    c0 = (b / ju) * (k / ju + k / jl) - k * b / (ju * jl)
    return (-c1 + math.sqrt(c1 * c1 - 4.0 * c2 * c0)) / (2.0 * c2)


def _lower_friction(params, w: float) -> float:
    """T_l(w) of eq. (14) on the forward slip branch, written out."""
    return (
        params.lower_static
        + params.lower_hump_1 * math.tanh(0.5 * params.lower_hump_rate_1 * w)
        + params.lower_hump_2 * math.tanh(0.5 * params.lower_hump_rate_2 * w)
        + params.lower_viscous * w
    )


def _torque_residual(params, u: float, w: float) -> float:
    """km u - T_up(w) - T_l(w) of eq. (20)."""
    t_up = params.upper_static_pos + params.upper_viscous_pos * w
    return params.motor_constant * u - t_up - _lower_friction(params, w)


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_critical_slope_is_the_hurwitz_root(preset):
    p = load_params(preset)
    assert task.critical_friction_slope(p) == pytest.approx(_hurwitz_threshold(p), rel=1e-10)
    assert task.critical_friction_slope(p) == pytest.approx(-0.00114220, abs=5e-9)


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
@pytest.mark.parametrize("u", [0.2, 0.7, 1.3, 2.9, 4.6])
def test_equilibrium_speed_balances_the_torques(preset, u):
    p = load_params(preset)
    w = task.equilibrium_speed(p, u)
    assert w > 0
    assert abs(_torque_residual(p, u, w)) < 1e-12
    assert task.nominal_voltage(p, w) == pytest.approx(u, rel=1e-12)
    y = task.equilibrium_state(p, u)
    assert y[0] * p.string_stiffness == pytest.approx(_lower_friction(p, w), rel=1e-12)  # x1 = T_l / k


def test_below_uc1_the_rig_rests():
    p = load_params("brake")
    assert task.equilibrium_speed(p, p.uc1) == 0.0
    assert task.equilibrium_speed(p, 0.5 * p.uc1) == 0.0


def test_brake_regime_boundaries_unchanged():
    r = task.operating_regimes(load_params("brake"))
    assert r.uc1 == pytest.approx(0.1164374, abs=1e-7)  # A
    assert r.hopf == pytest.approx((0.5829985,), abs=1e-7)  # B
    assert r.transitions == pytest.approx((1.7812193,), abs=2e-4)  # D (refined to ~0.1 mV)
    assert [name for name, _, _ in r.intervals] == ["equilibrium", "limit_cycle", "stick_slip"]
    assert r.regime_of(0.5) == "equilibrium" and r.regime_of(1.0) == "limit_cycle"
    assert r.regime_of(2.0) == "stick_slip"


def test_no_brake_regime_boundaries_unchanged():
    r = task.operating_regimes(load_params("no_brake"))
    assert r.uc1 == pytest.approx(0.0947609, abs=1e-7)  # A
    assert r.hopf == pytest.approx((0.4889230, 1.4295986), abs=1e-7)  # B, C
    assert r.transitions == pytest.approx((0.6002989, 1.2936388, 1.6711465), abs=2e-4)  # D, E, F
    names = [name for name, _, _ in r.intervals]
    assert names == ["equilibrium", "limit_cycle", "stick_slip", "limit_cycle", "equilibrium"]


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_stability_changes_at_the_hopf_points(preset):
    p = load_params(preset)
    for u in task.hopf_voltages(p):
        w = task.equilibrium_speed(p, u)
        assert stable_at_speed(p, w * (1 - 1e-4)) != stable_at_speed(p, w * (1 + 1e-4))
