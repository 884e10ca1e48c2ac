"""DrillString-v1: the v0 observation followed by the encoder angles within the revolution
and the encoder-exact integrated lower speed error; everything else as v0.

The expected entries are computed here from the true angles in ``info["true_state"]``
with the encoder's floor quantisation written out, not read from the env."""

from __future__ import annotations

import math
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from test_vector_env import assert_same

import drill_env  # noqa: F401  (registers the environments)
from drill_env.envs.config import INTEGRAL_BOUND, INTEGRAL_SCALE, OBSERVATION_NAMES_V1
from drill_env.envs.drill_string import DrillStringEnv

V1 = ("DrillString-v1", "DrillStringNoBrake-v1")
OBS = {name: i for i, name in enumerate(OBSERVATION_NAMES_V1)}
N_COUNTS = 2000  # the default encoder


def encoder(theta: float, n: int = N_COUNTS) -> float:
    """The encoder reading of a true angle: whole counts, rounded down."""
    return math.floor(theta * n / (2.0 * math.pi)) * 2.0 * math.pi / n


def within_revolution(theta: float, n: int = N_COUNTS) -> float:
    counts = math.floor(theta * n / (2.0 * math.pi))
    return (counts % n) * 2.0 * math.pi / n


@pytest.mark.parametrize("env_id", V1)
def test_checkers_are_silent(env_id):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env, wrapped = gym.make(env_id).unwrapped, gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env)
        sb3_check_env(wrapped, warn=True)
    assert env.observation_space.shape == (13,)


@pytest.mark.parametrize("env_id", V1)
def test_v1_runs_the_v0_episode_and_observes_more(env_id):
    v0 = gym.make(env_id.replace("-v1", "-v0"), warmup_time=5.0)
    v1 = gym.make(env_id, warmup_time=5.0)
    (o0, i0), (o1, i1) = v0.reset(seed=4), v1.reset(seed=4)
    assert o0.shape == (8,) and o1.shape == (13,)
    np.testing.assert_array_equal(o0, o1[:8])
    rng = np.random.default_rng(2)
    for _ in range(30):
        a = rng.uniform(-1, 1, size=1).astype(np.float32)
        (o0, r0, *_, i0), (o1, r1, *_, i1) = v0.step(a), v1.step(a)
        np.testing.assert_array_equal(o0, o1[:8])
        np.testing.assert_array_equal(i0["true_state"], i1["true_state"])
        assert r0 == r1


@pytest.mark.parametrize("env_id", V1)
def test_angle_and_integral_entries_from_the_true_angles(env_id):
    env = gym.make(env_id, normalize_observation=False, warmup_time=5.0, max_episode_steps=10**6)
    obs, info = env.reset(seed=7, options={"nominal_voltage": 2.0})
    w = info["target_speed"]
    ql0 = encoder(info["true_state"][4])
    assert obs[OBS["lower_speed_error_integral"]] == 0.0
    rng = np.random.default_rng(1)
    for _ in range(600):  # 30 s: several revolutions, angles far from 0
        obs, _, _, _, info = env.step(rng.uniform(0.2, 0.8, size=1).astype(np.float32))
        thu = info["true_state"][3]
        thl = info["true_state"][4]
        for disk, theta in (("lower", thl), ("upper", thu)):
            a = within_revolution(theta)
            assert obs[OBS[f"{disk}_angle_sin"]] == pytest.approx(math.sin(a), abs=1e-6)
            assert obs[OBS[f"{disk}_angle_cos"]] == pytest.approx(math.cos(a), abs=1e-6)
        expected = (encoder(thl) - ql0) - w * info["time"]
        assert obs[OBS["lower_speed_error_integral"]] == pytest.approx(expected, abs=1e-4, rel=1e-6)
        assert info["integral_clipped"] is False
    assert info["true_state"][4] > 8 * 2 * math.pi  # the bit turned more than 8 revolutions
    # normalised: the same divided by the scale, sin/cos as they are
    env_n = gym.make(env_id, warmup_time=5.0)
    o_n, _ = env_n.reset(seed=7, options={"nominal_voltage": 2.0})
    o_p, _ = gym.make(env_id, warmup_time=5.0, normalize_observation=False).reset(
        seed=7, options={"nominal_voltage": 2.0}
    )
    np.testing.assert_allclose(o_n[8:12], o_p[8:12], rtol=0, atol=1e-7)
    assert env_n.unwrapped.settings.observation_scales[12] == INTEGRAL_SCALE


def test_integral_restarts_at_reset_and_is_clipped_with_a_flag():
    # the bit standing still at a high target: it falls behind w* per second
    env = gym.make(
        "DrillString-v1", normalize_observation=False, max_episode_steps=10**6, start="rest", warmup_time=0.0
    )
    obs, info = env.reset(seed=0, options={"nominal_voltage": 5.0})
    w = info["target_speed"]
    steps_to_bound = int(math.ceil(INTEGRAL_BOUND / w / env.unwrapped.control_dt))
    back = np.array([-1.0], np.float32)  # -5 V: the disks turn backwards, the lag grows faster than w* t
    clipped_at = None
    for k in range(steps_to_bound + 40):
        obs, _, _, _, info = env.step(back)
        e = obs[OBS["lower_speed_error_integral"]]
        if info["integral_clipped"]:
            clipped_at = k if clipped_at is None else clipped_at
            assert e == pytest.approx(-INTEGRAL_BOUND, rel=1e-7)
        else:
            assert -INTEGRAL_BOUND < e <= 0.0
    assert clipped_at is not None and 20 <= clipped_at <= steps_to_bound
    obs, info = env.reset(seed=1)
    assert obs[OBS["lower_speed_error_integral"]] == 0.0 and info["integral_clipped"] is False


def test_determinism_and_pickling():
    env = gym.make("DrillString-v1", warmup_time=5.0)
    twin = gym.make("DrillString-v1", warmup_time=5.0)
    np.testing.assert_array_equal(env.reset(seed=3)[0], twin.reset(seed=3)[0])
    for _ in range(5):
        a = np.array([0.3], np.float32)
        np.testing.assert_array_equal(env.step(a)[0], twin.step(a)[0])
    copy = pickle.loads(pickle.dumps(env))
    for _ in range(10):
        a = np.array([-0.2], np.float32)
        r1, r2 = env.step(a), copy.step(a)
        np.testing.assert_array_equal(r1[0], r2[0])
        assert r1[1] == r2[1]
        assert_same(r1[4], r2[4])


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_native_vector_env_v1_equals_sync(mode):
    kw = {"max_episode_steps": 12, "warmup_time": 3.0, "start_angle": "random"}
    native = gym.make_vec("DrillString-v1", num_envs=4, autoreset_mode=mode, **kw)
    sync = gym.make_vec(
        "DrillString-v1", num_envs=4, vectorization_mode="sync", vector_kwargs={"autoreset_mode": mode}, **kw
    )
    assert native.single_observation_space == sync.single_observation_space
    for x, y in zip(native.reset(seed=9), sync.reset(seed=9), strict=True):
        assert_same(x, y)
    rng = np.random.default_rng(5)
    for _ in range(30):  # two autoresets of every rig
        a = rng.uniform(-1, 1, size=(4, 1)).astype(np.float32)
        r1, r2 = native.step(a), sync.step(a)
        for x, y in zip(r1, r2, strict=True):
            assert_same(x, y)


def test_version_history_arguments_and_start_angle():
    doc = DrillStringEnv.__doc__
    assert "## Version History" in doc and "* v1:" in doc and "* v0:" in doc
    for bad in (2, "1", True, 1.0):
        with pytest.raises(ValueError, match="observation_version"):
            DrillStringEnv(observation_version=bad)
    for bad in (-0.1, 2 * math.pi, "north", float("nan")):
        with pytest.raises(ValueError, match="start_angle"):
            DrillStringEnv(start_angle=bad)
    assert gym.make("DrillString-v0").observation_space.shape == (8,)
    # start_angle only moves where the disks stand: same twist and speeds, angles shifted
    a = gym.make("DrillString-v1", warmup_time=3.0)
    b = gym.make("DrillString-v1", warmup_time=3.0, start_angle=1.0)
    c = gym.make("DrillString-v1", warmup_time=3.0, start_angle="random")
    (_, ia), (_, ib), (_, ic) = a.reset(seed=2), b.reset(seed=2), c.reset(seed=2)
    np.testing.assert_array_equal(ia["true_state"][:3], ib["true_state"][:3])
    np.testing.assert_array_equal(ia["true_state"][:3], ic["true_state"][:3])
    assert ib["true_state"][4] - ia["true_state"][4] == pytest.approx(1.0, abs=1e-9)
    assert ia["target_speed"] == ic["target_speed"]
    shifts = {
        round(c.reset(seed=s)[1]["true_state"][4] - a.reset(seed=s)[1]["true_state"][4], 6) for s in range(6)
    }
    assert len(shifts) == 6 and all(0.0 <= x < 2 * math.pi for x in shifts)
