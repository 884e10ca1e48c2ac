"""The exact nonsmooth simulator against an independent reference, known answers and
the statements of the paper.

The reference (``tests/oracle.py``) integrates the same model with SciPy's
``solve_ivp`` and terminal events and shares no code with the package's kernels.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from oracle import oracle_simulate
from scipy.integrate import solve_ivp
from scipy.optimize import brentq
from scipy.signal import find_peaks

import drill_env
from drill_env import ParameterError
from drill_env import _layout as L
from drill_env.friction import lower_friction_curve, lower_friction_slope
from drill_env.metrics import dominant_period

TIGHT = {"rtol": 1e-12, "atol": 1e-14}

# -- helpers --------------------------------------------------------------------------------


def state_error(a, b) -> float:
    """Largest difference of the paper's state (x1, x2, x3) between two sampled runs."""
    return max(float(np.max(np.abs(getattr(a, n) - getattr(b, n)))) for n in ("x1", "x2", "x3"))


def assert_agrees_with_oracle(res, ora, state_tol: float, event_tol: float) -> None:
    assert res.status == 0, res.message
    np.testing.assert_array_equal(res.t, ora.t)
    # The same switching events, in the same order, at the same instants.
    assert len(res.events) == len(ora.event_t)
    np.testing.assert_array_equal(res.events.disk, ora.event_disk)
    np.testing.assert_array_equal(res.events.mode_before, ora.event_before)
    np.testing.assert_array_equal(res.events.mode_after, ora.event_after)
    np.testing.assert_allclose(res.events.t, ora.event_t, rtol=0, atol=event_tol)
    # The same trajectory; the angle grows without bound, so it is compared relatively.
    assert state_error(res, ora) <= state_tol
    np.testing.assert_allclose(res.theta_l, ora.theta_l, rtol=state_tol, atol=state_tol)
    # The same modes, except at samples within a hair of a switching instant.
    near = np.zeros(res.t.size, bool)
    for te in ora.event_t:
        near |= np.abs(res.t - te) < 1e-6
    np.testing.assert_array_equal(res.mode_u[~near], ora.modes[~near, 0])
    np.testing.assert_array_equal(res.mode_l[~near], ora.modes[~near, 1])


def slip_equilibrium(p, u: float) -> np.ndarray:
    """Eq. (20) (u > uc1) or eq. (22) (u < uc1_neg): the equilibrium (x1, x2, x3) in slip."""
    km, tsup, tsun = p.motor_constant, p.upper_static_pos, p.upper_static_neg
    if u > p.uc1:
        x3 = brentq(
            lambda w: km * u - p.upper_viscous_pos * w - tsup - lower_friction_curve(p, w), 1e-14, 1e3
        )
        return np.array([lower_friction_curve(p, x3) / p.string_stiffness, x3, x3])
    x3 = brentq(lambda w: km * u - p.upper_viscous_neg * w + tsun + lower_friction_curve(p, w), -1e3, -1e-14)
    return np.array([-lower_friction_curve(p, x3) / p.string_stiffness, x3, x3])


def slip_jacobian(p, dl: float) -> np.ndarray:
    """Linearisation of eq. (36) about a forward-slip equilibrium with friction slope d_l."""
    ju, jl, kth, bup = p.upper_inertia, p.lower_inertia, p.string_stiffness, p.upper_viscous_pos
    return np.array([[0.0, 1.0, -1.0], [-kth / ju, -bup / ju, 0.0], [kth / jl, 0.0, -dl / jl]])


def hurwitz_threshold(p) -> float:
    """The friction slope at which the slip equilibrium loses stability (Routh-Hurwitz).

    det(sI - J) = s^3 + a2 s^2 + a1 s + a0 with, for d = d_l/Jl, bu = bup/Ju,
    ku = k_theta/Ju, kl = k_theta/Jl:  a2 = bu + d,  a1 = bu d + ku + kl,  a0 = ku d + kl bu.
    Stable iff a2, a0 > 0 and a2 a1 > a0, i.e. bu d^2 + (bu^2 + kl) d + bu ku > 0: d must lie
    above the larger root of that quadratic (the other conditions are then implied).
    """
    bu = p.upper_viscous_pos / p.upper_inertia
    ku = p.string_stiffness / p.upper_inertia
    kl = p.string_stiffness / p.lower_inertia
    b = bu**2 + kl
    d = (-b + math.sqrt(b * b - 4 * bu * bu * ku)) / (2 * bu)
    return d * p.lower_inertia


def upper_creep(p, u: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form (x1, x2) from rest while the lower disk stays stuck and the upper slips
    forward: Ju x1'' + bup x1' + k_theta x1 = km u - T_sup, x1(0) = x1'(0) = 0."""
    s1, s2 = np.roots([p.upper_inertia, p.upper_viscous_pos, p.string_stiffness]).real
    a = (p.motor_constant * u - p.upper_static_pos) / p.string_stiffness
    c1, c2 = -a * s2 / (s2 - s1), a * s1 / (s2 - s1)
    return a + c1 * np.exp(s1 * t) + c2 * np.exp(s2 * t), c1 * s1 * np.exp(s1 * t) + c2 * s2 * np.exp(s2 * t)


def stick_set(p, u: float) -> tuple[float, float]:
    """The x1-interval of the equilibrium set (26)."""
    kth = p.string_stiffness
    lo = max(-p.lower_static / kth, (p.motor_constant * u - p.upper_static_pos) / kth)
    hi = min(p.lower_static / kth, (p.motor_constant * u + p.upper_static_neg) / kth)
    return lo, hi


def lower_edge_twist(p) -> float:
    """A twist x1 with k_theta * x1 == T_sl exactly in floating point (the band edge)."""
    x1 = p.lower_static / p.string_stiffness
    for _ in range(8):
        v = p.string_stiffness * x1
        if v == p.lower_static:
            return x1
        x1 = np.nextafter(x1, -np.inf if v > p.lower_static else np.inf)
    raise AssertionError("no twist puts the lower disk exactly on its band edge")


# -- the result object ------------------------------------------------------------------------


def test_result_arrays_and_default_start_at_rest(brake):
    res = drill_env.simulate(brake, 2.0, 10.0, dt=0.05)
    assert res.success and res.status == 0
    n = res.t.size
    assert n == 201 and res.t[0] == 0.0 and res.t[-1] == pytest.approx(10.0, abs=1e-12)
    for name in ("u", "theta_u", "theta_l", "x1", "x2", "x3", "stick_u", "stick_l", "mode_u", "mode_l"):
        assert getattr(res, name).shape == (n,), name
    # Default x0: at rest, no twist; both disks start stuck unless the input breaks one free.
    assert (res.x1[0], res.x2[0], res.x3[0], res.theta_l[0], res.theta_u[0]) == (0.0, 0.0, 0.0, 0.0, 0.0)
    assert res.stick_l[0] and not res.stick_u[0]  # km * 2 V > T_sup: the upper disk moves at once
    np.testing.assert_allclose(res.theta_u - res.theta_l, res.x1, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(res.stick_u, res.mode_u == 0)
    np.testing.assert_array_equal(res.u, 2.0)
    df = res.to_pandas()
    assert list(df.columns) == ["t", "u", "theta_u", "theta_l", "x1", "x2", "x3", "stick_u", "stick_l"]
    assert len(df) == n
    ev = res.events.to_pandas()
    assert list(ev.columns[:4]) == ["t", "disk", "mode_before", "mode_after"]
    assert res.events.kinds()[0] == "lower stick->slip+"


def test_initial_state_forms_agree(brake):
    a = drill_env.simulate(brake, 1.5, 20.0, x0=(0.3, 0.5, -0.2))
    b = drill_env.simulate(brake, 1.5, 20.0, x0=(1.3, 1.0, 0.5, -0.2))  # theta_u, theta_l, x2, x3
    c = drill_env.simulate(brake, 1.5, 20.0, x0={"theta_u": 1.3, "theta_l": 1.0, "x2": 0.5, "x3": -0.2})
    # 1.3 - 1.0 differs from 0.3 by one rounding (5.6e-17); the flow may amplify that.
    for other in (b, c):
        for name in ("x1", "x2", "x3"):
            np.testing.assert_allclose(getattr(other, name), getattr(a, name), rtol=0, atol=1e-10)
        np.testing.assert_allclose(other.theta_l - a.theta_l, 1.0, rtol=0, atol=1e-12)
    assert b.theta_u[0] == 1.3 and b.theta_l[0] == 1.0


def test_start_time_option(brake):
    a = drill_env.simulate(brake, 2.0, 50.0)
    b = drill_env.simulate(brake, 2.0, 60.0, t0=10.0)
    np.testing.assert_allclose(b.t, a.t + 10.0, rtol=0, atol=1e-12)
    assert state_error(a, b) < 1e-8
    np.testing.assert_allclose(b.events.t, a.events.t + 10.0, rtol=0, atol=1e-8)


def test_voltage_limit_option(brake):
    clipped = drill_env.simulate(brake, 7.0, 20.0, voltage_limit=5.0)
    five = drill_env.simulate(brake, 5.0, 20.0)
    assert state_error(clipped, five) == 0.0
    np.testing.assert_array_equal(clipped.u, 5.0)
    np.testing.assert_array_equal(clipped.u_requested, 7.0)
    assert clipped.clipped.all()
    assert drill_env.simulate(brake, 7.0, 1.0).clipped is None  # no limit unless asked
    zoh = drill_env.simulate(brake, [7.0, -7.0, 3.0], 3.0, control_dt=1.0, voltage_limit=5.0, dt=0.5)
    np.testing.assert_array_equal(zoh.u, [5.0, 5.0, -5.0, -5.0, 3.0, 3.0, 3.0])
    np.testing.assert_array_equal(zoh.clipped, [True, True, True, True, False, False, False])


def test_step_cap_reports_status(brake):
    with pytest.warns(RuntimeWarning, match="maximum number of steps"):
        res = drill_env.simulate(brake, 2.0, 100.0, max_steps=50)
    assert res.status == 1 and not res.success
    stop = np.flatnonzero(np.isnan(res.u))
    assert stop.size > 0 and np.all(np.diff(stop) == 1) and stop[-1] == res.t.size - 1
    assert np.all(res.x1[stop] == res.x1[stop[0]])  # samples past the stop hold the last state


# -- agreement with the independent reference --------------------------------------------------


@pytest.mark.parametrize(
    ("preset", "u", "t_final"),
    [
        ("brake", 2.0, 300.0),  # stick-slip, Fig. 9
        ("brake", 1.0, 200.0),  # limit cycle without stick, Fig. 9
        ("brake", 4.5, 150.0),  # stick-slip with reversal of the lower disk
        ("brake", -3.75, 150.0),  # negative direction, reversal at the end of a slip phase
        ("no_brake", 1.0, 300.0),  # stick-slip between D and E, Fig. 8(a)
        ("no_brake", -1.0, 150.0),
        ("no_brake", 3.0, 100.0),  # above E: an equilibrium again
        ("no_brake", 1.29, 400.0),  # next to E: stick phases of 25 ms once per period
    ],
)
def test_agrees_with_reference_through_stick_slip_cycles(preset, u, t_final):
    p = drill_env.load_params(preset)
    ora = oracle_simulate(p, u, t_final, t_eval=0.01 * np.arange(int(round(t_final / 0.01)) + 1))
    res = drill_env.simulate(p, u, t_final, **TIGHT)
    assert_agrees_with_oracle(res, ora, state_tol=1e-7, event_tol=1e-8)
    # At the default tolerances the trajectory stays within the accuracy target.
    default = drill_env.simulate(p, u, t_final)
    assert state_error(default, ora) <= 1e-6
    if (preset, u) in {("brake", 2.0), ("no_brake", 1.0)}:
        breakaways = np.sum((res.events.disk == 1) & (res.events.mode_before == 0))
        assert breakaways >= 70  # many stick-slip cycles were compared


@pytest.mark.parametrize(
    ("preset", "control_dt", "seed"), [("brake", 2.0, 1), ("brake", 0.5, 2), ("no_brake", 2.0, 3)]
)
def test_zero_order_hold_agrees_with_reference(preset, control_dt, seed):
    """Random voltages in [-5, 5] V: both disks stick, slip and reverse; inputs jump."""
    p = drill_env.load_params(preset)
    u = np.random.default_rng(seed).uniform(-5.0, 5.0, size=int(100 / control_dt))
    res = drill_env.simulate(p, u, 100.0, control_dt=control_dt, **TIGHT)
    ora = oracle_simulate(p, u, 100.0, control_dt=control_dt)
    assert_agrees_with_oracle(res, ora, state_tol=1e-7, event_tol=1e-8)
    kinds = set(res.events.kinds())
    assert {"upper slip+->slip-", "upper slip-->slip+", "lower slip+->slip-", "lower slip-->slip+"} <= kinds
    # The voltage is held over each control period [k T, (k + 1) T), switching on its boundary.
    k = np.searchsorted(control_dt * np.arange(u.size + 1), res.t, side="right") - 1
    np.testing.assert_array_equal(res.u, u[np.minimum(k, u.size - 1)])


def test_function_of_time_input_agrees_with_reference(brake):
    def u(t):
        return 2.5 + 1.5 * math.sin(0.3 * t)

    res = drill_env.simulate(brake, u, 120.0, **TIGHT)
    ora = oracle_simulate(brake, u, 120.0)
    assert_agrees_with_oracle(res, ora, state_tol=1e-7, event_tol=1e-8)
    np.testing.assert_allclose(res.u, 2.5 + 1.5 * np.sin(0.3 * res.t), rtol=0, atol=1e-15)
    assert len(res.events) > 20


def test_zero_order_hold_equals_piecewise_constant_function(brake):
    values = np.array([0.05, 2.0, 1.2, 3.0, 0.1, 2.5])

    def held(t):
        return values[min(int(t // 5.0), 5)]

    tight = dict(rtol=1e-10, atol=1e-12)
    zoh = drill_env.simulate(brake, values, 30.0, control_dt=5.0, **tight)
    fun = drill_env.simulate(brake, held, 30.0, **tight)
    assert zoh.status == fun.status == 0
    np.testing.assert_array_equal(zoh.u, fun.u)  # including the samples on the switching instants
    # Modes agree except on a jump itself, which the function's event lands a hair after.
    on_jump = np.isin(zoh.t, 5.0 * np.arange(1, 6))
    np.testing.assert_array_equal(zoh.mode_u[~on_jump], fun.mode_u[~on_jump])
    np.testing.assert_array_equal(zoh.mode_l[~on_jump], fun.mode_l[~on_jump])
    # The hold ends steps exactly on the jumps; the function's jumps are found by step
    # rejection, so the two agree to the accuracy of the integration, not bit for bit.
    assert state_error(zoh, fun) < 1e-7
    np.testing.assert_array_equal(zoh.events.kinds(), fun.events.kinds())
    np.testing.assert_allclose(zoh.events.t, fun.events.t, rtol=0, atol=1e-7)


def test_input_jump_releases_a_stuck_disk_on_the_boundary(brake):
    res = drill_env.simulate(brake, [0.0, 1.0], 4.0, control_dt=2.0, dt=0.5)
    assert res.events.t[0] == 2.0 and res.events.kinds()[0] == "upper stick->slip+"
    k = np.flatnonzero(res.t == 2.0)[0]
    assert res.u[k] == 1.0 and not res.stick_u[k]  # the sample on the jump sees the new input
    assert np.all(res.stick_u[:k]) and np.all(res.x2[:k] == 0.0)


# -- convergence ---------------------------------------------------------------------------------


@pytest.mark.parametrize(("preset", "u"), [("brake", 2.0), ("brake", 1.0), ("no_brake", 1.0)])
def test_error_converges_with_the_tolerance(preset, u):
    ref = drill_env.simulate(preset, u, 60.0, rtol=1e-13, atol=1e-15)
    rtols = 10.0 ** -np.arange(5, 12)
    errors, event_errors = [], []
    for rtol in rtols:
        res = drill_env.simulate(preset, u, 60.0, rtol=rtol, atol=1e-2 * rtol)
        errors.append(state_error(res, ref))
        assert len(res.events) == len(ref.events)
        event_errors.append(np.max(np.abs(res.events.t - ref.events.t)))
    errors = np.array(errors)
    scale = max(np.max(np.abs(ref.x1)), np.max(np.abs(ref.x2)), np.max(np.abs(ref.x3)))
    # Error scaled by the tolerance stays bounded ...
    assert np.all(errors / (rtols * scale) < 100.0), errors / (rtols * scale)
    assert np.all(np.array(event_errors) < 1e3 * rtols), event_errors
    # ... and falls in proportion to it (log-log slope ~ 1), over six decades.
    slope = np.polyfit(np.log10(rtols), np.log10(errors), 1)[0]
    assert 0.75 < slope < 1.25, slope


@pytest.mark.parametrize("u", [2.0, 1.0])
def test_default_tolerance_meets_the_accuracy_target(brake, u):
    ref = drill_env.simulate(brake, u, 100.0, rtol=1e-13, atol=1e-15)
    assert state_error(drill_env.simulate(brake, u, 100.0), ref) <= 1e-6


# -- stick is exact ------------------------------------------------------------------------------


def test_speed_is_exactly_zero_while_stuck(brake_2v):
    res = brake_2v
    stuck = res.stick_l
    assert 0.01 < stuck.mean() < 0.2  # stick phases were sampled
    assert np.all(res.x3[stuck] == 0.0)
    assert np.all(res.x3[res.mode_l == 1] > 0.0)
    # The lower angle does not creep during a stick phase.
    edges = np.flatnonzero(np.diff(stuck.astype(int)))
    for a, b in zip(edges[1::2] + 1, edges[2::2] + 1, strict=False):
        assert np.ptp(res.theta_l[a:b]) == 0.0
    # Events put the disk that switches exactly at rest, on its band edge when it breaks away.
    ev = res.events
    assert np.all(ev.state[ev.disk == 1, L.X3] == 0.0)
    breakaway = (ev.disk == 1) & (ev.mode_before == 0)
    residual = res.params.string_stiffness * ev.state[breakaway, L.X1] - res.params.lower_static
    assert np.max(np.abs(residual)) < 1e-11


def test_both_disks_stuck_hold_the_state_exactly(brake):
    res = drill_env.simulate(brake, 0.05, 60.0, x0=(0.5, 1.0, 2.0))
    both = res.stick_u & res.stick_l
    assert both[-1] and both.sum() > 1000
    assert np.all(res.x2[res.stick_u] == 0.0) and np.all(res.x3[res.stick_l] == 0.0)
    first = np.flatnonzero(both)[0]
    assert np.all(both[first:])
    assert np.ptp(res.x1[first:]) == 0.0 and np.ptp(res.theta_l[first:]) == 0.0


# -- the paper's analysis ------------------------------------------------------------------------


def test_equilibrium_of_eq_20_is_reached_at_half_a_volt(brake):
    # Sec. 4: no torsional vibration at 0.5 V; the rig settles on the slip equilibrium (20).
    res = drill_env.simulate(brake, 0.5, 400.0)
    eq = slip_equilibrium(brake, 0.5)
    final = np.array([res.x1[-1], res.x2[-1], res.x3[-1]])
    np.testing.assert_allclose(final, eq, rtol=0, atol=1e-8)
    last = res.window(100.0)
    assert np.ptp(last.x3) < 1e-8 and not last.stick_l.any()
    assert lower_friction_slope(brake, eq[2]) > hurwitz_threshold(brake)  # consistent with (23)


def test_equilibrium_of_eq_22_in_the_negative_direction(brake):
    res = drill_env.simulate(brake, -0.5, 400.0)
    eq = slip_equilibrium(brake, -0.5)
    assert eq[2] < 0
    np.testing.assert_allclose([res.x1[-1], res.x2[-1], res.x3[-1]], eq, rtol=0, atol=1e-8)


def test_routh_hurwitz_threshold_from_the_parameters(brake, no_brake):
    for p in (brake, no_brake):  # it depends on (11), (13), (15) only
        d_crit = hurwitz_threshold(p)
        assert d_crit == pytest.approx(-0.00114, abs=5e-6)  # eq. (23), to the paper's digits
        # The eigenvalues cross the imaginary axis there, and only there (a Hopf point).
        for d, stable in ((d_crit + 1e-6, True), (d_crit - 1e-6, False), (0.01, True), (-0.01, False)):
            lam = np.linalg.eigvals(slip_jacobian(p, d))
            assert (lam.real.max() < 0) == stable, (d, lam)
        lam = np.linalg.eigvals(slip_jacobian(p, d_crit))
        assert np.min(np.abs(lam.real)) < 1e-12 and np.max(np.abs(lam.imag)) > 1.0


@pytest.mark.parametrize(
    ("preset", "branch", "offset"),
    [
        ("brake", "B", +0.0015),  # d_l above the threshold: below uc2, stable
        ("brake", "B", -0.0015),  # just past point B: unstable
        ("no_brake", "B", +0.0015),
        ("no_brake", "B", -0.0015),
        ("no_brake", "C", -0.0015),  # between B and C: unstable
        ("no_brake", "C", +0.0015),  # past point C: stable again
    ],
)
def test_simulated_growth_rate_matches_the_linearisation(preset, branch, offset):
    p = drill_env.load_params(preset)
    d_crit = hurwitz_threshold(p)
    w = np.linspace(1e-3, 10.0, 100_001)
    w_min = w[np.argmin(lower_friction_slope(p, w))]
    bracket = (1e-6, w_min) if branch == "B" else (w_min, 10.0)
    x3 = brentq(lambda s: lower_friction_slope(p, s) - (d_crit + offset), *bracket)
    u = (p.upper_static_pos + p.upper_viscous_pos * x3 + lower_friction_curve(p, x3)) / p.motor_constant
    eq = slip_equilibrium(p, u)
    assert eq[2] == pytest.approx(x3, rel=1e-9)
    lam = np.linalg.eigvals(slip_jacobian(p, lower_friction_slope(p, x3)))
    rate = lam[np.abs(lam.imag) > 0].real[0]
    assert (rate < 0) == (offset > 0)

    res = drill_env.simulate(p, u, 300.0, x0=eq + [0.0, 0.0, 1e-5])
    assert len(res.events) == 0  # a small oscillation about slip: no switching
    dev = np.abs(res.x3 - eq[2])
    peaks, _ = find_peaks(dev)
    keep = (res.t[peaks] > 10.0) & (dev[peaks] < 1e-4) & (dev[peaks] > 1e-10)  # linear regime
    assert keep.sum() > 20
    measured = np.polyfit(res.t[peaks][keep], np.log(dev[peaks][keep]), 1)[0]
    assert measured == pytest.approx(rate, rel=0.01)


@pytest.mark.parametrize("below", [0.0, 1e-9, 1e-3])
def test_lower_disk_never_moves_at_or_below_uc1(brake, below):
    u = brake.uc1 * (1.0 - below)
    res = drill_env.simulate(brake, u, 400.0, dt=0.1, rtol=1e-11, atol=1e-13)
    assert res.status == 0
    assert np.all(res.x3 == 0.0) and res.stick_l.all() and len(res.events) == 0
    # Meanwhile the upper disk creeps forward exactly as the linear ODE says.
    x1, x2 = upper_creep(brake, u, res.t)
    np.testing.assert_allclose(res.x1, x1, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.x2, x2, rtol=0, atol=1e-10)
    assert np.all(brake.string_stiffness * res.x1 <= brake.lower_static)
    # It tends to the stick set (26), which it reaches only asymptotically.
    lo, hi = stick_set(brake, u)
    assert abs(res.x1[-1] - np.clip(res.x1[-1], lo, hi)) < 1e-6


@pytest.mark.parametrize("above", [1e-6, 1e-3])
def test_lower_disk_breaks_away_just_above_uc1(brake, above):
    u = brake.uc1 + above
    res = drill_env.simulate(brake, u, 400.0, dt=0.1, rtol=1e-11, atol=1e-13)
    # Break-away when k_theta x1(t) reaches T_sl on the closed-form creep of the upper disk.
    t_star = brentq(
        lambda t: brake.string_stiffness * upper_creep(brake, u, t)[0] - brake.lower_static, 1.0, 1e3
    )
    assert 50.0 < t_star < 400.0
    assert res.events.kinds()[0] == "lower stick->slip+"
    assert res.events.t[0] == pytest.approx(t_star, abs=1e-3)
    assert res.x3.max() > 0.0


@pytest.mark.parametrize(
    ("u", "x0"),
    [
        (0.05, (0.5, 1.0, 2.0)),
        (-0.08, (-1.0, -2.0, 5.0)),
        (0.1, (1.0, 0.5, -8.0)),
        (0.0, (0.0, 0.0, 12.5)),
        ("uc1", (0.0, -1.0, 3.0)),
        ("uc1_neg", (0.3, 0.2, -3.0)),
    ],
)
def test_lyapunov_function_27_does_not_increase_in_region_30(brake, u, x0):
    p = brake
    u = getattr(p, u) if isinstance(u, str) else u
    assert p.uc1_neg <= u <= p.uc1  # condition (25)
    lo, hi = stick_set(p, u)
    # Start inside the estimate C of the region of attraction (34): V1 <= Jl 13^2 / 2.
    v1 = 0.5 * (p.string_stiffness * x0[0] ** 2 + p.upper_inertia * x0[1] ** 2 + p.lower_inertia * x0[2] ** 2)
    assert v1 <= 0.5 * p.lower_inertia * 13.0**2
    res = drill_env.simulate(p, u, 200.0, x0=x0, dt=0.002, rtol=1e-11, atol=1e-13)
    assert res.status == 0
    assert np.max(np.abs(res.x3)) < 13.0  # the trajectory stays in region (30)
    for x1_eq in (lo, 0.5 * (lo + hi), hi):  # every point of the set (26)
        v = 0.5 * (
            p.string_stiffness * (res.x1 - x1_eq) ** 2
            + p.upper_inertia * res.x2**2
            + p.lower_inertia * res.x3**2
        )
        assert np.max(np.diff(v)) <= 1e-12 * v[0]
        assert v[-1] < v[0]
    # The trajectory ends in the stick set (26), or tends to it while the upper disk creeps
    # along the slow mode of Ju s^2 + bup s + k_theta (twist lag = speed * time constant).
    tau = max(
        1.0 / np.min(np.abs(np.roots([p.upper_inertia, b, p.string_stiffness])))
        for b in (p.upper_viscous_pos, p.upper_viscous_neg)
    )
    assert abs(res.x1[-1] - np.clip(res.x1[-1], lo, hi)) <= 1e-9 + 1.01 * tau * abs(res.x2[-1])
    assert abs(res.x2[-1]) < 1e-3 and abs(res.x3[-1]) < 1e-12
    assert np.all(res.x2[res.stick_u] == 0.0) and np.all(res.x3[res.stick_l] == 0.0)


def test_fig_9_limit_cycle_without_stick_at_1_volt(brake_1v):
    last = brake_1v.window(100.0)
    assert not last.stick_l.any() and not last.stick_u.any()
    assert last.x3.min() > 0.1  # the lower disk keeps turning ...
    assert np.ptp(last.x3) > 2.0  # ... on a large torsional oscillation, not an equilibrium
    # A settled cycle: the extremes of successive 50 s windows agree.
    prev = brake_1v.t >= brake_1v.t[-1] - 200.0
    prev &= brake_1v.t < brake_1v.t[-1] - 100.0
    assert last.x3.max() == pytest.approx(brake_1v.x3[prev].max(), rel=1e-6)
    assert last.x3.min() == pytest.approx(brake_1v.x3[prev].min(), rel=1e-6)
    # The period stays close to that of the linear resonance (Sec. 4), about 4 s.
    period = dominant_period(last.t, last.x3)
    assert period == pytest.approx(2 * np.pi / brake_1v.params.resonance_rad_s, rel=0.1)


def test_fig_9_stick_slip_at_2_volts(brake_2v):
    last = brake_2v.window(100.0)
    assert last.x3.min() == 0.0 and last.x3.max() > 5.0
    period = dominant_period(last.t, last.x3)
    assert period == pytest.approx(2 * np.pi / brake_2v.params.resonance_rad_s, rel=0.1)
    # One stick phase per period of the cycle.
    starts = np.flatnonzero(np.diff(last.stick_l.astype(int)) == 1)
    assert abs(starts.size - 100.0 / period) <= 1.0
    assert 0.01 < last.stick_l.mean() < 0.1
    assert not last.stick_u.any()


# -- switching corner cases ----------------------------------------------------------------------


def backward_to_simultaneous_rest(p, u: float, x1_meet: float, duration: float) -> np.ndarray:
    """The state from which both disks, slipping forward, reach zero speed at the same
    instant ``duration`` later with twist ``x1_meet``: integrate the slip+ field backward."""

    def slip_forward(t, y):
        x1, x2, x3 = y
        tfu = p.upper_static_pos + p.upper_viscous_pos * x2
        tfl = lower_friction_curve(p, x3) + 0.0  # x3 > 0 along the way
        return [
            x2 - x3,
            (p.motor_constant * u - p.string_stiffness * x1 - tfu) / p.upper_inertia,
            (p.string_stiffness * x1 - tfl) / p.lower_inertia,
        ]

    sol = solve_ivp(
        slip_forward,
        (0.0, -duration),
        [x1_meet, 0.0, 0.0],
        method="DOP853",
        rtol=1e-13,
        atol=1e-15,
        dense_output=True,
    )
    path = sol.sol(np.linspace(-duration, -1e-3, 200))
    assert np.all(path[1] > 0) and np.all(path[2] > 0)  # both really slip forward on the way
    return sol.y[:, -1]


@pytest.mark.parametrize(
    ("x1_meet", "after"),
    [
        (0.0, ("stick", "stick")),  # both loads inside their bands: both stick
        (0.5, ("stick", "stick")),
        (-2.0, ("stick", "slip-")),  # the lower load leaves its band: the lower disk reverses
    ],
)
def test_both_disks_switch_at_one_instant(brake, x1_meet, after):
    x1_meet = x1_meet * brake.lower_static / brake.string_stiffness
    x0 = backward_to_simultaneous_rest(brake, 0.0, x1_meet, 0.5)
    res = drill_env.simulate(brake, 0.0, 3.0, x0=x0, **TIGHT)
    assert res.status == 0
    kinds = res.events.kinds()
    assert kinds[:2] == [f"upper slip+->{after[0]}", f"lower slip+->{after[1]}"]
    np.testing.assert_allclose(res.events.t[:2], 0.5, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.events.state[:2, L.X1], x1_meet, rtol=0, atol=1e-9)
    ora = oracle_simulate(brake, 0.0, 3.0, x0=x0)
    assert len(ora.event_t) == len(res.events)
    assert state_error(res, ora) < 1e-8
    if after[1] == "stick":
        assert len(res.events) == 2 and res.stick_u[-1] and res.stick_l[-1]
        assert res.x1[-1] == pytest.approx(x1_meet, abs=1e-9)


def test_both_bands_exceeded_at_the_start(brake):
    # At rest with both loads outside their bands: both disks slip from t = 0.
    x1 = 2.0 * brake.lower_static / brake.string_stiffness
    u = (brake.upper_static_pos + brake.string_stiffness * x1 + 0.1) / brake.motor_constant
    res = drill_env.simulate(brake, u, 60.0, x0=(x1, 0.0, 0.0), **TIGHT)
    assert res.mode_u[0] == 1 and res.mode_l[0] == 1
    assert res.x2[1] > 0 and res.x3[1] > 0
    ora = oracle_simulate(brake, u, 60.0, x0=(x1, 0.0, 0.0))
    assert_agrees_with_oracle(res, ora, state_tol=1e-8, event_tol=1e-8)
    # And the reverse: at rest, both loads beyond the negative edges.
    u = (-brake.upper_static_neg - brake.string_stiffness * x1 - 0.1) / brake.motor_constant
    res = drill_env.simulate(brake, u, 60.0, x0=(-x1, 0.0, 0.0), **TIGHT)
    assert res.mode_u[0] == -1 and res.mode_l[0] == -1
    assert_agrees_with_oracle(res, oracle_simulate(brake, u, 60.0, x0=(-x1, 0.0, 0.0)), 1e-8, 1e-8)


@pytest.mark.parametrize(
    ("upper_speed", "breaks_away"),
    [
        (0.0, False),  # nothing pushes it further: it stays on the edge, stuck
        (0.5, True),  # the twist grows: it slips at once
        (-0.5, False),  # the twist shrinks: it stays stuck
    ],
)
def test_start_exactly_on_the_lower_band_edge(brake, upper_speed, breaks_away):
    x1 = lower_edge_twist(brake)
    # The upper disk, if at rest, holds inside its own band (u chosen for that).
    u = (brake.string_stiffness * x1) / brake.motor_constant
    res = drill_env.simulate(brake, u, 30.0, x0=(x1, upper_speed, 0.0), **TIGHT)
    assert res.status == 0
    assert res.mode_l[0] == 0  # the closed band holds it at the start
    if breaks_away:
        assert res.events.kinds()[0] == "lower stick->slip+" and res.events.t[0] < 1e-9
        assert res.x3[1] > 0
    else:
        assert np.all(res.x3 == 0.0)
    if upper_speed == 0.0:
        assert len(res.events) == 0 and np.ptp(res.x1) == 0.0
    ora = oracle_simulate(brake, u, 30.0, x0=(x1, upper_speed, 0.0))
    assert_agrees_with_oracle(res, ora, state_tol=1e-8, event_tol=1e-9)


def test_start_exactly_on_the_upper_band_edge(brake):
    # Upper load km u - k_theta x1 equal to T_sup in floating point, upper disk at rest.
    u = brake.upper_static_pos / brake.motor_constant
    while brake.motor_constant * u != brake.upper_static_pos:
        u = np.nextafter(u, np.inf if brake.motor_constant * u < brake.upper_static_pos else -np.inf)
    still = drill_env.simulate(brake, u, 20.0, x0=(0.0, 0.0, 0.0))
    assert still.mode_u[0] == 0 and len(still.events) == 0 and np.all(still.x2 == 0.0)
    # The lower disk turning forward unwinds the string: the upper load leaves the band at once.
    res = drill_env.simulate(brake, u, 20.0, x0=(0.0, 0.0, 0.5), **TIGHT)
    assert res.events.kinds()[0] == "upper stick->slip+" and res.events.t[0] < 1e-9
    ora = oracle_simulate(brake, u, 20.0, x0=(0.0, 0.0, 0.5))
    assert_agrees_with_oracle(res, ora, state_tol=1e-8, event_tol=1e-9)


def test_no_chattering_where_a_reversal_is_followed_by_a_quick_stop(brake):
    # At these voltages the lower disk reverses and stops again within milliseconds.
    for u in (-3.75, 11.0):
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            res = drill_env.simulate(brake, u, 100.0)
        assert res.status == 0
        kinds = res.events.kinds()
        reversal = next(i for i, k in enumerate(kinds) if k in ("lower slip+->slip-", "lower slip-->slip+"))
        assert kinds[reversal + 1].endswith("->stick")
        assert 1e-4 < res.events.t[reversal + 1] - res.events.t[reversal] < 0.2


@pytest.fixture(scope="module")
def near_e_reference(no_brake):
    return oracle_simulate(no_brake, 1.29, 400.0)


@pytest.mark.parametrize("rtol", [1e-6, 1e-8, 1e-10])
def test_a_short_stick_phase_inside_one_step_is_not_skipped(no_brake, near_e_reference, rtol):
    # Next to point E the lower speed touches zero for 25 ms per 4 s period. A step can
    # start and end with the speed positive while it dips through zero in between: the
    # dip must still be found, the disk must stick, and it must never run backwards on
    # the forward slip branch.
    res = drill_env.simulate(no_brake, 1.29, 400.0, dt=0.001, rtol=rtol, atol=1e-2 * rtol)
    assert res.status == 0
    assert np.all(res.x3[res.mode_l == 1] >= 0.0)
    sticks = (res.events.disk == 1) & (res.events.mode_after == 0)
    ref = near_e_reference
    ref_sticks = sum(d == 1 and a == 0 for d, a in zip(ref.event_disk, ref.event_after, strict=True))
    assert ref_sticks > 90  # one per period over 400 s
    assert sticks.sum() == ref_sticks
    np.testing.assert_allclose(res.events.t, ref.event_t, rtol=0, atol=1e3 * rtol)
    last = res.window(100.0)
    assert 0.004 < last.stick_l.mean() < 0.008
    assert last.x3.min() == 0.0


# -- batches -------------------------------------------------------------------------------------


def test_batch_equals_single_runs(brake):
    voltages = np.array([0.05, 0.5, 1.0, 2.0, 4.0, -3.0])
    batch = drill_env.simulate_batch(brake, voltages, 60.0)
    assert batch.x3.shape == (voltages.size, 6001)
    for i, u in enumerate(voltages):
        single = drill_env.simulate(brake, u, 60.0)
        rig = batch.rig(i)
        for name in ("x1", "x2", "x3", "theta_l", "u", "mode_u", "mode_l"):
            np.testing.assert_array_equal(getattr(rig, name), getattr(single, name), err_msg=name)
        assert batch.stats["events"][i] == len(single.events)


def test_batch_with_parameter_list_states_and_held_inputs(brake, no_brake):
    params = [brake, no_brake, brake.replace(lower_static=0.05)]
    u = np.array([[2.0, 0.5, 3.0, 1.0], [1.0, 1.0, -1.0, 0.3], [4.0, -4.0, 2.0, 2.0]])
    x0 = np.array([[0.0, 0.0, 0.0], [0.5, 0.2, -0.1], [1.0, 1.0, 1.0]])
    batch = drill_env.simulate_batch(params, u, 40.0, x0=x0, control_dt=10.0)
    for i in range(3):
        single = drill_env.simulate(params[i], u[i], 40.0, x0=x0[i], control_dt=10.0)
        assert state_error(batch.rig(i), single) == 0.0
        np.testing.assert_array_equal(batch.rig(i).u, single.u)


# -- bad input -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "kwargs", "error", "match"),
    [
        ((2.0, math.nan), {}, ValueError, "t_final"),
        ((2.0, 0.0), {}, ValueError, "t_final"),
        ((2.0, -5.0), {}, ValueError, "t_final"),
        ((2.0, math.inf), {}, ValueError, "t_final"),
        ((2.0, "long"), {}, ValueError, "t_final"),
        ((2.0, 10.0), {"t0": math.nan}, ValueError, "t0"),
        ((2.0, 10.0), {"dt": 0.0}, ValueError, "dt"),
        ((2.0, 10.0), {"dt": math.nan}, ValueError, "dt"),
        ((2.0, 10.0), {"rtol": -1e-6}, ValueError, "rtol"),
        ((2.0, 10.0), {"atol": 0.0}, ValueError, "atol"),
        ((2.0, 10.0), {"voltage_limit": 0.0}, ValueError, "voltage_limit"),
        ((math.nan, 10.0), {}, ValueError, "u"),
        ((math.inf, 10.0), {}, ValueError, "u"),
        (([1.0, math.nan], 2.0), {"control_dt": 1.0}, ValueError, r"u\[1\]"),
        (([1.0, 2.0], 2.0), {}, ValueError, "control_dt"),
        (([1.0, 2.0], 2.0), {"control_dt": -1.0}, ValueError, "control_dt"),
        (([1.0, 2.0], 5.0), {"control_dt": 1.0}, ValueError, "u: 2 values"),
        (([[1.0, 2.0]], 2.0), {"control_dt": 1.0}, ValueError, "u"),
        ((2.0, 10.0), {"x0": (1.0, 2.0)}, ValueError, "x0"),
        ((2.0, 10.0), {"x0": (0.0, math.nan, 0.0)}, ValueError, r"x0\.x2"),
        ((2.0, 10.0), {"x0": {"x4": 1.0}}, ValueError, "x0.*x4"),
        ((2.0, 10.0), {"x0": {"x1": 1.0, "theta_u": 1.0}}, ValueError, "x0"),
        ((2.0, 10.0), {"tolerance": 1e-6}, TypeError, "tolerance"),
    ],
)
def test_bad_input_names_the_field(brake, args, kwargs, error, match):
    with pytest.raises(error, match=match):
        drill_env.simulate(brake, *args, **kwargs)


def test_bad_rig_and_input_function(brake):
    with pytest.raises(ParameterError, match="preset"):
        drill_env.simulate("no_such_rig", 2.0, 10.0)
    with pytest.raises(ParameterError, match="params"):
        drill_env.simulate(42, 2.0, 10.0)  # type: ignore[arg-type]
    table = {"a": 1.0}
    with pytest.raises(TypeError, match="u: a function of time"):
        drill_env.simulate(brake, lambda t: table["a"] * t, 10.0)


def test_bad_batch_input_names_the_field(brake):
    with pytest.raises(ValueError, match="t_final"):
        drill_env.simulate_batch(brake, [1.0, 2.0], 0.0)
    with pytest.raises(ValueError, match="u"):
        drill_env.simulate_batch(brake, [1.0, math.nan], 10.0)
    with pytest.raises(ValueError, match="params"):
        drill_env.simulate_batch([brake, brake], [1.0, 2.0, 3.0], 10.0, n=3)
    with pytest.raises(ValueError, match="x0"):
        drill_env.simulate_batch(brake, [1.0, 2.0], 10.0, x0=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="control_dt"):
        drill_env.simulate_batch(brake, np.ones((2, 4)), 10.0)


# -- compiled-code cache -------------------------------------------------------------------------


def test_one_compiled_kernel_serves_every_input_function():
    # The input function reaches the kernel as a C function pointer float64(float64),
    # so different user functions share one specialisation of the kernel.
    from drill_env import kernel

    def sine(amp):
        return lambda t: 2.0 + amp * math.sin(t)

    before = len(kernel.run.signatures)
    for amp in (0.5, 1.0, 1.5):
        res = drill_env.simulate("brake", sine(amp), 5.0)
        assert res.success and np.allclose(res.u, 2.0 + amp * np.sin(res.t))
    drill_env.simulate("brake", 2.0, 5.0)
    assert len(kernel.run.signatures) - before <= 1


def test_kernels_are_cached_on_disk_across_processes(tmp_path):
    # A second process loads the compiled kernels from the cache instead of compiling:
    # numba reports no new compilation of run() there.
    import subprocess
    import sys

    code = (
        "import math, drill_env, numba;"
        "from drill_env import kernel;"
        "drill_env.simulate('brake', lambda t: 1.0 + 0.5 * math.sin(t), 2.0);"
        "drill_env.simulate('brake', 2.0, 2.0);"
        "print(all(s for s in kernel.run.stats.cache_hits.values()), len(kernel.run.stats.cache_misses))"
    )
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    hits, misses = out.stdout.split()
    assert hits == "True" and misses == "0", out.stdout
