"""Warm start of a policy by behaviour cloning of a classical controller (agents/learning/warm_start.py)."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces
from test_train import CONFIGS, ROOT, small_config

from drill_env.agents.learning.rl import TrainConfig, load_config, load_policy, train
from drill_env.agents.learning.warm_start import (
    WarmStartConfig,
    collect_demonstrations,
    nominal_controller,
    warm_start,
)
from drill_env.agents.registry import teacher_policy

ANGLES = ["lower_angle_sin", "lower_angle_cos", "upper_angle_sin", "upper_angle_cos"]


class _ConstantRig:
    """An SB3-like vector env whose every step pays ``reward`` and ends episodes at ``length``."""

    def __init__(self, n_envs: int, reward: float, length: int):
        self.num_envs, self.reward, self.length = n_envs, reward, length
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.t = 0
        self.actions: list[np.ndarray] = []

    def reset(self):
        self.t = 0
        return np.zeros((self.num_envs, 2), np.float32)

    def step(self, action):
        self.actions.append(np.array(action))
        self.t += 1
        done = np.full(self.num_envs, self.t % self.length == 0)
        obs = np.full((self.num_envs, 2), self.t, np.float32)
        return obs, np.full(self.num_envs, self.reward), done, [{}] * self.num_envs


class _Half:
    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.full((len(obs), 1), 0.5, np.float32), state


def test_demonstration_returns_are_the_discounted_sums():
    gamma, length = 0.9, 5
    rig = _ConstantRig(3, 2.0, length)
    data = collect_demonstrations(rig, _Half(), 20, 0.0, gamma, seed=0)  # 7 rounds of 3 rigs
    assert data["obs"].shape == (21, 2) and data["action"].shape == (21, 1)
    assert np.all(data["action"] == 0.5) and all(np.all(a == 0.5) for a in rig.actions)  # no noise
    ret = data["returns"].reshape(7, 3)[:, 0]
    run = data["running_returns"].reshape(7, 3)[:, 0]
    # the first episode (steps 0-4) ends: the return from step k is 2 (1 - g^(5-k)) / (1 - g)
    for k in range(5):
        assert ret[k] == pytest.approx(2.0 * (1 - gamma ** (5 - k)) / (1 - gamma))
        assert run[k] == pytest.approx(2.0 * (1 - gamma ** (k + 1)) / (1 - gamma))
    # the second is cut by the rollout's end: completed by the geometric tail of its last reward
    assert ret[5] == pytest.approx(2.0 / (1 - gamma)) and ret[6] == pytest.approx(2.0 / (1 - gamma))
    assert run[5] == pytest.approx(2.0) and run[6] == pytest.approx(2.0 * (1 + gamma))


def test_action_noise_goes_to_the_rig_not_to_the_labels():
    rig = _ConstantRig(400, 0.0, 10)
    data = collect_demonstrations(rig, _Half(), 400, 0.2, 0.99, seed=1)
    assert np.all(data["action"] == 0.5)
    applied = rig.actions[0]
    assert applied.std() == pytest.approx(0.2, rel=0.15) and applied.mean() == pytest.approx(0.5, abs=0.03)
    # data aggregation: the driver acts, the controller labels
    rig = _ConstantRig(400, 0.0, 10)
    data = collect_demonstrations(
        rig, _Half(), 400, 0.0, 0.99, seed=1, driver=lambda obs: -0.25 * np.ones((len(obs), 1))
    )
    assert np.all(data["action"] == 0.5) and np.all(rig.actions[0] == -0.25)


def test_warm_start_config_names_the_field():
    for bad, field in (
        ({"controller": "mpc"}, "warm_start.controller"),
        ({"steps": 0}, "warm_start.steps"),
        ({"epochs": 1.5}, "warm_start.epochs"),
        ({"learning_rate": 0.0}, "warm_start.learning_rate"),
        ({"action_noise": -0.1}, "warm_start.action_noise"),
        ({"rounds": 0}, "warm_start.rounds"),
        ({"noise": 0.1}, "unknown key"),
    ):
        with pytest.raises(ValueError, match=field):
            WarmStartConfig.from_any(bad)
    with pytest.raises(ValueError, match="warm_start"):
        TrainConfig(algo="ppo", warm_start="lqi")
    residual = load_config(CONFIGS / "ppo_robust.yaml").to_dict()
    with pytest.raises(ValueError, match="warm_start"):
        TrainConfig(**{**residual, "warm_start": {"controller": "lqi"}})


@pytest.fixture
def one_torch_thread():
    """As the training configs run: many small torch ops thrash with more threads on few cores."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_the_clone_acts_like_the_controller_on_rigs_it_was_not_fitted_on(algo, one_torch_thread):
    cfg = TrainConfig(**{**small_config(algo, 256).to_dict(), "n_envs": 16})
    model = _model(cfg)
    lqi = nominal_controller("lqi", cfg.env_id, cfg.env_kwargs)
    ws = WarmStartConfig(controller="lqi", steps=4000, epochs=30, batch_size=256, action_noise=0.05)
    info = warm_start(model, ws, cfg.env_id, cfg.env_kwargs, seed=0)
    assert info["steps"] >= 4000 and info["action_mse_after"] < 0.05 * info["action_mse_before"]
    # fresh rigs (other seeds), driven by the controller: the clone's action against the controller's
    from drill_env.envs.sb3 import sb3_vec_env

    venv = sb3_vec_env(cfg.env_id, 8, seed=777, **cfg.env_kwargs)
    test = collect_demonstrations(venv, lqi, 800, 0.05, 0.99, seed=5)
    venv.close()
    clone, _ = model.predict(test["obs"], deterministic=True)
    spread = float(np.mean((test["action"] - test["action"].mean()) ** 2))
    assert float(np.mean((clone - test["action"]) ** 2)) < 0.1 * spread


def _model(cfg):
    from stable_baselines3.common.vec_env import VecNormalize

    from drill_env.agents.learning.rl import _algo_class, algo_kwargs, make_train_vec_env

    venv = VecNormalize(make_train_vec_env(cfg, 0), norm_obs=False, norm_reward=True)
    return _algo_class(cfg.algo)(
        "MlpPolicy", venv, seed=0, verbose=0, device="cpu", **algo_kwargs(cfg.hyperparameters)
    )


def test_training_with_a_warm_start_records_it(tmp_path, one_torch_thread):
    cfg = small_config("ppo", 256).to_dict()
    cfg["warm_start"] = {"controller": "lqi", "steps": 1000, "epochs": 2}
    summary = train(TrainConfig(**cfg), 1, tmp_path / "out", tmp_path / "run", progress_bar=False)
    ws = summary["warm_start"]
    assert ws["controller"] == "lqi" and ws["steps"] >= 1000 and ws["wall_time_s"] <= summary["wall_time_s"]
    assert summary["config"]["warm_start"]["steps"] == 1000
    assert load_config(tmp_path / "out" / "config.yaml").warm_start == WarmStartConfig(steps=1000, epochs=2)


@pytest.mark.parametrize("suffix", ["", "_no_brake"])
def test_warm_start_configs_differ_from_the_shipped_ones_only_where_they_say(suffix):
    warm = load_config(CONFIGS / f"ppo_lqi_clone{suffix}.yaml").to_dict()
    scratch = load_config(CONFIGS / "experiments" / f"ppo_from_scratch{suffix}.yaml").to_dict()
    assert warm.pop("warm_start")["controller"] == "lqi"
    assert warm.pop("ignored_observations") == ANGLES
    if suffix == "_no_brake":  # 90 s training episodes, as the benchmark runs (see the config)
        assert warm["env_kwargs"].pop("max_episode_steps") == 1800
    for key in ("total_timesteps", "evaluation"):
        warm.pop(key), scratch.pop(key)
    for hp in (warm["hyperparameters"], scratch["hyperparameters"]):
        hp.pop("learning_rate")
        hp["policy_kwargs"].pop("log_std_init")
    assert warm == scratch


def test_ignored_observations_name_the_field():
    with pytest.raises(ValueError, match="ignored_observations: 'angle'"):
        TrainConfig(algo="ppo", env_id="DrillString-v1", ignored_observations=["angle"])
    with pytest.raises(ValueError, match="ignored_observations: 'lower_angle_sin'"):  # v0 has no angles
        TrainConfig(algo="ppo", env_id="DrillString-v0", ignored_observations=["lower_angle_sin"])
    with pytest.raises(ValueError, match="ignored_observations: expected a list"):
        TrainConfig(algo="ppo", env_id="DrillString-v1", ignored_observations="lower_angle_sin")


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_the_trained_policy_does_not_depend_on_ignored_observations(tmp_path, algo, one_torch_thread):
    cfg = small_config(algo, 256).to_dict()
    cfg["ignored_observations"] = ANGLES
    summary = train(TrainConfig(**cfg), 2, tmp_path / "out", tmp_path / "run", progress_bar=False)
    assert summary["config"]["ignored_observations"] == ANGLES
    policy = load_policy(tmp_path / "out" / "policy.zip", trusted=True)  # made by this test
    obs = np.random.default_rng(3).uniform(-1, 1, (64, 13)).astype(np.float32)
    moved = obs.copy()
    moved[:, 8:12] = np.random.default_rng(4).uniform(-1, 1, (64, 4))
    a, _ = policy.predict(obs, deterministic=True)
    b, _ = policy.predict(moved, deterministic=True)
    np.testing.assert_array_equal(a, b)
    other = obs.copy()
    other[:, 0] += 0.5  # the lower speed still matters
    c, _ = policy.predict(other, deterministic=True)
    assert np.abs(c - a).max() > 1e-4


def test_the_committed_no_brake_ppo_lqi_clone_keeps_the_integral_action():
    # at the slip equilibrium of each stable operating point, a bit further ahead of its
    # reference angle must get less voltage (as the LQI it was cloned from); PPO on 20 s
    # episodes reversed this at 1.8-5 V and steady offsets then grew without bound
    import gymnasium as gym

    path = ROOT / "results" / "agents" / "ppo_lqi_clone_no_brake" / "policy.zip"
    policy = load_policy(path)
    env = gym.make("DrillStringNoBrake-v1", start="equilibrium")
    lag = np.linspace(-2.0, 2.0, 5)  # [rad] integrated lower speed error
    for volts in (0.4, 1.8, 2.5, 3.5, 4.5):
        obs, _ = env.reset(seed=5, options={"nominal_voltage": volts})
        batch = np.repeat(obs[None], lag.size, axis=0)
        batch[:, 12] = lag / (2 * np.pi)
        action, _ = policy.predict(batch, deterministic=True)
        assert np.all(np.diff(action.ravel()) < 0), (volts, action.ravel())
    env.close()


# -- distillation of a trained policy into a residual policy ---------------------------------------

DISTILLED = {
    "DrillString-v1": "experiments/ppo_robust_distilled",
    "DrillStringNoBrake-v1": "ppo_robust_no_brake",
}


def test_distillation_config_names_the_field():
    from drill_env.agents.learning.warm_start import WARM_START_POLICIES
    from drill_env.agents.registry import LEARNED

    assert set(WARM_START_POLICIES) <= set(LEARNED)
    with pytest.raises(ValueError, match=r"^warm_start: give controller .* or policy .*, not both$"):
        WarmStartConfig.from_any({"controller": "lqi", "policy": "ppo"})
    for bad in ("mpc", "ppo_robust", 3):
        with pytest.raises(
            ValueError,
            match=rf"^warm_start\.policy: {bad!r} is not one of \['ppo', 'sac', 'ppo_lqi_clone'\]$",
        ):
            WarmStartConfig.from_any({"policy": bad})
    assert WarmStartConfig().controller == "lqi" and WarmStartConfig(policy="sac").controller is None
    for teacher in ("ppo", "ppo_lqi_clone"):
        assert WarmStartConfig.from_any({"policy": teacher}).policy == teacher
    residual = load_config(CONFIGS / "ppo_robust.yaml").to_dict()
    with pytest.raises(ValueError, match=r"^warm_start\.controller: a residual policy starts as its base"):
        TrainConfig(**{**residual, "warm_start": {"controller": "lqi"}})
    with pytest.raises(ValueError, match=r"^warm_start\.policy: allowed only with residual"):
        TrainConfig(**{**small_config("ppo", 256).to_dict(), "warm_start": {"policy": "ppo"}})
    cfg = TrainConfig(**{**residual, "warm_start": {"policy": "sac", "steps": 10}})
    assert cfg.to_dict()["warm_start"]["policy"] == "sac" and "controller" not in cfg.to_dict()["warm_start"]
    assert TrainConfig(**cfg.to_dict()) == cfg


def test_a_missing_teacher_policy_names_its_file(tmp_path, monkeypatch):
    from drill_env.agents.registry import AGENTS_DIR_ENV

    monkeypatch.setenv(AGENTS_DIR_ENV, str(tmp_path))
    with pytest.raises(
        ValueError, match=f"no trained sac policy for preset 'no_brake' at {tmp_path}/sac_no_brake/policy.zip"
    ):
        teacher_policy("sac", "DrillStringNoBrake-v1", {})


@pytest.mark.parametrize("suffix", ["", "_no_brake"])
def test_distilled_configs_differ_from_the_residual_ones_only_where_they_say(suffix):
    # brake: the distilled recipe was not kept; without the brake the residual one was not
    distilled_name = {"": "experiments/ppo_robust_distilled", "_no_brake": "ppo_robust_no_brake"}[suffix]
    residual_name = {"": "ppo_robust", "_no_brake": "experiments/ppo_robust_residual_no_brake"}[suffix]
    distilled = load_config(CONFIGS / f"{distilled_name}.yaml").to_dict()
    residual = load_config(CONFIGS / f"{residual_name}.yaml").to_dict()
    warm = load_config(CONFIGS / f"ppo_lqi_clone{suffix}.yaml").to_dict()
    ws = distilled.pop("warm_start")
    assert ws.pop("policy") == "ppo_lqi_clone" and ws == {
        k: v for k, v in warm["warm_start"].items() if k != "controller"
    }
    assert distilled.pop("ignored_observations") == ANGLES
    # the no-brake policy's base slows its feedforward where the error is noise (README)
    options = {"base_options": {"variable_step": True}} if suffix == "_no_brake" else {}
    assert distilled.pop("residual") == {"base": "lqi_angle_ff", "scale": 0.2, **options}
    assert residual.pop("residual") == {"base": "lqi_angle_ff", "scale": 0.2}
    assert (
        distilled.pop("total_timesteps") == 200_000 and distilled.pop("evaluation")["every_steps"] == 50_000
    )
    if suffix == "_no_brake":  # 90 s training episodes, as ppo_lqi_clone_no_brake.yaml
        assert distilled["env_kwargs"].pop("max_episode_steps") == 1800
    hp = distilled.pop("hyperparameters")
    assert (hp["learning_rate"], hp["n_epochs"], hp["batch_size"]) == ("lin_3.0e-5", 5, 1024)
    assert hp["policy_kwargs"]["log_std_init"] == -3.0
    for key in ("total_timesteps", "evaluation", "hyperparameters"):
        residual.pop(key)
    assert distilled == residual


def _lqi_feedback_and_feedforward(base, obs, state):
    """Independent of the controller's code: u_nom - K dx [V] from the LQI's entries of the
    state, and sum_h Re(C_h exp(j h theta_l)) [V] with theta_l from the encoder's sin/cos."""
    spec = base.spec
    y = spec.to_physical(obs)
    col = {n: y[:, spec.index(n)] for n in spec.observation_names}
    w = col["target_speed"]
    dx = np.stack(
        [col["twist"] - state[:, 1], col["upper_speed"] - w, col["lower_speed"] - w, state[:, 0]], axis=1
    )
    feedback = col["nominal_voltage"] - np.sum(state[:, 2:6] * dx, axis=1)
    theta = np.arctan2(col["lower_angle_sin"], col["lower_angle_cos"])
    ff = sum(
        state[:, 7 + 2 * i] * np.cos(h * theta) - state[:, 8 + 2 * i] * np.sin(h * theta)
        for i, h in enumerate((1, 2))
    )
    return feedback, ff


@pytest.mark.parametrize("env_id", sorted(DISTILLED))
def test_the_distillation_label_makes_the_residual_voltage_the_teachers_plus_the_feedforward(env_id):
    import gymnasium as gym

    from drill_env.agents.learning.residual import _combine, base_controller
    from drill_env.agents.learning.warm_start import ResidualLabels
    from drill_env.agents.registry import build_controller
    from drill_env.envs import ENV_IDS
    from drill_env.envs.sb3 import sb3_vec_env

    cfg = load_config(CONFIGS / f"{DISTILLED[env_id]}.yaml")
    # episodes long enough for the feedforward's adaptation to start (after ~15 s) and act
    kwargs = {**cfg.env_kwargs, "max_episode_steps": 600}
    scale = cfg.residual.scale
    labels = ResidualLabels(
        teacher_policy(cfg.warm_start.policy, env_id, kwargs),
        base_controller(cfg.residual, env_id, kwargs),
        scale,
    )
    env = gym.make(env_id, **kwargs)
    teacher = build_controller(cfg.warm_start.policy, env, ENV_IDS[env_id])  # the benchmark's, loaded anew
    env.close()
    base = labels.base
    n = 3
    venv = sb3_vec_env(env_id, n, seed=4321, **kwargs)
    obs, start = venv.reset(), np.ones(n, dtype=bool)
    state = ref_state = None
    rng = np.random.default_rng(0)
    checked = with_ff = 0
    for _ in range(900):
        label, state = labels.predict(obs, state=state, episode_start=start)
        # the base as the residual training rigs step it
        base_action, next_ref = base.predict(obs, state=ref_state, episode_start=start)
        np.testing.assert_array_equal(labels.base_action, base_action)
        if ref_state is not None:
            keep = ~start  # rows that continue an episode: ref_state is the state control sees
            feedback, ff = _lqi_feedback_and_feedforward(base, obs[keep], ref_state[keep])
            a_teacher = teacher.predict(obs[keep], deterministic=True)[0].ravel()
            want = a_teacher + ff / 5.0
            lab, a_base = label[keep].ravel(), base_action[keep].ravel()
            np.testing.assert_allclose(a_base, np.clip(feedback + ff, -5, 5) / 5.0, atol=1e-6)
            ok = (np.abs(lab) < 1.0) & (np.abs(feedback + ff) < 5.0) & (np.abs(want) <= 1.0)
            np.testing.assert_allclose(a_base[ok] + scale * lab[ok], want[ok], atol=1e-6)
            np.testing.assert_allclose(_combine(a_base, lab, scale)[ok], want[ok], atol=1e-6)
            # the brief's form: the label is the teacher's action less the LQI's feedback
            np.testing.assert_allclose(lab[ok], (a_teacher - feedback / 5.0)[ok] / scale, atol=1e-5)
            checked += int(ok.sum())
            with_ff += int(np.sum(ok & (np.abs(ff) > 0.01)))
        ref_state = next_ref
        noisy = labels.target + 0.1 * rng.standard_normal(labels.target.shape).astype(np.float32)
        obs, _, done, _ = venv.step(np.clip(noisy, -1, 1))
        start = np.asarray(done, dtype=bool).copy()
    venv.close()
    assert checked > 0.9 * 899 * n and with_ff > 100  # the feedforward did act in the check


def test_a_tiny_distillation_moves_the_residual_policy_to_the_teacher(one_torch_thread):
    from drill_env.agents.learning.residual import ResidualPolicy
    from drill_env.agents.learning.rl import SB3Policy, ignore_observations

    cfg = load_config(CONFIGS / "experiments" / "ppo_robust_distilled.yaml").to_dict()
    cfg.update(n_envs=4)
    cfg["hyperparameters"].update(batch_size=512)  # one rollout of 4 rigs x 128 steps
    cfg["warm_start"].update(steps=400, rounds=2, epochs=30, batch_size=128)
    cfg = TrainConfig(**cfg)
    model = _model(cfg)
    ignore_observations(model, cfg)
    with pytest.raises(ValueError, match="warm_start.policy: 'ppo_lqi_clone' must be loaded by the caller"):
        warm_start(model, cfg.warm_start, cfg.env_id, cfg.env_kwargs, seed=3, residual=cfg.residual)
    teacher = teacher_policy("ppo_lqi_clone", cfg.env_id, cfg.env_kwargs)
    info = warm_start(
        model, cfg.warm_start, cfg.env_id, cfg.env_kwargs, seed=3, residual=cfg.residual, teacher=teacher
    )
    assert (
        info["policy"] == "ppo_lqi_clone"
        and "controller" not in info
        and info["steps"] >= 800
        and info["rounds"] == 2
    )
    assert info["action_mse_after"] < 0.2 * info["action_mse_before"]
    assert info["value_mse_after"] < info["value_mse_before"]
    first = model.policy.mlp_extractor.policy_net[0].weight.detach().numpy()
    assert np.all(first[:, 8:12] == 0.0)  # the ignored angles stay ignored
    # held-out rigs (other seeds), driven by teacher + feedforward: the residual policy as the
    # benchmark runs it against the zero-correction base
    labels = _labeller(cfg)
    policy = ResidualPolicy(SB3Policy(model, "ppo"), labels.base, cfg.residual.scale)
    rms_policy, rms_base = _distance_to_the_target(policy, labels, cfg, 999, 4, 150, drive="target")
    assert rms_policy < np.sqrt(0.5) * rms_base, (rms_policy, rms_base)


def _distance_to_the_target(policy, labels, cfg, seed, n, steps, drive):
    """RMS distance [action units] of ``policy``'s action and of the base's alone from the
    distillation's target (teacher + feedforward) on ``n`` rigs of ``cfg``'s training env
    (seeded ``seed``, randomised as in training) over ``steps`` steps, the rigs driven by the
    target (``drive="target"``) or by the policy itself."""
    from drill_env.envs.sb3 import sb3_vec_env

    venv = sb3_vec_env(cfg.env_id, n, seed=seed, **cfg.env_kwargs)
    obs, start = venv.reset(), np.ones(n, dtype=bool)
    state = pstate = None
    err_policy, err_base = [], []
    for _ in range(steps):
        _, state = labels.predict(obs, state=state, episode_start=start)
        action, pstate = policy.predict(obs, state=pstate, episode_start=start)
        target = np.clip(labels.target, -1, 1)
        err_policy.append(action - target)
        err_base.append(labels.base_action - target)
        obs, _, done, _ = venv.step(target if drive == "target" else action)
        start = np.asarray(done, dtype=bool).copy()
    venv.close()
    return float(np.sqrt(np.mean(np.square(err_policy)))), float(np.sqrt(np.mean(np.square(err_base))))


def _labeller(cfg):
    from drill_env.agents.learning.residual import base_controller
    from drill_env.agents.learning.warm_start import ResidualLabels

    return ResidualLabels(
        teacher_policy(cfg.warm_start.policy, cfg.env_id, cfg.env_kwargs),
        base_controller(cfg.residual, cfg.env_id, cfg.env_kwargs),
        cfg.residual.scale,
    )


def test_training_with_a_distillation_records_it(tmp_path, one_torch_thread):
    cfg = load_config(CONFIGS / "experiments" / "ppo_robust_distilled.yaml").to_dict()
    cfg.update(n_envs=2, total_timesteps=128)
    cfg["hyperparameters"].update(n_steps=64, batch_size=64, n_epochs=1)
    cfg["evaluation"] = {"every_steps": 128, "episodes_per_regime": 1, "seed": 7}
    cfg["env_kwargs"] = {**cfg["env_kwargs"], "warmup_time": 2.0, "warmup_jitter": 0.5}
    cfg["warm_start"].update(steps=200, rounds=2, epochs=2)
    cfg = TrainConfig(**cfg)
    teacher = teacher_policy("ppo_lqi_clone", cfg.env_id, cfg.env_kwargs)
    summary = train(cfg, 1, tmp_path / "out", tmp_path / "run", progress_bar=False, teacher=teacher)
    ws = summary["warm_start"]
    assert (
        ws["policy"] == "ppo_lqi_clone" and ws["steps"] >= 400 and ws["wall_time_s"] <= summary["wall_time_s"]
    )
    assert summary["config"]["warm_start"]["policy"] == "ppo_lqi_clone"
    saved = load_config(tmp_path / "out" / "config.yaml")
    assert saved.warm_start == WarmStartConfig(
        policy="ppo_lqi_clone", steps=200, rounds=2, epochs=2, learning_rate=3e-3
    )
    assert saved.residual.base == "lqi_angle_ff"


def test_train_command_refuses_a_bad_or_missing_teacher_before_training(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from drill_env.agents.registry import AGENTS_DIR_ENV
    from drill_env.cli import app

    config = (CONFIGS / "ppo_robust_no_brake.yaml").read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text(config.replace("  policy: ppo_lqi_clone ", "  policy: ppo_robust "))
    runner = CliRunner()
    args = ["train", "--algo", "ppo", "--seed", "0", "--out", str(tmp_path / "out")]
    res = runner.invoke(app, [*args, "--config", str(bad)])
    assert res.exit_code == 2 and "warm_start.policy: 'ppo_robust' is not one of" in res.output
    assert "Traceback" not in res.output
    monkeypatch.setenv(AGENTS_DIR_ENV, str(tmp_path / "agents"))
    res = runner.invoke(app, [*args, "--config", str(CONFIGS / "ppo_robust_no_brake.yaml")])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert (
        f"no trained ppo_lqi_clone policy for preset 'no_brake' at {tmp_path}/agents/ppo_lqi_clone_no_brake/policy.zip"
        in res.output
    )
    assert not (tmp_path / "out").exists()  # nothing trained


def test_the_committed_no_brake_ppo_robust_applies_ppo_lqi_clone_plus_the_feedforward(one_torch_thread):
    """The shipped ppo_robust without the brake is what its config says: on randomised rigs it
    did not see, driven by itself, its voltage is ppo_lqi_clone's plus lqi_angle_ff's
    feedforward, far closer than the base alone is (the distillation kept, PPO's fine-tuning
    small)."""
    import gymnasium as gym

    from drill_env.agents.registry import build_controller

    folder = ROOT / "results" / "agents" / "ppo_robust_no_brake"
    cfg = load_config(folder / "config.yaml")
    assert cfg.warm_start is not None and cfg.warm_start.policy == "ppo_lqi_clone"
    labels = _labeller(cfg)
    env = gym.make(cfg.env_id)
    policy = build_controller("ppo_robust", env, "no_brake")
    env.close()
    rms_policy, rms_base = _distance_to_the_target(policy, labels, cfg, 2718, 4, 400, drive="policy")
    rms_policy, rms_base = 5.0 * rms_policy, 5.0 * rms_base  # [V]
    assert rms_policy < 0.2 * rms_base and rms_policy < 0.05, (rms_policy, rms_base)
