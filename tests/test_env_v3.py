"""DrillString-v3: the v2 rig whose tracking term is the absolute speed error
``|x3 - w*| / (1 rad/s)`` (``tracking_cost="absolute"``); action, observation, dynamics,
episodes and the other reward terms as v2.

The reference is v2 on the same seed and actions, and the tracking term recomputed here from
the true 1 kHz samples of each step (``last_step_samples``), not from the env's kernel. The
native vector env of v3 is checked with v2's in test_env_v2.py."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import drill_env  # noqa: F401  (registers the environments)
from drill_env.envs import ENV_VERSIONS
from drill_env.envs.config import TRACKING_COSTS

V3 = ("DrillString-v3", "DrillStringNoBrake-v3")
WEIGHTS = {"tracking": 10.0, "stick": 1.0, "oscillation": 0.5, "effort": 0.1}


@pytest.mark.parametrize("env_id", V3)
def test_checkers_are_silent_and_the_spaces_are_v2s(env_id):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env, wrapped = gym.make(env_id).unwrapped, gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env)
        sb3_check_env(wrapped, warn=True)
    v2 = gym.make(env_id.replace("-v3", "-v2"))
    assert env.observation_space == v2.observation_space
    assert env.action_space == v2.action_space
    assert ENV_VERSIONS[env_id] == 3
    assert env.settings.tracking_cost == "absolute" and env.settings.action_mode == "correction"
    assert v2.unwrapped.settings.tracking_cost == "relative_squared"


@pytest.mark.parametrize("env_id", V3)
def test_v3_runs_the_v2_episode_and_scores_the_absolute_speed_error(env_id):
    kw = {"warmup_time": 5.0, "reward_weights": WEIGHTS}
    v2 = gym.make(env_id.replace("-v3", "-v2"), **kw)
    v3 = gym.make(env_id, **kw)
    (o2, i2), (o3, i3) = (
        v2.reset(seed=5, options={"regime": "stick_slip"}),
        v3.reset(seed=5, options={"regime": "stick_slip"}),
    )
    np.testing.assert_array_equal(o2, o3)
    target = float(i3["target_speed"])
    assert target == i2["target_speed"] and target > 1.0  # where the two forms differ
    rng = np.random.default_rng(1)
    largest = 0.0
    for _ in range(60):
        a = rng.uniform(-1, 1, size=1).astype(np.float32)
        s2, s3 = v2.step(a), v3.step(a)
        np.testing.assert_array_equal(s2[0], s3[0])  # same episode
        r2, r3 = s2[4]["rewards"], s3[4]["rewards"]
        for term in ("stick", "oscillation", "effort"):
            assert r3[term] == r2[term]
        x3 = v3.unwrapped.last_step_samples()["lower_speed"]
        assert r3["tracking"] == pytest.approx(np.mean(np.abs(x3 - target)), rel=1e-12)
        assert r2["tracking"] == pytest.approx(np.mean(((x3 - target) / target) ** 2), rel=1e-12)
        assert s3[1] == pytest.approx(-sum(WEIGHTS[k] * r3[k] for k in WEIGHTS), rel=1e-12)
        largest = max(largest, r3["tracking"])
    assert largest > 0.1  # the stick-slip episode tests errors well away from zero


def test_below_one_rad_per_s_v3_is_the_root_of_v2_per_sample():
    """Under 1 rad/s v2 divides by 1 rad/s too: per sample v3 scores |e| where v2 scores e^2."""
    terms = {}
    for env_id in ("DrillString-v2", "DrillString-v3"):
        env = gym.make(env_id, start="equilibrium", warmup_time=0.0)
        _, info = env.reset(seed=0, options={"nominal_voltage": 0.3})
        target = float(info["target_speed"])
        assert 0.0 < target < 1.0
        for _ in range(20):  # 1 s at 1 V above the equilibrium's voltage
            _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
        e = env.unwrapped.last_step_samples()["lower_speed"] - target
        terms[env_id] = (info["rewards"]["tracking"], e)
    (t2, e2), (t3, e3) = terms["DrillString-v2"], terms["DrillString-v3"]
    np.testing.assert_array_equal(e2, e3)
    assert 0.01 < np.max(np.abs(e3)) < 1.0
    assert t2 == pytest.approx(np.mean(e2**2), rel=1e-12)
    assert t3 == pytest.approx(np.mean(np.abs(e3)), rel=1e-12)


@pytest.mark.parametrize("bad", ["absolute_squared", "", 1, None])
def test_tracking_cost_is_checked(bad):
    with pytest.raises(
        ValueError, match=r"tracking_cost: .* is not one of \['relative_squared', 'absolute'\]"
    ):
        gym.make("DrillString-v2", tracking_cost=bad)
    assert TRACKING_COSTS == ("relative_squared", "absolute")
