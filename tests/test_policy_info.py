"""A policy file says what it was trained on: the record inside the zip is what ``load_policy``,
the benchmark and sim-to-real read; a file with no record and no config beside it is refused;
``upgrade-policies`` adds the record to a former file and leaves its actions as they were."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from drill_env.agents.learning.policy_info import (
    POLICY_INFO_MEMBER,
    policy_training_record,
    read_policy_info,
)
from drill_env.agents.learning.rl import (
    load_policy,
    policy_observation_version,
    upgrade_policy_file,
)
from drill_env.cli import app
from drill_env.envs import ENV_VERSIONS

ROOT = Path(__file__).resolve().parent.parent
AGENTS = ROOT / "results" / "agents"
COMMITTED = sorted(p.relative_to(AGENTS).as_posix() for p in AGENTS.glob("**/policy.zip"))


def _without_record(src: Path, dst: Path) -> None:
    """``src`` as a policy file saved before policies carried their record."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for info in zin.infolist():
            if info.filename != POLICY_INFO_MEMBER:
                zout.writestr(info, zin.read(info.filename))


def _observations(space, n: int = 16) -> np.ndarray:
    rng = np.random.default_rng(7)
    low, high = np.clip(space.low, -3, 3), np.clip(space.high, -3, 3)
    return rng.uniform(low, high, size=(n, *space.shape)).astype(np.float32)


@pytest.mark.parametrize("relative", COMMITTED)
def test_each_committed_policy_carries_its_record_and_acts_as_before_its_conversion(relative, tmp_path):
    committed = AGENTS / relative
    config = yaml.safe_load((committed.parent / "config.yaml").read_text())
    info = read_policy_info(committed)
    assert info is not None, f"{relative} carries no {POLICY_INFO_MEMBER}"
    assert info["env_id"] == config["env_id"] and info["algo"] == config["algo"]
    assert info["env_kwargs"] == json.loads(json.dumps(config.get("env_kwargs") or {}))
    assert info["observation_version"] == ENV_VERSIONS[config["env_id"]]
    assert info["training_config"].get("residual") == config.get("residual")
    # the file as it was before the conversion: no record, its config.yaml beside it
    former = tmp_path / Path(relative).parent / "policy.zip"
    _without_record(committed, former)
    shutil.copy(committed.parent / "config.yaml", former.parent / "config.yaml")
    shutil.copy(committed.parent / "training_summary.json", former.parent / "training_summary.json")
    assert read_policy_info(former) is None
    before = load_policy(former, trusted=True)
    obs = _observations(before.observation_space)
    actions_before = before.predict(obs)[0]
    assert upgrade_policy_file(former, trusted=True) == [POLICY_INFO_MEMBER]
    # the conversion is the committed file, byte for byte, and it is idempotent
    assert former.read_bytes() == committed.read_bytes()
    assert upgrade_policy_file(former, trusted=True) == []
    (former.parent / "config.yaml").unlink()  # the record alone is enough now
    (former.parent / "training_summary.json").unlink()
    after = load_policy(former, trusted=True)
    np.testing.assert_array_equal(after.predict(obs)[0], actions_before)  # exactly
    np.testing.assert_array_equal(load_policy(committed).predict(obs)[0], actions_before)
    assert policy_observation_version(former) == info["observation_version"]


def test_a_policy_with_no_record_and_no_config_is_refused_naming_what_is_missing(tmp_path):
    # a v3 policy (a correction around the nominal voltage) must never run as v1
    lone = tmp_path / "ppo" / "policy.zip"
    _without_record(AGENTS / "ppo" / "policy.zip", lone)
    missing = r"does not say what it was trained on \(env_id, env_kwargs, observation_version\)"
    for read in (
        lambda: load_policy(lone, trusted=True),
        lambda: load_policy(lone, algo="ppo", trusted=True),
        lambda: policy_observation_version(lone),
        lambda: policy_training_record(lone),
        lambda: upgrade_policy_file(lone, trusted=True),
    ):
        with pytest.raises(ValueError, match=missing) as exc:
            read()
        assert "\n" not in str(exc.value)
    # the benchmark: one line, exit 2, nothing run
    res = CliRunner().invoke(
        app,
        [
            "benchmark",
            "--quick",
            "--controllers",
            "ppo",
            "--preset",
            "brake",
            "--agents-dir",
            str(tmp_path),
            "--trust-policies",
            "--out",
            str(tmp_path / "bench"),
        ],
    )
    assert res.exit_code == 2, res.output
    assert "does not say what it was trained on" in res.output and "Traceback" not in res.output


def test_a_lone_policy_file_with_its_record_runs_on_its_own_version(tmp_path):
    # the zip alone, no config.yaml, no summary: everything is read from inside it
    lone = tmp_path / "ppo" / "policy.zip"
    lone.parent.mkdir()
    shutil.copy(AGENTS / "ppo" / "policy.zip", lone)
    assert policy_observation_version(lone) == 3
    from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env
    from drill_env.agents.registry import build_controller, observation_version

    assert observation_version("ppo", "brake", tmp_path) == 3
    env = make_env("brake", EpisodeSettings(), 3)
    ctrl = build_controller("ppo", env, "brake", agents_dir=tmp_path, trusted=True)  # a copy made here
    # the benchmark's run of it at 1 V: suppressed (a v1 reading would apply 0.13 V: suppression 0)
    m = evaluate(ctrl, "brake", 1.0, 0, EpisodeSettings(), env=env)
    assert m.suppression > 0.95 and not m.stalled
    env.close()
    # a stated algorithm other than the file's is an error
    with pytest.raises(ValueError, match=r"algo: 'sac' given, but .* was trained with 'ppo'"):
        load_policy(lone, algo="sac", trusted=True)


def test_a_policy_of_the_other_rig_is_refused(tmp_path):
    from drill_env.agents.evaluation.episodes import EpisodeSettings, make_env
    from drill_env.agents.registry import build_controller

    folder = tmp_path / "ppo_no_brake"
    folder.mkdir()
    shutil.copy(AGENTS / "ppo" / "policy.zip", folder / "policy.zip")  # trained on the braked rig
    env = make_env("no_brake", EpisodeSettings(), 3)
    with pytest.raises(
        ValueError, match=r"was trained on DrillString-v3 \(preset 'brake'\), not on preset 'no_brake'"
    ):
        build_controller("ppo", env, "no_brake", agents_dir=tmp_path, trusted=True)
    env.close()


def test_a_malformed_record_is_named(tmp_path):
    bad = tmp_path / "policy.zip"
    shutil.copy(AGENTS / "ppo" / "policy.zip", bad)
    from drill_env.agents.learning.policy_info import rewrite_policy_zip

    rewrite_policy_zip(bad, replace={POLICY_INFO_MEMBER: b'{"format": 1, "algo": "ppo"}'})
    with pytest.raises(ValueError, match=r"drill_env\.json lacks env_id, env_kwargs, observation_version"):
        load_policy(bad, trusted=True)
