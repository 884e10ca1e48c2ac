"""Shooting on the nonsmooth flow: monodromy (with saltation) against finite differences of
the event-driven simulator, Floquet multipliers, periodicity, and the limit cycle against
long simulations."""

from __future__ import annotations

import math

import numpy as np
import pytest

import drill_env
from drill_env.analysis import hopf_points, limit_cycle
from drill_env.analysis import variational as V
from drill_env.analysis.continuation import ContinuationSettings, _first_orbit, _Solver
from drill_env.analysis.equilibria import nominal_vector
from drill_env.analysis.shooting import section_return, section_state
from drill_env.metrics import dominant_period

TIGHT = {"rtol": 1e-12, "atol": 1e-14}


def fd_flow_map(params, u, x0, T, d=1e-6):
    """d x(T) / d (x0, u) by central differences of the simulator's flow map."""

    def phi(x, uu=u):
        return drill_env.simulate(params, uu, T, x0=x, dt=T, **TIGHT).final_state[:3]

    x0 = np.asarray(x0, dtype=float)
    M = np.zeros((3, 4))
    for j in range(3):
        e = np.zeros(3)
        e[j] = d
        M[:, j] = (phi(x0 + e) - phi(x0 - e)) / (2 * d)
    M[:, 3] = (phi(x0, u + d) - phi(x0, u - d)) / (2 * d)
    return M


# Transients chosen to cross every kind of switch: the lower disk sticking, breaking away
# and reversing; the upper disk sticking and breaking away.
TRANSIENTS = [
    ("no_brake", 0.05, (0.5, 0.3, -0.5), 6.0, {"upper slip+->stick", "lower slip+->stick"}),
    ("no_brake", 0.3, (1.0, 0.05, 0.02), 7.0, {"lower slip+->stick", "lower stick->slip+"}),
    ("brake", 0.1, (3.0, 0.2, 1.5), 9.0, {"upper slip+->stick", "lower slip+->stick"}),
    (
        "brake",
        0.3,
        (12.0, 0.05, 2.0),
        15.0,
        {"upper stick->slip+", "lower slip+->slip-", "lower slip-->stick"},
    ),
    ("brake", -0.3, (2.0, 0.5, 1.0), 5.0, {"upper slip+->slip-", "lower slip+->stick"}),
]


@pytest.mark.parametrize(("preset", "u", "x0", "T", "kinds"), TRANSIENTS)
def test_sensitivity_with_saltation_matches_finite_differences(preset, u, x0, T, kinds):
    params = drill_env.load_params(preset)
    x, S, _, info = V.flow_map(params.as_array(), u, np.array(x0), T)
    ref = drill_env.simulate(params, u, T, x0=x0, dt=T, **TIGHT)
    assert kinds <= set(ref.events.kinds())  # the transient crosses the switches it is meant to
    assert int(info[V.I_EVENTS]) == len(ref.events)
    np.testing.assert_allclose(x, ref.final_state[:3], rtol=0, atol=1e-9)
    fd = fd_flow_map(params, u, x0, T)
    assert np.max(np.abs(S - fd)) <= 2e-5 * max(1.0, np.max(np.abs(S)))


def test_entering_stick_projects_out_the_stuck_speed():
    """While the lower disk sticks, x3 = 0 whatever the start: its sensitivity row is zero."""
    params = drill_env.load_params("no_brake")
    x, S, modes, _ = V.flow_map(params.as_array(), 0.05, np.array([0.5, 0.3, -0.5]), 6.0)
    assert modes[1] == 0 and x[2] == 0.0
    assert np.all(S[2] == 0.0) and np.all(S[1] == 0.0)  # both disks stuck
    assert np.max(np.abs(S[0])) > 0.05  # the twist still remembers the start


CYCLES = [
    ("no_brake", 0.55),
    ("no_brake", 1.0),
    ("no_brake", 1.5),
    ("brake", 1.0),
    ("brake", 2.0),
    ("brake", 4.5),
]


@pytest.fixture(scope="module")
def cycles():
    return {(pr, u): limit_cycle(pr, u) for pr, u in CYCLES}


@pytest.mark.parametrize(("preset", "u"), CYCLES)
def test_monodromy_matches_finite_differences(cycles, preset, u):
    c = cycles[(preset, u)]
    params, p = nominal_vector(preset)
    r = section_return(p, u, c.xi)
    fd = fd_flow_map(params, u, section_state(c.xi), r.period)
    S = np.column_stack([r.monodromy, r.dx_du])
    assert np.max(np.abs(S - fd)) <= 2e-6 * max(1.0, np.max(np.abs(S)))


@pytest.mark.parametrize(("preset", "u"), CYCLES)
def test_trivial_multiplier_and_periodicity(cycles, preset, u):
    c = cycles[(preset, u)]
    assert abs(c.multipliers[0] - 1.0) < 1e-8
    assert c.trivial_multiplier_error < 1e-8
    assert c.residual < 1e-9
    # The event-driven simulator, started on the orbit, closes it after one period.
    params = drill_env.load_params(preset)
    res = drill_env.simulate(params, u, c.period, x0=c.state, dt=c.period / 200, **TIGHT)
    assert np.max(np.abs(res.final_state[:3] - c.state)) < 1e-8
    # Its extremes are those the shooting recorded.
    assert res.x3.max() <= c.x3_max + 1e-9 and res.x3.max() > c.x3_max - 1e-3
    assert res.x3.min() >= c.x3_min - 1e-9
    if c.stick_slip:
        # x3 = 0 while stuck; below 0 only when the disk reverses before it sticks (4.5 V).
        assert c.x3_min == 0.0 if c.reversals == 0 else c.x3_min < 0.0
        assert c.multipliers[2] == pytest.approx(0.0, abs=1e-10)
        assert res.stick_l.mean() == pytest.approx(c.stick_fraction, abs=0.02)
    else:
        assert not res.stick_l.any()


@pytest.mark.parametrize(("preset", "u"), [("no_brake", 1.0), ("brake", 0.7), ("brake", 2.0), ("brake", 4.5)])
def test_limit_cycle_agrees_with_long_simulation(cycles, preset, u):
    c = cycles.get((preset, u)) or limit_cycle(preset, u)
    params = drill_env.load_params(preset)
    res = drill_env.simulate(params, u, 1500.0, x0=(0.0, 0.0, 0.0), dt=0.005)
    tail = res.window(100.0)
    scale = max(abs(c.x3_max), abs(c.x3_min))
    assert abs(tail.x3.max() - c.x3_max) < 1e-4 * scale
    assert abs(tail.x3.min() - c.x3_min) < 1e-4 * scale
    assert dominant_period(tail.t, tail.x3) == pytest.approx(c.period, rel=2e-3)
    assert tail.stick_l.mean() == pytest.approx(c.stick_fraction, abs=0.01)
    assert c.stable


def test_fig9_no_stick_slip_at_1v_stick_slip_at_2v(cycles):
    """Statement 6 (Fig. 9, brake): the limit cycle has no stick-slip at 1 V, stick-slip at 2 V."""
    one, two = cycles[("brake", 1.0)], cycles[("brake", 2.0)]
    assert not one.stick_slip and one.x3_min > 0.2
    assert two.stick_slip and two.stick_phases == 1 and two.x3_min == 0.0
    assert two.amplitude > 2 * one.amplitude


def test_no_cycle_where_the_equilibrium_attracts():
    assert limit_cycle("brake", 0.5) is None  # below B: no vibration (as on the rig)
    assert limit_cycle("brake", 0.05) is None  # the stick set
    assert limit_cycle("no_brake", 2.2) is None  # beyond the fold F


@pytest.mark.parametrize("preset", ["no_brake", "brake"])
def test_small_cycles_follow_the_hopf_normal_form(preset):
    """The first Lyapunov coefficient predicts how far in u a small cycle sits from the
    Hopf point: u - u_H = -omega l1 r^2 / Re(lambda)'. Checked against shooting."""
    params, p = nominal_vector(preset)
    hs = hopf_points(params, 0.0, 5.0 if preset == "brake" else 3.0)
    for h in hs:
        solver = _Solver(params, p, ContinuationSettings())
        eps = 2e-3
        X, _, _ = _first_orbit(solver, h, eps)
        q = h.eigenvector
        c = q[1] - q[2]
        rv = np.real(q * np.exp(1j * (0.5 * math.pi - math.atan2(c.imag, c.real))))
        radius = eps / (2 * np.hypot(rv[0], rv[2]))
        assert (X[2] - h.u) / h.amplitude_offset(radius) == pytest.approx(1.0, abs=0.01)
        # The sign alone: supercritical cycles where the equilibrium is unstable.
        assert np.sign(X[2] - h.u) == (1.0 if h.supercritical else -1.0) * np.sign(h.crossing_speed)
