"""Robust learned policies: domain randomisation of the library's effects, its validation in
the training config, a tiny randomised training run the benchmark loads, residual policies."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from drill_env.agents.controllers.base import ControllerSpec
from drill_env.agents.controllers.gains import classical_controller
from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env
from drill_env.agents.learning.residual import (
    BASE_OBSERVATIONS,
    ResidualConfig,
    ResidualPolicy,
    base_controller,
    step_base,
)
from drill_env.agents.learning.rl import (
    TrainConfig,
    UntrustedPolicyError,
    load_config,
    load_policy,
    make_train_vec_env,
    train,
)
from drill_env.agents.registry import build_controller, observation_version, training_config
from drill_env.cli import app
from drill_env.envs.config import DomainRandomization

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs" / "agents"

EFFECTS = {
    "lower_position_amp_1": (0.02, 0.15),
    "lower_position_phase_1": (0.0, 2.0 * math.pi),
    "motor_lag": (0.005, 0.02),
}


def _plants(dr, seeds):
    env = gym.make("DrillString-v1", domain_randomization=dr, warmup_time=1.0, warmup_jitter=0.0)
    out = []
    for s in seeds:
        env.reset(seed=s)
        out.append(env.unwrapped.true_params)
    env.close()
    return out


def test_effects_are_drawn_within_their_ranges_after_the_factors():
    seeds = range(31, 43)
    # friction +-10 %: no draw is redrawn for being non-dissipative (a draw that is, with or
    # without the effects, is redrawn whole, and the two streams part)
    with_effects = _plants({"friction_rel": 0.1, "effects": EFFECTS}, seeds)
    without = _plants({"friction_rel": 0.1}, seeds)
    for p, q in zip(with_effects, without, strict=True):
        for name, (lo, hi) in EFFECTS.items():
            assert lo <= getattr(p.effects, name) <= hi
        # the factors are drawn first: the same friction as without effects for the seed
        assert p.lower_static == q.lower_static and p.upper_inertia == q.upper_inertia
        assert q.effects.active == ()
        assert p.effects.upper_position_amp_1 == 0.0  # an effect not listed keeps its value
    amps = np.array([p.effects.lower_position_amp_1 for p in with_effects])
    assert np.ptp(amps) > 0.05  # drawn per episode, not once


@pytest.mark.parametrize(
    ("effects", "field"),
    [
        ({"lower_position_amp_1": [0.0, 1.2]}, "effects.lower_position_amp_1"),
        ({"motor_lag": [-0.01, 0.02]}, "effects.motor_lag"),
        ({"motor_lag": [0.02, 0.01]}, "effects.motor_lag"),
        ({"motor_lag": [0.0, float("nan")]}, "effects.motor_lag"),
        ({"motor_lag": 0.02}, "effects.motor_lag"),
        ({"lower_position_amp_1": [0, 0.6], "lower_position_amp_2": [-0.5, 0]}, "lower_position_amp_1/_2"),
        ({"a1": [0.0, 0.1]}, "effects: unknown effect(s) ['a1']"),
    ],
)
def test_a_bad_randomisation_range_is_a_one_line_error_naming_the_field(tmp_path, effects, field):
    cfg = yaml.safe_load((CONFIGS / "experiments" / "ppo_robust_from_scratch.yaml").read_text())
    cfg["env_kwargs"]["domain_randomization"]["effects"] = effects
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(cfg))
    with pytest.raises(ValueError) as err:
        load_config(path)
    msg = str(err.value)
    assert msg.startswith("env_kwargs.domain_randomization.") and field in msg and "\n" not in msg
    res = CliRunner().invoke(app, ["train", "--algo", "ppo", "--config", str(path), "--no-progress"])
    assert res.exit_code == 2 and field in res.output and "Traceback" not in res.output
    # the other entries of domain_randomization are checked the same way
    cfg["env_kwargs"]["domain_randomization"] = {"friction_rel": 0.9}
    with pytest.raises(ValueError, match=r"^env_kwargs\.domain_randomization\.friction_rel: 0\.9 is outside"):
        TrainConfig(**cfg)


def test_residual_config_validation():
    assert ResidualConfig.from_any(None) is None
    assert ResidualConfig.from_any({"base": "lqi", "scale": 0.3}).scale == 0.3
    with pytest.raises(ValueError, match=r"^residual\.scale: 1\.5 is outside the allowed range \(0, 1\]$"):
        ResidualConfig(scale=1.5)
    with pytest.raises(ValueError, match=r"^residual\.base: 'ppo' is not one of"):
        ResidualConfig(base="ppo")
    with pytest.raises(ValueError, match=r"^residual: unknown key\(s\) \['gain'\]"):
        ResidualConfig.from_any({"gain": 1.0})
    with pytest.raises(ValueError, match=r"^residual\.critic_burn_in: -5 is not an integer >= 0$"):
        ResidualConfig(critic_burn_in=-5)
    with pytest.raises(ValueError, match=r"^residual\.initial_log_std: allowed only with zero_start: true$"):
        ResidualConfig(initial_log_std=-2.0)
    with pytest.raises(ValueError, match=r"^residual\.initial_log_std: -20\.0 is outside the allowed range"):
        ResidualConfig(zero_start=True, initial_log_std=-20.0)
    with pytest.raises(ValueError, match=r"^residual\.zero_start: 'yes' is not true or false$"):
        ResidualConfig(zero_start="yes")
    with pytest.raises(ValueError, match=r"^residual\.observe_base: 1 is not true or false"):
        ResidualConfig(observe_base=1)
    cfg = ResidualConfig.from_any(
        {
            "base": "lqi",
            "zero_start": True,
            "initial_log_std": -2,
            "critic_burn_in": 300,
            "observe_base": True,
        }
    )
    assert ResidualConfig.from_any(cfg.to_dict()) == cfg and cfg.observe_base
    assert "observe_base" not in ResidualConfig().to_dict()
    # the distillation labels the rig's observation alone: the two are refused together
    distilled = load_config(CONFIGS / "ppo_robust_no_brake.yaml").to_dict()
    with pytest.raises(ValueError, match=r"^residual\.observe_base: not available with warm_start"):
        TrainConfig(**{**distilled, "residual": {**distilled["residual"], "observe_base": True}})
    # the base's own options: the feedforward's only, checked like a gains file's
    with pytest.raises(ValueError, match=r"^residual\.base_options: allowed only with base lqi_angle_ff"):
        ResidualConfig(base="lqi", base_options={"variable_step": True})
    with pytest.raises(
        ValueError, match=r"^residual\.base_options: expected a mapping of \['adaptation_time'"
    ):
        ResidualConfig(base="lqi_angle_ff", base_options={"step": 2})
    with pytest.raises(ValueError, match=r"^residual\.base_options\.significance: "):
        ResidualConfig(base="lqi_angle_ff", base_options={"variable_step": True, "significance": -1.0})
    cfg = ResidualConfig(base="lqi_angle_ff", base_options={"variable_step": True})
    assert cfg.to_dict()["base_options"] == {"variable_step": True}
    assert ResidualConfig.from_any(cfg.to_dict()) == cfg
    assert "base_options" not in ResidualConfig(base="lqi_angle_ff", base_options={}).to_dict()
    # a burn-in needs an off-policy critic: a PPO config with one is refused when it is loaded
    ppo = load_config(CONFIGS / "experiments" / "ppo_robust_from_scratch.yaml").to_dict()
    with pytest.raises(ValueError, match=r"^residual\.critic_burn_in: allowed only with algo sac"):
        TrainConfig(**{**ppo, "residual": {"base": "lqi", "critic_burn_in": 100}})


def _tiny_robust_config(residual=None) -> TrainConfig:
    cfg = load_config(CONFIGS / "experiments" / "ppo_robust_from_scratch.yaml").to_dict()
    cfg.update(total_timesteps=512, n_envs=2, torch_threads=1)
    cfg["evaluation"] = {"every_steps": 256, "episodes_per_regime": 1, "seed": 5}
    cfg["env_kwargs"] = {
        "warmup_time": 2.0,
        "warmup_jitter": 0.5,
        "domain_randomization": {"friction_rel": 0.1, "effects": EFFECTS},
    }
    cfg["hyperparameters"].update(n_steps=128, batch_size=64, n_epochs=2)
    if residual is not None:
        cfg["residual"] = residual
    return TrainConfig(**cfg)


def test_a_tiny_robust_training_run_writes_a_policy_the_benchmark_loads(tmp_path):
    cfg = _tiny_robust_config()
    agents_dir = tmp_path / "agents"
    summary = train(cfg, 2, agents_dir / "ppo_robust", tmp_path / "logs", progress_bar=False)
    assert summary["total_timesteps"] >= 512 and np.isfinite(summary["best_eval_return"])
    # each evaluation runs the policy of its moment, not the one at the start
    curve = np.loadtxt(agents_dir / "ppo_robust" / "eval.csv", delimiter=",", skiprows=1, usecols=2)
    assert curve.size == 3 and len(set(curve.tolist())) > 1
    saved = yaml.safe_load((agents_dir / "ppo_robust" / "config.yaml").read_text())
    assert saved["env_kwargs"]["domain_randomization"]["effects"]["motor_lag"] == [0.005, 0.02]
    # as the benchmark loads it: by name, from --agents-dir, on the observation it was trained on
    assert observation_version("ppo_robust", "brake", agents_dir) == 1
    settings = EpisodeSettings(duration=3.0, window=1.0, warmup_time=5.0, warmup_jitter=0.0)
    env = make_env("brake", settings, 1)
    with pytest.raises(UntrustedPolicyError, match="trusted=True"):
        build_controller("ppo_robust", env, "brake", agents_dir=agents_dir)
    policy = build_controller("ppo_robust", env, "brake", agents_dir=agents_dir, trusted=True)
    m = evaluate(policy, "brake", 1.0, 0, settings, name="ppo_robust", env=env)
    assert m.controller == "ppo_robust" and m.sim_status == 0 and np.isfinite(m.rms_error)
    with pytest.raises(ValueError, match="no trained ppo_robust policy for preset 'no_brake'"):
        build_controller("ppo_robust", env, "no_brake", agents_dir=agents_dir, trusted=True)


class _ConstantPolicy:
    """A stand-in for a trained policy: always the same normalised action."""

    def __init__(self, value: float):
        self.value = np.float32(value)

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(observation)
        shape = (1,) if obs.ndim == 1 else (obs.shape[0], 1)
        return np.full(shape, self.value, dtype=np.float32), None


@pytest.mark.parametrize("base_name", ["lqi", "torque_feedback"])
def test_residual_action_is_the_base_controllers_when_the_policy_outputs_zero(base_name):
    env = gym.make("DrillString-v1", warmup_time=10.0, warmup_jitter=0.0)
    spec = ControllerSpec.from_env(env)
    base = classical_controller(base_name, spec, "brake")
    twin = classical_controller(base_name, spec, "brake")  # run alone, its own state
    zero = ResidualPolicy(_ConstantPolicy(0.0), base, 0.2)
    push = ResidualPolicy(_ConstantPolicy(1.0), classical_controller(base_name, spec, "brake"), 0.2)
    obs, _ = env.reset(seed=4, options={"regime": "limit_cycle"})
    s_res = s_base = s_push = None
    start = np.ones(1, dtype=bool)
    for _ in range(60):
        a_res, s_res = zero.predict(obs, s_res, start)
        a_base, s_base = twin.predict(obs, s_base, start)
        a_push, s_push = push.predict(obs, s_push, start)
        np.testing.assert_array_equal(a_res, a_base)
        np.testing.assert_allclose(a_push, np.minimum(a_base + 0.2, 1.0), atol=1e-6)
        start = np.zeros(1, dtype=bool)
        obs, *_ = env.step(a_res)
    env.close()


def test_a_residual_base_with_options_is_that_feedforward_in_training_and_in_the_saved_policy(tmp_path):
    """``base_options`` reach the base wherever it is built: the training rigs' base (from the
    config) and the base of the policy loaded from the saved ``config.yaml`` are both
    ``lqi_angle_ff`` with the variable step, and act as one built directly with it (and not as
    the gains file's own, which differs once the adaptation starts)."""
    from drill_env.agents.controllers.angle_feedforward import LQIAngleFeedforward
    from drill_env.agents.controllers.gains import load_gains

    residual = {"base": "lqi_angle_ff", "scale": 0.2, "base_options": {"variable_step": True}}
    cfg = _tiny_robust_config(residual)
    base = base_controller(cfg.residual, cfg.env_id, cfg.env_kwargs)
    assert base.describe()["variable_step"] is True
    summary = train(cfg, 2, tmp_path / "ppo_robust", tmp_path / "logs", progress_bar=False)
    assert np.isfinite(summary["best_eval_return"])
    saved = yaml.safe_load((tmp_path / "ppo_robust" / "config.yaml").read_text())
    assert saved["residual"]["base_options"] == {"variable_step": True}
    policy = load_policy(tmp_path / "ppo_robust" / "policy.zip", trusted=True)  # made by this test
    assert policy.describe()["residual_on"]["variable_step"] is True
    env = gym.make("DrillString-v1", warmup_time=10.0, warmup_jitter=0.0)
    spec = ControllerSpec.from_env(env)
    gains = dict(load_gains(None)["presets"]["brake"]["lqi"]["gains"])
    direct = LQIAngleFeedforward(spec, **gains, variable_step=True)
    plain = classical_controller("lqi_angle_ff", spec, "brake")
    obs, _ = env.reset(seed=3, options={"regime": "limit_cycle"})
    s_l = s_d = s_p = None
    start = np.ones(1, dtype=bool)
    differs = 0.0
    for _ in range(1500):  # past the feedforward's hold: it adapts
        a_l, s_l = policy.base.predict(obs, s_l, start)
        a_d, s_d = direct.predict(obs, s_d, start)
        a_p, s_p = plain.predict(obs, s_p, start)
        np.testing.assert_array_equal(a_l, a_d)
        differs = max(differs, float(np.abs(a_l - a_p).max()))
        start = np.zeros(1, dtype=bool)
        obs, *_ = env.step(a_l)
    env.close()
    assert differs > 1e-4


@pytest.mark.parametrize("observe_base", [False, True])
def test_residual_training_rigs_with_a_zero_correction_run_the_base_controller(observe_base):
    """The training wrapper applies base + scale x correction, with the base's state reset where
    an episode ends: with zero corrections the rigs follow a plain rig set driven by the base
    controller, over an episode boundary. With observe_base every observation, the terminal
    ones too, carries the action and feedforward share of a base run alone beside it."""
    residual = {"base": "lqi_angle_ff", "scale": 0.2, "observe_base": observe_base}
    cfg = _tiny_robust_config(residual)
    cfg_plain = TrainConfig(**{**cfg.to_dict(), "residual": None})
    residual_rigs = make_train_vec_env(cfg, 11)
    plain_rigs = make_train_vec_env(cfg_plain, 11)
    n_obs = plain_rigs.observation_space.shape[0]
    k = len(BASE_OBSERVATIONS) if observe_base else 0
    assert residual_rigs.observation_space.shape == (n_obs + k,)
    base = base_controller(cfg.residual, cfg.env_id, cfg.env_kwargs)
    twin = base_controller(cfg.residual, cfg.env_id, cfg.env_kwargs)  # for the terminal observations
    obs_r, obs_p = residual_rigs.reset(), plain_rigs.reset()
    state, start = None, np.ones(2, dtype=bool)
    n_done, ff_seen = 0, 0.0
    for _ in range(420):  # the episodes last 400 steps
        a, ff, next_state = step_base(base, obs_p, state, start)
        np.testing.assert_array_equal(obs_r[:, :n_obs], obs_p)
        if observe_base:
            np.testing.assert_array_equal(obs_r[:, n_obs:], np.concatenate([a, ff], axis=1))
            ff_seen = max(ff_seen, float(np.abs(ff).max()))
        obs_r, rew_r, done_r, info_r = residual_rigs.step(np.zeros((2, 1), dtype=np.float32))
        obs_p, rew_p, done_p, info_p = plain_rigs.step(a)
        np.testing.assert_array_equal(rew_r, rew_p)
        for i in np.flatnonzero(done_p):
            terminal_r, terminal_p = info_r[i]["terminal_observation"], info_p[i]["terminal_observation"]
            np.testing.assert_array_equal(terminal_r[:n_obs], terminal_p)
            if observe_base:  # what the base would do there, still in its episode
                a_end, ff_end, _ = step_base(twin, terminal_p, next_state[i : i + 1], None)
                np.testing.assert_array_equal(terminal_r[n_obs:], [a_end[0, 0], ff_end[0, 0]])
        state, start = next_state, done_p
        n_done += int(done_p.sum())
    assert n_done == 2
    assert not observe_base or ff_seen > 1e-3  # the feedforward entry is not a constant 0
    residual_rigs.close()
    plain_rigs.close()


def test_a_residual_policy_that_observes_its_base_sees_what_the_training_rigs_showed(tmp_path):
    """A tiny observe_base run: the saved policy takes the base's two entries after the rig's
    observation, the benchmark loads it on the rig's observation version and runs it, and its
    action is the base's plus the saved network's correction of the extended observation."""
    cfg = _tiny_robust_config({"base": "lqi_angle_ff", "scale": 0.2, "observe_base": True})
    agents_dir = tmp_path / "agents"
    train(cfg, 2, agents_dir / "ppo_robust", tmp_path / "logs", progress_bar=False)
    assert observation_version("ppo_robust", "brake", agents_dir) == 1
    settings = EpisodeSettings(duration=3.0, window=1.0, warmup_time=5.0, warmup_jitter=0.0)
    env = make_env("brake", settings, 1)
    with pytest.raises(UntrustedPolicyError, match="trusted=True"):
        build_controller("ppo_robust", env, "brake", agents_dir=agents_dir)
    policy = build_controller("ppo_robust", env, "brake", agents_dir=agents_dir, trusted=True)
    assert isinstance(policy, ResidualPolicy) and policy.observe_base
    n_obs = env.observation_space.shape[0]
    assert policy.policy.observation_space.shape == (n_obs + 2,)
    assert policy.observation_space.shape == (n_obs,)
    assert policy.describe()["observes"] == list(BASE_OBSERVATIONS)
    twin = base_controller(cfg.residual, cfg.env_id, cfg.env_kwargs)
    obs, _ = env.reset(seed=3, options={"nominal_voltage": 1.0})
    state = twin_state = None
    start = np.ones(1, dtype=bool)
    for _ in range(20):
        action, state = policy.predict(obs, state, start)
        a, ff, twin_state = step_base(twin, obs, twin_state, start)
        seen = np.concatenate([obs, a[0], ff[0]]).astype(np.float32)
        correction = policy.policy.model.predict(seen, deterministic=True)[0]
        # the benchmark's numpy forward pass against SB3's torch one: float32 rounding, at most
        # 5e-5 of the correction's range (x 0.2); the base's entries swapped move it by 6e-4
        np.testing.assert_allclose(action, np.clip(a[0] + 0.2 * correction, -1, 1), atol=2e-5)
        start = np.zeros(1, dtype=bool)
        obs, *_ = env.step(action)
    m = evaluate(policy, "brake", 1.0, 0, settings, name="ppo_robust", env=env)
    assert m.sim_status == 0 and np.isfinite(m.rms_error)
    # an env whose observation is not the one the policy saw before the base's entries
    with pytest.raises(ValueError, match=r"(?s)observation_space: .* before its \['base_action'"):
        policy.check_env(make_env("brake", settings, 0))


def _tiny_sac_config(residual) -> TrainConfig:
    cfg = load_config(CONFIGS / "experiments" / "sac_residual.yaml").to_dict()
    cfg.update(total_timesteps=256, n_envs=2, torch_threads=1, residual=residual)
    cfg["evaluation"] = {"every_steps": 128, "episodes_per_regime": 1, "seed": 5}
    cfg["env_kwargs"] = {"warmup_time": 2.0, "warmup_jitter": 0.5}
    cfg["hyperparameters"].update(learning_starts=64, batch_size=32, gradient_steps=2, buffer_size=1000)
    return TrainConfig(**cfg)


def test_a_zero_start_sac_residual_is_its_base_until_the_burn_in_ends(tmp_path):
    """zero_start: the untrained policy's deterministic correction is exactly zero (the policy is
    its base controller) with the asked exploration spread; critic_burn_in: the actor is the
    same after the burn-in's gradient steps while the critics learn, and learns after it."""
    import torch
    from stable_baselines3 import SAC

    from drill_env.agents.learning.residual import critic_burn_in_callback, start_from_base

    residual = ResidualConfig(base="lqi", zero_start=True, initial_log_std=-2.5, critic_burn_in=10_000)
    # through `train`: a run shorter than the burn-in leaves the policy at its start
    train(_tiny_sac_config(residual.to_dict()), 3, tmp_path / "sac", tmp_path / "logs", progress_bar=False)
    # the file of a residual policy's correction loads only as stable-baselines3's own class
    from drill_env.agents.learning.residual import correction_policy_class

    sac_class = {"policy_class": correction_policy_class("sac", stable_baselines3=True)}
    model = SAC.load(str(tmp_path / "logs" / "final_policy.zip"), device="cpu", custom_objects=sac_class)
    assert model.num_timesteps >= 256 and model._n_updates > 0  # the critics did learn
    obs = np.random.default_rng(0).normal(size=(50, model.observation_space.shape[0])).astype(np.float32)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], 0.0)
    _, log_std, _ = model.policy.actor.get_action_dist_params(torch.as_tensor(obs))
    np.testing.assert_array_equal(log_std.detach().numpy(), -2.5)

    # a burn-in shorter than the run: frozen for its steps, then learning
    venv = make_train_vec_env(_tiny_sac_config(None), 4)
    model = SAC("MlpPolicy", venv, learning_starts=32, batch_size=32, gradient_steps=1, seed=4, device="cpu")
    short = ResidualConfig(base="lqi", zero_start=True, critic_burn_in=100)
    start_from_base(model, short)
    mu0 = model.policy.actor.mu.weight.detach().clone()
    critic0 = [p.detach().clone() for p in model.critic.parameters()]
    model.learn(96, callback=critic_burn_in_callback(model, short))
    assert torch.equal(model.policy.actor.mu.weight, mu0)
    assert any(not torch.equal(a, b) for a, b in zip(critic0, model.critic.parameters(), strict=True))
    model.learn(64, callback=critic_burn_in_callback(model, short), reset_num_timesteps=False)
    assert not torch.equal(model.policy.actor.mu.weight, mu0)
    venv.close()


ROBUST_POLICIES = [(n, p) for n in ("ppo_robust", "sac_robust") for p in ("brake", "no_brake")]


@pytest.mark.parametrize(("name", "preset"), ROBUST_POLICIES)
def test_committed_robust_policies_were_trained_over_the_family(name, preset):
    """The committed robust policies were trained over the whole standard family (each of its
    parameter factors within the training ranges, the shipped effects and noise), load as what
    their config says, and are learned: the kept (evaluation-best) policy is a later one than
    the start and beat it."""
    from drill_env.agents.evaluation.plants import standard_family

    shipped = yaml.safe_load((CONFIGS / "experiments" / "ppo_robust_from_scratch.yaml").read_text())[
        "env_kwargs"
    ]["domain_randomization"]
    for config in (
        "ppo_robust",
        "experiments/ppo_robust_residual_no_brake",
        "experiments/sac_residual",
        "experiments/sac_residual_no_brake",
    ):
        assert (
            yaml.safe_load((CONFIGS / f"{config}.yaml").read_text())["env_kwargs"]["domain_randomization"]
            == shipped
        )
        cfg = load_config(CONFIGS / f"{config}.yaml")
        assert (cfg.algo, cfg.residual.base) == (Path(config).name.split("_")[0], "lqi_angle_ff")
    dr = DomainRandomization.from_any(shipped)
    assert dr.effects["lower_position_amp_1"] == (0.0, 0.15)
    folder = name if preset == "brake" else f"{name}_{preset}"
    path = ROOT / "results" / "agents" / folder
    committed = yaml.safe_load((path / "config.yaml").read_text())
    ranges = committed["env_kwargs"]["domain_randomization"]
    # the same effects and noise as the shipped ranges; the parametric ranges at least the
    # family's (the sac_robust configs widen them)
    assert {k: v for k, v in ranges.items() if not k.endswith("_rel")} == {
        k: v for k, v in shipped.items() if not k.endswith("_rel")
    }
    group = {
        "lower_inertia": "inertia_rel",
        "string_stiffness": "stiffness_rel",
        "lower_static": "friction_rel",
        "lower_hump_1": "friction_rel",
        "lower_hump_2": "friction_rel",
        "motor_constant": "motor_constant_rel",
    }
    family = standard_family()
    assert {p for plant in family for p in plant.scale} == set(group)
    for plant in family:
        for parameter, factor in plant.scale.items():
            assert abs(factor - 1.0) <= ranges[group[parameter]] + 1e-12, (plant.name, ranges)
        for effect, value in plant.effects.items():
            lo, hi = ranges["effects"][effect]
            assert lo <= value <= hi, (plant.name, effect)
        if "angle_noise_std" in plant.sensors:
            assert plant.sensors["angle_noise_std"] <= ranges["angle_noise_std"][1]
    assert committed["algo"] == name.split("_")[0]
    # the shipped config of that policy is the one it was trained with
    assert committed == load_config(CONFIGS / f"{training_config(name, preset)}.yaml").to_dict()
    summary = json.loads((path / "training_summary.json").read_text())
    start = np.loadtxt(path / "eval.csv", delimiter=",", skiprows=1, usecols=2, max_rows=1)
    assert summary["best_at_timesteps"] > 0 and summary["best_eval_return"] > float(start)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # committed: loads without a warning
        env = make_env(preset, EpisodeSettings(), 1)
        policy = build_controller(name, env, preset)
    assert isinstance(policy, ResidualPolicy) == ("residual" in committed)


# every committed policy folder (results/agents/<name>/ and the earlier results/agents/v0/<name>/)
SHIPPED_POLICY_FOLDERS = sorted(
    p.parent.relative_to(ROOT / "results" / "agents").as_posix()
    for p in (ROOT / "results" / "agents").glob("**/policy.zip")
)


def test_the_shipped_policy_folders_are_the_benchmarks_and_the_earlier_ones():
    from drill_env.agents.registry import LEARNED

    current = {f"{c}{suffix}" for c in LEARNED for suffix in ("", "_no_brake")}
    earlier = {f"v0/{c}{suffix}" for c in ("ppo", "sac") for suffix in ("", "_no_brake")}
    assert set(SHIPPED_POLICY_FOLDERS) == current | earlier


@pytest.mark.parametrize("folder", SHIPPED_POLICY_FOLDERS)
def test_every_shipped_policy_was_trained_with_the_config_of_its_name(folder):
    """configs/agents/<name>.yaml is the recipe of results/agents/<name>/: the config the
    policy was trained with, as its folder records it, and the one the registry names."""
    committed = yaml.safe_load((ROOT / "results" / "agents" / folder / "config.yaml").read_text())
    summary = json.loads((ROOT / "results" / "agents" / folder / "training_summary.json").read_text())
    assert summary["config"] == committed
    if folder.startswith("v0/"):  # trained in SB3's DummyVecEnv before the config named it
        assert "vec_env" not in committed
        committed = {**committed, "vec_env": "dummy"}
    assert committed == load_config(CONFIGS / f"{folder}.yaml").to_dict()
    name = Path(folder).name
    if "/" not in folder:
        base, preset = (
            (name[: -len("_no_brake")], "no_brake") if name.endswith("_no_brake") else (name, "brake")
        )
        assert training_config(base, preset) == name


@pytest.mark.parametrize(
    ("name", "preset"), [("sac_robust", "brake"), ("sac_robust", "no_brake"), ("ppo_robust", "no_brake")]
)
def test_committed_policies_that_ignore_the_encoder_angles_do(name, preset):
    """A committed policy whose config ignores the encoder angles acts the same whatever the
    angles: its correction is no forcing at the rotation frequency."""
    from drill_env.agents.learning.rl import load_policy, observation_names
    from drill_env.agents.registry import policy_path

    path = policy_path(name, preset)
    cfg = load_config(path.parent / "config.yaml")
    assert set(cfg.ignored_observations) == {
        "lower_angle_sin",
        "lower_angle_cos",
        "upper_angle_sin",
        "upper_angle_cos",
    }
    model = load_policy(path).policy.model
    names = observation_names(cfg.env_id)
    rng = np.random.default_rng(5)
    obs = rng.normal(size=(64, len(names))).astype(np.float32)
    turned = obs.copy()
    for disk in ("lower", "upper"):
        phase = rng.uniform(0.0, 2.0 * np.pi, size=64)
        turned[:, names.index(f"{disk}_angle_sin")] = np.sin(phase)
        turned[:, names.index(f"{disk}_angle_cos")] = np.cos(phase)
    a0 = model.predict(obs, deterministic=True)[0]
    a1 = model.predict(turned, deterministic=True)[0]
    assert np.ptp(model.predict(obs[::-1], deterministic=True)[0] - a0) > 1e-3  # it does act on the rest
    np.testing.assert_array_equal(a0, a1)


@pytest.mark.parametrize(("preset", "plant"), [("brake", "hump_x1.20"), ("no_brake", "km_x0.95")])
def test_committed_sac_robust_suppresses_where_its_correction_once_sustained_a_cycle(preset, plant):
    """At 0.7 V on these plants the `sac_robust` trained with the family's own ranges sustained
    an oscillation its base does not have (suppression 0.575-0.712 with the brake, 0.786
    without; the base 0.987 and 0.992). The committed policies, trained with the plants inside
    their ranges, suppress the cycle there as the base does (the benchmark's run, seed 0)."""
    from drill_env.agents.controllers.open_loop import OpenLoop
    from drill_env.agents.evaluation.plants import standard_family

    # the benchmark's run (agents/evaluation/timeseries.py builds the same two envs), on this plant only
    family = {p.name: p for p in standard_family()}
    settings = EpisodeSettings()
    version = observation_version("sac_robust", preset)
    design = make_env(preset, settings, version)
    env = make_env(preset, settings, version, params=family[plant].rig(preset))
    try:
        reference = evaluate(
            OpenLoop(ControllerSpec.from_env(env)), preset, 0.7, 0, settings, env=env, open_loop_amplitude=0.0
        )
        policy = build_controller("sac_robust", design, preset)
        res = evaluate(policy, preset, 0.7, 0, settings, env=env, open_loop_amplitude=reference.amplitude)
    finally:
        env.close()
        design.close()
    assert reference.amplitude > 0.5  # a cycle to suppress [rad/s]
    assert res.suppression >= 0.95, res
    assert res.rms_error < 0.03, res  # [rad/s]


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_committed_robust_policies_are_at_least_the_nominal_ones_on_the_worst_case_over_the_family(preset):
    """The target on the committed results (`results/robust_rl/five_seeds/`: the learned
    policies over the full family grid, seeds 0-4, command in results/README.md): at every
    voltage each robust policy's worst run over the plants and seeds is above 0.85, and
    ppo_robust's at least ppo's wherever the design model's target is reachable on the plant,
    but for margins under 0.004 against the from-scratch v3 `ppo` without the brake (sac_robust
    is behind sac at some voltages: summary.md). The run that sets `ppo_robust`'s smallest
    margin is re-run with the committed policy and reproduces the CSV: the results are this
    policy's, not an earlier one's.

    Reproduces to within 30 % of the amplitude, not to the last digit: the run is chaotic
    (stick-slip on a plant with position-dependent friction), and NumPy's BLAS chooses its
    kernels by CPU, so the controllers' matrix products differ in the last bits from one
    machine to another. Re-run under every OpenBLAS core type this machine can execute
    (``OPENBLAS_CORETYPE``), the amplitude of these runs spread by 1.1 % with the brake and 19 %
    without it; the kernels of the machine the results were made on reproduce them exactly."""
    from drill_env.agents.evaluation.benchmark.store import load_results
    from drill_env.agents.evaluation.plants import standard_family
    from drill_env.agents.evaluation.robustness import worst_by_voltage, worst_case_verdict

    folder = ROOT / "results" / "robust_rl" / "five_seeds"
    df = load_results(folder / "benchmark.csv")
    assert set(df["seed"]) == set(range(5)) and df["plant"].nunique() == len(standard_family())
    worst = worst_by_voltage(df, preset)
    family = {p.name: p for p in standard_family()}

    def unreachable(plant_name: str, voltage: float) -> bool:
        """The design model's target speed at ``voltage`` is beyond what the plant turns at the
        amplifier limit: every controller saturates there (k_m -5 % at 5 V)."""
        from drill_env.envs.task import VOLTAGE_LIMIT, equilibrium_speed, nominal_params
        from drill_env.params import load_params

        rig = nominal_params(family[plant_name].rig(preset) or load_params(preset))
        return equilibrium_speed(rig, VOLTAGE_LIMIT) < equilibrium_speed(load_params(preset), voltage)

    for robust, nominal in (("ppo_robust", "ppo"), ("sac_robust", "sac")):
        verdict = worst_case_verdict(worst, robust, nominal)
        assert verdict["voltages"] == len(worst[nominal]) >= 9, verdict
        assert min(s for s, _ in worst[robust].values()) >= 0.85
        if robust == "ppo_robust":
            # with the design model's set point (the rule since the benchmark stopped handing the
            # controllers the plant's), ppo_robust is behind ppo where the target cannot be
            # reached within the amplifier's 5 V on the worst plant, and, since `ppo` is the
            # from-scratch policy of the v3 envs, without the brake at 1.15-1.6 V by less than
            # 0.004 (0.0034, 0.0026, 0.0016 and 0.0004 in the committed results, worst runs of
            # 0.986-0.993 against 0.990-0.994, both on the 3 mrad angle noise): nowhere by more
            assert all(
                unreachable(worst[robust][v][1], v) or margin > -0.004
                for v, margin in verdict["behind"].items()
            ), verdict
    _, voltage = worst_case_verdict(worst, "ppo_robust", "ppo")["smallest"]
    suppression, plant_name = worst["ppo_robust"][voltage]
    rows = df[(df["preset"] == preset) & (df["controller"] == "ppo_robust") & (df["voltage"] == voltage)]
    row = rows[(rows["plant"] == plant_name) & (rows["suppression"] == suppression)].iloc[0]
    plant = {p.name: p for p in standard_family()}[plant_name]
    settings = EpisodeSettings(
        **{
            k: v
            for k, v in json.loads((folder / "benchmark_config.json").read_text())["episode"].items()
            if k != "env_kwargs"
        }
    )
    version = observation_version("ppo_robust", preset)
    design = make_env(preset, settings, version)
    env = make_env(preset, settings, version, params=plant.rig(preset), overrides=plant.env_overrides())
    try:
        policy = build_controller("ppo_robust", design, preset)
        res = evaluate(
            policy,
            preset,
            voltage,
            int(row["seed"]),
            settings,
            env=env,
            open_loop_amplitude=row["open_loop_amplitude"],
        )
    finally:
        env.close()
        design.close()
    assert res.amplitude == pytest.approx(row["amplitude"], rel=0.3)
