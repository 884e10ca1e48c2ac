"""The native vector environment equals N single environments, step for step."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from drill_env.envs._core import INTEGRAL_TERM_CAP
from drill_env.envs.config import OBSERVATION_NAMES_V1
from drill_env.envs.vector import DrillStringVectorEnv

N = 4


def assert_same(a, b, path=""):
    """Exact equality of nested vector-env outputs (dicts of arrays, object arrays)."""
    if isinstance(a, dict):
        assert set(a) == set(b), (path, sorted(set(a) ^ set(b)))
        for k in a:
            assert_same(a[k], b[k], f"{path}/{k}")
        return
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, (path, a.shape, b.shape, a.dtype, b.dtype)
    if a.dtype == object:
        for x, y in zip(a, b, strict=True):
            if isinstance(x, (dict, np.ndarray)):
                assert_same(x, y, path)
            else:
                assert x == y, (path, x, y)
    else:
        assert np.array_equal(a, b), (path, a, b)


def make_pair(env_id, mode, max_steps, **kwargs):
    native = gym.make_vec(env_id, num_envs=N, max_episode_steps=max_steps, autoreset_mode=mode, **kwargs)
    sync = gym.make_vec(
        env_id,
        num_envs=N,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": mode},
        max_episode_steps=max_steps,
        **kwargs,
    )
    return native, sync


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        ("DrillString-v0", {}),
        (
            "DrillStringNoBrake-v0",
            {"domain_randomization": True, "sensors": {"delay_samples": 3, "angle_noise_std": 2e-4}},
        ),
    ],
)
def test_native_vector_env_equals_sync_vector_of_single_envs(env_id, kwargs, mode):
    native, sync = make_pair(env_id, mode, max_steps=15, warmup_time=5.0, **kwargs)
    assert isinstance(native.unwrapped, DrillStringVectorEnv)
    assert native.metadata["autoreset_mode"] == mode
    assert native.single_observation_space == sync.single_observation_space
    assert native.single_action_space == sync.single_action_space
    o1, i1 = native.reset(seed=21)
    o2, i2 = sync.reset(seed=21)
    assert_same(o1, o2)
    assert_same(i1, i2)
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(40):  # crosses two autoresets of every rig
        a = rng.uniform(-1.0, 1.0, size=(N, 1)).astype(np.float32)
        r1, r2 = native.step(a), sync.step(a)
        for x, y in zip(r1[:4], r2[:4], strict=True):
            assert_same(x, y)
        assert_same(r1[4], r2[4])
        ended += int(np.sum(r1[3]))
    assert ended >= 2 * N
    # reset again without a seed: the generators continue identically
    assert_same(native.reset()[0], sync.reset()[0])


def test_step_is_one_compiled_call_over_all_rigs(monkeypatch):
    from drill_env.envs import _core

    calls = []
    original = _core.batch_step

    def counting(*args):
        calls.append(args[0].shape[0])
        return original(*args)

    monkeypatch.setattr(_core, "batch_step", counting)
    env = gym.make_vec("DrillString-v0", num_envs=8)
    env.reset(seed=0)
    env.step(np.zeros((8, 1), np.float32))
    assert calls == [8]


def test_rewards_and_voltage_limit_in_the_vector_env():
    env = gym.make_vec("DrillString-v0", num_envs=3, normalize_observation=False)
    env.reset(seed=2)
    with pytest.raises(
        ValueError, match=r"^actions\[0\]: 2\.0 is outside the action space: allowed range \[-1, 1\]"
    ):
        env.step(np.array([[2.0], [-7.0], [0.3]], np.float32))
    a = np.array([[1.0], [-1.0], [0.3]], np.float32)
    obs, rew, term, trunc, info = env.step(a)
    assert np.all(np.abs(info["voltage"]) <= 5.0)
    np.testing.assert_array_equal(info["voltage"], [5.0, -5.0, float(np.float32(0.3)) * 5.0])
    np.testing.assert_array_equal(info["voltage_clipped"], [False, False, False])
    np.testing.assert_array_equal(obs[:, 5], np.float32(info["voltage"]))
    w = {"tracking": 1.0, "stick": 1.0, "oscillation": 0.5, "effort": 0.1}
    expected = -sum(w[k] * info["rewards"][k] for k in w)
    np.testing.assert_allclose(rew, expected, rtol=1e-12)
    assert not term.any() and not trunc.any()


def test_the_integral_term_is_the_observed_integral_and_weighs_in_the_reward():
    """On observation version 1 the integral term is the lower_speed_error_integral entry
    in revolutions (the same encoder readings), in the vector env and the single env alike,
    and its weight enters the reward."""
    w = {"tracking": 10.0, "stick": 1.0, "oscillation": 0.5, "effort": 0.1, "integral": 2.0}
    kw = dict(reward_weights=w, normalize_observation=False)
    vec = gym.make_vec("DrillString-v2", num_envs=2, **kw)
    one = gym.make("DrillString-v2", **kw)
    vec.reset(seed=5, options={"regime": "stick_slip"})
    one.reset(seed=5, options={"regime": "stick_slip"})
    k = OBSERVATION_NAMES_V1.index("lower_speed_error_integral")
    largest = 0.0
    for _ in range(60):
        obs, rew, _, _, info = vec.step(np.zeros((2, 1), np.float32))
        o1, r1, _, _, i1 = one.step(np.zeros(1, np.float32))
        observed = np.minimum(np.abs(obs[:, k]) / (2 * np.pi), INTEGRAL_TERM_CAP)
        np.testing.assert_allclose(info["rewards"]["integral"], observed, rtol=1e-6)
        np.testing.assert_allclose(rew, -sum(w[n] * info["rewards"][n] for n in w), rtol=1e-12)
        assert i1["rewards"]["integral"] == pytest.approx(info["rewards"]["integral"][0], rel=1e-12)
        assert r1 == pytest.approx(rew[0], rel=1e-12)
        largest = max(largest, float(info["rewards"]["integral"].max()))
    assert largest > 0.05  # open-loop stick-slip loses angle against the target


def test_the_overdrive_term_and_the_applied_voltage_match_the_single_env():
    """A request beyond +-5 V is limited by the amplifier in the vector env as in the single
    env, and both report the same overdrive term and reward."""
    w = {"tracking": 10.0, "stick": 1.0, "oscillation": 0.5, "effort": 0.1, "overdrive": 1.5}
    vec = gym.make_vec("DrillString-v2", num_envs=2, reward_weights=w)
    one = gym.make("DrillString-v2", reward_weights=w)
    opts = {"nominal_voltage": 4.8}
    vec.reset(seed=7, options=opts)
    one.reset(seed=7, options=opts)
    seen = 0
    for k in range(30):
        a = 0.9 * np.sin(k / 3.0)  # 3 to 6.6 V asked
        _, rew, _, _, info = vec.step(np.array([[a], [a]], np.float32))
        _, r1, _, _, i1 = one.step(np.array([a], np.float32))
        asked = 4.8 + 2.0 * float(np.float32(a))
        np.testing.assert_allclose(info["voltage"], min(asked, 5.0), rtol=1e-6)
        np.testing.assert_array_equal(info["voltage_clipped"], asked > 5.0)
        np.testing.assert_allclose(
            info["rewards"]["overdrive"], max(asked - 5.0, 0.0) / 5.0, rtol=1e-6, atol=1e-9
        )
        assert i1["rewards"]["overdrive"] == pytest.approx(info["rewards"]["overdrive"][0], rel=1e-12)
        assert i1["voltage"] == pytest.approx(info["voltage"][0], rel=1e-12)
        assert r1 == pytest.approx(rew[0], rel=1e-12)
        np.testing.assert_allclose(rew, -sum(w[n] * info["rewards"][n] for n in w), rtol=1e-12)
        seen += asked > 5.0
    assert 5 < seen < 25  # requests on both sides of the limit


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_bad_actions_raise(bad):
    env = gym.make_vec("DrillString-v0", num_envs=2)
    env.reset(seed=0)
    with pytest.raises(
        ValueError, match=r"actions\[1\]: .* outside the action space: allowed range \[-1, 1\], finite"
    ):
        env.step(np.array([[0.0], [bad]], np.float32))
    for shape in ((3, 1), (2,), (1, 2), (2, 1, 1)):
        with pytest.raises(ValueError, match=r"actions: expected shape \(2, 1\), got shape"):
            env.step(np.zeros(shape, np.float32))


def test_the_vector_env_of_four_rigs_takes_only_shape_4_1():
    from drill_env.envs.vector import DrillStringVectorEnv

    env = DrillStringVectorEnv(num_envs=4)
    env.reset(seed=0)
    for shape in ((4,), (1, 4), (2, 2)):
        with pytest.raises(ValueError, match=rf"^actions: expected shape \(4, 1\), got shape \({shape[0]},"):
            env.step(np.zeros(shape, np.float32))
    env.step(np.zeros((4, 1), np.float32))


def test_bad_arguments_and_options_raise():
    with pytest.raises(ValueError, match="num_envs"):
        DrillStringVectorEnv(num_envs=0)
    with pytest.raises(ValueError, match="autoreset_mode"):
        DrillStringVectorEnv(num_envs=2, autoreset_mode="Sometimes")
    with pytest.raises(ValueError, match="render_mode"):
        DrillStringVectorEnv(num_envs=2, render_mode="rgb_array")
    env = DrillStringVectorEnv(num_envs=2)
    with pytest.raises(ValueError, match="target_speed"):
        env.reset(seed=0, options={"target_speed": -1.0})
    with pytest.raises(ValueError, match="reset_mask"):
        env.reset(seed=0, options={"reset_mask": np.array([1, 0])})
    with pytest.raises(ValueError, match="seed"):
        env.reset(seed=[1, 2, 3])


def test_reset_options_seeds_and_mask():
    env = DrillStringVectorEnv(num_envs=3)
    _, info = env.reset(seed=[5, 6, 7], options={"regime": "limit_cycle"})
    assert list(info["regime"]) == ["limit_cycle"] * 3
    single = gym.make("DrillString-v0")
    _, sinfo = single.reset(seed=6, options={"regime": "limit_cycle"})
    assert info["nominal_voltage"][1] == sinfo["nominal_voltage"]
    before = env.step(np.zeros((3, 1), np.float32))[0]
    obs, info = env.reset(options={"reset_mask": np.array([False, True, False]), "nominal_voltage": 3.0})
    np.testing.assert_array_equal(info["_nominal_voltage"], [False, True, False])
    assert info["nominal_voltage"][1] == 3.0
    np.testing.assert_array_equal(obs[[0, 2]], before[[0, 2]])  # untouched rigs keep their state


def test_pickled_vector_env_continues_identically():
    env = gym.make_vec("DrillString-v0", num_envs=3)
    env.reset(seed=1)
    env.step(np.full((3, 1), 0.2, np.float32))
    twin = pickle.loads(pickle.dumps(env))
    for k in range(5):
        a = np.full((3, 1), 0.1 * k, np.float32)
        r1, r2 = env.step(a), twin.step(a)
        for x, y in zip(r1, r2, strict=True):
            assert_same(x, y)


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_explicit_reset_mid_episode_restarts_the_step_count(mode):
    # An explicit reset() (full or masked) starts new episodes: their truncation comes after
    # max_episode_steps steps counted from that reset, as in SyncVectorEnv of single envs.
    max_steps = 12
    native, sync = make_pair("DrillString-v0", mode, max_steps=max_steps, warmup_time=5.0)
    assert_same(native.reset(seed=3)[0], sync.reset(seed=3)[0])
    rng = np.random.default_rng(1)

    def step_both():
        a = rng.uniform(-1.0, 1.0, size=(N, 1)).astype(np.float32)
        r1, r2 = native.step(a), sync.step(a)
        for x, y in zip(r1, r2, strict=True):
            assert_same(x, y)
        return r1[3]

    for _ in range(5):
        assert not step_both().any()
    assert_same(native.reset()[0], sync.reset()[0])  # explicit reset mid-episode
    for k in range(1, max_steps + 1):
        np.testing.assert_array_equal(step_both(), np.full(N, k == max_steps))
    # masked reset mid-episode: only rig 1 restarts its count
    if mode == AutoresetMode.NEXT_STEP:
        step_both()  # the autoreset step
    for _ in range(4):
        assert not step_both().any()
    mask = np.array([False, True, False, False])
    o1, i1 = native.reset(options={"reset_mask": mask.copy()})
    o2, i2 = sync.reset(options={"reset_mask": mask.copy()})
    assert_same(o1, o2)
    assert_same(i1, i2)
    for k in range(5, max_steps + 5):
        trunc = step_both()
        np.testing.assert_array_equal(
            trunc, [k == max_steps, k == max_steps + 4, k == max_steps, k == max_steps]
        )
