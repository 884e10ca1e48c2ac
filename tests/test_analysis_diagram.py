"""The bifurcation diagrams of Fig. 8: points A-F, branches, and their independent check."""

from __future__ import annotations

import json

import numpy as np
import pytest

import drill_env
from drill_env.analysis import bifurcation_diagram, brute_force_check, continue_from_hopf, hopf_points
from drill_env.analysis.equilibria import nominal_vector, slip_equilibrium

TIGHT = {"rtol": 1e-12, "atol": 1e-14}


@pytest.fixture(scope="module")
def no_brake_diagram():
    return bifurcation_diagram("no_brake", u_max=2.5)


@pytest.fixture(scope="module")
def brake_diagram():
    return bifurcation_diagram("brake", u_max=5.0)


@pytest.fixture(scope="module")
def brake_full_diagram():
    return bifurcation_diagram("brake", u_max=16.0)


def _seg(d, name):
    return d.segment(name)


def test_statement_5_no_brake_points_and_types(no_brake_diagram):
    """Fig. 8(a): A, supercritical Hopf B, stick-slip from D to E (not bifurcations),
    subcritical Hopf C, fold F; in u: A < B < D < E < C < F."""
    d = no_brake_diagram
    pts = d.points
    assert list(pts) == ["A", "B", "C", "D", "E", "F"]
    assert pts["A"].type == "start_of_motion"
    assert pts["B"].type == "hopf_supercritical" and pts["B"].detail["branch_agrees_with_l1"]
    assert pts["C"].type == "hopf_subcritical" and pts["C"].detail["branch_agrees_with_l1"]
    assert pts["D"].type == "grazing_stick_onset"
    assert pts["E"].type == "grazing_stick_end"
    assert pts["F"].type == "fold_periodic"
    order = [pts[k].u for k in "ABDECF"]
    assert order == sorted(order)
    p = d.params
    assert pts["A"].u == pytest.approx((p.upper_static_pos + p.lower_static) / p.motor_constant, rel=1e-14)
    # The fold: a multiplier through +1; grazing: the orbit's minimum of x3 touches 0.
    assert pts["F"].detail["multiplier_near_1"] == pytest.approx(1.0, abs=1e-5)
    assert abs(pts["D"].detail["x3_min"]) < 1e-6 and abs(pts["E"].detail["x3_min"]) < 1e-6
    # Regression values of this model (tolerance: the bisection's).
    expected = {"B": 0.4889230, "C": 1.4295986, "D": 0.6003071, "E": 1.2936381, "F": 1.6610970}
    for k, v in expected.items():
        assert pts[k].u == pytest.approx(v, abs=2e-7)


def test_statement_5_no_brake_branches(no_brake_diagram):
    d = no_brake_diagram
    assert d.branch_names == ["e1", "e2", "e3", "e4", "p1", "p2", "p3", "p4"]
    stable = {b.name: bool(np.all(b.stable)) for b in d.equilibrium_branches}
    assert stable == {"e1": True, "e2": True, "e3": False, "e4": True}
    pts = d.points
    spans = {"p1": ("B", "D"), "p2": ("D", "E"), "p3": ("E", "F"), "p4": ("F", "C")}
    for name, (a, b) in spans.items():
        seg = _seg(d, name)
        assert seg.u.min() == pytest.approx(min(pts[a].u, pts[b].u), abs=1e-3)
        assert seg.u.max() == pytest.approx(max(pts[a].u, pts[b].u), abs=1e-3)
        inner = seg.cycles[1:-1]
        assert all(c.stable == (name != "p4") for c in inner), name
        assert all(c.stick_slip == (name == "p2") for c in inner), name
    # Every orbit of the diagram: the trivial multiplier and the periodicity residual.
    for seg in d.periodic_segments:
        for c in seg.cycles:
            assert abs(c.multipliers[0] - 1.0) < 1e-7
            assert c.trivial_multiplier_error < 1e-7
            assert c.residual < 1e-8


def test_coexistence_between_c_and_f(no_brake_diagram):
    """Statement 5: stable equilibrium and stable limit cycle coexist between C and F,
    separated by the unstable cycle p4."""
    d = no_brake_diagram
    uc, uf = d.points["C"].u, d.points["F"].u
    for u in np.linspace(uc, uf, 6)[1:-1]:
        assert slip_equilibrium(d.params, u).stable
        cyc = sorted(d.cycles_at(u), key=lambda c: c.amplitude)
        assert [c.stable for c in cyc] == [False, True]
        inner, outer = cyc
        eq_x3 = slip_equilibrium(d.params, u).x3
        assert outer.x3_min < inner.x3_min < eq_x3 < inner.x3_max < outer.x3_max
    # Just past the fold the two cycles are gone, just before they are close together.
    assert d.cycles_at(uf + 1e-3) == []
    near = d.cycles_at(uf - 1e-4)
    assert len(near) == 2 and abs(near[0].x3_min - near[1].x3_min) < 0.05


@pytest.mark.parametrize("which", ["D", "E"])
def test_grazing_points_by_simulation(no_brake_diagram, which):
    """Across D (E) the simulator, started on the computed orbit, sees the lower-disk speed
    stay positive on one side and reach zero on the other (within +-2 mV of the point)."""
    d = no_brake_diagram
    u0 = d.points[which].u
    lowest = {}
    for du in (-2e-3, 2e-3):
        (c,) = [c for c in d.cycles_at(u0 + du) if c.stable]
        assert c.stick_slip == ((du > 0) == (which == "D"))
        res = drill_env.simulate(d.params, c.u, c.period, x0=c.state, dt=c.period / 2000, **TIGHT)
        lowest[du] = float(res.x3.min())
    smooth, sticky = (-2e-3, 2e-3) if which == "D" else (2e-3, -2e-3)
    assert 0.0 < lowest[smooth] < 0.01
    assert lowest[sticky] <= 0.0


def test_simulator_sticks_on_the_short_stick_phase_next_to_e(no_brake_diagram):
    """A zero of the lower-disk speed inside one step (next to grazing) is found, not integrated through."""
    d = no_brake_diagram
    (c,) = [c for c in d.cycles_at(d.points["E"].u - 2e-3) if c.stable]
    assert 0.0 < c.stick_fraction < 0.01  # the orbit sticks for about 18 ms per period
    res = drill_env.simulate(d.params, c.u, c.period, x0=c.state, dt=c.period / 2000, **TIGHT)
    assert res.x3.min() >= 0.0 and res.stick_l.any()


def test_continuation_from_c_retraces_the_branch(no_brake_diagram):
    """Started at C instead of B, the continuation meets F, E, D at the same voltages and ends at B."""
    d = no_brake_diagram
    params, p = nominal_vector("no_brake")
    hs = hopf_points(params, 0.0, 2.5)
    br = continue_from_hopf(params, p, hs[1], 0.0, 2.5, [h.u for h in hs])
    assert br.end_hopf_u == pytest.approx(hs[0].u, abs=1e-12)
    kinds = [e.kind for e in br.events]
    assert kinds == ["fold", "stick_onset", "stick_end"]
    for e, name in zip(br.events, "FED", strict=True):
        assert e.u == pytest.approx(d.points[name].u, abs=1e-7)


def test_statement_6_brake_to_5v_only_a_b_d(brake_diagram):
    """Fig. 8(b): over 0-5 V only A, B and D; C, E, F lie beyond 5 V."""
    d = brake_diagram
    assert list(d.points) == ["A", "B", "D"]
    assert d.points["B"].type == "hopf_supercritical"
    assert d.points["B"].u == pytest.approx(0.5829985, abs=2e-7)
    assert d.points["D"].u == pytest.approx(1.7812094, abs=2e-7)
    assert d.branch_names == ["e1", "e2", "e3", "p1", "p2"]
    assert not _seg(d, "p1").stick_slip and _seg(d, "p2").stick_slip
    assert max(_seg(d, "p2").u) == pytest.approx(5.0, abs=1e-12)
    assert d.branches[0].end_reason.startswith("u reached the end")


def test_brake_c_e_f_beyond_5v(brake_full_diagram):
    d = brake_full_diagram
    assert list(d.points) == ["A", "B", "C", "D", "E", "F"]
    pts = d.points
    assert 5.0 < pts["C"].u < pts["E"].u < pts["F"].u
    assert pts["C"].type == "hopf_subcritical" and pts["C"].detail["branch_agrees_with_l1"]
    assert pts["C"].u == pytest.approx(13.1285175, abs=2e-7)
    assert pts["F"].detail["multiplier_near_1"] == pytest.approx(1.0, abs=1e-5)
    # The lower disk reverses briefly before it sticks from about 3.7 V to 12.7 V.
    kinds = [o.type for o in d.other_points]
    assert kinds == ["reversal_onset", "reversal_end"]


def test_json_layout(no_brake_diagram, brake_diagram, tmp_path):
    for d in (no_brake_diagram, brake_diagram):
        path = tmp_path / "bifurcation.json"
        d.save_json(path)
        data = json.loads(path.read_text())
        assert data["preset"] == d.preset
        assert set(data["points"]) == set(d.points)
        for pt in data["points"].values():
            assert isinstance(pt["u"], float) and isinstance(pt["type"], str)
        for b in data["branches"]:
            n = len(b["u"])
            assert b["kind"] in ("equilibrium", "periodic") and n >= 2
            assert len(b["stable"]) == len(b["x3_min"]) == len(b["x3_max"]) == n
            assert all(lo <= hi for lo, hi in zip(b["x3_min"], b["x3_max"], strict=True))
            if b["kind"] == "periodic":
                assert len(b["period"]) == len(b["multipliers"]) == n
                assert all(len(m) == 3 for m in b["multipliers"])
    assert "C" not in json.loads(path.read_text())["points"]  # absent in the brake range


def test_brute_force_confirms_the_no_brake_diagram(no_brake_diagram):
    """A short version of the independent check (the full one is marked slow)."""
    d = no_brake_diagram
    check = brute_force_check(
        d, u_grid=[0.05, 0.3, 0.55, 0.9, 1.35, 1.5, 1.6, 2.0], settle=3000.0, dwell=800.0
    )
    assert check.passed, check.summary()
    assert check.max_error < 1e-3
    assert [c["u"] for c in check.coexistence] == [1.5, 1.6]
    assert set(check.branches_confirmed) == {"e1", "e2", "e4", "p1", "p2", "p3"}
    # The sweeps show the hysteresis: up, the cycle holds past C; down, the equilibrium past F.
    fwd = [r for r in check.runs if r.kind == "forward"]
    bwd = [r for r in check.runs if r.kind == "backward"]
    assert [r.attractor for r in fwd if r.u in (1.5, 1.6)] == ["cycle", "cycle"]
    assert [r.attractor for r in bwd if r.u in (1.5, 1.6)] == ["equilibrium", "equilibrium"]


@pytest.mark.slow
@pytest.mark.parametrize(("preset", "umax"), [("no_brake", 2.5), ("brake", 5.0)])
def test_brute_force_full_check(preset, umax):
    d = bifurcation_diagram(preset, u_max=umax)
    check = brute_force_check(d)
    assert check.passed, check.summary()
    assert check.max_error < 1e-3
