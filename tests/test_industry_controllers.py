"""The industry's stick-slip controllers: SoftTorque-type and Z-Torque-type, designed by their
published rules on the design model."""

from __future__ import annotations

import cmath
import math

import numpy as np
import pytest

import drill_env  # noqa: F401
from drill_env.agents.controllers.base import ControllerSpec
from drill_env.agents.controllers.impedance import characteristic_impedance, torsional_mode
from drill_env.agents.controllers.soft_torque import SoftTorque, band_pass_coefficients
from drill_env.agents.controllers.z_torque import ZTorque
from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env
from drill_env.agents.registry import CLASSICAL, build_controller
from drill_env.friction import lower_friction_curve
from drill_env.params import load_params

SHORT = EpisodeSettings(duration=30.0, window=10.0, warmup_time=25.0, warmup_jitter=2.0)


def test_the_string_quantities_of_the_paper_rig():
    p = load_params("brake")
    # sqrt(0.078 / 0.0326) and sqrt(0.078 * 0.0326): the 4.06 s torsional period of the paper
    assert torsional_mode(p) == pytest.approx(1.5468, abs=1e-4)
    assert 2 * math.pi / torsional_mode(p) == pytest.approx(4.06, abs=0.01)
    assert characteristic_impedance(p) == pytest.approx(0.050427, abs=1e-6)


@pytest.mark.parametrize("stiffness_factor", [1.0, 0.3, 4.0])
def test_soft_torque_matches_the_string_impedance_at_its_mode(stiffness_factor):
    # the top drive's impedance at w_s, from the discrete band-pass's own frequency response
    # (not the analog one the rule assumes), equals zeta: zero reflection, on rigs far apart
    base = load_params("brake")
    p = base.replace(string_stiffness=base.string_stiffness * stiffness_factor)
    spec = ControllerSpec(params=p, control_dt=0.05)
    c = SoftTorque.design(spec)
    w = torsional_mode(p)
    assert c.i_torque == pytest.approx(p.upper_inertia * w * w)
    b0, a1, a2 = band_pass_coefficients(c.mode, c.band_pass_damping, spec.control_dt)
    z = cmath.exp(1j * w * spec.control_dt)
    h = b0 * (1 - z**-2) / (1 + a1 / z + a2 / z**2)
    assert abs(h - 1) < 1e-9
    reactance = p.upper_inertia * w - c.i_torque / w
    z_top = (c.p_torque + p.upper_viscous_pos + 1j * reactance) / (1 - c.torque_gain * h)
    assert abs(z_top - characteristic_impedance(p)) < 1e-9
    reflection = (characteristic_impedance(p) - z_top) / (characteristic_impedance(p) + z_top)
    assert abs(reflection) < 1e-9


def test_z_torque_rules():
    p = load_params("brake")
    for dt in (0.05, 0.01):
        c = ZTorque.design(ControllerSpec(params=p, control_dt=dt))
        w_c = min(4 * torsional_mode(p), 0.1 * math.pi / dt)
        # critically damped upper-disk speed loop at w_c: J s^2 + (b + P) s + I = J (s + w_c)^2
        assert c.i_torque == pytest.approx(p.upper_inertia * w_c**2)
        assert c.p_torque + p.upper_viscous_pos == pytest.approx(2 * p.upper_inertia * w_c)
        assert c.impedance == pytest.approx(characteristic_impedance(p))
        assert c.tau_hp == pytest.approx(4 * math.pi / torsional_mode(p))


def test_z_torque_presents_the_impedance_to_a_torque_oscillation():
    # with the string torque swinging at the mode, the requested speed swings by T / zeta
    p = load_params("brake")
    spec = ControllerSpec(params=p, control_dt=0.05)
    c = ZTorque.design(spec)
    w = torsional_mode(p)
    n = 2000
    t = np.arange(n) * spec.control_dt
    torque = 0.2 + 0.01 * np.sin(w * t)
    y = np.zeros((n, 8))
    y[:, spec.index("twist")] = torque / p.string_stiffness
    y[:, spec.index("target_speed")] = 2.0
    state = c.initial_state(y[:1])
    w_ref = []
    for k in range(n):
        t_slow = state[0, 1]
        w_ref.append(2.0 - (torque[k] - t_slow) / c.impedance)
        _, state = c.control(y[k : k + 1], state)
    swing = np.ptp(np.array(w_ref)[n // 2 :])
    assert swing == pytest.approx(2 * 0.01 / characteristic_impedance(p), rel=0.03)


def test_both_are_registered_and_need_no_gains_file(tmp_path):
    assert {"soft_torque", "z_torque"} <= set(CLASSICAL)
    env = make_env("brake", SHORT)
    missing = tmp_path / "none.yaml"
    for name, cls in (("soft_torque", SoftTorque), ("z_torque", ZTorque)):
        assert isinstance(build_controller(name, env, "brake", gains_file=missing), cls)


@pytest.mark.parametrize(
    "preset,voltage", [("brake", 1.2), ("brake", 3.0), ("no_brake", 1.0), ("no_brake", 0.55)]
)
def test_they_suppress_the_open_loop_cycle(preset, voltage):
    env = make_env(preset, SHORT)
    for name, floor in (("soft_torque", 0.6), ("z_torque", 0.95)):
        m = evaluate(build_controller(name, env, preset), preset, voltage, 3, SHORT, env=env)
        assert m.open_loop_amplitude > 0.5
        assert not m.stalled and m.suppression > floor, (name, m.suppression)


def test_they_are_designed_on_the_design_model_not_the_plant():
    # a plant with 30 % more lower friction: the controller is the same as on the nominal rig
    nominal = make_env("brake", SHORT)
    heavy = make_env("brake", SHORT, params=load_params("brake").replace(lower_static=0.122))
    for name in ("soft_torque", "z_torque"):
        a = build_controller(name, nominal, "brake").describe()
        b = build_controller(name, heavy, "brake").describe()
        assert a == b


@pytest.mark.parametrize("preset,dt", [("brake", 0.05), ("no_brake", 0.01)])
def test_z_torque_actions_are_those_of_its_published_law(preset, dt):
    # the law of the module docstring written out here, step by step, against the controller
    # (which reuses the torque feedback's code): the same voltages and states, the limit and the
    # anti-windup included
    p = load_params(preset)
    spec = ControllerSpec(params=p, control_dt=dt)
    c = ZTorque.design(spec)
    km, vmax = p.motor_constant, spec.voltage_limit
    kp, ki = c.p_torque / km, c.i_torque / km
    tracking = max(kp / ki, dt)
    a = 1.0 - math.exp(-dt / c.tau_hp)
    rng = np.random.default_rng(3)
    n, batch = 300, 4
    y = rng.normal(size=(n, batch, 8))
    it, iw, iu, iv = (spec.index(k) for k in ("target_speed", "twist", "nominal_voltage", "upper_speed_mean"))
    y[:, :, it] = 1.0 + np.abs(y[:, :, it])
    y[:, :, iw] *= 5.0  # large torque swings: the 5 V limit is reached
    state = c.initial_state(y[0])
    z = np.zeros(batch)
    t_slow = np.asarray([float(np.asarray(lower_friction_curve(p, w))) for w in y[0, :, it]])
    np.testing.assert_allclose(state[:, 1], t_slow, rtol=1e-12)
    hit_limit = False
    for k in range(n):
        torque = p.string_stiffness * y[k, :, iw]
        e = y[k, :, it] - (torque - t_slow) / c.impedance - y[k, :, iv]
        u_req = y[k, :, iu] + kp * e + ki * z
        u_ref = np.clip(u_req, -vmax, vmax)
        hit_limit |= bool(np.any(u_ref != u_req))
        z = z + dt * e + dt / (ki * tracking) * (u_ref - u_req)
        t_slow = t_slow + a * (torque - t_slow)
        u, state = c.control(y[k], state)
        np.testing.assert_allclose(u, u_ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(state, np.stack([z, t_slow], axis=1), rtol=1e-10, atol=1e-12)
    assert hit_limit
