"""Policy files are code: loading one from outside results/agents/ is refused before anything
in it is unpickled unless the caller trusts it; the committed policies load silently. Every
command that loads policies refuses untrusted ones without --trust-policies (no terminal)."""

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
    TRUST_ENV_VAR,
    UntrustedPolicyError,
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


def test_a_copy_elsewhere_is_refused_and_loads_the_same_policy_when_trusted(tmp_path, monkeypatch):
    monkeypatch.delenv(TRUST_ENV_VAR, raising=False)
    committed = policy_path("ppo_lqi_clone", "brake")
    copy = tmp_path / "ppo" / "policy.zip"
    copy.parent.mkdir()
    shutil.copy(committed, copy)
    with pytest.raises(
        UntrustedPolicyError, match=r"not one of the committed policies.*arbitrary code.*trusted=True"
    ):
        load_policy(copy, algo="ppo")
    assert str(copy) in untrusted_policy_note(copy)
    with warnings.catch_warnings(record=True) as record:  # the caller vouches for it
        warnings.simplefilter("always")
        policy = load_policy(copy, algo="ppo", trusted=True)
    assert untrusted_warnings(record) == []
    obs = DrillStringVectorEnv(num_envs=4, observation_version=1).reset(seed=3)[0]
    np.testing.assert_array_equal(policy.predict(obs)[0], load_policy(committed, algo="ppo").predict(obs)[0])
    monkeypatch.setenv(TRUST_ENV_VAR, "1")  # what a command sets once its user vouched
    load_policy(copy, algo="ppo")


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


def test_benchmark_controllers_from_another_agents_dir_need_trust(tmp_path, monkeypatch):
    monkeypatch.delenv(TRUST_ENV_VAR, raising=False)
    shutil.copytree(policy_path("ppo_lqi_clone", "brake").parent, tmp_path / "ppo_lqi_clone")
    env = gym.make("DrillString-v1")
    with pytest.raises(UntrustedPolicyError, match=str(tmp_path)):
        build_controller("ppo_lqi_clone", env, "brake", agents_dir=tmp_path)
    build_controller("ppo_lqi_clone", env, "brake", agents_dir=tmp_path, trusted=True)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        build_controller("ppo_lqi_clone", env, "brake")  # the committed one
    assert untrusted_warnings(record) == []


def _evil_policy(folder, marker):
    """A copy of a committed policy whose stored observation space is a pickle that creates
    ``marker`` when loaded: what a malicious .zip can do."""

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    import cloudpickle

    evil = folder / "policy.zip"
    evil.parent.mkdir(parents=True, exist_ok=True)
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
    src_dir = policy_path("ppo_lqi_clone", "brake").parent
    for name in ("config.yaml", "training_summary.json"):
        shutil.copy(src_dir / name, folder / name)
    return evil


def test_the_refusal_comes_before_any_unpickling(tmp_path, monkeypatch):
    monkeypatch.delenv(TRUST_ENV_VAR, raising=False)
    marker = tmp_path / "pwned"
    evil = _evil_policy(tmp_path / "ppo", marker)
    with pytest.raises(UntrustedPolicyError):
        load_policy(evil, algo="ppo")
    assert not marker.exists()
    # let through, loading runs the payload: this is why it is refused
    with pytest.raises(Exception):  # noqa: B017
        load_policy(evil, algo="ppo", trusted=True)
    assert marker.exists()


# -- every command that loads policies: a folder of malicious zips is refused ---------------------


def _evil_agents_dir(root, marker):
    """An agents folder (laid out like results/agents) whose every policy is malicious."""
    for name in ("ppo_robust", "ppo_lqi_clone_no_brake", "ppo_lqi_clone"):
        _evil_policy(root / name, marker)
    return root


def _one_error_line(res) -> str:
    assert res.exit_code == 2, (res.exit_code, res.output)
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    errors = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1, res.output
    return errors[0]


@pytest.mark.parametrize(
    "args",
    [
        ["sim-to-real", "--quick", "--controllers", "lqi,ppo_robust", "--out", "{tmp}/s2r"],
        [
            "train",
            "--algo",
            "ppo",
            "--config",
            "ppo_robust_no_brake",
            "--out",
            "{tmp}/t/ppo",
            "--no-progress",
        ],
        ["benchmark", "--quick", "--preset", "brake", "--controllers", "ppo_robust", "--out", "{tmp}/b"],
        ["upgrade-policies", "{agents}"],
    ],
    ids=lambda a: a[0],
)
def test_every_command_refuses_an_untrusted_policy_folder_without_unpickling(tmp_path, monkeypatch, args):
    from typer.testing import CliRunner

    from drill_env.cli import app

    marker = tmp_path / "pwned"
    agents = _evil_agents_dir(tmp_path / "agents", marker)
    monkeypatch.delenv(TRUST_ENV_VAR, raising=False)
    monkeypatch.setenv("DRILL_ENV_AGENTS_DIR", str(agents))
    argv = [a.format(tmp=tmp_path, agents=agents) for a in args]
    line = _one_error_line(CliRunner().invoke(app, argv))  # CliRunner: no terminal
    assert str(agents) in line and ("--trust" in line), line
    assert not marker.exists()
    assert not any((tmp_path / d).exists() for d in ("s2r", "t", "b"))


def _drop_record(path) -> None:
    """The policy zip ``path`` as saved before policies carried what they were trained on."""
    import zipfile

    from drill_env.agents.learning.policy_info import POLICY_INFO_MEMBER

    with zipfile.ZipFile(path) as zf:
        items = [(i, zf.read(i.filename)) for i in zf.infolist() if i.filename != POLICY_INFO_MEMBER]
    with zipfile.ZipFile(path, "w") as zf:
        for info, content in items:
            zf.writestr(info, content)


def test_policy_cards_and_upgrade_policies_refuse_a_bad_config_yaml_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from drill_env.cli import app

    bad = {
        "deep": "algo: " + "[" * 5000 + "]" * 5000 + "\n",
        "python-tag": "algo: !!python/object/apply:os.system ['touch pwned']\nenv_id: DrillString-v3\n",
        "laughs": "a: &a [x, x, x, x, x, x, x, x, x, x]\n"
        + "".join(
            f"{c}: &{c} [{', '.join(['*' + p] * 10)}]\n" for p, c in zip("abcdefgh", "bcdefghi", strict=True)
        )
        + "algo: *i\n",
        "nul": "algo: ppo\x00\n",
    }
    for kind, text in bad.items():
        folder = tmp_path / kind / "ppo"
        shutil.copytree(policy_path("ppo", "brake").parent, folder)
        (folder / "config.yaml").write_text(text)
        _drop_record(folder / "policy.zip")  # a former file: upgrade-policies reads its config.yaml
        for argv in (
            ["policy-cards", str(folder.parent)],
            ["upgrade-policies", "--trusted", str(folder.parent)],
        ):
            line = _one_error_line(CliRunner().invoke(app, argv))
            assert "config.yaml" in line, (kind, line)
    assert not (tmp_path / "pwned").exists()


def test_upgrade_policies_refuses_a_zip_bomb_even_when_trusted(tmp_path):
    from typer.testing import CliRunner

    from drill_env.agents.learning.rl import MAX_POLICY_INFLATED_BYTES, upgrade_policy_file
    from drill_env.cli import app

    folder = tmp_path / "ppo"
    shutil.copytree(policy_path("ppo", "brake").parent, folder)
    bomb = folder / "policy.zip"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        with zf.open("data", "w", force_zip64=True) as f:
            chunk = b"\0" * (1 << 20)
            for _ in range(MAX_POLICY_INFLATED_BYTES // len(chunk) + 1):
                f.write(chunk)
    before = bomb.read_bytes()
    line = _one_error_line(CliRunner().invoke(app, ["upgrade-policies", "--trusted", str(tmp_path)]))
    assert "inflates to 65 MiB; allowed: at most 64 MiB" in line
    with pytest.raises(ValueError, match="inflates"):
        upgrade_policy_file(bomb, trusted=True)
    assert bomb.read_bytes() == before
