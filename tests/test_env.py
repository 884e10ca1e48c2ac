"""The Gymnasium environment: API conformance, determinism, the amplifier limit, the
observation as the rig's sensors see the exact simulation, rewards, task and regimes."""

from __future__ import annotations

import math
import pickle
import subprocess
import sys
import warnings

import gymnasium as gym
import numba as nb
import numpy as np
import pytest
import scipy.signal as sg

import drill_env
from drill_env import _layout as L
from drill_env import friction
from drill_env.envs import ENV_IDS, ENV_VERSIONS, MAX_EPISODE_STEPS, register_envs
from drill_env.envs import _core as C
from drill_env.envs.config import OBSERVATION_NAMES, REWARD_NAMES
from drill_env.envs.task import (
    REGIMES,
    critical_friction_slope,
    equilibrium_speed,
    nominal_voltage,
    operating_regimes,
)
from drill_env.kernel import N_STATS, ST_LOGGED, run

IDS = [i for i in ENV_IDS if ENV_VERSIONS[i] == 0]  # the v0 ids; v1: tests/test_env_v1.py
OBS = {name: i for i, name in enumerate(OBSERVATION_NAMES)}


def rollout(env, seed, n, actions=None, reset_options=None):
    """(obs, reward, terminated, truncated, info) per step, resetting at episode ends."""
    env.action_space.seed(seed)
    obs, info = env.reset(seed=seed, options=reset_options)
    out = [(obs, 0.0, False, False, info)]
    for k in range(n):
        a = env.action_space.sample() if actions is None else actions[k]
        step = env.step(a)
        out.append(step)
        if step[2] or step[3]:
            out.append(env.reset())
    return out


def assert_same(a, b, path=""):
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            assert_same(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and np.array_equal(a, b), path
    else:
        assert a == b, (path, a, b)


# -- registration and API conformance ------------------------------------------------------------


def test_registration_is_idempotent_and_complete():
    register_envs()
    register_envs()
    for env_id, preset in ENV_IDS.items():
        spec = gym.spec(env_id)
        assert spec.max_episode_steps == MAX_EPISODE_STEPS
        assert spec.kwargs["params"] == preset
        assert spec.vector_entry_point == "drill_env.envs.vector:DrillStringVectorEnv"
        env = gym.make(env_id)
        assert env.unwrapped.settings.params.name == preset


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_check_env_passes_without_warnings(env_id):
    from gymnasium.utils.env_checker import check_env

    # gym.make of a v0 id warns that v1 exists (Gymnasium's versioning); the env itself must not
    envs = [gym.make(env_id).unwrapped, gym.make(env_id, render_mode="rgb_array").unwrapped]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for env in envs:
            check_env(env)


@pytest.mark.parametrize("env_id", IDS)
def test_sb3_check_env_passes_without_warnings(env_id):
    from stable_baselines3.common.env_checker import check_env

    env = gym.make(env_id)  # a v0 id: Gymnasium's "out of date" notice comes from make
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env, warn=True)


def test_make_accepts_keyword_overrides():
    env = gym.make(
        "DrillString-v0",
        control_dt=0.02,
        sensors={"counts_per_rev": 500},
        params_overrides={"lower_static": 0.1},
        task={"voltage_range": (1.0, 1.5)},
        normalize_observation=False,
    )
    obs, info = env.reset(seed=3)
    u = env.unwrapped
    assert u.settings.params.lower_static == 0.1
    assert 1.0 <= info["nominal_voltage"] <= 1.5
    _, _, _, _, info = env.step(np.array([0.2], np.float32))
    assert info["time"] == pytest.approx(0.02)
    assert u.last_step_samples()["t"].size == 20
    r = 2 * np.pi / 500
    for o in (obs, env.step(np.array([0.2], np.float32))[0]):
        k = float(o[OBS["twist"]]) / r
        assert abs(k - round(k)) < 1e-3 * max(1.0, abs(k))  # float32 of whole counts


# -- determinism and pickling --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"domain_randomization": True, "sensors": {"angle_noise_std": 3e-4, "speed_noise_std": 0.02}}],
)
def test_twin_rollouts_with_the_same_seed_are_identical(kwargs):
    runs = [rollout(gym.make("DrillString-v0", max_episode_steps=40, **kwargs), 7, 100) for _ in range(2)]
    assert_same(runs[0], runs[1])
    other = rollout(gym.make("DrillString-v0", max_episode_steps=40, **kwargs), 8, 5)
    assert other[0][4]["nominal_voltage"] != runs[0][0][4]["nominal_voltage"]


def test_pickled_env_continues_identically():
    env = gym.make("DrillString-v0", sensors={"speed_noise_std": 0.05}, render_mode="rgb_array")
    env.reset(seed=11)
    for _ in range(10):
        env.step(np.array([0.3], np.float32))
    env.render()
    twin = pickle.loads(pickle.dumps(env))
    acts = np.random.default_rng(0).uniform(-1, 1, size=(30, 1)).astype(np.float32)
    for a in acts:
        assert_same(env.step(a), twin.step(a))
    assert twin.render().shape == env.render().shape


# -- the amplifier --------------------------------------------------------------------------------------


def test_voltage_limit_holds_for_any_action():
    """Every action of the action space gives at most the amplifier's +-5 V; one beyond the
    space (a finite 1e308 among them) is refused naming the range, never clipped silently."""
    env = gym.make("DrillString-v0")
    env.reset(seed=0)
    big = float(np.finfo(np.float32).max)
    cases = [1.0, -1.0, 0.999, 0.0, float(np.nextafter(np.float32(1.0), np.float32(0.0)))]
    rng = np.random.default_rng(1)
    cases += list(rng.uniform(-1.0, 1.0, size=100))
    for a in cases:
        obs, _, _, _, info = env.step(np.array([a], dtype=np.float32))
        requested = 5.0 * float(np.float32(a))
        assert -5.0 <= info["voltage"] <= 5.0
        assert info["voltage_requested"] == requested
        assert info["voltage_clipped"] == (abs(requested) > 5.0)
        assert info["voltage"] == max(-5.0, min(5.0, requested))
        samples = env.unwrapped.last_step_samples()
        assert np.all(np.abs(samples["voltage"]) <= 5.0) and np.all(samples["voltage"] == info["voltage"])
        assert abs(float(obs[OBS["voltage"]]) * 5.0 - info["voltage"]) < 1e-5
    for a in (1e6, -1e6, 1.5, -1.0001, big, -big, 1e308, -1e308):
        with pytest.raises(
            ValueError, match=r"^action: .* is outside the action space: allowed range \[-1, 1\]"
        ):
            env.step(np.array([a], dtype=np.float64))
    venv = gym.make("DrillString-v0", action_mode="voltage")
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"^action: 7\.3.* allowed range \[-5, 5\]"):
        venv.step(np.array([7.3], np.float32))
    _, _, _, _, info = venv.step(np.array([5.0], np.float32))
    assert info["voltage"] == 5.0 and not info["voltage_clipped"]
    assert venv.action_space.high[0] == 5.0
    # a correction (v2) can ask beyond the amplifier: the rig's own clip, visible in info
    corr = gym.make("DrillString-v2")
    corr.reset(seed=0, options={"nominal_voltage": 4.5})
    _, _, _, _, info = corr.step(np.array([1.0], np.float32))
    assert (
        info["voltage_requested"] == pytest.approx(6.5) and info["voltage"] == 5.0 and info["voltage_clipped"]
    )


def test_wrong_action_shapes_are_refused_naming_the_shape():
    env = gym.make("DrillString-v3")
    env.reset(seed=0)
    for action, shape in (
        (np.zeros((1, 1)), r"\(1, 1\)"),
        (np.float32(0.2), r"\(\)"),
        (0.2, r"\(\)"),
        ([[0.2]], r"\(1, 1\)"),
    ):
        with pytest.raises(
            ValueError, match=rf"^action: expected shape \(1,\), got shape {shape} \(allowed range \[-1, 1\]"
        ):
            env.step(action)
    env.step([0.2])  # a list of one number is shape (1,)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_actions_raise(bad):
    env = gym.make("DrillString-v0")
    env.reset(seed=0)
    for action in (np.array([bad], np.float32), [bad]):
        with pytest.raises(
            ValueError, match=r"action: .* outside the action space: allowed range \[-1, 1\], finite"
        ):
            env.step(action)
    for action in (bad, np.array([[bad]])):
        with pytest.raises(ValueError, match=r"action: expected shape \(1,\)"):
            env.step(action)
    with pytest.raises(ValueError, match=r"action: expected shape \(1,\)"):
        env.step(np.zeros(2, np.float32))
    with pytest.raises(ValueError, match="action"):
        env.step("fast")
    env.step(np.array([0.1], np.float32))  # still usable


@pytest.mark.parametrize(
    ("options", "field"),
    [
        ({"target_speed": -1.0}, "target_speed"),
        ({"target_speed": 0.0}, "target_speed"),
        ({"target_speed": 100.0}, "target_speed"),
        ({"target_speed": float("nan")}, "target_speed"),
        ({"target_speed": "fast"}, "target_speed"),
        ({"nominal_voltage": 0.05}, "nominal_voltage"),
        ({"nominal_voltage": 5.5}, "nominal_voltage"),
        ({"nominal_voltage": float("inf")}, "nominal_voltage"),
        ({"regime": "chaos"}, "regime"),
        ({"start": "spinning"}, "start"),
        ({"voltage": 1.0}, "unknown key"),
        ({"target_speed": 1.0, "nominal_voltage": 1.0}, "at most one"),
        ("stick_slip", "options"),
    ],
)
def test_bad_reset_options_raise(options, field):
    env = gym.make("DrillString-v0")
    with pytest.raises(ValueError, match=field):
        env.reset(seed=0, options=options)
    env.reset(seed=0, options={"target_speed": 2.0})  # still usable


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"control_dt": 0.0505}, "control_dt"),
        ({"control_dt": -0.05}, "control_dt"),
        ({"sensors": {"counts": 100}}, "unknown key"),
        ({"sensors": {"counts_per_rev": 0}}, "counts_per_rev"),
        ({"reward_weights": {"tracking": -1.0}}, "reward_weights.tracking"),
        ({"reward_weights": {"speed": 1.0}}, "unknown key"),
        ({"params_overrides": {"lower_static": -0.1}}, "lower_static"),
        ({"params_overrides": {"friction": 0.1}}, "unknown parameter"),
        ({"task": {"regimes": ("chaos",)}}, "regimes"),
        ({"task": {"voltage_range": (0.01, 1.0)}}, "voltage_range"),
        ({"task": {"target_speed_range": (1.0, 50.0)}}, "target_speed_range"),
        ({"start": "spinning"}, "start"),
        ({"action_mode": "volts"}, "action_mode"),
        ({"domain_randomization": {"friction_rel": 0.9}}, "friction_rel"),
        ({"domain_randomization": {"encoder_counts": (0,)}}, "encoder_counts"),
        ({"rtol": 0.0}, "rtol"),
    ],
)
def test_bad_arguments_raise(kwargs, field):
    with pytest.raises(ValueError, match=field):
        gym.make("DrillString-v0", **kwargs)
    if set(kwargs) <= {"control_dt", "sensors", "start", "action_mode"}:
        with pytest.raises(ValueError, match=field):
            gym.make_vec("DrillString-v0", num_envs=2, **kwargs)


def test_unknown_render_mode_raises():
    from drill_env.envs.drill_string import DrillStringEnv

    with pytest.raises(ValueError, match="render_mode"):
        DrillStringEnv(render_mode="ascii")


def test_simulator_failure_truncates_with_a_warning():
    env = gym.make("DrillString-v0")
    env.reset(seed=0)
    env.unwrapped._ecfg[C.EC_MAX_STEPS] = 0  # the kernel then stops at once (status 1)
    with pytest.warns(RuntimeWarning, match="simulator stopped"):
        _, _, terminated, truncated, info = env.step(np.array([0.2], np.float32))
    assert truncated and not terminated and info["sim_status"] == 1


# -- what the observation is ------------------------------------------------------------------------


def test_observation_is_the_sensor_chain_applied_to_the_exact_simulation():
    """Run from rest; rebuild every observation from the true 1 kHz samples with an
    independent implementation of quantisation, differentiation and filtering; and
    check the true samples against drill_env.simulate with the same voltages."""
    counts = 2000
    r = 2 * np.pi / counts
    env = gym.make("DrillString-v0", normalize_observation=False, start="rest", rtol=1e-10, atol=1e-12)
    obs0, info0 = env.reset(seed=4, options={"nominal_voltage": 2.0})
    assert np.all(info0["true_state"] == 0.0) and np.all(obs0[:5] == 0.0)
    rng = np.random.default_rng(2)
    volts = np.concatenate([np.full(40, 2.0), rng.uniform(-1.0, 5.0, size=60)])
    obs_list, samples, infos = [], [], []
    for u in volts:
        obs, _, _, _, info = env.step(np.array([u / 5.0], np.float32))
        obs_list.append(obs)
        infos.append(info)
        samples.append(env.unwrapped.last_step_samples())
    cat = {k: np.concatenate([s[k] for s in samples]) for k in samples[0]}
    # independent chain, starting at rest at angle 0
    b, a = sg.butter(2, 200.0 / (2 * np.pi), fs=1000.0)
    ref = {}
    for disk in ("upper", "lower"):
        q = np.floor(np.concatenate([[0.0], cat[f"{disk}_angle"]]) / r) * r
        raw = np.diff(q) * 1000.0
        ref[disk] = (q[1:], sg.lfilter(b, a, raw))
    n = 50
    for k, (obs, info) in enumerate(zip(obs_list, infos, strict=True)):
        end = (k + 1) * n - 1
        start = k * n - 1
        qu, vu = ref["upper"][0][end], ref["upper"][1][end]
        ql, vl = ref["lower"][0][end], ref["lower"][1][end]
        assert obs[OBS["twist"]] == np.float32(qu - ql)
        np.testing.assert_allclose(obs[OBS["upper_speed"]], vu, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(obs[OBS["lower_speed"]], vl, rtol=1e-6, atol=1e-9)
        qu0 = ref["upper"][0][start] if start >= 0 else 0.0
        ql0 = ref["lower"][0][start] if start >= 0 else 0.0
        np.testing.assert_allclose(obs[OBS["upper_speed_mean"]], (qu - qu0) / 0.05, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(obs[OBS["lower_speed_mean"]], (ql - ql0) / 0.05, rtol=1e-6, atol=1e-9)
        assert obs[OBS["voltage"]] == np.float32(info["voltage"])
        assert obs[OBS["target_speed"]] == np.float32(info0["target_speed"])
        assert obs[OBS["nominal_voltage"]] == np.float32(info0["nominal_voltage"])
        # and the true state, which the observation does not contain, differs by less than a count
        true = info["true_state"]
        assert abs(float(obs[OBS["twist"]]) - true[0]) < 2 * r
        assert true[3] == cat["upper_angle"][end] and true[4] == cat["lower_angle"][end]
    # the true samples are the exact simulator's: one kernel call over all hold periods agrees
    # to the accumulated integration error (rtol 1e-10), far below one encoder count
    ref_state = kernel_run("brake", volts, 0.05, 0.001 * np.arange(1, volts.size * 50 + 1))
    np.testing.assert_allclose(cat["lower_speed"], ref_state["x3"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(cat["upper_speed"], ref_state["x2"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(cat["lower_angle"], ref_state["theta_l"], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(cat["lower_stuck"], ref_state["stick_l"])


@nb.njit
def _run_zoh(
    p, y, modes, seg_t, seg_u, t_out, rtol, atol, Y, M, U, ev_t, ev_disk, ev_from, ev_to, ev_y, stats
):
    return run(
        p,
        y,
        modes,
        seg_t,
        seg_u,
        None,
        False,
        np.inf,
        t_out,
        rtol,
        atol,
        0.0,
        10**8,
        Y,
        M,
        U,
        ev_t,
        ev_disk,
        ev_from,
        ev_to,
        ev_y,
        stats,
    )


def kernel_run(preset, volts, control_dt, t_out, rtol=1e-10, atol=1e-12, events=4096):
    """The rig from rest under a zero-order hold of ``volts``, integrated by
    drill_env.kernel.run in a single call and sampled at ``t_out``."""
    p = drill_env.load_params(preset).as_array()
    volts = np.atleast_1d(np.asarray(volts, dtype=float))
    seg_t = control_dt * np.arange(volts.size + 1)
    t_out = np.asarray(t_out, dtype=float)
    n = t_out.size
    Y = np.empty((n, L.NY))
    M = np.empty((n, 2), dtype=np.int64)
    U = np.empty(n)
    ev = (
        np.empty(events),
        np.empty(events, np.int64),
        np.empty(events, np.int64),
        np.empty(events, np.int64),
        np.empty((events, L.NY)),
    )
    stats = np.zeros(N_STATS)
    y = np.zeros(L.NY)
    status = _run_zoh(p, y, np.zeros(2, np.int64), seg_t, volts, t_out, rtol, atol, Y, M, U, *ev, stats)
    assert status == 0
    k = int(stats[ST_LOGGED])
    return {
        "x2": Y[:, L.X2],
        "x3": Y[:, L.X3],
        "theta_l": Y[:, L.THL],
        "stick_l": M[:, 1] == 0,
        "event_t": ev[0][:k],
        "event_disk": ev[1][:k],
        "event_to": ev[3][:k],
    }


def test_true_state_is_only_in_info():
    env = gym.make("DrillString-v0", normalize_observation=False)
    obs, info = env.reset(seed=5, options={"regime": "stick_slip"})
    for _ in range(30):
        obs, _, _, _, info = env.step(np.array([0.5], np.float32))
        true = info["true_state"]
        # the estimates are close to, but not, the true values
        assert obs[OBS["lower_speed"]] != np.float32(true[2]) or true[2] == 0.0
        assert abs(obs[OBS["twist"]] - true[0]) < 2 * (2 * np.pi / 2000)
    assert set(info) >= {"true_state", "upper_stuck", "lower_stuck", "rewards", "voltage_clipped"}


# -- reward -------------------------------------------------------------------------------------------


def test_reward_is_the_weighted_sum_of_documented_terms():
    weights = {
        "tracking": 1.0,
        "stick": 2.0,
        "oscillation": 0.3,
        "effort": 0.7,
        "integral": 0.4,
        "overdrive": 0.9,
    }
    env = gym.make("DrillString-v0", reward_weights=weights)
    _, info0 = env.reset(seed=9, options={"regime": "stick_slip"})
    target, unom = info0["target_speed"], info0["nominal_voltage"]
    angle0 = info0["true_state"][4]
    count = 2.0 * math.pi / env.unwrapped.settings.sensors.counts_per_rev
    s = max(target, 1.0)
    seen_stick = False
    for k in range(100):
        a = min(unom / 5.0 + 0.1 * math.sin(k / 5.0), 1.0)
        _, reward, _, _, info = env.step(np.array([a], np.float32))
        smp = env.unwrapped.last_step_samples()
        terms = info["rewards"]
        assert list(terms) == list(REWARD_NAMES)
        assert terms["tracking"] == pytest.approx(
            np.mean(((smp["lower_speed"] - target) / s) ** 2), rel=1e-12
        )
        assert terms["stick"] == pytest.approx(np.mean(smp["lower_stuck"]), abs=1e-15)
        osc = np.mean(((smp["upper_speed"] - smp["lower_speed"]) / s) ** 2)
        assert terms["oscillation"] == pytest.approx(osc, rel=1e-12, abs=1e-300)
        assert terms["effort"] == pytest.approx(((info["voltage"] - unom) / 5.0) ** 2, rel=1e-12, abs=1e-300)
        # the angle lost against the target since the reset, from the true angle; the term
        # reads it from the encoder (two readings, each within a count of the truth)
        lost = info["true_state"][4] - angle0 - target * info["time"]
        assert terms["integral"] == pytest.approx(
            min(abs(lost) / (2.0 * math.pi), C.INTEGRAL_TERM_CAP), abs=2.0 * count / (2.0 * math.pi)
        )
        excess = max(abs(info["voltage_requested"]) - 5.0, 0.0) / 5.0
        assert terms["overdrive"] == pytest.approx(excess, rel=1e-12, abs=1e-300)
        assert reward == pytest.approx(-sum(weights[k] * terms[k] for k in REWARD_NAMES), rel=1e-12)
        assert all(v >= 0.0 for v in terms.values())
        seen_stick |= terms["stick"] > 0
    assert seen_stick
    assert terms["integral"] > 0.1  # open-loop stick-slip loses angle: the term is not trivially 0


def test_the_integral_term_saturates_at_its_cap():
    """A bit held at 0 V loses its target speed times the time: the term grows as the angle
    lost, in revolutions, up to INTEGRAL_TERM_CAP and stays there."""
    env = gym.make(
        "DrillString-v0",
        reward_weights={"integral": 1.0, "tracking": 0.0, "stick": 0.0, "oscillation": 0.0, "effort": 0.0},
    )
    _, info0 = env.reset(seed=3, options={"nominal_voltage": 4.0})
    angle0 = info0["true_state"][4]
    seen = []
    for _ in range(200):
        _, reward, _, _, info = env.step(np.array([0.0], np.float32))
        lost = abs(info["true_state"][4] - angle0 - info0["target_speed"] * info["time"]) / (2.0 * math.pi)
        expected = min(lost, C.INTEGRAL_TERM_CAP)
        assert info["rewards"]["integral"] == pytest.approx(expected, abs=2e-3)
        assert reward == pytest.approx(-info["rewards"]["integral"], rel=1e-12)
        seen.append(lost)
    assert min(seen) < C.INTEGRAL_TERM_CAP < max(seen)  # both sides of the cap were exercised


@pytest.mark.parametrize(
    "env_id, volts_per_action, offset, actions",
    [
        # correction mode: u_nom + 2 V a, up to 6.5 V asked at u_nom 4.5 V
        ("DrillString-v2", 2.0, 4.5, (0.1, 0.25, 0.7, 1.0, 0.6, 0.2)),
        # the same at another distance from the limit (in normalized mode an action of the
        # box never asks beyond the amplifier; one beyond the box is refused)
        ("DrillString-v2", 2.0, 4.5, (-0.3, 0.15, 0.6, 0.95, 0.4, 0.0)),
    ],
)
def test_the_overdrive_term_is_the_request_beyond_the_amplifier_limit(
    env_id, volts_per_action, offset, actions
):
    """The amplifier applies +-5 V at most, and the overdrive term is what was asked beyond
    it, over 5 V. The rig runs as at the limit itself, so the other terms are those of a
    request of exactly the limit."""
    only = {"tracking": 0.0, "stick": 0.0, "oscillation": 0.0, "effort": 0.0, "overdrive": 1.0}
    over = gym.make(env_id, reward_weights=only)
    at = gym.make(env_id, reward_weights=only)
    opts = {"nominal_voltage": 4.5}
    over.reset(seed=4, options=opts)
    at.reset(seed=4, options=opts)
    clipped = 0
    for a in actions:
        asked = offset + volts_per_action * float(np.float32(a))
        applied = min(max(asked, -5.0), 5.0)
        _, r_over, _, _, i_over = over.step(np.array([a], np.float32))
        _, r_at, _, _, i_at = at.step(np.array([(applied - offset) / volts_per_action], np.float64))
        assert i_over["voltage_requested"] == pytest.approx(asked, rel=1e-12)
        assert i_over["voltage"] == pytest.approx(applied, rel=1e-12)
        assert i_over["voltage_clipped"] == (abs(asked) > 5.0)
        excess = max(abs(asked) - 5.0, 0.0) / 5.0
        assert i_over["rewards"]["overdrive"] == pytest.approx(excess, rel=1e-9, abs=1e-12)
        assert r_over == pytest.approx(-excess, rel=1e-9, abs=1e-12)
        assert i_at["rewards"]["overdrive"] == pytest.approx(0.0, abs=1e-12)
        for name in ("tracking", "stick", "oscillation", "effort", "integral"):
            assert i_over["rewards"][name] == pytest.approx(i_at["rewards"][name], rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(i_over["true_state"], i_at["true_state"], rtol=1e-9, atol=1e-12)
        clipped += i_over["voltage_clipped"]
    assert 0 < clipped < len(actions)  # requests on both sides of the limit


def test_holding_the_nominal_voltage_at_a_stable_point_costs_nothing():
    env = gym.make("DrillString-v0")
    _, info = env.reset(seed=1, options={"nominal_voltage": 0.35})
    assert info["regime"] == "equilibrium"
    a = np.array([0.35 / 5.0], np.float64)
    for _ in range(40):
        _, reward, _, _, info = env.step(a)
        assert reward > -1e-6
    assert abs(info["true_state"][2] - equilibrium_speed(drill_env.load_params("brake"), 0.35)) < 1e-4


# -- task and regimes -------------------------------------------------------------------------------


def test_routh_hurwitz_threshold_is_the_papers():
    p = drill_env.load_params("brake")
    assert round(critical_friction_slope(p), 5) == -0.00114  # statement 1 of the paper


def test_brake_regimes_match_the_paper_and_the_simulator():
    p = drill_env.load_params("brake")
    reg = operating_regimes(p)
    names = [n for n, _, _ in reg.intervals]
    assert names == ["equilibrium", "limit_cycle", "stick_slip"]  # A, B, D only below 5 V (Fig. 8b)
    (lo0, hi0), (lo1, hi1), (lo2, hi2) = [(lo, hi) for _, lo, hi in reg.intervals]
    assert lo0 == pytest.approx(p.uc1) and hi0 == lo1 and hi1 == lo2 and hi2 == 5.0
    b, d = hi0, hi1
    assert 0.5 < b < 0.7  # no vibration measured at 0.5 V, a limit cycle at 0.7 V
    assert 1.0 < d < 2.0  # Fig. 9: no stick-slip at 1 V, stick-slip at 2 V
    # B is the Routh-Hurwitz crossing on the equilibrium of eq. (20)
    wb = equilibrium_speed(p, b)
    assert float(friction.lower_friction_slope(p, wb)) == pytest.approx(critical_friction_slope(p), rel=1e-8)
    assert nominal_voltage(p, wb) == pytest.approx(b, rel=1e-12)
    # D by independent simulation: the lower disk sticks on the cycle just above, never just below
    for u, sticks in ((d + 0.03, True), (d - 0.03, False)):
        res = kernel_run("brake", u, 200.0, np.linspace(150.0, 200.0, 5001), rtol=1e-10, atol=1e-12)
        assert bool(res["stick_l"].any()) == sticks, u
        late = res["event_t"] > 150.0
        lower_sticks = (res["event_disk"][late] == 1) & (res["event_to"][late] == 0)
        assert bool(lower_sticks.any()) == sticks, u


def test_no_brake_regimes_have_the_papers_sequence():
    p = drill_env.load_params("no_brake")
    reg = operating_regimes(p)
    assert [n for n, _, _ in reg.intervals] == [
        "equilibrium",
        "limit_cycle",
        "stick_slip",
        "limit_cycle",
        "equilibrium",
    ]  # A, B, D, E, F (Fig. 8a)
    assert len(reg.hopf) == 2  # supercritical B, subcritical C
    c = reg.hopf[1]
    # between C and F the equilibrium is stable but the cycle attracts the start from rest
    _, lo, hi = reg.intervals[3]
    assert lo < c < hi


def test_equilibrium_speed_matches_a_long_simulation():
    p = drill_env.load_params("brake")
    for u in (0.3, 0.45):
        res = kernel_run("brake", u, 150.0, [150.0])
        assert res["x3"][-1] == pytest.approx(equilibrium_speed(p, u), rel=1e-6)


def test_episodes_cover_all_regimes_within_their_intervals():
    env = gym.make("DrillString-v0")
    reg = env.unwrapped.settings.sampler.regimes
    seen = set()
    for seed in range(30):
        _, info = env.reset(seed=seed)
        seen.add(info["regime"])
        u = info["nominal_voltage"]
        assert any(lo <= u <= hi for lo, hi in reg.intervals_of(info["regime"]))
        assert info["target_speed"] >= 0.1 - 1e-12
        assert info["target_speed"] == pytest.approx(equilibrium_speed(env.unwrapped.settings.params, u))
    assert seen == set(REGIMES)
    for regime in REGIMES:
        _, info = env.reset(seed=1, options={"regime": regime})
        assert info["regime"] == regime
    _, info = env.reset(seed=1, options={"target_speed": 3.0})
    assert info["target_speed"] == 3.0 and info["regime"] == "stick_slip"


def test_open_loop_start_is_on_the_open_loop_behaviour():
    env = gym.make("DrillString-v0")
    for regime, sticks in (("stick_slip", True), ("equilibrium", False)):
        _, info = env.reset(seed=2, options={"regime": regime})
        a = np.array([info["nominal_voltage"] / 5.0])
        stuck = [env.step(a)[4]["rewards"]["stick"] for _ in range(120)]
        assert (max(stuck) > 0) == sticks
    # rest and equilibrium starts
    _, info = env.reset(seed=2, options={"nominal_voltage": 1.0, "start": "rest"})
    assert np.all(info["true_state"] == 0.0) and info["lower_stuck"] and info["voltage"] == 0.0
    obs, info = env.reset(seed=2, options={"nominal_voltage": 1.0, "start": "equilibrium"})
    w = info["target_speed"]
    assert info["true_state"][1] == w and info["true_state"][2] == w
    assert obs[OBS["lower_speed"]] == pytest.approx(w / 10.0, rel=1e-6)


# -- domain randomisation -------------------------------------------------------------------------


def test_domain_randomisation_is_off_by_default_and_bounded_when_on():
    nominal = drill_env.load_params("brake")
    env = gym.make("DrillString-v0")
    env.reset(seed=0)
    assert env.unwrapped.true_params == nominal
    dr = {
        "friction_rel": 0.2,
        "inertia_rel": 0.1,
        "encoder_counts": (500, 1024),
        "speed_noise_std": (0.0, 0.1),
    }
    env = gym.make("DrillString-v0", domain_randomization=dr)
    friction_fields = (
        "upper_static_pos",
        "upper_viscous_pos",
        "lower_static",
        "lower_hump_1",
        "lower_hump_rate_2",
    )
    draws, counts = [], set()
    for seed in range(12):
        env.reset(seed=seed)
        p = env.unwrapped.true_params
        for f in friction_fields:
            assert 0.8 <= getattr(p, f) / getattr(nominal, f) <= 1.2
        for f in ("upper_inertia", "lower_inertia"):
            assert 0.9 <= getattr(p, f) / getattr(nominal, f) <= 1.1
        assert p.string_stiffness == nominal.string_stiffness and p.motor_constant == nominal.motor_constant
        sc = env.unwrapped.sensor_config
        counts.add(sc.counts_per_rev)
        assert 0.0 <= sc.speed_noise_std <= 0.1
        draws.append(p.lower_static)
        # the nominal model, not the randomised plant, defines the task
        assert env.unwrapped.operating_point.target_speed == pytest.approx(
            equilibrium_speed(nominal, env.unwrapped.operating_point.nominal_voltage)
        )
    assert len(set(draws)) == len(draws) and counts == {500, 1024}


# -- rendering ------------------------------------------------------------------------------------


def test_rgb_array_rendering():
    env = gym.make("DrillString-v0", render_mode="rgb_array")
    env.reset(seed=0, options={"regime": "stick_slip"})
    for _ in range(40):
        env.step(np.array([0.4], np.float32))
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.shape[0] >= 200 and frame.shape[1] >= 400
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 20  # disks, traces, text
    env.close()


def test_importing_and_stepping_does_not_import_plotting():
    code = (
        "import sys, numpy as np, gymnasium as gym, drill_env\n"
        "env = gym.make('DrillString-v0'); env.reset(seed=0); env.step(np.zeros(1, np.float32))\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)


def test_observations_stay_in_the_space_under_random_actions():
    env = gym.make("DrillStringNoBrake-v0", max_episode_steps=100)
    for obs, *_ in rollout(env, 3, 250):
        assert env.observation_space.contains(obs)
        assert np.all(np.isfinite(obs))
    assert math.isclose(env.unwrapped.control_dt, 0.05)


# -- slow checks ------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("env_id", IDS)
def test_long_randomised_rollouts_stay_valid(env_id):
    """Many episodes with domain randomisation, noise and delay under random actions: the
    simulator never stops, observations stay finite and inside the space."""
    env = gym.make(
        env_id,
        domain_randomization=True,
        sensors={"delay_samples": 5, "angle_noise_std": 2e-4, "speed_noise_std": 0.02},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a simulator stop would warn
        steps = rollout(env, 123, 20_000)
    for entry in steps:
        obs, info = entry[0], entry[-1]
        assert env.observation_space.contains(obs)
        if len(entry) == 5:  # a step (the others are resets)
            assert math.isfinite(entry[1]) and not entry[2]
            assert info.get("sim_status", 0) == 0  # absent only in the reset entries


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_regime_boundaries_do_not_depend_on_the_grid(preset):
    p = drill_env.load_params(preset)
    coarse = operating_regimes(p, spacing=0.1)
    fine = operating_regimes(p, spacing=0.04)
    assert [n for n, _, _ in coarse.intervals] == [n for n, _, _ in fine.intervals]
    for (_, lo1, hi1), (_, lo2, hi2) in zip(coarse.intervals, fine.intervals, strict=True):
        assert abs(lo1 - lo2) < 2e-3 and abs(hi1 - hi2) < 2e-3
