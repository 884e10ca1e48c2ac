"""The scenario suite's option sets of the environments (drill_env.envs.scenarios)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import drill_env  # noqa: F401  (registers the environments)
from drill_env import simulate
from drill_env.envs.scenarios import (
    SCENARIO_NAMES,
    SCENARIOS,
    VOLTAGES,
    FrictionSchedule,
    get_scenario,
    resolve_scenarios,
)
from drill_env.envs.task import equilibrium_speed, operating_regimes
from drill_env.params import load_params

IDS = {"brake": "DrillString-v3", "no_brake": "DrillStringNoBrake-v3"}


def _regime(preset: str, u: float) -> str:
    for name, lo, hi in operating_regimes(load_params(preset)).intervals:
        if lo < u <= hi:
            return name
    raise AssertionError(u)


@pytest.mark.parametrize("preset", sorted(IDS))
@pytest.mark.parametrize("name", SCENARIO_NAMES)
def test_every_scenario_makes_resets_and_steps(preset, name):
    env = gym.make(IDS[preset], scenario=name, warmup_time=1.0, warmup_jitter=0.0)
    obs, info = env.reset(seed=0)
    sc = SCENARIOS[name]
    v0 = sc.set_point_voltages(preset)[0]
    assert info["scenario"] == name and info["nominal_voltage"] == pytest.approx(v0)
    assert env.observation_space.contains(obs)
    obs, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))
    assert info["scenario"] == name and info["sim_status"] == 0
    assert info["friction_scale"] == pytest.approx(sc.friction_factor(env.unwrapped.control_dt))
    if sc.start == "rest":
        assert info["time"] == pytest.approx(env.unwrapped.control_dt)
    for key, value in sc.sensors.items():
        assert getattr(env.unwrapped.sensor_config, key) == value


@pytest.mark.parametrize("preset", sorted(IDS))
def test_set_points_sit_in_the_regimes_the_docs_name(preset):
    # what each scenario's docstring promises, checked against the design model's regimes
    regimes = {
        "start_up": ["stick_slip"],
        "set_point_steps": ["equilibrium", "stick_slip", "limit_cycle"],
        "friction_step": ["limit_cycle"],
        "friction_drift": ["limit_cycle"],
        "sensing_delay": ["stick_slip"],
        "sensing_noise": ["limit_cycle"],
        "effort": ["stick_slip"],
    }
    for name, expected in regimes.items():
        assert [_regime(preset, u) for u in VOLTAGES[name][preset]] == expected, name


def test_set_point_steps_change_the_observed_target_at_their_times():
    env = gym.make("DrillString-v3", scenario="set_point_steps", normalize_observation=False)
    env.reset(seed=1)
    dt = env.unwrapped.control_dt
    params = load_params("brake")
    seen = {}
    for _ in range(int(round(90.0 / dt))):
        obs, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))  # correction 0: open loop
        seen[round(info["time"], 6)] = (float(obs[6]), float(obs[7]), info["voltage"])
    # the target is the design model's equilibrium speed at each set point's voltage (eq. 20)
    for t, u in ((29.95, 0.5), (30.0, 2.5), (59.95, 2.5), (60.0, 1.0), (90.0, 1.0)):
        target, unom, _ = seen[t]
        assert unom == pytest.approx(u)
        assert target == pytest.approx(equilibrium_speed(params, u), rel=1e-6)
    # and the action 0 of the correction mode applies the new nominal voltage from then on
    assert seen[30.05][2] == pytest.approx(2.5) and seen[30.0][2] == pytest.approx(0.5)


def test_friction_step_runs_the_plant_with_the_scaled_curve():
    # after the step the env's rig moves as an independent simulation of the x1.4 plant does
    env = gym.make("DrillString-v3", scenario="friction_step", warmup_time=5.0, warmup_jitter=0.0)
    env.reset(seed=0)
    dt = env.unwrapped.control_dt
    states = []
    for _ in range(int(round(26.0 / dt))):
        _, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))
        states.append(info["true_state"])
    states = np.array(states)
    k0 = int(round(24.0 / dt)) - 1  # t = 24 s, after the step at 20 s
    x1, x2, x3, th_u, th_l = states[k0]
    base = load_params("brake")
    scaled = base.replace(
        **{
            f: getattr(base, f) * 1.4
            for f in ("lower_static", "lower_viscous", "lower_hump_1", "lower_hump_2")
        }
    )
    res = simulate(scaled, 1.5, 2.0, x0={"theta_u": th_u, "theta_l": th_l, "x2": x2, "x3": x3}, dt=dt)
    np.testing.assert_allclose(res.x3[1:], states[k0 + 1 : k0 + 41, 2], atol=1e-5)
    unscaled = simulate(base, 1.5, 2.0, x0={"theta_u": th_u, "theta_l": th_l, "x2": x2, "x3": x3}, dt=dt)
    assert np.max(np.abs(unscaled.x3[1:] - states[k0 + 1 : k0 + 41, 2])) > 1e-3


def test_friction_schedule_is_piecewise_linear_with_steps():
    f = FrictionSchedule(((0.0, 0.7), (80.0, 1.4)))
    assert [f.factor(t) for t in (-1.0, 0.0, 40.0, 80.0, 100.0)] == pytest.approx([0.7, 0.7, 1.05, 1.4, 1.4])
    step = FrictionSchedule(((20.0, 1.0), (20.0, 1.4)))
    assert step.factor(19.999) == 1.0 and step.factor(20.0) == 1.4
    with pytest.raises(ValueError, match="factor"):
        FrictionSchedule(((0.0, 0.0),))
    with pytest.raises(ValueError, match="times"):
        FrictionSchedule(((5.0, 1.0), (1.0, 1.2)))


def test_drift_warm_up_runs_at_the_switch_on_friction():
    env = gym.make("DrillString-v3", scenario="friction_drift")
    env.reset(seed=0)
    p = env.unwrapped._p
    from drill_env import _layout as L

    assert p[L.TSL] == pytest.approx(0.7 * load_params("brake").lower_static)


def test_a_bad_scenario_name_is_one_clear_error():
    with pytest.raises(ValueError, match=r"scenario: 'nope' is not one of \['start_up'"):
        gym.make("DrillString-v3", scenario="nope")
    with pytest.raises(ValueError, match="not among"):
        resolve_scenarios("start_up,nope")
    assert resolve_scenarios("effort, start_up") == ("start_up", "effort")
    assert resolve_scenarios("all") == SCENARIO_NAMES
    assert get_scenario("effort") is SCENARIOS["effort"]


def test_reset_options_still_choose_the_first_set_point():
    env = gym.make("DrillString-v3", scenario="set_point_steps", warmup_time=1.0)
    _, info = env.reset(seed=0, options={"nominal_voltage": 0.8})
    assert info["nominal_voltage"] == pytest.approx(0.8)


def test_vector_env_runs_static_scenarios_and_refuses_schedules():
    kw = {"scenario": "sensing_delay", "warmup_time": 2.0, "warmup_jitter": 0.0}
    vec = gym.make_vec("DrillString-v3", num_envs=1, **kw)
    single = gym.make("DrillString-v3", **kw)
    a, _ = vec.reset(seed=4)
    b, _ = single.reset(seed=4)
    np.testing.assert_array_equal(a[0], b)
    for _ in range(5):
        a, *_ = vec.step(np.full((1, 1), 0.1, dtype=np.float32))
        b, *_ = single.step(np.full(1, 0.1, dtype=np.float32))
    np.testing.assert_array_equal(a[0], b)
    with pytest.raises(ValueError, match="native vector env"):
        gym.make_vec("DrillString-v3", num_envs=2, scenario="friction_step")
