"""Policy files are code: loading one from outside results/agents/ warns before anything in
it is unpickled; the committed policies load silently."""

from __future__ import annotations

import base64
import json
import shutil
import warnings
import zipfile

import gymnasium as gym
import numpy as np
import pytest

from drill_env.agents.learning.rl import (
    COMMITTED_POLICY_DIR,
    UntrustedPolicyWarning,
    load_policy,
    untrusted_policy_note,
)
from drill_env.agents.registry import build_controller, default_agents_dir, policy_path
from drill_env.envs.vector import DrillStringVectorEnv


def untrusted_warnings(record) -> list[warnings.WarningMessage]:
    return [w for w in record if issubclass(w.category, UntrustedPolicyWarning)]


def test_the_committed_directory_is_the_registrys_default():
    assert COMMITTED_POLICY_DIR.resolve() == default_agents_dir().resolve()


def test_committed_policy_loads_without_a_warning():
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        load_policy(policy_path("ppo_lqi_clone", "brake"))
    assert untrusted_warnings(record) == []


def test_a_copy_elsewhere_warns_and_still_loads_the_same_policy(tmp_path):
    committed = policy_path("ppo_lqi_clone", "brake")
    copy = tmp_path / "ppo" / "policy.zip"
    copy.parent.mkdir()
    shutil.copy(committed, copy)
    with pytest.warns(UntrustedPolicyWarning, match=r"not one of the committed policies.*arbitrary code"):
        policy = load_policy(copy, algo="ppo")
    assert str(copy) in untrusted_policy_note(copy)
    obs = DrillStringVectorEnv(num_envs=4, observation_version=1).reset(seed=3)[0]
    np.testing.assert_array_equal(policy.predict(obs)[0], load_policy(committed, algo="ppo").predict(obs)[0])
    with warnings.catch_warnings(record=True) as record:  # the caller vouches for it
        warnings.simplefilter("always")
        load_policy(copy, algo="ppo", trusted=True)
    assert untrusted_warnings(record) == []


def test_a_link_out_of_the_committed_directory_is_not_trusted(tmp_path):
    link = tmp_path / "policy.zip"
    link.symlink_to(policy_path("sac_robust", "brake"))
    assert untrusted_policy_note(link) is None  # it resolves to the committed file
    outside = tmp_path / "elsewhere.zip"
    shutil.copy(policy_path("sac_robust", "brake"), outside)
    assert untrusted_policy_note(outside) is not None
    # a path that names results/agents/ but leaves it with ..
    sneaky = COMMITTED_POLICY_DIR / ".." / ".." / "outside.zip"
    assert untrusted_policy_note(sneaky) is not None


def test_benchmark_controllers_from_another_agents_dir_warn(tmp_path):
    shutil.copytree(policy_path("ppo_lqi_clone", "brake").parent, tmp_path / "ppo_lqi_clone")
    env = gym.make("DrillString-v1")
    with pytest.warns(UntrustedPolicyWarning, match=str(tmp_path)):
        build_controller("ppo_lqi_clone", env, "brake", agents_dir=tmp_path)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        build_controller("ppo_lqi_clone", env, "brake")  # the committed one
    assert untrusted_warnings(record) == []


def test_the_warning_comes_before_any_unpickling(tmp_path):
    # A policy whose stored observation space is a pickle that creates a file when loaded:
    # what a malicious .zip can do. Turned into an error, the warning stops the load first.
    marker = tmp_path / "pwned"

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    import cloudpickle

    evil = tmp_path / "policy.zip"
    with zipfile.ZipFile(policy_path("ppo_lqi_clone", "brake")) as src, zipfile.ZipFile(evil, "w") as dst:
        for item in src.infolist():
            content = src.read(item.filename)
            if item.filename == "data":
                data = json.loads(content)
                data["observation_space"][":serialized:"] = base64.b64encode(
                    cloudpickle.dumps(Payload())
                ).decode()
                content = json.dumps(data).encode()
            dst.writestr(item, content)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UntrustedPolicyWarning)
        with pytest.raises(UntrustedPolicyWarning):
            load_policy(evil, algo="ppo")
    assert not marker.exists()
    # let through, loading runs the payload: this is why the warning exists
    with pytest.warns(UntrustedPolicyWarning), pytest.raises(Exception):  # noqa: B017
        load_policy(evil, algo="ppo")
    assert marker.exists()
