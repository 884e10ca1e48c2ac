"""rl-zoo3 fits: the shipped hyperparameter files (``configs/agents/rl_zoo3/``) train through
``python -m rl_zoo3.train`` and match the project's own training configs."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from doc_sources import doc_sources

import drill_env  # noqa: F401  (registers the environments)
from drill_env.agents.learning.rl import load_config
from drill_env.envs import ENV_IDS, ENV_VERSIONS

# Looked up, not imported: importing rl_zoo3 replaces gymnasium's TimeLimit for the whole
# process (rl_zoo3.gym_patches), which would change every later test's environments.
for _module in ("rl_zoo3", "sb3_contrib"):
    if importlib.util.find_spec(_module) is None:
        pytest.skip(f"{_module} is not installed (pip install -e '.[zoo]')", allow_module_level=True)

ROOT = Path(__file__).resolve().parent.parent
ZOO = ROOT / "configs" / "agents" / "rl_zoo3"
FILES = sorted(ZOO.glob("*.yml"))
# the files of the shipped from-scratch recipes (PPO on v3, SAC on v2) and the others (v1)
SHIPPED = {"ppo": 3, "sac": 2}


def ids_of(version: int) -> list[str]:
    return sorted(i for i in ENV_IDS if ENV_VERSIONS[i] == version)


def zoo_train(tmp_path: Path, algo: str, steps: int, *params: str) -> Path:
    env_id = f"DrillString-v{SHIPPED.get(algo, 1)}"
    cmd = [
        sys.executable,
        "-m",
        "rl_zoo3.train",
        "--algo",
        algo,
        "--env",
        env_id,
        "--gym-packages",
        "drill_env",
        "-conf",
        str(ZOO / f"{algo}.yml"),
        "-n",
        str(steps),
        "--log-folder",
        str(tmp_path / "logs"),
        "--seed",
        "0",
        "--eval-freq",
        "-1",
    ]
    if params:
        cmd += ["-params", *params]
    res = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    models = list((tmp_path / "logs" / algo).glob(f"{env_id}_*/{env_id}.zip"))
    assert len(models) == 1, res.stdout[-2000:]
    return models[0]


def test_every_file_covers_its_ids_with_known_algorithms():
    assert {f.stem for f in FILES} == {"ppo", "sac", "tqc", "ppo_lstm"}
    for f in FILES:
        data = yaml.safe_load(f.read_text())
        assert sorted(data) == ids_of(SHIPPED.get(f.stem, 1)), f
        for env_id, hp in data.items():
            gym.spec(env_id)  # registered by drill_env
            assert hp["policy"] in ("MlpPolicy", "MlpLstmPolicy")
            assert hp["n_timesteps"] > 0 and hp["n_envs"] >= 1


@pytest.mark.parametrize("algo", SHIPPED)
def test_zoo_files_mirror_the_training_configs(algo):
    # the same hyperparameters as the shipped drill-env train configs: ppo.yml
    # configs/agents/ppo[_no_brake].yaml, sac.yml configs/agents/sac[_no_brake].yaml
    zoo = yaml.safe_load((ZOO / f"{algo}.yml").read_text())
    recipe = algo
    header = (ZOO / f"{algo}.yml").read_text().split("\nDrillString")[0]
    assert f"configs/agents/{recipe}.yaml" in header
    for env_id, hp in zoo.items():
        name = recipe if ENV_IDS[env_id] == "brake" else f"{recipe}_{ENV_IDS[env_id]}"
        cfg = load_config(ROOT / "configs" / "agents" / f"{name}.yaml")
        assert cfg.env_id == env_id
        assert hp["n_envs"] == cfg.n_envs and hp["n_timesteps"] == cfg.total_timesteps
        assert hp.get("env_kwargs", {}) == cfg.env_kwargs
        ours = dict(cfg.hyperparameters)
        policy_kwargs = ours.pop("policy_kwargs")
        assert eval(hp["policy_kwargs"], {"dict": dict}) == policy_kwargs  # noqa: S307 (rl-zoo3's own format)
        for key, value in ours.items():
            assert hp[key] == value, key
        assert ("normalize" in hp) == cfg.normalize_reward


@pytest.mark.slow
def test_rl_zoo3_trains_ppo_with_the_shipped_file(tmp_path):
    # the command: python -m rl_zoo3.train --algo ppo --env DrillString-v3
    #   --gym-packages drill_env -conf configs/agents/rl_zoo3/ppo.yml -n 5000
    path = zoo_train(tmp_path, "ppo", 5000)
    with zipfile.ZipFile(path) as zf:
        assert "policy.pth" in zf.namelist()
    from stable_baselines3 import PPO

    # the schedules are rl-zoo3 objects: unpickling them would import rl_zoo3 (and its
    # process-wide TimeLimit patch) into the test process; inference does not need them
    schedules = {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.2}
    model = PPO.load(str(path), device="cpu", custom_objects=schedules)
    assert "rl_zoo3" not in sys.modules
    env = gym.make("DrillString-v3")
    obs, _ = env.reset(seed=0)
    assert model.observation_space.shape == obs.shape == (13,)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action)
    assert np.isfinite(env.step(action)[1])


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["sac", "tqc", "ppo_lstm"])
def test_rl_zoo3_trains_the_other_algorithms(tmp_path, algo):
    params = (
        ("learning_starts:200", "n_envs:2", "batch_size:64")
        if algo in ("sac", "tqc")
        else ("n_envs:4", "batch_size:128")
    )
    path = zoo_train(tmp_path, algo, 1000, *params)
    assert path.stat().st_size > 0


def test_the_documented_rl_zoo3_commands_name_an_env_their_file_has():
    import re
    import shlex

    commands = [
        line
        for page in doc_sources(readme=False)
        for line in page.read_text().splitlines()
        if line.startswith("python -m rl_zoo3.train")
    ]
    assert len(commands) >= 4
    for line in commands:
        args = shlex.split(re.sub(r"\s+#.*$", "", line))
        algo, env_id, conf = (args[args.index(flag) + 1] for flag in ("--algo", "--env", "-conf"))
        assert Path(conf).stem == algo, line
        assert env_id in yaml.safe_load((ROOT / conf).read_text()), line
