"""Reinforcement learning: a few hundred steps of PPO and SAC training through the command's
code path, the committed policies load and are evaluated, the plateau criterion, configs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env
from drill_env.agents.learning.rl import (
    SB3Policy,
    TrainConfig,
    algo_kwargs,
    load_config,
    load_policy,
    make_train_vec_env,
    observation_names,
    plateau,
    policy_observation_version,
    train,
)
from drill_env.agents.registry import default_agents_dir, policy_path
from drill_env.cli import app

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs" / "agents"
SUMMARY_KEYS = {
    "algo",
    "env_id",
    "seed",
    "total_timesteps",
    "wall_time_s",
    "n_evaluations",
    "final_eval_return",
    "best_eval_return",
    "best_at_timesteps",
    "converged",
    "convergence",
    "reference_returns",
    "config",
}


def small_config(algo: str, steps: int) -> TrainConfig:
    # PPO and SAC from scratch on the v1 rigs (ppo_lqi_clone starts from a clone of the LQI);
    # TQC and CrossQ (sb3-contrib) as their v2 trials
    name = {
        "ppo": "experiments/ppo_from_scratch",
        "sac": "experiments/sac_v1",
        "tqc": "experiments/tqc",
        "crossq": "experiments/crossq",
    }[algo]
    cfg = load_config(CONFIGS / f"{name}.yaml").to_dict()
    cfg.update(total_timesteps=steps, n_envs=2 if algo == "ppo" else 1)
    cfg["evaluation"] = {"every_steps": steps // 2, "episodes_per_regime": 1, "seed": 7}
    cfg["env_kwargs"] = {"warmup_time": 2.0, "warmup_jitter": 0.5}
    if algo == "ppo":
        cfg["hyperparameters"].update(n_steps=64, batch_size=64, n_epochs=2)
    else:
        cfg["hyperparameters"].update(learning_starts=100, buffer_size=1000, batch_size=32)
    return TrainConfig(**cfg)


# tqc and crossq run through the same training loop as sac (the contrib test below trains crossq in
# the default run); their few hundred steps each are in the slow run
@pytest.mark.parametrize(
    ("algo", "steps"),
    [
        ("ppo", 256),
        ("sac", 300),
        pytest.param("tqc", 300, marks=pytest.mark.slow),
        pytest.param("crossq", 300, marks=pytest.mark.slow),
    ],
)
def test_a_few_hundred_steps_of_training(tmp_path, algo, steps):
    cfg = small_config(algo, steps)
    summary = train(cfg, 3, tmp_path / "out", tmp_path / "run", progress_bar=False)
    assert SUMMARY_KEYS <= set(summary)
    assert summary["algo"] == algo and summary["seed"] == 3 and summary["total_timesteps"] >= steps
    assert summary["n_evaluations"] >= 3 and summary["converged"] is False  # too few evaluations
    assert (
        np.isfinite(summary["final_eval_return"])
        and summary["best_eval_return"] >= summary["final_eval_return"]
    )
    out = tmp_path / "out"
    for name in ("policy.zip", "config.yaml", "training_summary.json", "eval.csv", "learning_curve.png"):
        assert (out / name).is_file(), name
    assert json.loads((out / "training_summary.json").read_text())["seed"] == 3
    assert (tmp_path / "run" / "progress.csv").is_file()
    assert any(p.name.startswith("events.out.tfevents") for p in (tmp_path / "run").iterdir())
    policy = load_policy(out / "policy.zip", trusted=True)  # made by this test
    env = make_env("brake", EpisodeSettings(), policy_observation_version(out / "policy.zip"))
    policy.check_env(env)
    a, _ = policy.predict(env.reset(seed=0)[0], deterministic=True)
    assert a.shape == (1,) and -1.0 <= a[0] <= 1.0
    # the numpy actor (PPO, SAC, TQC) or SB3's own predict (CrossQ's batch-renormalised
    # actor, in its evaluation mode) gives the saved model's deterministic action
    obs = np.stack([env.reset(seed=k)[0] for k in range(8)])
    sb3, _ = policy.model.predict(obs, deterministic=True)
    np.testing.assert_allclose(policy.predict(obs, deterministic=True)[0], sb3, atol=1e-5)
    assert (policy._actor is None) == (algo == "crossq")


@pytest.mark.parametrize("name", ["ppo", "sac", "ppo_lqi_clone"])
def test_committed_policy_loads_and_is_evaluated(name):
    algo = name.split("_")[0]
    path = policy_path(name, "brake")
    assert path.parent.parent == default_agents_dir()
    summary = json.loads((path.parent / "training_summary.json").read_text())
    assert SUMMARY_KEYS <= set(summary) and summary["algo"] == algo
    assert summary["total_timesteps"] >= 10_000 and summary["wall_time_s"] > 0
    assert isinstance(summary["converged"], bool)
    cfg = yaml.safe_load((path.parent / "config.yaml").read_text())
    # from scratch: PPO on v3 (the correction action, the absolute tracking term), SAC on v2
    # (the correction action); the LQI clone on v1
    version = {"ppo": 3, "sac": 2, "ppo_lqi_clone": 1}[name]
    assert cfg["algo"] == algo and cfg["env_id"] == f"DrillString-v{version}"
    assert policy_observation_version(path) == version
    assert ("warm_start" in cfg) == (name == "ppo_lqi_clone") and "residual" not in cfg
    policy = load_policy(path)
    assert isinstance(policy, SB3Policy)
    settings = EpisodeSettings(duration=10.0, window=5.0, warmup_time=20.0, warmup_jitter=1.0)
    env = make_env("brake", settings, version)
    policy.check_env(env)
    m = evaluate(policy, "brake", 1.0, 0, settings, name=name, env=env)
    assert m.controller == name and m.sim_status == 0
    assert np.isfinite(m.amplitude) and 0.0 <= m.u_peak_abs <= 5.0
    # the committed policy learnt something: it beats open loop on the Hopf cycle at 1 V
    assert m.suppression > 0.5


def test_contrib_algorithms_train_what_the_config_says_and_refuse_what_they_cannot(tmp_path, monkeypatch):
    import sys

    import torch
    from sb3_contrib import TQC, CrossQ

    from drill_env.agents.learning.rl import _algo_class

    assert _algo_class("tqc") is TQC and _algo_class("crossq") is CrossQ
    cfg = small_config("crossq", 300)
    assert cfg.ignored_observations  # as the shipped SAC recipe: the angle entries
    train(cfg, 0, tmp_path / "out", tmp_path / "run", progress_bar=False)
    model = CrossQ.load(str(tmp_path / "out" / "policy.zip"), device="cpu")
    first = next(m for m in model.policy.actor.latent_pi if isinstance(m, torch.nn.Linear))
    columns = [observation_names(cfg.env_id).index(n) for n in cfg.ignored_observations]
    assert torch.all(first.weight[:, columns] == 0) and torch.any(first.weight != 0)
    for key, value in (("residual", {"base": "lqi"}), ("warm_start", {"controller": "lqi"})):
        with pytest.raises(ValueError, match=f"{key}: available with algo ppo or sac, not tqc"):
            TrainConfig(algo="tqc", env_id="DrillString-v2", **{key: value})
    monkeypatch.setitem(sys.modules, "sb3_contrib", None)  # as if not installed
    with pytest.raises(ValueError, match=r"algo: crossq needs sb3-contrib.*drill-env\[zoo\]"):
        _algo_class("crossq")


def test_plateau_criterion():
    rising = np.linspace(-300.0, -10.0, 16)
    assert plateau(rising)["converged"] is False
    flat = np.concatenate([np.linspace(-300.0, -15.0, 8), np.full(8, -15.0) + np.tile([0.3, -0.3], 4)])
    res = plateau(flat)
    assert res["converged"] is True and res["last_gain"] == pytest.approx(0.0, abs=1e-12)
    assert plateau(flat[:5])["converged"] is False  # fewer than min_evaluations
    # hand-computed: last quarter mean -10, previous quarter mean -12: a gain of 2 > 0.05 x 10
    r = np.array([-100.0, -50.0, -20.0, -15.0, -12.0, -12.0, -10.0, -10.0])
    res = plateau(r)
    assert res["last_mean"] == -10.0 and res["previous_mean"] == -12.0 and res["last_gain"] == 2.0
    assert res["converged"] is False
    r[-2:] = -11.6  # a gain of 0.4 <= 0.05 x 11.6
    assert plateau(r)["converged"] is True


def test_config_validation_names_the_field(tmp_path):
    with pytest.raises(ValueError, match="algo"):
        TrainConfig(algo="dqn")
    with pytest.raises(ValueError, match="env_id"):
        TrainConfig(algo="ppo", env_id="CartPole-v1")
    with pytest.raises(ValueError, match="hyperparameters"):
        TrainConfig(algo="ppo", hyperparameters={"seed": 1})
    with pytest.raises(ValueError, match="evaluation"):
        TrainConfig(algo="ppo", evaluation={"every_steps": 0})
    bad = tmp_path / "bad.yaml"
    bad.write_text("algo: ppo\nlearning_rate: 0.1\n")
    with pytest.raises(ValueError, match="learning_rate"):
        load_config(bad)
    shipped = sorted(p for p in CONFIGS.glob("*.yaml") if p.name != "controllers.yaml")
    assert shipped
    for path in shipped:  # each recipe's algorithm is the first word of its name
        assert load_config(path).algo == path.stem.split("_")[0], path


def test_cli_train_rejects_bad_input(tmp_path):
    runner = CliRunner()
    res = runner.invoke(app, ["train", "--algo", "dqn", "--config", str(CONFIGS / "ppo_lqi_clone.yaml")])
    assert res.exit_code == 2 and "--algo" in res.output
    res = runner.invoke(app, ["train", "--algo", "sac", "--config", str(CONFIGS / "ppo_lqi_clone.yaml")])
    assert res.exit_code == 2 and "does not match" in res.output
    res = runner.invoke(app, ["train", "--algo", "ppo", "--config", str(tmp_path / "none.yaml")])
    assert res.exit_code == 2 and "no such file" in res.output


def test_native_and_dummy_training_envs_give_the_same_rollouts():
    # vec_env: native (one compiled call) and dummy (SB3's DummyVecEnv of Monitor-wrapped
    # single envs) are the same rigs: same observations, rewards, dones and episode stats
    d = small_config("ppo", 256).to_dict()
    d["env_kwargs"].update(max_episode_steps=50)
    cfg = TrainConfig(**d)
    a = make_train_vec_env(cfg, 5)
    b = make_train_vec_env(TrainConfig(**{**d, "vec_env": "dummy"}), 5)
    np.testing.assert_array_equal(a.reset(), b.reset())
    rng = np.random.default_rng(0)
    finished = 0
    for _ in range(120):
        act = rng.uniform(-1, 1, size=(cfg.n_envs, 1)).astype(np.float32)
        (oa, ra, da, ia), (ob, rb, db, ib) = a.step(act), b.step(act)
        np.testing.assert_array_equal(oa, ob)
        np.testing.assert_array_equal(ra, rb)
        np.testing.assert_array_equal(da, db)
        for x, y in zip(ia, ib, strict=True):
            if "episode" in y:
                finished += 1
                assert x["episode"]["r"] == pytest.approx(y["episode"]["r"], rel=1e-6)
                assert x["episode"]["l"] == y["episode"]["l"]
                np.testing.assert_array_equal(x["terminal_observation"], y["terminal_observation"])
    assert finished == 2 * cfg.n_envs  # every rig ended two 50-step episodes


def test_linear_schedules_and_their_errors():
    hp = algo_kwargs({"learning_rate": "lin_6e-4", "clip_range": 0.2})
    assert hp["learning_rate"](1.0) == pytest.approx(6e-4) and hp["learning_rate"](0.25) == pytest.approx(
        1.5e-4
    )
    assert hp["clip_range"] == 0.2
    for bad in ("6e-4", "lin_x", "lin_-1", "lin_inf"):
        with pytest.raises(ValueError, match="hyperparameters.learning_rate"):
            TrainConfig(algo="ppo", hyperparameters={"learning_rate": bad})
    with pytest.raises(ValueError, match="vec_env"):
        TrainConfig(algo="ppo", vec_env="subproc")


def test_cli_train_and_tune_default_to_fresh_run_folders(tmp_path, monkeypatch):
    # by default nothing committed is written: train and tune create a new run folder each
    import yaml as _yaml

    cfg = small_config("ppo", 128).to_dict()
    cfg["evaluation"]["every_steps"] = 64
    cfg["hyperparameters"].update(n_steps=32, batch_size=32)
    (tmp_path / "tiny.yaml").write_text(_yaml.safe_dump(cfg))
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    args = ["train", "--algo", "ppo", "--config", "tiny.yaml", "--no-progress"]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    second = runner.invoke(app, args)
    assert second.exit_code == 0, second.output
    runs = sorted((tmp_path / "runs" / "train").glob("ppo_seed0_*"))
    assert len(runs) == 2  # two runs, two folders: the second did not replace the first
    for run in runs:
        assert (run / "ppo" / "policy.zip").is_file() and (run / "logs").is_dir()
        assert f"--agents-dir {run.relative_to(tmp_path)}" in first.output + second.output
        # the card of the new policy: how it started and the config it was trained with
        card = (run / "ppo" / "policy.md").read_text()
        assert card.startswith("# `ppo`: PPO, from scratch\n")
        assert "| training config | `tiny.yaml` |" in card and "| training | seed 0, " in card
    assert not (tmp_path / "results").exists()
    # the run folder is laid out like results/agents: the benchmark finds the policy there
    from drill_env.agents.registry import policy_path

    assert policy_path("ppo", "brake", runs[0]) == runs[0] / "ppo" / "policy.zip"
    # two runs into sibling folders (as results/agents/NAME) keep their logs apart
    for name in ("ppo", "ppo_other"):
        out = runner.invoke(app, [*args, "--out", f"agents/{name}"])
        assert out.exit_code == 0, out.output
    progress = {n: (tmp_path / "agents" / "logs" / n / "progress.csv") for n in ("ppo", "ppo_other")}
    assert all(f.is_file() and f.stat().st_size > 0 for f in progress.values())
    assert (tmp_path / "agents" / "logs" / "ppo" / "final_policy.zip").is_file()


def test_td3_trains_a_few_thousand_steps_and_its_policy_loads_and_acts(tmp_path):
    import torch
    from stable_baselines3 import TD3
    from stable_baselines3.common.noise import NormalActionNoise

    cfg = load_config(CONFIGS / "experiments" / "td3.yaml").to_dict()
    cfg.update(total_timesteps=2048, n_envs=8)
    cfg["evaluation"] = {"every_steps": 2048, "episodes_per_regime": 1, "seed": 7}
    cfg["env_kwargs"] = {"warmup_time": 2.0, "warmup_jitter": 0.5}
    cfg["hyperparameters"].update(learning_starts=400, buffer_size=4000, batch_size=64, gradient_steps=1)
    cfg = TrainConfig(**cfg)
    summary = train(cfg, 5, tmp_path / "out", tmp_path / "run", progress_bar=False)
    assert summary["algo"] == "td3" and summary["total_timesteps"] >= 2048 and summary["n_evaluations"] >= 2
    assert np.isfinite(summary["best_eval_return"])
    path = tmp_path / "out" / "policy.zip"
    policy = load_policy(path, trusted=True)  # made by this test; the algorithm read from the zip
    assert isinstance(policy.model, TD3) and policy._actor is not None
    env = make_env("brake", EpisodeSettings(), policy_observation_version(path))
    policy.check_env(env)
    obs = np.stack([env.reset(seed=k)[0] for k in range(8)])
    sb3, _ = policy.model.predict(obs, deterministic=True)
    np.testing.assert_allclose(policy.predict(obs, deterministic=True)[0], sb3, atol=1e-5)
    assert np.all(np.abs(sb3) <= 1.0) and np.ptp(sb3) > 0  # it acts, and on what it observes
    columns = [observation_names(cfg.env_id).index(n) for n in cfg.ignored_observations]
    for actor in (policy.model.policy.actor, policy.model.policy.actor_target):
        first = next(m for m in actor.mu if isinstance(m, torch.nn.Linear))
        assert torch.all(first.weight[:, columns] == 0) and torch.any(first.weight != 0)
    noise = algo_kwargs({"action_noise_std": 0.2}, n_actions=1)["action_noise"]
    assert isinstance(noise, NormalActionNoise) and noise._sigma.tolist() == [0.2]
    for bad in (0, -0.1, "0.1", True):
        with pytest.raises(ValueError, match="hyperparameters.action_noise_std: expected a number > 0"):
            TrainConfig(algo="td3", hyperparameters={"action_noise_std": bad})
    with pytest.raises(
        ValueError, match="action_noise_std: available with the off-policy algorithms, not ppo"
    ):
        TrainConfig(algo="ppo", hyperparameters={"action_noise_std": 0.1})
    with pytest.raises(ValueError, match="residual: available with algo ppo or sac, not td3"):
        TrainConfig(algo="td3", env_id="DrillString-v2", residual={"base": "lqi"})


def test_a_run_shorter_than_one_logging_interval_writes_everything(tmp_path):
    # 60 SAC steps: no episode ends, SB3 logs nothing (a blank progress.csv); the run still
    # writes its policy, summary and a learning curve that says so
    cfg = small_config("sac", 60)
    summary = train(cfg, 0, tmp_path / "out", tmp_path / "run", progress_bar=False)
    assert summary["total_timesteps"] >= 60 and summary["n_evaluations"] >= 1
    for name in ("policy.zip", "config.yaml", "training_summary.json", "eval.csv", "learning_curve.png"):
        assert (tmp_path / "out" / name).is_file(), name


def test_activation_by_name_builds_that_network_and_the_numpy_actor_runs_it():
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO

    from drill_env.agents.learning.rl import SB3Policy

    hp = algo_kwargs({"policy_kwargs": {"net_arch": [16, 16], "activation_fn": "ReLU"}})
    assert hp["policy_kwargs"]["activation_fn"] is torch.nn.ReLU
    env = gym.make("DrillString-v1")
    model = PPO("MlpPolicy", env, seed=3, device="cpu", **hp)
    assert sum(isinstance(m, torch.nn.ReLU) for m in model.policy.mlp_extractor.policy_net) == 2
    with torch.no_grad():  # an action head large enough that tanh in place of ReLU would show
        model.policy.action_net.weight.mul_(30.0)
    obs = np.stack([env.observation_space.sample() for _ in range(64)]) * 0.2
    sb3, _ = model.predict(obs, deterministic=True)
    fast, _ = SB3Policy(model, "ppo").predict(obs, deterministic=True)
    assert np.abs(sb3).max() > 0.05
    np.testing.assert_allclose(fast, sb3, atol=1e-5)
    env.close()
    with pytest.raises(ValueError, match="hyperparameters.policy_kwargs.activation_fn"):
        TrainConfig(algo="ppo", hyperparameters={"policy_kwargs": {"activation_fn": "GELU"}})


def test_max_wall_time_stops_the_training_and_keeps_the_best_policy(tmp_path, monkeypatch):
    # a budget far below what total_timesteps would take: the run stops at the budget with a
    # last evaluation, says so, and its steps and wall time are in the summary
    cfg = small_config("ppo", 10_000_000)
    clock = {"t": 0.0}

    def fake_clock() -> float:  # every call advances 1 s: the budget is reached after a few steps
        clock["t"] += 1.0
        return clock["t"]

    import drill_env.agents.learning.rl as rl

    monkeypatch.setattr(rl.time, "perf_counter", fake_clock)
    summary = train(cfg, 0, tmp_path / "out", tmp_path / "run", progress_bar=False, max_wall_time_s=40.0)
    assert summary["stopped_by"] == "max_wall_time" and summary["max_wall_time_s"] == 40.0
    assert 0 < summary["env_steps"] == summary["total_timesteps"] < 10_000
    assert summary["wall_time_s"] >= 40.0
    on_disk = json.loads((tmp_path / "out" / "training_summary.json").read_text())
    assert on_disk["stopped_by"] == "max_wall_time" and on_disk["env_steps"] == summary["env_steps"]
    # the last evaluation is at the step the run stopped, and the kept policy is the best one
    evals = np.genfromtxt(tmp_path / "out" / "eval.csv", delimiter=",", names=True)
    assert int(np.atleast_1d(evals["timesteps"])[-1]) == summary["total_timesteps"]
    assert (tmp_path / "out" / "policy.zip").is_file()
    assert summary["best_eval_return"] == pytest.approx(np.max(np.atleast_1d(evals["mean_return"])))
    # without a budget the same run is ended by total_timesteps
    small = train(small_config("ppo", 128), 0, tmp_path / "o2", tmp_path / "r2", progress_bar=False)
    assert small["stopped_by"] == "total_timesteps" and small["max_wall_time_s"] is None


@pytest.mark.parametrize("bad", ["0", "-5", "nan", "inf", "x"])
def test_cli_max_wall_time_must_be_a_positive_number(bad):
    res = CliRunner().invoke(
        app,
        ["train", "--algo", "ppo", "--config", str(CONFIGS / "ppo_lqi_clone.yaml"), "--max-wall-time", bad],
    )
    assert res.exit_code == 2, res.output
    assert "--max-wall-time" in res.output and "Traceback" not in res.output
    for bad_api in (0, -1.0, float("nan"), float("inf"), "10"):
        with pytest.raises(ValueError, match="max_wall_time_s"):
            train(small_config("ppo", 64), 0, "unused", "unused", max_wall_time_s=bad_api)


def test_time_limit_truncations_are_bootstrapped_by_ppo_and_sac():
    # The SB3 adapter marks a time-limit end as TimeLimit.truncated with its terminal
    # observation. PPO must add gamma * V(terminal observation) to the last reward of a
    # truncated episode; SAC's replay buffer must store it as a timeout (done, not terminal).
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.callbacks import BaseCallback

    from drill_env import sb3_vec_env

    steps = 16  # episode length: two episodes in the rollout below

    class Raw(BaseCallback):
        def __init__(self):
            super().__init__()
            self.rewards, self.dones, self.terminal = [], [], {}

        def _on_step(self) -> bool:
            # called before SB3 bootstraps rewards in place: these are the env's own
            self.rewards.append(np.array(self.locals["rewards"], dtype=np.float64))
            self.dones.append(np.array(self.locals["dones"]))
            for i, info in enumerate(self.locals["infos"]):
                if info.get("TimeLimit.truncated"):
                    # the value function of the moment (the update after the rollout changes it)
                    obs = self.model.policy.obs_to_tensor(info["terminal_observation"])[0]
                    with torch.no_grad():
                        value = self.model.policy.predict_values(obs)[0].item()
                    self.terminal[(len(self.rewards) - 1, i)] = value
            return True

    venv = sb3_vec_env("DrillString-v1", 2, seed=0, max_episode_steps=steps)
    ppo = PPO(
        "MlpPolicy", venv, n_steps=2 * steps, batch_size=32, n_epochs=1, gamma=0.9, seed=0, device="cpu"
    )
    raw = Raw()
    ppo.learn(total_timesteps=2 * 2 * steps, callback=raw)
    assert len(raw.terminal) == 4  # both rigs truncated twice, never terminated
    buf = ppo.rollout_buffer
    # the buffer holds the rollout collected last; learn() ran exactly one rollout
    for (t, i), value in raw.terminal.items():
        expected = raw.rewards[t][i] + 0.9 * value
        assert buf.rewards[t, i] == pytest.approx(expected, rel=1e-5)
        assert abs(value) > 1e-6 and buf.rewards[t, i] != pytest.approx(raw.rewards[t][i], rel=1e-5)
    others = [(t, i) for t in range(2 * steps) for i in range(2) if (t, i) not in raw.terminal]
    assert all(buf.rewards[t, i] == pytest.approx(raw.rewards[t][i], rel=1e-6) for t, i in others)

    venv = sb3_vec_env("DrillString-v1", 2, seed=0, max_episode_steps=steps)
    sac = SAC("MlpPolicy", venv, learning_starts=10_000, buffer_size=1000, seed=0, device="cpu")
    sac.learn(total_timesteps=2 * 2 * steps)
    rb = sac.replay_buffer
    ends = np.argwhere(rb.dones[: rb.pos] > 0)
    assert len(ends) == 4 and np.all(rb.timeouts[: rb.pos][rb.dones[: rb.pos] > 0] == 1)
    # what SAC's target uses: done * (1 - timeout) = 0 — the critic bootstraps through them
    samples = rb._get_samples(np.arange(rb.pos))
    assert float(samples.dones.sum()) == 0.0


@pytest.mark.parametrize("path", sorted((CONFIGS / "experiments").glob("*.yaml")), ids=lambda p: p.stem)
def test_every_recipe_tried_loads_builds_its_env_and_is_listed(path):
    """The recipes tried and not kept still train: each loads, its env (reward weights and all)
    builds, and the folder's README lists it."""
    assert f"`{path.name}`" in (CONFIGS / "experiments" / "README.md").read_text()
    cfg = load_config(path, n_envs=2)
    env = make_train_vec_env(cfg, 0)
    try:
        assert env.num_envs == 2
    finally:
        env.close()
