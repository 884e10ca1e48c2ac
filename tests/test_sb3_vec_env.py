"""The SB3 VecEnv over the native batched env equals SB3's DummyVecEnv of single envs."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack, VecMonitor, VecNormalize

import drill_env
from drill_env.envs import ENV_IDS, MAX_EPISODE_STEPS
from drill_env.envs.sb3 import DrillStringSB3VecEnv, sb3_vec_env

ALL_IDS = sorted(ENV_IDS)  # DrillString-v1 is covered once registered
N = 4


def make_pair(env_id, n=N, seed=0, **kwargs):
    """The adapter and the DummyVecEnv of single envs it replaces, seeded alike."""
    fast = sb3_vec_env(env_id, n, seed=seed, **kwargs)
    dummy = DummyVecEnv([lambda: gym.make(env_id, **kwargs) for _ in range(n)])
    dummy.seed(seed)
    return fast, dummy


def assert_same(a, b, path=""):
    """Exact equality of observations, rewards, dones and infos (nested dicts, lists, arrays,
    Python scalars of the same type)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (path, sorted(set(a) ^ set(b)))
        for k in a:
            assert_same(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{path}[{k}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.shape == b.shape and a.dtype == b.dtype, (path, a, b)
        assert np.array_equal(a, b), (path, a, b)
    else:
        assert type(a) is type(b) and a == b, (path, a, b)


def reset_both(fast, dummy):
    assert_same(fast.reset(), dummy.reset())
    assert_same(fast.reset_infos, dummy.reset_infos)


def step_both(fast, dummy, actions):
    out = fast.step(actions)
    assert_same(out, dummy.step(actions))
    assert_same(fast.reset_infos, dummy.reset_infos)
    return out


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_equals_dummy_vec_env_across_explicit_reset_and_autoreset(env_id):
    fast, dummy = make_pair(env_id, seed=11)
    assert isinstance(fast, DrillStringSB3VecEnv)
    assert fast.num_envs == N
    assert fast.observation_space == dummy.observation_space
    assert fast.action_space == dummy.action_space
    reset_both(fast, dummy)  # seeds 11..14
    rng = np.random.default_rng(5)
    explicit = 150
    ends = []
    for k in range(explicit + MAX_EPISODE_STEPS + 20):
        if k == explicit:  # SB3 calls reset() at every learn(): new episodes mid-way, unseeded
            reset_both(fast, dummy)
        a = rng.uniform(-1.0, 1.0, size=(N, 1)).astype(np.float32)
        _, _, dones, infos = step_both(fast, dummy, a)
        for i in np.flatnonzero(dones):
            ends.append((k, int(i)))
            assert infos[i]["TimeLimit.truncated"] is True
            assert infos[i]["terminal_observation"].shape == fast.observation_space.shape
        assert not any(infos[i]["TimeLimit.truncated"] for i in np.flatnonzero(~dones))
    # every episode started by the explicit reset is truncated after MAX_EPISODE_STEPS steps
    assert ends == [(explicit + MAX_EPISODE_STEPS - 1, i) for i in range(N)]
    fast.close()
    dummy.close()


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_equals_dummy_vec_env_with_seeds_options_and_short_episodes(env_id):
    kw = {"max_episode_steps": 25, "domain_randomization": True}
    fast, dummy = make_pair(env_id, seed=2, **kw)
    reset_both(fast, dummy)
    rng = np.random.default_rng(9)
    n_done = 0
    for k in range(90):
        if k == 30:  # per-env options and new seeds, used by the next reset only
            opts = [{"regime": "limit_cycle"}, {}, {"nominal_voltage": 3.0}, {"regime": "limit_cycle"}]
            fast.set_options(opts)
            dummy.set_options(opts)
            assert fast.seed(40) == dummy.seed(40) == [40, 41, 42, 43]
            reset_both(fast, dummy)
            assert fast.reset_infos[0]["regime"] == "limit_cycle"
            assert fast.reset_infos[2]["nominal_voltage"] == 3.0
            assert fast._seeds == [None] * N and fast._options == [{}] * N
        if k == 50:
            reset_both(fast, dummy)  # again, unseeded: the rigs' generators continue
        a = rng.uniform(-1.0, 1.0, size=(N, 1)).astype(np.float32)
        n_done += int(step_both(fast, dummy, a)[2].sum())
    assert n_done >= 2 * N


@pytest.mark.parametrize("wrapper", ["VecNormalize", "VecMonitor", "VecFrameStack"])
def test_sb3_wrappers(wrapper):
    def wrap(venv):
        if wrapper == "VecNormalize":
            return VecNormalize(venv, gamma=0.99)
        if wrapper == "VecMonitor":
            return VecMonitor(venv)
        return VecFrameStack(venv, n_stack=3)

    fast, dummy = make_pair("DrillString-v0", seed=4, max_episode_steps=20)
    wf, wd = wrap(fast), wrap(dummy)
    assert_same(wf.reset(), wd.reset())
    rng = np.random.default_rng(1)
    episodes = 0
    for _ in range(45):
        a = rng.uniform(-1.0, 1.0, size=(N, 1)).astype(np.float32)
        (o1, r1, d1, i1), (o2, r2, d2, i2) = wf.step(a), wd.step(a)
        assert_same((o1, r1, d1), (o2, r2, d2))
        for x, y in zip(i1, i2, strict=True):
            if "episode" in x:  # VecMonitor: the episode's return and length (its "t" is a wall time)
                episodes += 1
                assert (x["episode"]["r"], x["episode"]["l"]) == (y["episode"]["r"], y["episode"]["l"])
                x, y = dict(x), dict(y)
                del x["episode"], y["episode"]
            assert_same(x, y)
    if wrapper == "VecMonitor":
        assert episodes == 2 * N
    if wrapper == "VecNormalize":
        assert_same(wf.get_original_obs(), wd.get_original_obs())
        assert_same(wf.get_original_reward(), wd.get_original_reward())


def test_ppo_learns_on_the_adapter():
    from stable_baselines3 import PPO

    venv = drill_env.sb3_vec_env("DrillString-v0", n_envs=2, seed=0)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=2, device="cpu", seed=0)
    model.learn(256)
    assert model.num_timesteps == 256


def test_attributes_methods_and_errors():
    venv = sb3_vec_env("DrillString-v0", 3, seed=1)
    venv.reset()
    assert venv.get_attr("control_dt") == [0.05] * 3
    assert venv.get_attr("render_mode", indices=[0, 2]) == [None, None]
    assert venv.has_attr("max_episode_steps") and not venv.has_attr("no_such_attribute")
    with pytest.raises(AttributeError, match="no_such_attribute"):
        venv.get_attr("no_such_attribute")
    single = gym.make("DrillString-v0")
    single.reset(seed=2)
    assert venv.get_attr("operating_point", indices=1) == [single.unwrapped.operating_point]
    venv.set_attr("some_flag", 7)
    assert venv.get_attr("some_flag") == [7] * 3
    with pytest.raises(NotImplementedError, match="set_attr.*share"):
        venv.set_attr("some_flag", 8, indices=[0])
    with pytest.raises(NotImplementedError, match="env_method\\('reset'\\)"):
        venv.env_method("reset")
    assert venv.env_is_wrapped(gym.wrappers.TimeLimit) == [False] * 3
    with pytest.raises(NotImplementedError, match="render"):
        venv.render()
    with pytest.raises(NotImplementedError, match="render"):
        venv.get_images()
    with pytest.raises(RuntimeError, match="step_async"):
        venv.step_wait()


@pytest.mark.parametrize("bad", [0, -2, 2.0, True, "4", None])
def test_bad_n_envs(bad):
    with pytest.raises(ValueError, match="n_envs"):
        sb3_vec_env("DrillString-v0", bad)


def test_env_kwargs_are_validated_by_the_env():
    with pytest.raises(ValueError, match="control_dt"):
        sb3_vec_env("DrillString-v0", 2, control_dt=-1.0)
    with pytest.raises(ValueError, match="max_episode_steps"):
        sb3_vec_env("DrillString-v0", 2, max_episode_steps=0)
    with pytest.raises(ValueError, match="autoreset_mode"):
        sb3_vec_env("DrillString-v0", 2, autoreset_mode="NextStep")
    with pytest.raises(ValueError, match="seed"):
        sb3_vec_env("DrillString-v0", 2, seed=1.5)
    with pytest.raises(ValueError, match="no native vector env"):
        sb3_vec_env("Pendulum-v1", 2)
    venv = sb3_vec_env("DrillString-v0", 2)
    venv.set_options({"target_speed": -1.0})
    with pytest.raises(ValueError, match="target_speed"):
        venv.reset()


def test_import_drill_env_does_not_import_sb3():
    code = (
        "import sys, drill_env; assert 'stable_baselines3' not in sys.modules; "
        "f = drill_env.sb3_vec_env; assert 'stable_baselines3' in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
