"""The trained policy files: stable-baselines3's own load of a residual policy's correction
raises instead of giving a policy that acts without its base; ``upgrade-policies`` rewrites
the stored objects and nothing else; each policy folder's card says how it started."""

from __future__ import annotations

import shutil
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_robust_training import _tiny_robust_config
from typer.testing import CliRunner

from drill_env.agents.learning.cards import describe_policy, policy_card, policy_folders, policy_start
from drill_env.agents.learning.residual import CorrectionOnlyError, ResidualPolicy
from drill_env.agents.learning.rl import (
    is_correction_file,
    load_policy,
    renamed_objects,
    stored_policy_class,
    upgrade_policy_file,
)
from drill_env.cli import app

ROOT = Path(__file__).resolve().parent.parent
AGENTS = ROOT / "results" / "agents"
COMMITTED = sorted(p.relative_to(AGENTS).as_posix() for p in AGENTS.glob("**/policy.zip"))
FORMER = ROOT / "tests" / "data" / "former_package_name" / "ppo_robust"


def _sb3_class(algo: str):
    from stable_baselines3 import PPO, SAC

    return {"ppo": PPO, "sac": SAC}[algo]


def _observations(space, n: int = 32) -> np.ndarray:
    rng = np.random.default_rng(0)
    low, high = np.clip(space.low, -3, 3), np.clip(space.high, -3, 3)
    return rng.uniform(low, high, size=(n, *space.shape)).astype(np.float32)


def _entries(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as zf:
        return {name: zf.read(name) for name in zf.namelist()}


def test_the_committed_policy_files_are_the_benchmarks_and_the_four_v0_ones():
    from drill_env.agents.registry import LEARNED

    # one per learned controller and rig, and the version-0 ppo, sac on both rigs
    assert len(COMMITTED) == 2 * len(LEARNED) + 4 and all(p.endswith("/policy.zip") for p in COMMITTED)


@pytest.mark.parametrize("relative", COMMITTED)
def test_sb3_load_of_a_committed_file_gives_the_whole_controller_or_raises_naming_load_policy(relative):
    path = AGENTS / relative
    config = yaml.safe_load((path.parent / "config.yaml").read_text())
    algo = config["algo"]
    policy = load_policy(path)
    assert not renamed_objects(path)  # every stored object under its present module path
    if config.get("residual"):
        assert isinstance(policy, ResidualPolicy) and is_correction_file(path)
        with pytest.raises(
            CorrectionOnlyError, match=r"drill_env\.agents\.learning\.rl\.load_policy\(path\)"
        ):
            _sb3_class(algo).load(str(path), device="cpu")
        return
    assert not is_correction_file(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing left out, nothing guessed
        model = _sb3_class(algo).load(str(path), device="cpu")
    obs = _observations(model.observation_space)
    ours, _ = policy.predict(obs)
    theirs, _ = model.predict(obs, deterministic=True)
    # the numpy pass of load_policy against SB3's own (float32 rounding)
    np.testing.assert_allclose(ours, theirs, atol=1e-5, rtol=0)


def test_upgrading_a_former_residual_file_changes_its_objects_and_nothing_else(tmp_path):
    folder = tmp_path / "ppo_robust"
    shutil.copytree(FORMER, folder)
    path = folder / "policy.zip"
    assert stored_policy_class(path) == ("stable_baselines3.common.policies", "ActorCriticPolicy")
    before = _entries(path)
    policy = load_policy(path, trusted=True)
    obs = _observations(policy.observation_space, 16)
    actions_before = policy.predict(obs)[0]
    model_before = policy.policy.model
    assert upgrade_policy_file(path, trusted=True) == [
        "learning_rate",
        "lr_schedule",
        "policy_class",
        "drill_env.json",
    ]
    after = _entries(path)
    assert list(after) == [*before, "drill_env.json"]  # the record of what it was trained on added
    assert {name for name in before if before[name] != after[name]} == {"data"}  # weights untouched
    assert stored_policy_class(path) == (
        "drill_env.agents.learning.residual",
        "ResidualCorrectionActorCriticPolicy",
    )
    assert is_correction_file(path) and not renamed_objects(path)
    upgraded = load_policy(path, trusted=True)
    np.testing.assert_array_equal(upgraded.predict(obs)[0], actions_before)  # bit for bit
    model = upgraded.policy.model
    for name, tensor in model.policy.state_dict().items():
        assert np.array_equal(tensor.numpy(), model_before.policy.state_dict()[name].numpy()), name
    for progress in (1.0, 0.3):
        assert model.lr_schedule(progress) == model_before.lr_schedule(progress)
    with pytest.raises(CorrectionOnlyError, match="load_policy"):
        _sb3_class("ppo").load(str(path), device="cpu")
    assert upgrade_policy_file(path, trusted=True) == [] and _entries(path) == after  # up to date: untouched


def test_a_correction_file_without_the_config_of_its_base_is_refused(tmp_path):
    import json

    from drill_env.agents.learning.policy_info import POLICY_INFO_MEMBER, rewrite_policy_zip

    path = tmp_path / "policy.zip"
    shutil.copy(AGENTS / "ppo_robust" / "policy.zip", path)
    info = json.loads(_entries(path)[POLICY_INFO_MEMBER])
    del info["training_config"]["residual"]  # a record that names no base
    rewrite_policy_zip(path, info=info)
    with pytest.raises(
        ValueError, match=r"holds the correction of a residual policy, but its training record"
    ):
        load_policy(path, algo="ppo", trusted=True)


def test_a_residual_policy_is_saved_as_a_correction_that_sb3_refuses_alone(tmp_path):
    cfg = _tiny_robust_config(residual={"base": "lqi", "scale": 0.2})
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(cfg.to_dict()))
    out = tmp_path / "agents" / "ppo_robust"
    res = CliRunner().invoke(
        app,
        [
            "train",
            "--algo",
            "ppo",
            "--config",
            str(tmp_path / "tiny.yaml"),
            "--out",
            str(out),
            "--no-progress",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "policy.md" in res.output
    (tmp_path / "logs").symlink_to(tmp_path / "agents" / "logs" / "ppo_robust")
    for path in (out / "policy.zip", tmp_path / "logs" / "final_policy.zip"):
        assert is_correction_file(path), path
    with pytest.raises(CorrectionOnlyError, match="load_policy"):
        _sb3_class("ppo").load(str(out / "policy.zip"), device="cpu")
    policy = load_policy(out / "policy.zip", trusted=True)
    assert isinstance(policy, ResidualPolicy)
    card = (out / "policy.md").read_text()
    assert (
        card.startswith("# `ppo_robust`: PPO, residual on lqi\n") and "raises `CorrectionOnlyError`" in card
    )


def test_the_cli_upgrades_only_trusted_folders_and_finds_the_committed_ones_up_to_date(tmp_path):
    runner = CliRunner()
    res = runner.invoke(app, ["upgrade-policies", str(AGENTS)])
    assert res.exit_code == 0, res.output
    assert res.output.count(": up to date") == len(COMMITTED)
    shutil.copytree(FORMER, tmp_path / "agents" / "ppo_robust")
    res = runner.invoke(app, ["upgrade-policies", str(tmp_path / "agents")])
    assert res.exit_code == 2 and "not one of the committed policies" in res.output
    res = runner.invoke(app, ["upgrade-policies", str(tmp_path / "agents"), "--trusted"])
    assert res.exit_code == 0 and "rewrote learning_rate, lr_schedule, policy_class" in res.output
    res = runner.invoke(app, ["upgrade-policies", str(tmp_path / "none")])
    assert res.exit_code == 2 and res.output.startswith("error: AGENTS_DIR:")


# -- policy cards ---------------------------------------------------------------------------------


def test_policy_start_names_each_kind_of_start():
    assert policy_start({"algo": "sac"}) == "from scratch"
    assert policy_start({"warm_start": {"controller": "lqi", "steps": 10}}) == "clone of lqi"
    assert policy_start({"warm_start": {"steps": 10}}) == "clone of lqi"  # lqi by default
    assert policy_start({"residual": {"base": "lqi_angle_ff"}}) == "residual on lqi_angle_ff"
    assert (
        policy_start({"residual": {"base": "lqi_angle_ff"}, "warm_start": {"policy": "ppo"}})
        == "residual on lqi_angle_ff, distilled from ppo"
    )


SHIPPED_STARTS = {
    "ppo": "from scratch",
    "ppo_no_brake": "from scratch",
    "sac": "from scratch",
    "sac_no_brake": "from scratch",
    "ppo_lqi_clone": "clone of lqi",
    "ppo_lqi_clone_no_brake": "clone of lqi",
    "ppo_robust": "residual on lqi_angle_ff",
    "ppo_robust_no_brake": "residual on lqi_angle_ff, distilled from ppo_lqi_clone",
    "sac_robust": "residual on lqi_angle_ff",
    "sac_robust_no_brake": "residual on lqi_angle_ff",
    "v0/ppo": "from scratch",
    "v0/ppo_no_brake": "from scratch",
    "v0/sac": "from scratch",
    "v0/sac_no_brake": "from scratch",
}


@pytest.mark.parametrize("name", sorted(SHIPPED_STARTS))
def test_the_committed_cards_are_what_the_code_writes_from_each_folder(name):
    d = describe_policy(AGENTS / name)
    assert d.start == SHIPPED_STARTS[name]
    assert d.config == f"configs/agents/{name}.yaml" and d.folder == f"results/agents/{name}"
    assert (AGENTS / name / "policy.md").read_text() == policy_card(d)
    assert f"--config configs/agents/{name}.yaml --seed 0 --out results/agents/{name}" in policy_card(d)


def test_the_cli_writes_a_card_per_policy_and_the_table(tmp_path):
    agents = tmp_path / "agents"
    for name in ("ppo_lqi_clone", "sac_robust"):
        shutil.copytree(AGENTS / name, agents / name)
        (agents / name / "policy.md").unlink()
    res = CliRunner().invoke(app, ["policy-cards", str(agents)])
    assert res.exit_code == 0, res.output
    assert [p.name for p in policy_folders(agents)] == ["ppo_lqi_clone", "sac_robust"]
    table = (agents / "README.md").read_text()
    rows = [line for line in table.splitlines() if line.startswith("| [")]
    assert rows == [
        "| [`ppo_lqi_clone`](ppo_lqi_clone/policy.md) | PPO | `DrillString-v1` | clone of lqi "
        "| `configs/agents/ppo_lqi_clone.yaml` "
        "| 1 015 808 | -93.9 | yes |",
        "| [`sac_robust`](sac_robust/policy.md) | SAC | `DrillString-v1` | residual on lqi_angle_ff "
        "| `configs/agents/sac_robust.yaml` | 90 000 | -161.0 | no |",
    ]
    card = (agents / "ppo_lqi_clone" / "policy.md").read_text()
    assert "| start | clone of lqi |" in card and f'load_policy("{agents}/ppo_lqi_clone/policy.zip")' in card
    assert "behaviour cloning, 3 rounds of 50 000 env-steps" in card
    res = CliRunner().invoke(app, ["policy-cards", str(tmp_path / "empty")])
    assert res.exit_code == 2 and res.output.startswith("error: AGENTS_DIR:")
