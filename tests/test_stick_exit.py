"""Breakaways of stuck disks under time-varying inputs and torques, against independent answers.

While both disks stick the vector field is zero: nothing in the state tells the integrator
that the input is about to push a disk out of its static band. These cases were once
missed or found late (a pulse of u(t) while stuck, periodic pulses, an external torque
just above the static level, a stuck lower disk whose load leaves its band and comes back
within one step of a bang-bang zero-order hold). Each is checked against an answer the
package did not compute: the exact breakaway instant where the holding torque is a known
function of time (brentq on it, or asin for a sine), and the reference solver of
``tests/oracle.py`` (SciPy's ``solve_ivp`` with terminal events, ``max_step`` bounding its
steps while stuck). Tolerances are far below 1 ms: a late breakaway fails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from oracle import oracle_simulate
from scipy.optimize import brentq

import drill_env

TIGHT = {"rtol": 1e-12, "atol": 1e-12}
GRID = 0.01  # [s] sample spacing of the comparisons


def grid(t_final: float) -> np.ndarray:
    return GRID * np.arange(int(round(t_final / GRID)) + 1)


def compare(res, ora, *, event_tol: float, speed_tol: float) -> None:
    """Same events (disk, modes) at the same instants, same lower/upper speeds on the grid."""
    assert res.status == 0, res.message
    assert len(res.events) == len(ora.event_t), (list(res.events.t), ora.event_t)
    np.testing.assert_array_equal(res.events.disk, ora.event_disk)
    np.testing.assert_array_equal(res.events.mode_before, ora.event_before)
    np.testing.assert_array_equal(res.events.mode_after, ora.event_after)
    np.testing.assert_allclose(res.events.t, ora.event_t, rtol=0, atol=event_tol)
    np.testing.assert_allclose(res.x3, ora.x3, rtol=0, atol=speed_tol)
    np.testing.assert_allclose(res.x2, ora.x2, rtol=0, atol=speed_tol)


def first_breakaway(res, disk: int) -> float:
    sel = (res.events.disk == disk) & (res.events.mode_before == 0)
    assert sel.any(), "no breakaway"
    return float(res.events.t[sel][0])


# -- pulses and bumps of u(t) while both disks stick ---------------------------------------------


@pytest.mark.parametrize("height", [2.0, 1.0, -2.0, 5.0])
def test_rectangular_pulse_while_stuck_matches_the_zero_order_hold_reference(brake, height):
    # u(t) = height on [2.3, 2.5) s: the same input as a hold of period 0.1 s, which the
    # reference integrates between the instants where the voltage jumps.
    def f(t):
        return height if 2.3 <= t < 2.5 else 0.0

    held = [f(0.1 * k + 0.05) for k in range(50)]
    ora = oracle_simulate(brake, held, 5.0, t_eval=grid(5.0), control_dt=0.1)
    assert len(ora.event_t) >= 2
    for tol, event_tol, speed_tol in ((TIGHT, 1e-9, 1e-7), ({}, 1e-7, 1e-5)):
        res = drill_env.simulate(brake, f, 5.0, **tol)
        compare(res, ora, event_tol=event_tol, speed_tol=speed_tol)
        assert first_breakaway(res, 0) == pytest.approx(2.3, abs=event_tol)


@pytest.mark.parametrize(("amp", "width"), [(1.5, 0.1), (1.0, 0.02), (-2.0, 0.05), (0.6, 0.3)])
def test_smooth_bump_while_stuck_breaks_away_where_the_torque_leaves_the_band(brake, amp, width):
    tc = 2.0

    def f(t):
        return amp * math.exp(-(((t - tc) / width) ** 2))

    # Both disks rest at x1 = 0: the upper disk breaks away where km u(t) reaches its band.
    edge = brake.upper_static_pos if amp > 0 else -brake.upper_static_neg
    assert abs(brake.motor_constant * amp) > abs(edge)
    exact = brentq(lambda t: brake.motor_constant * f(t) - edge, tc - 6 * width, tc, xtol=1e-15)
    ora = oracle_simulate(brake, f, 4.0, t_eval=grid(4.0), max_step=1e-3)
    for tol, event_tol, speed_tol in ((TIGHT, 1e-9, 1e-7), ({}, 1e-7, 1e-5)):
        res = drill_env.simulate(brake, f, 4.0, **tol)
        assert first_breakaway(res, 0) == pytest.approx(exact, abs=event_tol)
        compare(res, ora, event_tol=max(event_tol, 1e-8), speed_tol=speed_tol)


@pytest.mark.parametrize("amp", [0.2, 0.5, 1.0])
def test_periodic_pulses_each_break_the_upper_disk_away(brake, amp):
    # a sin(pi t / 2)^40: a narrow pulse at t = 1, 3, 5, 7, 9 s
    def f(t):
        return amp * math.sin(0.5 * math.pi * t) ** 40

    ora = oracle_simulate(brake, f, 10.0, t_eval=grid(10.0), max_step=1e-3)
    res = drill_env.simulate(brake, f, 10.0)
    compare(res, ora, event_tol=1e-7, speed_tol=1e-5)
    starts = (res.events.disk == 0) & (res.events.mode_before == 0)
    if brake.motor_constant * amp > brake.upper_static_pos:
        assert np.sum(starts) == 5
        # each pulse releases the disk on its rising edge, before its peak at 1, 3, ... s
        np.testing.assert_array_less(res.events.t[starts] - np.arange(1.0, 10.0, 2.0), 0.0)
        np.testing.assert_array_less(np.arange(1.0, 10.0, 2.0) - 0.3, res.events.t[starts])
    else:
        assert np.sum(starts) == 0


# -- an external torque on the lower disk just above the static level ---------------------------


@pytest.mark.parametrize("excess", [0.01, 0.05, 0.2])
def test_disturbance_just_above_breakaway(excess):
    p = drill_env.load_params("brake")
    amp = p.lower_static * (1.0 + excess)
    p = drill_env.load_params("brake", disturbance_amp=amp, disturbance_freq=1.0)
    # both disks at rest, u = 0: the lower disk holds A sin(t) until it reaches T_sl
    exact = math.asin(1.0 / (1.0 + excess))
    ora = oracle_simulate(p, 0.0, 4.0, t_eval=grid(4.0), max_step=1e-3)
    assert ora.event_t[0] == pytest.approx(exact, abs=1e-8)
    for tol, event_tol, speed_tol in ((TIGHT, 1e-9, 1e-7), ({}, 1e-7, 1e-5)):
        res = drill_env.simulate(p, 0.0, 4.0, **tol)
        assert first_breakaway(res, 1) == pytest.approx(exact, abs=event_tol)
        compare(res, ora, event_tol=max(event_tol, 1e-8), speed_tol=speed_tol)


# -- bang-bang zero-order hold from states at a band edge ----------------------------------------

EDGE_CASE = {"u": [-5, 0, 0, 5, 5, 5, 0, 0], "x0": (-0.649256831283175, 0.0, 0.0)}


@pytest.mark.parametrize("tol", [1e-6, 1e-9, 1e-12])
def test_band_exit_within_one_step_is_found_at_any_tolerance(brake, tol):
    # the stuck lower disk's load leaves its band and comes back within one step
    ora = oracle_simulate(brake, EDGE_CASE["u"], 0.8, x0=EDGE_CASE["x0"], t_eval=grid(0.8), control_dt=0.1)
    assert first_breakaway_oracle(ora, 1) == pytest.approx(0.301866, abs=1e-6)
    res = drill_env.simulate(
        brake, EDGE_CASE["u"], 0.8, x0=EDGE_CASE["x0"], control_dt=0.1, rtol=tol, atol=tol
    )
    event_tol = {1e-6: 1e-5, 1e-9: 1e-7, 1e-12: 1e-9}[tol]
    assert first_breakaway(res, 1) == pytest.approx(first_breakaway_oracle(ora, 1), abs=event_tol)
    compare(res, ora, event_tol=event_tol, speed_tol={1e-6: 1e-3, 1e-9: 1e-5, 1e-12: 1e-7}[tol])


def first_breakaway_oracle(ora, disk: int) -> float:
    for t, d, before in zip(ora.event_t, ora.event_disk, ora.event_before, strict=True):
        if d == disk and before == 0:
            return t
    raise AssertionError("no breakaway in the reference")


def bang_bang_case(brake, seed: int):
    """A random +-5 V / 0 V hold of 8 periods from rest with the lower disk's load within
    0.5 % of an edge of its band."""
    rng = np.random.default_rng(seed)
    u = rng.choice([-5.0, 0.0, 5.0], size=8)
    edge = brake.lower_static / brake.string_stiffness
    x1 = rng.choice([-1.0, 1.0]) * edge * (1.0 - rng.uniform(0.0, 5e-3))
    return list(u), (x1, 0.0, 0.0)


@pytest.mark.parametrize("seed", range(12))
def test_random_bang_bang_from_band_edges_agrees_with_reference(brake, seed):
    u, x0 = bang_bang_case(brake, seed)
    ora = oracle_simulate(brake, u, 0.8, x0=x0, t_eval=grid(0.8), control_dt=0.1)
    res = drill_env.simulate(brake, u, 0.8, x0=x0, control_dt=0.1)
    compare(res, ora, event_tol=1e-7, speed_tol=1e-5)


# -- property: random inputs of these kinds ------------------------------------------------------


@settings(max_examples=12)
@given(
    start=st.floats(0.2, 1.5),
    width=st.floats(0.005, 0.3),
    amp=st.floats(0.3, 4.0) | st.floats(-4.0, -0.3),
)
def test_property_bump_breakaway_instant(start, width, amp):
    p = drill_env.load_params("brake")

    def f(t):
        return amp * math.exp(-(((t - start) / width) ** 2))

    edge = p.upper_static_pos if amp > 0 else -p.upper_static_neg
    res = drill_env.simulate(p, f, start + 0.5)
    starts = (res.events.disk == 0) & (res.events.mode_before == 0)
    if abs(p.motor_constant * amp) <= abs(edge) * (1.0 - 1e-9):
        assert not starts.any()  # never reaches the band: no event
        return
    exact = brentq(lambda t: p.motor_constant * f(t) - edge, start - 8 * width, start, xtol=1e-15)
    assert float(res.events.t[starts][0]) == pytest.approx(exact, abs=1e-7)


@settings(max_examples=10)
@given(seed=st.integers(0, 10**6))
def test_property_bang_bang_from_band_edges(seed):
    p = drill_env.load_params("brake")
    u, x0 = bang_bang_case(p, seed)
    ora = oracle_simulate(p, u, 0.8, x0=x0, t_eval=grid(0.8), control_dt=0.1)
    res = drill_env.simulate(p, u, 0.8, x0=x0, control_dt=0.1)
    compare(res, ora, event_tol=1e-7, speed_tol=1e-5)


@settings(max_examples=10)
@given(excess=st.floats(0.001, 1.0), freq=st.floats(0.5, 20.0))
def test_property_disturbance_breakaway(excess, freq):
    base = drill_env.load_params("brake")
    p = drill_env.load_params(
        "brake", disturbance_amp=base.lower_static * (1 + excess), disturbance_freq=freq
    )
    exact = math.asin(1.0 / (1.0 + excess)) / freq
    res = drill_env.simulate(p, 0.0, exact + 0.2)
    assert first_breakaway(res, 1) == pytest.approx(exact, abs=1e-7)
