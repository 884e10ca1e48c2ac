"""Friction heating (temperature-dependent lower friction) in the exact simulator.

The smooth slip phase is checked against SciPy's ``solve_ivp`` on the model written out
here on its own (tanh form of the Stribeck part, not the package's laws), the stick phase
against the exact decay of the thermal state, and the breakaway of a stuck lower disk
against its band scaled by the thermal state.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import drill_env
from drill_env import ParameterError
from drill_env import _layout as L
from drill_env.envs.equilibrium import equilibrium_speed

KAPPA = 0.3  # [1/W] strong heating, so that a wrong term shows far above the tolerances
TAU_TH = 4.0  # [s]


def _heated(kappa: float = KAPPA, tau: float = TAU_TH):
    return drill_env.load_params("brake", friction_heating=kappa, thermal_time=tau)


def _slip_rhs(q, u: float, kappa: float, tau: float):
    """Both disks slipping forward: eq. (10) with the lower static + Stribeck part scaled
    by 1 + kappa Th and tau Th' = T_fl x3 - Th."""

    def f(t, y):
        x1, x2, x3, _, th = y
        stribeck = q.lower_hump_1 * math.tanh(0.5 * q.lower_hump_rate_1 * x3) + q.lower_hump_2 * math.tanh(
            0.5 * q.lower_hump_rate_2 * x3
        )
        t_fl = (1.0 + kappa * th) * (q.lower_static + stribeck) + q.lower_viscous * x3
        t_fu = q.upper_static_pos + q.upper_viscous_pos * x2
        ts = q.string_stiffness * x1
        return [
            x2 - x3,
            (q.motor_constant * u - ts - t_fu) / q.upper_inertia,
            (ts - t_fl) / q.lower_inertia,
            x3,
            (t_fl * x3 - th) / tau,
        ]

    return f


def test_slip_phase_matches_solve_ivp_with_the_thermal_state():
    q = _heated()
    u = 4.0
    w = equilibrium_speed(q, u)
    x1 = float(drill_env.friction.lower_friction_curve(q, w)) / q.string_stiffness
    th0 = 0.2  # [W] a warm start, so that the heating acts from the first instant
    x0 = {"x1": x1, "x2": w, "x3": w, "thermal_state": th0}
    res = drill_env.simulate(q, u, 12.0, x0=x0, dt=0.05, rtol=1e-11, atol=1e-12)
    assert res.status == 0
    assert np.all(res.mode_l == 1) and np.all(res.mode_u == 1), "the check needs a run without stick"
    ref = solve_ivp(
        _slip_rhs(q, u, KAPPA, TAU_TH),
        (0.0, 12.0),
        [x1, w, w, 0.0, th0],
        method="DOP853",
        t_eval=res.t,
        rtol=1e-12,
        atol=1e-13,
    )
    assert ref.success
    for got, want in (
        (res.x1, ref.y[0]),
        (res.x2, ref.y[1]),
        (res.x3, ref.y[2]),
        (res.thermal_state, ref.y[4]),
    ):
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-8)
    # the heating is far from negligible at that tolerance: the lower speed moves by > 1e-2
    nominal = q.replace(friction_heating=0.0, thermal_time=0.0)
    cold = drill_env.simulate(nominal, u, 12.0, x0=x0 | {"thermal_state": 0.0}, dt=0.05)
    assert np.max(np.abs(cold.x3 - res.x3)) > 1e-2
    # P > 0 while slipping: the state rises towards the dissipated power
    assert res.thermal_state[-1] > th0


def test_stick_phase_thermal_state_decays_with_the_thermal_time():
    q = _heated()
    u = 0.5 * q.uc1  # both disks stay stuck: no power is dissipated
    res = drill_env.simulate(q, u, 20.0, x0={"thermal_state": 2.0}, dt=0.1)
    assert res.status == 0 and np.all(res.stick_l) and np.all(res.stick_u)
    np.testing.assert_allclose(res.thermal_state, 2.0 * np.exp(-res.t / TAU_TH), rtol=1e-7, atol=1e-12)
    assert len(res.events) == 0


def test_stuck_lower_disk_breaks_away_at_its_heated_band():
    q = _heated()
    th0 = 1.5  # [W] the band is 1 + 0.3 * 1.5 = 1.45 times wider at the start
    u = 1.5  # the upper disk slips at once and winds up the string
    res = drill_env.simulate(q, u, 10.0, x0={"thermal_state": th0}, dt=0.01, rtol=1e-11, atol=1e-12)
    ev = res.events
    first = int(np.flatnonzero((ev.disk == 1) & (ev.mode_before == 0))[0])
    t_ev, y_ev = float(ev.t[first]), ev.state[first]
    th_ev = th0 * math.exp(-t_ev / TAU_TH)  # stuck until then: the state only decays
    assert y_ev[L.TH] == pytest.approx(th_ev, rel=1e-8)
    load = q.string_stiffness * y_ev[L.X1]
    assert load == pytest.approx((1.0 + KAPPA * th_ev) * q.lower_static, rel=1e-8)
    # without the heating the disk leaves its band earlier, at T_sl
    cold = drill_env.simulate(q.replace(friction_heating=0.0, thermal_time=0.0), u, 10.0, dt=0.01)
    first_cold = int(np.flatnonzero((cold.events.disk == 1) & (cold.events.mode_before == 0))[0])
    assert cold.events.t[first_cold] < t_ev - 0.05


def test_a_run_split_in_two_carries_the_thermal_state_over():
    q = _heated(0.05, 20.0)
    whole = drill_env.simulate(q, 3.0, 20.0, dt=0.01)
    first = drill_env.simulate(q, 3.0, 10.0, dt=0.01)
    y = first.final_state
    x0 = {"x1": y[L.X1], "x2": y[L.X2], "x3": y[L.X3], "theta_l": y[L.THL], "thermal_state": y[L.TH]}
    second = drill_env.simulate(q, 3.0, 20.0, x0=x0, dt=0.01, t0=10.0)
    assert first.final_state.size == L.NY and first.final_state[L.TH] > 0.0
    assert second.thermal_state[-1] == pytest.approx(whole.thermal_state[-1], rel=1e-5)
    # a new run starts cold
    assert whole.thermal_state[0] == 0.0


@pytest.mark.parametrize(
    ("effects", "needle"),
    [
        ({"friction_heating": 0.1}, "friction_heating/thermal_time"),
        ({"thermal_time": 10.0}, "friction_heating/thermal_time"),
        ({"friction_heating": 0.1, "thermal_time": -1.0}, "effects.thermal_time"),
        ({"friction_heating": math.inf, "thermal_time": 1.0}, "effects.friction_heating"),
    ],
)
def test_bad_heating_parameters_are_refused_naming_the_field(effects, needle):
    with pytest.raises(ParameterError, match=needle):
        drill_env.load_params("brake", **effects)


def test_thermal_state_in_x0_is_checked():
    with pytest.raises(ValueError, match="x0.thermal_state: .*>= 0 W"):
        drill_env.simulate(_heated(), 1.0, 1.0, x0={"thermal_state": -1.0})
    with pytest.raises(
        ValueError, match=r"x0.thermal_state: the rig has no such state \(effects.friction_heating"
    ):
        drill_env.simulate("brake", 1.0, 1.0, x0={"thermal_state": 1.0})


def test_negative_heating_that_would_reverse_the_friction_is_refused():
    with pytest.raises(
        ValueError, match="effects.friction_heating: .* makes the lower friction level negative"
    ):
        drill_env.simulate(_heated(-20.0, 1.0), 4.0, 10.0)


def test_the_bifurcation_analysis_refuses_friction_heating():
    from drill_env.analysis.equilibria import nominal_vector

    with pytest.raises(ValueError, match="friction_heating"):
        nominal_vector(_heated())


def test_batch_runs_heated_rigs_like_single_runs():
    rigs = [_heated(0.05, 20.0), _heated(-0.1, 50.0)]
    batch = drill_env.simulate_batch(rigs, [2.0, 3.5], 20.0, dt=0.05)
    for i, (q, u) in enumerate(zip(rigs, (2.0, 3.5), strict=True)):
        one = drill_env.simulate(q, u, 20.0, dt=0.05)
        np.testing.assert_array_equal(batch.rig(i).thermal_state, one.thermal_state)
        np.testing.assert_array_equal(batch.rig(i).x3, one.x3)
    assert batch.rig(0).thermal_state[-1] > 0.1


def test_random_heating_fields_need_both():
    from drill_env.envs.config import DomainRandomization

    with pytest.raises(ValueError, match="friction_heating/thermal_time"):
        DomainRandomization(effects={"friction_heating": (0.0, 0.2)})
