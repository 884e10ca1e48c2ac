"""Properties of the exact simulator on random inputs, states and rigs.

Each example draws a rig (a preset with every parameter scaled by up to x1.5 either
way, kept only where the slip friction stays dissipative, eq. (4)), a start state (at
rest; anywhere; exactly on the edge of the lower or the upper static band; or at rest
with the voltage exactly at uc1) and a piecewise-constant voltage schedule in [-5, 5] V
(a zero-order hold, with the special voltages 0, uc1, uc1_neg and +-5 V drawn often).
For each:

* the simulator agrees with the independent reference of ``tests/oracle.py`` (SciPy's
  ``solve_ivp`` with terminal events, a band-exit scan of stuck disks on a 0.1 ms grid):
  the same switching events in the same order, at the same instants, and the same
  states on a 10 ms grid;
* a stuck disk's speed is exactly 0, its angle does not move, and every event leaves
  the disk that sticks exactly at rest;
* the run terminates normally with a bounded number of events and integration steps per
  simulated second (no chattering, no step cap).

Starts on a band edge that the reference cannot resolve at round-off (the load leaving the
edge at second order, or moving inward so that its event function starts at exactly zero,
or a breakaway that reverses within nanoseconds) are checked against known answers in the
tests at the end instead.

The examples come from the hypothesis profile of ``conftest.py`` (a small derandomised
set by default; many more, random, in the tests marked slow).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from oracle import oracle_simulate
from scipy.optimize import brentq

import drill_env
from drill_env import ParameterError
from drill_env import _layout as L

TIGHT = {"rtol": 1e-12, "atol": 1e-14}
GRID = 0.01  # [s] sample spacing of the comparisons
SCAN = 1e-4  # [s] grid of the reference's search for band exits while a disk sticks
BREAKAWAY_TOL = 1e-9  # [s] a stuck disk starting to slip: located by root finding on both sides
EVENT_TOL = 1e-8  # [s] a speed reaching zero: carries the integration error of the slip before it
STATE_TOL = 1e-7  # [rad, rad/s] twist and speeds on the sample grid
# Bounds that make "never hangs" testable: chattering (events piling up at one instant) or
# a step size collapsing would exceed them by orders of magnitude. Stick-slip of these rigs
# has one stick phase per torsional period (seconds); a voltage jump can release both disks
# and each may reverse once. Measured over 700 examples of the two strategies below: at
# most 12 events per simulated second in the short runs from band edges, 40 per second with
# 0.05 s holds (two per hold), and 140 accepted steps per simulated second (the step cap of
# simulate() is 2000 per second).
EVENTS_PER_SECOND = 30
EVENTS_PER_JUMP = 4
STEPS_PER_SECOND = 1000

SCALED_FIELDS = (
    "motor_constant",
    "upper_inertia",
    "upper_static_pos",
    "upper_static_neg",
    "upper_viscous_pos",
    "upper_viscous_neg",
    "lower_inertia",
    "string_stiffness",
    "lower_viscous",
    "lower_hump_rate_1",
    "lower_hump_rate_2",
)
PRESETS = {name: drill_env.load_params(name) for name in ("brake", "no_brake")}


@st.composite
def rigs(draw) -> drill_env.RigParams:
    """A preset with each parameter multiplied by a factor in [1/1.5, 1.5] (log-uniform).

    The lower disk's static level and its two hump terms share one factor, times a second
    one within +-10 % for each hump term, so the friction curve keeps its shape; a draw that
    would make it non-dissipative (eq. 4, refused by RigParams) is skipped."""

    def factor(span: float) -> float:
        return span ** draw(st.floats(-1.0, 1.0, allow_nan=False))

    base = PRESETS[draw(st.sampled_from(sorted(PRESETS)))]
    changes = {name: getattr(base, name) * factor(1.5) for name in SCALED_FIELDS}
    level = factor(1.5)
    changes["lower_static"] = base.lower_static * level
    for name in ("lower_hump_1", "lower_hump_2"):
        changes[name] = getattr(base, name) * level * factor(1.1)
    try:
        return dataclasses.replace(base, name="random", **changes)
    except ParameterError:
        assume(False)
        raise


def nudge(value: float, target: float, fn) -> float:
    """``value`` moved by a few ulps so that ``fn(value) == target`` exactly, if it can be."""
    for _ in range(16):
        got = fn(value)
        if got == target:
            return value
        value = float(np.nextafter(value, math.inf if got < target else -math.inf))
    assume(False)  # no float lands exactly on the edge (rare): try another example
    raise AssertionError


@st.composite
def cases(draw):
    """(rig, schedule, control_dt, x0, kind)."""
    p = draw(rigs())
    control_dt = draw(st.sampled_from([0.1, 0.25, 0.5, 1.0]))
    n = draw(st.integers(1, 5))
    special = [0.0, p.uc1, p.uc1_neg, 5.0, -5.0]
    volts = st.floats(-5.0, 5.0, allow_nan=False) | st.sampled_from(special)
    schedule = draw(st.lists(volts, min_size=n, max_size=n))
    kind = draw(st.sampled_from(["rest", "anywhere", "lower_edge", "upper_edge", "uc1"]))
    kth, km = p.string_stiffness, p.motor_constant
    edge = p.lower_static / kth
    speed = st.floats(-3.0, 3.0, allow_nan=False) | st.just(0.0)
    # Leaving a band edge at a speed of round-off size is the second-order case below (the
    # reference cannot resolve it). From 0.1 mrad/s up, a breakaway that reverses within
    # microseconds is resolved by both: see test_lower_edge_start_moving_outward.
    edge_speed = st.floats(1e-4, 3.0) | st.just(0.0)
    if kind == "rest":
        x0 = (0.0, 0.0, 0.0)
    elif kind == "anywhere":
        x0 = (draw(st.floats(-1.5 * edge, 1.5 * edge)), draw(speed), draw(speed))
    elif kind == "lower_edge":
        # k_theta x1 == +-T_sl exactly: the lower disk at rest on the edge of its band
        sign = draw(st.sampled_from([1.0, -1.0]))
        x1 = nudge(sign * edge, sign * p.lower_static, lambda x: kth * x)
        x0 = (x1, sign * draw(edge_speed), 0.0)
        # The twist moving outward breaks the lower disk away at t = 0. Not inward: then the
        # band-exit event function of the reference starts at exactly zero and solve_ivp takes
        # the start for a crossing (it chatters at t = 0); see test_lower_edge_start_moving_inward.
        # With the upper disk at rest, any hold that breaks it away makes the twist leave the
        # edge at second order (x1' = 0, x1'' != 0) and the lower speed grow as t^3, which the
        # reference cannot resolve at round-off either; see
        # test_lower_edge_start_with_the_upper_disk_breaking_away. Then every hold keeps the
        # upper disk in its band and nothing may move.
        if x0[1] == 0.0:
            loads = km * np.asarray(schedule) - kth * x1
            assume(np.all((-p.upper_static_neg <= loads) & (loads <= p.upper_static_pos)))
    elif kind == "upper_edge":
        # km u0 - k_theta x1 == T_sup (or -T_sun) exactly: the upper disk at rest on its edge
        x1 = draw(st.floats(-edge, edge, exclude_min=True, exclude_max=True))  # not on the lower edge too
        upper = draw(st.sampled_from([p.upper_static_pos, -p.upper_static_neg]))
        schedule[0] = nudge((upper + kth * x1) / km, upper, lambda u: km * u - kth * x1)
        assume(abs(schedule[0]) <= 5.0)
        # the lower disk turning towards the outside of the upper band or at rest (not inward:
        # as for the lower edge above)
        x0 = (x1, 0.0, math.copysign(draw(edge_speed), upper))
    else:  # "uc1": at rest, the largest voltage at which the rig stays stuck (point A)
        schedule[0] = p.uc1
        x0 = (0.0, 0.0, 0.0)
    if kind != "lower_edge":
        # Both disks at rest with the lower load within round-off of (not on) its edge is the
        # second-order case of the "lower_edge" starts, which the reference cannot resolve.
        assume(x0[1] != 0.0 or x0[2] != 0.0 or abs(abs(kth * x0[0]) - p.lower_static) > 1e-12)
    return p, schedule, control_dt, x0, kind


def run_both(p, schedule, control_dt, x0):
    t_final = control_dt * len(schedule)
    res = drill_env.simulate(p, schedule, t_final, x0=x0, dt=GRID, control_dt=control_dt, **TIGHT)
    t_eval = GRID * np.arange(int(round(t_final / GRID)) + 1)
    ora = oracle_simulate(p, schedule, t_final, x0=x0, t_eval=t_eval, control_dt=control_dt, scan_dt=SCAN)
    return res, ora


def check_agreement(res, ora) -> None:
    assert res.status == 0, res.message
    np.testing.assert_allclose(res.t, ora.t, rtol=0, atol=1e-12)
    kinds = res.events.kinds()
    assert len(res.events) == len(ora.event_t), (kinds, list(res.events.t), ora.event_t)
    np.testing.assert_array_equal(res.events.disk, ora.event_disk, err_msg=str(kinds))
    np.testing.assert_array_equal(res.events.mode_before, ora.event_before, err_msg=str(kinds))
    np.testing.assert_array_equal(res.events.mode_after, ora.event_after, err_msg=str(kinds))
    ora_t = np.asarray(ora.event_t, dtype=float)
    brk = res.events.mode_before == 0
    np.testing.assert_allclose(res.events.t[brk], ora_t[brk], rtol=0, atol=BREAKAWAY_TOL)
    np.testing.assert_allclose(res.events.t[~brk], ora_t[~brk], rtol=0, atol=EVENT_TOL)
    for name in ("x1", "x2", "x3"):
        np.testing.assert_allclose(
            getattr(res, name), getattr(ora, name), rtol=0, atol=STATE_TOL, err_msg=name
        )
    np.testing.assert_allclose(res.theta_l, ora.theta_l, rtol=STATE_TOL, atol=STATE_TOL)
    # modes on the grid, except at samples within a hair of a switching instant
    near = np.zeros(res.t.size, bool)
    for te in ora_t:
        near |= np.abs(res.t - te) < 1e-6
    np.testing.assert_array_equal(res.mode_u[~near], ora.modes[~near, 0])
    np.testing.assert_array_equal(res.mode_l[~near], ora.modes[~near, 1])


def check_stick_is_exact(res) -> None:
    assert np.all(res.x2[res.stick_u] == 0.0)
    assert np.all(res.x3[res.stick_l] == 0.0)
    # a slipping disk moves in the direction of its mode (never backwards on its branch)
    assert np.all(res.x3[res.mode_l == 1] >= 0.0) and np.all(res.x3[res.mode_l == -1] <= 0.0)
    assert np.all(res.x2[res.mode_u == 1] >= 0.0) and np.all(res.x2[res.mode_u == -1] <= 0.0)
    # the lower angle does not creep while it sticks: between two stuck samples with no
    # event of the lower disk from the first to the second (a short slip may lie between)
    lower_t = np.sort(res.events.t[res.events.disk == 1])
    pairs = np.flatnonzero(res.stick_l[:-1] & res.stick_l[1:])
    quiet = np.searchsorted(lower_t, res.t[pairs], "left") == np.searchsorted(
        lower_t, res.t[pairs + 1], "right"
    )
    assert pairs.size == 0 or np.all(res.theta_l[pairs[quiet] + 1] == res.theta_l[pairs[quiet]])
    # an event into stick leaves that disk exactly at rest
    ev = res.events
    into_stick = ev.mode_after == 0
    assert np.all(ev.state[into_stick & (ev.disk == 0), L.X2] == 0.0)
    assert np.all(ev.state[into_stick & (ev.disk == 1), L.X3] == 0.0)


def check_bounded(res, n_segments: int, t_final: float) -> None:
    assert res.status == 0, res.message
    assert len(res.events) <= EVENTS_PER_SECOND * t_final + EVENTS_PER_JUMP * n_segments, res.events.kinds()
    assert res.stats["steps"] <= STEPS_PER_SECOND * t_final + 100, res.stats


def check_case(p, schedule, control_dt, x0) -> None:
    res, ora = run_both(p, schedule, control_dt, x0)
    check_stick_is_exact(res)
    check_bounded(res, len(schedule), control_dt * len(schedule))
    check_agreement(res, ora)


@settings(max_examples=50)  # cheap (~0.1 s each): more than the profile's default
@given(case=cases())
def test_random_schedules_states_and_rigs_agree_with_the_reference(case):
    p, schedule, control_dt, x0, _ = case
    check_case(p, schedule, control_dt, x0)


@pytest.mark.slow
@given(case=cases())
def test_random_schedules_states_and_rigs_agree_with_the_reference_long(case):
    p, schedule, control_dt, x0, _ = case
    check_case(p, schedule, control_dt, x0)


@given(
    preset=st.sampled_from(sorted(PRESETS)),
    schedule=st.lists(st.floats(-5.0, 5.0, allow_nan=False), min_size=1, max_size=40),
    control_dt=st.sampled_from([0.05, 0.5, 2.0]),
    x0=st.tuples(st.floats(-3.0, 3.0), st.floats(-10.0, 10.0), st.floats(-10.0, 10.0)),
)
def test_long_random_holds_terminate_with_bounded_events_and_exact_stick(preset, schedule, control_dt, x0):
    # Up to 80 s of random holds from anywhere, at the default tolerances: no reference
    # (too slow at this length), but the invariants that need none.
    t_final = control_dt * len(schedule)
    res = drill_env.simulate(PRESETS[preset], schedule, t_final, x0=x0, control_dt=control_dt)
    check_bounded(res, len(schedule), t_final)
    check_stick_is_exact(res)


@pytest.mark.parametrize(
    ("preset", "sign", "u"), [("brake", 1.0, 1.0), ("brake", -1.0, -1.5), ("no_brake", 1.0, 2.0)]
)
def test_lower_edge_start_with_the_upper_disk_breaking_away(preset, sign, u):
    # Both disks at rest, the lower load exactly on its band edge, a voltage that breaks the
    # upper disk away at once: the twist leaves the edge at second order, so the lower disk
    # breaks away at t = 0 in the direction of the upper disk's acceleration a. Its speed
    # grows as x3(t) = k_theta a t^3 / (6 J_l) (1 + c t + O(t^2)): from J_l x3' = k_theta
    # (x1 - x1(0)) - s x3 and x1 - x1(0) = a t^2 / 2 + x2''(0) t^3 / 6, x2''(0) = -b_u a / J_u,
    # with s the slope of the slip friction at zero speed: c = -(b_u / J_u + s / J_l) / 4.
    p = PRESETS[preset]
    kth, jl = p.string_stiffness, p.lower_inertia
    x1 = nudge(sign * p.lower_static / kth, sign * p.lower_static, lambda x: kth * x)
    upper_band, b_u = (
        (p.upper_static_pos, p.upper_viscous_pos) if sign > 0 else (-p.upper_static_neg, p.upper_viscous_neg)
    )
    a = (p.motor_constant * u - kth * x1 - upper_band) / p.upper_inertia
    assert a * sign > 0
    s = 0.5 * (p.lower_hump_1 * p.lower_hump_rate_1 + p.lower_hump_2 * p.lower_hump_rate_2) + p.lower_viscous
    c = -(b_u / p.upper_inertia + s / jl) / 4.0
    res = drill_env.simulate(p, u, 0.02, x0=(x1, 0.0, 0.0), dt=1e-3, **TIGHT)
    assert res.status == 0
    assert res.mode_u[0] == sign  # the upper disk slips from the start (no event)
    assert res.events.kinds()[0] == f"lower stick->slip{'+' if sign > 0 else '-'}"
    assert res.events.t[0] == 0.0 and np.all(res.mode_l[1:] == sign)
    t = res.t[1:6]  # the first 5 ms: |c t| < 0.1, the O(t^2) term below 1e-3
    np.testing.assert_allclose(res.x3[1:6], kth * a * t**3 / (6.0 * jl) * (1.0 + c * t), rtol=1e-3)


def upper_slip_with_lower_stuck(p, u: float, x1_0: float, x2_0: float):
    """Closed-form (x1, x2)(t) while the lower disk sticks and the upper slips in the
    direction of x2_0: Ju x1'' + b x1' + k_theta x1 = km u -+ T_s (x1' = x2)."""
    b, band = (
        (p.upper_viscous_pos, p.upper_static_pos) if x2_0 > 0 else (p.upper_viscous_neg, -p.upper_static_neg)
    )
    s1, s2 = np.roots([p.upper_inertia, b, p.string_stiffness])
    x_eq = (p.motor_constant * u - band) / p.string_stiffness
    # x1 = x_eq + c1 e^{s1 t} + c2 e^{s2 t}, x1(0) = x1_0, x1'(0) = x2_0
    c1, c2 = np.linalg.solve(np.array([[1.0, 1.0], [s1, s2]]), np.array([x1_0 - x_eq, x2_0]))

    def x1(t):
        return (x_eq + c1 * np.exp(s1 * t) + c2 * np.exp(s2 * t)).real

    def x2(t):
        return (c1 * s1 * np.exp(s1 * t) + c2 * s2 * np.exp(s2 * t)).real

    return x1, x2


@pytest.mark.parametrize(
    ("sign", "speed"),
    [
        (1.0, 0.5),
        (1.0, 2e-3),
        (-1.0, 2e-3),
        (1.0, 1e-4),
        (1.0, 1e-5),
        (1.0, 1e-8),
        (-1.0, 1e-8),
        (1.0, 1e-12),
    ],
)
def test_lower_edge_start_moving_inward(sign, speed):
    # The lower load exactly on its band edge, the upper disk turning so that the twist
    # shrinks: the lower disk stays stuck, the upper one slows down and sticks where its
    # speed reaches 0 (its load -T_sl at 0 V is inside its band), and nothing moves after.
    p = PRESETS["brake"]
    kth = p.string_stiffness
    x1_0 = nudge(sign * p.lower_static / kth, sign * p.lower_static, lambda x: kth * x)
    x2_0 = -sign * speed
    x1, x2 = upper_slip_with_lower_stuck(p, 0.0, x1_0, x2_0)
    t_stop = brentq(lambda t: x2(t), 0.0, 2.0, xtol=1e-15)
    res = drill_env.simulate(p, 0.0, 2.0, x0=(x1_0, x2_0, 0.0), dt=1e-3, **TIGHT)
    assert res.status == 0
    assert res.events.kinds() == [f"upper slip{'-' if sign > 0 else '+'}->stick"]
    assert res.events.t[0] == pytest.approx(t_stop, abs=1e-9)
    assert np.all(res.x3 == 0.0) and np.all(res.mode_l == 0)
    moving = res.t < t_stop
    np.testing.assert_allclose(res.x1[moving], x1(res.t[moving]), rtol=0, atol=1e-10)
    assert np.ptp(res.x1[~moving]) == 0.0


@pytest.mark.parametrize("speed", [0.01, 0.003, 1e-3, 1e-4, 1e-5])
def test_lower_edge_start_moving_outward(speed):
    # The lower load exactly on its band edge, the upper disk turning forward so that the
    # twist grows, and -3 V braking the upper disk: the load leaves the closed band at once,
    # so the lower disk slips from t = 0 (forward); the upper disk reverses where its speed
    # reaches 0, the twist shrinks, and the lower disk sticks again. Against the reference.
    p = PRESETS["brake"]
    kth = p.string_stiffness
    x1_0 = nudge(p.lower_static / kth, p.lower_static, lambda x: kth * x)
    res, ora = run_both(p, [-3.0], 0.1, (x1_0, speed, 0.0))
    assert res.events.kinds() == ["lower stick->slip+", "upper slip+->slip-", "lower slip+->stick"]
    assert res.events.t[0] == 0.0
    check_agreement(res, ora)


@pytest.mark.parametrize("speed", [1e-2, 1e-6, 1e-10])
def test_upper_edge_start_moving_inward(speed):
    # The upper load exactly on its band edge (km u = T_sup, no twist), the lower disk turning
    # backward: the twist grows, the upper load km u - k_theta x1 falls into the band, so the
    # upper disk never moves; the lower one stops and sticks.
    p = PRESETS["brake"]
    km = p.motor_constant
    u = nudge(p.upper_static_pos / km, p.upper_static_pos, lambda v: km * v)
    res = drill_env.simulate(p, u, 0.5, x0=(0.0, 0.0, -speed), dt=1e-3, **TIGHT)
    assert res.status == 0
    assert res.events.kinds() == ["lower slip-->stick"]
    assert np.all(res.x2 == 0.0) and np.all(res.mode_u == 0)


@pytest.mark.parametrize("tol", [TIGHT, {}])
@pytest.mark.parametrize("speed", [1e-8, 1e-12])
def test_lower_edge_start_moving_outward_below_resolution(speed, tol):
    # As above, at speeds where the slip lasts about 3 v / a (a: the upper disk's braking
    # acceleration), nanoseconds, and the lower speed reaches ~1e-30 rad/s: below what the
    # reference or the dense output resolve. The disk breaks away at t = 0 and sticks again
    # within 10 ns, once (no chattering at the edge), and stays stuck.
    p = PRESETS["brake"]
    kth = p.string_stiffness
    x1_0 = nudge(p.lower_static / kth, p.lower_static, lambda x: kth * x)
    res = drill_env.simulate(p, -3.0, 0.1, x0=(x1_0, speed, 0.0), dt=1e-3, **tol)
    assert res.status == 0, res.message
    lower = res.events.disk == 1
    kinds = list(np.asarray(res.events.kinds())[lower])
    assert kinds == ["lower stick->slip+", "lower slip+->stick"]
    t_lower = res.events.t[lower]
    assert t_lower[0] == 0.0 and 0.0 <= t_lower[1] < 1e-8
    assert np.all(res.mode_l == 0) and np.all(res.x3 == 0.0)
    check_stick_is_exact(res)


@pytest.mark.parametrize(
    ("u", "x0", "n_events"),
    [
        (0.0, (1.0, -1e-5, 0.0), 1),  # lower load on its edge, moving inward: stays stuck
        (0.0, (-1.0, 1e-8, 0.0), 1),
        (-3.0, (1.0, 1e-3, 0.0), 3),  # moving outward, back within 0.13 ms: slips and re-sticks
        (-3.0, (1.0, 1e-4, 0.0), 3),
        ("upper", (0.0, 0.0, -1e-6), 1),  # upper load on its edge, moving inward
    ],
)
def test_sensitivity_flow_follows_the_simulator_from_band_edges(u, x0, n_events):
    # The flow with sensitivities of the bifurcation analysis shares the simulator's rule for
    # a disk on its band edge: the same number of switches and the same state.
    from drill_env.analysis import variational

    p = PRESETS["brake"]
    kth, km = p.string_stiffness, p.motor_constant
    if u == "upper":
        u = nudge(p.upper_static_pos / km, p.upper_static_pos, lambda v: km * v)
    else:
        sign = x0[0]
        x1 = nudge(sign * p.lower_static / kth, sign * p.lower_static, lambda x: kth * x)
        x0 = (x1, *x0[1:])
    t_end = 0.05
    x, _, modes, info = variational.flow_map(p.as_array(), u, np.array(x0), t_end, rtol=1e-12, atol=1e-14)
    res = drill_env.simulate(p, u, t_end, x0=x0, dt=t_end, **TIGHT)
    assert len(res.events) == n_events, res.events.kinds()
    assert info[variational.I_EVENTS] == n_events
    assert tuple(modes) == (res.mode_u[-1], res.mode_l[-1])
    np.testing.assert_allclose(x, [res.x1[-1], res.x2[-1], res.x3[-1]], rtol=0, atol=1e-9)
