"""DrillString-v2: the v1 rig whose action is the correction added to the episode's nominal
voltage (``action_mode="correction"``, +-2 V by default); observation, dynamics, reward and
episodes as v1.

The reference is v1 driven with the absolute voltage ``u_nom + 2 a`` computed here from the
reset info, not from the env's own conversion."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import drill_env  # noqa: F401  (registers the environments)
from drill_env.envs import ENV_VERSIONS
from drill_env.envs.config import CORRECTION_RANGE

V2 = ("DrillString-v2", "DrillStringNoBrake-v2")


@pytest.mark.parametrize("env_id", V2)
def test_checkers_are_silent_and_the_spaces_are_v1s(env_id):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env, wrapped = gym.make(env_id).unwrapped, gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env)
        sb3_check_env(wrapped, warn=True)
    v1 = gym.make(env_id.replace("-v2", "-v1"))
    assert env.observation_space == v1.observation_space
    assert env.action_space == v1.action_space
    assert ENV_VERSIONS[env_id] == 2 and env.settings.action_mode == "correction"
    assert CORRECTION_RANGE == 2.0


@pytest.mark.parametrize("env_id", V2)
def test_v2_runs_the_v1_episode_with_the_voltage_as_correction(env_id):
    v1 = gym.make(env_id.replace("-v2", "-v1"), warmup_time=5.0)
    v2 = gym.make(env_id, warmup_time=5.0)
    (o1, i1), (o2, i2) = v1.reset(seed=7), v2.reset(seed=7)
    np.testing.assert_array_equal(o1, o2)
    u_nom = float(i2["nominal_voltage"])
    assert u_nom == i1["nominal_voltage"]
    rng = np.random.default_rng(3)
    for k in range(40):
        a = rng.uniform(-1, 1, size=1).astype(np.float32)
        if k == 5:
            a[:] = 1.0  # beyond 5 V wherever u_nom > 3 V
        u = u_nom + 2.0 * float(a[0])
        s1 = v1.step(np.array([min(max(u, -5.0), 5.0) / 5.0], dtype=np.float32))  # v1: within its box
        s2 = v2.step(a)
        # v1's float32 action u/5 rounds the voltage by ~1e-7 V: agreement to that, not bit for bit
        np.testing.assert_allclose(s2[0], s1[0], rtol=1e-5, atol=1e-5)
        assert s2[1] == pytest.approx(s1[1], rel=1e-5, abs=1e-9)
        assert s2[4]["voltage_requested"] == pytest.approx(u, rel=1e-6)
        assert s2[4]["voltage"] == pytest.approx(min(max(u, -5.0), 5.0), rel=1e-6)
        assert s2[4]["voltage_clipped"] == (abs(u) > 5.0)


def test_clipping_at_the_rig_limit_is_visible():
    env = gym.make("DrillString-v2", warmup_time=1.0)
    env.reset(seed=0, options={"nominal_voltage": 4.5})
    _, _, _, _, info = env.step(np.array([1.0], dtype=np.float32))
    assert info["voltage_requested"] == pytest.approx(6.5, rel=1e-6)
    assert info["voltage"] == 5.0 and info["voltage_clipped"]
    _, _, _, _, info = env.step(np.array([0.0], dtype=np.float32))
    assert info["voltage"] == pytest.approx(4.5, rel=1e-6) and not info["voltage_clipped"]


def test_action_range_and_mode_arguments():
    env = gym.make("DrillString-v2", action_range=0.5, warmup_time=1.0)
    env.reset(seed=0, options={"nominal_voltage": 1.0})
    _, _, _, _, info = env.step(np.array([-1.0], dtype=np.float32))
    assert info["voltage"] == pytest.approx(0.5, rel=1e-6)
    # v1 with the correction mode is v2
    env = gym.make("DrillString-v1", action_mode="correction", warmup_time=1.0)
    env.reset(seed=0, options={"nominal_voltage": 1.0})
    _, _, _, _, info = env.step(np.array([0.25], dtype=np.float32))
    assert info["voltage"] == pytest.approx(1.5, rel=1e-6)
    for kwargs, match in (
        ({"action_range": 0.0}, "action_range"),
        ({"action_range": 10.5}, "action_range"),
        ({"action_range": "2"}, "action_range"),
        (
            {"action_mode": "normalized", "action_range": 2.0},
            "action_range: applies to action_mode='correction'",
        ),
        (
            {"action_mode": "offset"},
            r"action_mode: 'offset' is not one of \['normalized', 'voltage', 'correction'\]",
        ),
    ):
        with pytest.raises(ValueError, match=match):
            gym.make("DrillString-v2", **kwargs)


@pytest.mark.parametrize("env_id", ["DrillStringNoBrake-v2", "DrillString-v3"])
def test_native_vector_env_equals_single_envs(env_id):
    n = 3
    vec = gym.make_vec(env_id, num_envs=n, warmup_time=2.0)
    singles = [gym.make(env_id, warmup_time=2.0) for _ in range(n)]
    obs, _ = vec.reset(seed=[11, 12, 13])
    for k, env in enumerate(singles):
        o, _ = env.reset(seed=11 + k)
        np.testing.assert_allclose(obs[k], o, rtol=1e-6, atol=1e-7)
    rng = np.random.default_rng(0)
    for _ in range(10):
        a = rng.uniform(-1, 1, size=(n, 1)).astype(np.float32)
        obs, rew, _, _, info = vec.step(a)
        for k, env in enumerate(singles):
            o, r, _, _, i = env.step(a[k])
            np.testing.assert_allclose(obs[k], o, rtol=1e-6, atol=1e-7)
            assert rew[k] == pytest.approx(r, rel=1e-9, abs=1e-12)
            assert info["voltage"][k] == pytest.approx(i["voltage"], rel=1e-9)


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_a_classical_controller_asks_for_the_same_voltage_on_v1_and_v2(preset):
    """ControllerSpec.from_env turns the controller's voltage into v2's correction: on every
    observation of a v1 episode the two controllers ask for the same voltage, and the v2
    episode follows the v1 one (until float32 rounding of the actions, ~1e-7 V, flips an
    encoder count)."""
    from drill_env.agents.evaluation.episodes import EpisodeSettings, make_env, run_episode
    from drill_env.agents.registry import build_controller

    settings = EpisodeSettings(duration=10.0, window=2.0, warmup_time=5.0, warmup_jitter=1.0)
    envs = {v: make_env(preset, settings, observation_version=v) for v in (1, 2)}
    ctrl = {v: build_controller("lqi", envs[v], preset) for v in (1, 2)}
    assert not ctrl[1].spec.action_offset and ctrl[2].spec.action_offset
    obs, info = envs[1].reset(seed=3, options={"nominal_voltage": 1.0})
    u_nom = float(info["nominal_voltage"])
    state = {1: None, 2: None}
    start = np.ones(1, dtype=bool)
    for _ in range(200):
        a = {}
        for v in (1, 2):
            a[v], state[v] = ctrl[v].predict(obs, state=state[v], episode_start=start)
        start = np.zeros(1, dtype=bool)
        assert u_nom + 2.0 * float(a[2][0]) == pytest.approx(5.0 * float(a[1][0]), abs=2e-6)
        obs, *_ = envs[1].step(a[1])
    trajs = [
        run_episode(envs[v], ctrl[v], seed=3, n_steps=30, options={"nominal_voltage": 1.0}) for v in (1, 2)
    ]
    np.testing.assert_allclose(trajs[1].voltage, trajs[0].voltage, rtol=1e-4, atol=1e-5)
    assert np.ptp(trajs[0].voltage) > 0.05  # the controller acted


def test_spec_needs_the_observation_for_a_correction_action():
    from drill_env.agents.controllers.base import ControllerSpec

    spec = ControllerSpec.from_env(gym.make("DrillString-v2"))
    assert spec.action_offset and spec.action_to_volts == 2.0
    y = np.zeros((2, len(spec.observation_names)))
    y[:, spec.index("nominal_voltage")] = [1.0, 4.0]
    np.testing.assert_allclose(spec.to_action(np.array([1.5, 5.5]), y)[:, 0], [0.25, 0.5])
    with pytest.raises(ValueError, match="observations are needed"):
        spec.to_action(np.array([1.0]))
