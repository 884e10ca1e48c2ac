"""Properties of the environments on random actions, seeds and reset options, and the edges of
their Gymnasium API (seeds, actions and reset masks a user may pass by mistake).

For every registered id and for the native vector env: whatever the actions (inside the
box, far outside it, integers, scalars, arrays of any size-1 shape) and the reset options
(an operating point by regime, target speed or nominal voltage, any start), the env never
fails with anything but a ValueError naming the bad field; observations are finite float32
inside the observation space; rewards are finite and <= 0; the same seed, options and
actions give the same rollout bit for bit; and the native vector env equals Gymnasium's
SyncVectorEnv of single envs under random masked resets, autoresets and seeds.

The examples come from the hypothesis profile of ``conftest.py``.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode
from hypothesis import given, settings
from hypothesis import strategies as st

import drill_env  # noqa: F401  (registers the envs)
from drill_env.envs import ENV_IDS
from drill_env.envs.config import START_STATES
from drill_env.envs.task import REGIMES, VOLTAGE_LIMIT
from drill_env.envs.vector import DrillStringVectorEnv

IDS = sorted(ENV_IDS)
_ENVS: dict[tuple[str, int], gym.Env] = {}


def env_of(env_id: str, copy: int = 0) -> gym.Env:
    """One env per id (and copy), made once: making one computes the operating regimes."""
    key = (env_id, copy)
    if key not in _ENVS:
        _ENVS[key] = gym.make(env_id, disable_env_checker=True)
    return _ENVS[key]


# -- strategies -------------------------------------------------------------------------------

# actions inside the action space [-1, 1], its ends included (the env refuses any other)
numbers = st.floats(-1.0, 1.0, allow_nan=False) | st.sampled_from([0.0, -1.0, 1.0])


@st.composite
def actions(draw):
    """A valid action in one of the forms a user may pass: an array of shape (1,) (float32,
    float64 or int) or a list of one number (any other shape is refused, see test_env)."""
    value = draw(numbers | st.integers(-1, 1))
    form = draw(st.sampled_from(["f32", "f64", "list"]))
    if form == "f32":
        return np.array([value], dtype=np.float32)
    if form == "f64":
        return np.array([value], dtype=np.float64)
    return [value]


target_speeds = st.floats(-1.0, 20.0, allow_nan=False) | st.just(math.nan)
nominal_voltages = st.floats(-6.0, 6.0, allow_nan=False)


@st.composite
def reset_options(draw):
    """None, or a dict with at most one of regime / target_speed / nominal_voltage (values
    inside and outside their ranges) and maybe a start state."""
    if draw(st.booleans()):
        return None
    options = {}
    which = draw(st.sampled_from(["none", "regime", "target_speed", "nominal_voltage"]))
    if which == "regime":
        options["regime"] = draw(st.sampled_from(REGIMES))
    elif which == "target_speed":
        options["target_speed"] = draw(target_speeds)
    elif which == "nominal_voltage":
        options["nominal_voltage"] = draw(nominal_voltages)
    if draw(st.booleans()):
        options["start"] = draw(st.sampled_from(sorted(START_STATES)))
    return options


def reset_or_refused(env, seed, options):
    """Reset; an option outside its range must be refused with a ValueError naming it."""
    try:
        return env.reset(seed=seed, options=options)
    except ValueError as exc:
        named = [k for k in ("target_speed", "nominal_voltage") if options and k in options]
        assert named and named[0] in str(exc), exc
        return None


def check_obs(space, obs) -> None:
    assert obs.dtype == np.float32
    assert np.all(np.isfinite(obs))
    assert space.contains(obs), (obs, space)


def rollout(env, seed, options, acts):
    """Observations, rewards and applied voltages of a reset and the steps, checked as they come."""
    first = reset_or_refused(env, seed, options)
    if first is None:
        return None
    obs, info = first
    check_obs(env.observation_space, obs)
    out = [obs]
    rewards, volts = [], []
    scale = env.unwrapped.settings.action_to_volts
    # v2: the action is the correction to the episode's nominal voltage
    offset = float(info["nominal_voltage"]) if env.unwrapped.settings.action_offset else 0.0
    for a in acts:
        obs, reward, terminated, truncated, info = env.step(a)
        check_obs(env.observation_space, obs)
        assert math.isfinite(reward) and reward <= 0.0
        assert not terminated and not truncated  # at most 8 steps, far below the time limit
        requested = offset + float(np.asarray(a, dtype=np.float64).reshape(-1)[0]) * scale
        assert info["voltage_requested"] == requested
        assert info["voltage"] == min(max(requested, -VOLTAGE_LIMIT), VOLTAGE_LIMIT)
        assert info["voltage_clipped"] == (abs(requested) > VOLTAGE_LIMIT)
        assert np.all(np.isfinite(info["true_state"]))
        out.append(obs)
        rewards.append(reward)
        volts.append(info["voltage"])
    return np.array(out), np.array(rewards), np.array(volts)


# -- the single env -------------------------------------------------------------------------------


@settings(max_examples=40)  # cheap (~0.1 s each): more than the profile's default
@given(
    env_id=st.sampled_from(IDS),
    seed=st.integers(0, 2**63 - 1),
    options=reset_options(),
    acts=st.lists(actions(), min_size=1, max_size=8),
)
def test_random_actions_and_options_give_valid_reproducible_rollouts(env_id, seed, options, acts):
    check_rollouts(env_id, seed, options, acts)


@pytest.mark.slow
@given(
    env_id=st.sampled_from(IDS),
    seed=st.integers(0, 2**63 - 1),
    options=reset_options(),
    acts=st.lists(actions(), min_size=1, max_size=8),
)
def test_random_actions_and_options_give_valid_reproducible_rollouts_long(env_id, seed, options, acts):
    check_rollouts(env_id, seed, options, acts)


def check_rollouts(env_id, seed, options, acts):
    first = rollout(env_of(env_id), seed, options, acts)
    if first is None:
        return
    # the same seed, options and actions: the same rollout, also on another instance and
    # with the seed given as a NumPy integer
    again = rollout(env_of(env_id, copy=1), np.int64(seed), options, acts)
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("seed", [np.int64(7), np.int32(7), np.uint64(7)], ids=["int64", "int32", "uint64"])
def test_numpy_integer_seeds_are_accepted_like_ints(seed):
    env = env_of("DrillString-v1")
    a, info_a = env.reset(seed=seed)
    b, info_b = env.reset(seed=7)
    np.testing.assert_array_equal(a, b)
    assert info_a["nominal_voltage"] == info_b["nominal_voltage"]


@pytest.mark.parametrize("seed", [1.5, 7.0, np.float64(7.0), -1, True, np.bool_(True), "7", [7]])
def test_bad_seeds_are_refused_naming_the_seed(seed):
    env = env_of("DrillString-v0")
    with pytest.raises(ValueError, match=r"^seed: expected an integer >= 0 or None, got"):
        env.reset(seed=seed)


@pytest.mark.parametrize(
    "action",
    [True, False, np.array([True]), "0.5", np.array(["0.5"]), b"0.5", None, 1j, np.array([1 + 0j]), [None]],
    ids=repr,
)
def test_actions_that_are_not_real_numbers_are_refused(action):
    env, twin = env_of("DrillString-v0"), env_of("DrillString-v0", copy=1)
    env.reset(seed=0)
    twin.reset(seed=0)
    with pytest.raises(ValueError, match=r"^action: expected real numbers"):
        env.step(action)
    # nothing was simulated: the next step is the twin's first
    np.testing.assert_array_equal(env.step(np.array([0.2]))[0], twin.step(np.array([0.2]))[0])
    assert env.step(np.array([1], dtype=np.int64))[4]["voltage"] == 5.0  # an integer is a number


@pytest.mark.parametrize("speed", [5e-324, 1e-65, 1e-12])
def test_a_target_speed_too_small_for_float_voltages_gets_the_next_voltage_above_uc1(speed):
    # Its nominal voltage rounds to uc1, the end of the allowed (open) voltage range; the
    # request is valid (0 < speed), so it runs at the smallest voltage above uc1.
    env = env_of("DrillString-v1")
    uc1 = env.unwrapped.settings.params.uc1
    obs, info = env.reset(seed=0, options={"target_speed": speed})
    assert info["target_speed"] == speed
    assert uc1 < info["nominal_voltage"] <= uc1 * (1.0 + 1e-9)
    check_obs(env.observation_space, obs)


# -- the native vector env --------------------------------------------------------------------------


@st.composite
def vector_scripts(draw):
    """A vector env configuration, a first seed and a list of operations: steps with random
    actions and masked resets with random options and seeds."""
    n = draw(st.integers(1, 3))
    env_id = draw(st.sampled_from(IDS))
    mode = draw(st.sampled_from([AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP]))
    max_steps = draw(st.integers(1, 4))
    # the first reset seeds every rig (None would draw fresh entropy: no twin to compare with)
    seed = draw(st.integers(0, 2**32) | st.lists(st.integers(0, 2**32), min_size=n, max_size=n))
    ops = []
    for _ in range(draw(st.integers(1, 8))):
        if draw(st.integers(0, 3)) == 0:
            mask = np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)))
            rseed = draw(
                st.none()
                | st.integers(0, 100)
                | st.lists(st.none() | st.integers(0, 100), min_size=n, max_size=n)
            )
            ops.append(("reset", mask, draw(reset_options()), rseed))
        else:
            values = draw(st.lists(numbers, min_size=n, max_size=n))
            ops.append(("step", np.array(values, dtype=np.float32).reshape(n, 1)))
    return n, env_id, mode, max_steps, seed, ops


def vector_pair(n, env_id, mode, max_steps):
    native = gym.make_vec(env_id, num_envs=n, max_episode_steps=max_steps, autoreset_mode=mode)
    sync = gym.make_vec(
        env_id,
        num_envs=n,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": mode},
        max_episode_steps=max_steps,
    )
    return native, sync


def as_numpy_seed(seed):
    """The same seed with NumPy integers where the native env accepts them (SyncVectorEnv
    takes only Python ints)."""
    if isinstance(seed, int):
        return np.int64(seed)
    return [None if s is None else np.uint64(s) for s in seed]


@settings(max_examples=40)
@given(script=vector_scripts())
def test_vector_env_equals_sync_vector_under_random_steps_and_masked_resets(script):
    check_vector_script(script)


@pytest.mark.slow
@given(script=vector_scripts())
def test_vector_env_equals_sync_vector_under_random_steps_and_masked_resets_long(script):
    check_vector_script(script)


def check_vector_script(script):
    n, env_id, mode, max_steps, seed, ops = script
    native, sync = vector_pair(n, env_id, mode, max_steps)
    obs_n, _ = native.reset(seed=as_numpy_seed(seed))
    obs_s, _ = sync.reset(seed=seed)
    np.testing.assert_array_equal(obs_n, obs_s)
    check_obs(native.observation_space, obs_n)
    for op in ops:
        if op[0] == "reset":
            _, mask, options, rseed = op
            outcomes = []
            for env in (native, sync):
                opts = dict(options or {}, reset_mask=mask.copy())
                try:
                    outcomes.append(env.reset(seed=rseed, options=opts))
                except ValueError as exc:
                    outcomes.append(exc)
            if isinstance(outcomes[0], Exception) or isinstance(outcomes[1], Exception):
                # refused by both: an all-False mask, or an option outside its range
                assert all(isinstance(o, ValueError) for o in outcomes), outcomes
                text = str(outcomes[0])
                assert ("reset_mask" in text and not mask.any()) or any(
                    k in text for k in ("target_speed", "nominal_voltage")
                ), text
                return  # SyncVectorEnv may have cleared its autoreset flags before refusing
            (obs_n, _), (obs_s, _) = outcomes
        else:
            obs_n, rew_n, term_n, trunc_n, _ = native.step(op[1])
            obs_s, rew_s, term_s, trunc_s, _ = sync.step(op[1].reshape(n, 1))
            np.testing.assert_array_equal(rew_n, rew_s)
            np.testing.assert_array_equal(term_n, term_s)
            np.testing.assert_array_equal(trunc_n, trunc_s)
            assert np.all(np.isfinite(rew_n)) and np.all(rew_n <= 0.0)
            assert not term_n.any()
        np.testing.assert_array_equal(obs_n, obs_s)
        check_obs(native.observation_space, obs_n)


def test_vector_seeds_numpy_integers_and_arrays_like_ints():
    env = DrillStringVectorEnv(num_envs=3)
    ref, _ = env.reset(seed=11)
    for seed in (
        np.int64(11),
        np.uint32(11),
        [11, 12, 13],
        np.array([11, 12, 13]),
        [np.int64(11), 12, np.int8(13)],
    ):
        obs, _ = env.reset(seed=seed)
        np.testing.assert_array_equal(obs, ref)


@pytest.mark.parametrize(
    ("seed", "match"),
    [
        (1.5, r"^seed: expected an integer >= 0, None or a sequence of 3"),
        (True, r"^seed: expected an integer >= 0, None or a sequence of 3"),
        ("11", r"^seed: expected an integer >= 0, None or a sequence of 3"),
        (-1, r"^seed: expected an integer >= 0 or None"),
        ([1, 2], r"^seed: expected an int, None or 3 seeds, got 2"),
        ([1, 2.5, 3], r"^seed\[1\]: expected an integer >= 0 or None, got 2.5"),
        ([1, 2, -3], r"^seed\[2\]: expected an integer >= 0 or None, got -3"),
        (np.array([1.0, 2.0, 3.0]), r"^seed\[0\]: expected an integer >= 0 or None"),
    ],
)
def test_vector_bad_seeds_are_refused_naming_the_seed(seed, match):
    env = DrillStringVectorEnv(num_envs=3)
    with pytest.raises(ValueError, match=match):
        env.reset(seed=seed)


def test_vector_all_false_reset_mask_is_refused_and_changes_nothing():
    env = DrillStringVectorEnv(num_envs=3)
    with pytest.raises(ValueError, match=r"options\['reset_mask'\]: must select at least one rig"):
        env.reset(seed=1, options={"reset_mask": np.zeros(3, bool)})
    with pytest.raises(ResetNeeded, match="call reset"):  # nothing was reset
        env.step(np.zeros((3, 1), np.float32))
    obs, _ = env.reset(seed=1)
    step = env.step(np.zeros((3, 1), np.float32))
    with pytest.raises(ValueError, match="reset_mask"):
        env.reset(seed=5, options={"reset_mask": np.zeros(3, bool)})
    # the refused reset left the episodes running: the twin without it agrees
    twin = DrillStringVectorEnv(num_envs=3)
    twin.reset(seed=1)
    twin_step = twin.step(np.zeros((3, 1), np.float32))
    np.testing.assert_array_equal(step[0], twin_step[0])
    np.testing.assert_array_equal(env.step(np.full((3, 1), 0.3))[0], twin.step(np.full((3, 1), 0.3))[0])


def test_vector_step_needs_every_rig_reset_once():
    env = DrillStringVectorEnv(num_envs=3)
    env.reset(seed=1, options={"reset_mask": np.array([True, False, True])})
    with pytest.raises(ResetNeeded, match=r"rigs \[1\] were never reset"):
        env.step(np.zeros((3, 1), np.float32))
    env.reset(seed=1, options={"reset_mask": np.array([False, True, False])})
    obs = env.step(np.zeros((3, 1), np.float32))[0]
    check_obs(env.observation_space, obs)
    assert np.all(obs[:, 6] > 0.0)  # every rig has its episode's target speed (no zeros)


@pytest.mark.parametrize(
    "actions",
    [
        True,
        "0.5",
        np.array([True, False, True]),
        np.array(["0.5", "0.1", "0"]),
        [None, 0.1, 0.2],
        1j * np.ones(3),
    ],
    ids=repr,
)
def test_vector_actions_that_are_not_real_numbers_are_refused(actions):
    env = DrillStringVectorEnv(num_envs=3)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"^actions: expected real numbers"):
        env.step(actions)
    env.step(np.array([[1], [0], [-1]]))  # integers are numbers
