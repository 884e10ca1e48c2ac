"""The late phase of an off-policy run (``late_phase`` in a training config)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from drill_env.agents.learning.late_phase import LatePhaseConfig, apply_late_phase, late_phase_callback
from drill_env.agents.learning.rl import TrainConfig, load_config

CONFIGS = Path(__file__).resolve().parent.parent / "configs" / "agents"


@pytest.mark.parametrize(
    ("section", "message"),
    [
        ({"after": 0.0, "tau": 0.005}, "late_phase.after"),
        ({"after": 1.0, "tau": 0.005}, "late_phase.after"),
        ({"after": True, "tau": 0.005}, "late_phase.after"),
        ({"batch_size": 0}, "late_phase.batch_size"),
        ({"gradient_steps": 2.5}, "late_phase.gradient_steps"),
        ({"tau": 1.5}, "late_phase.tau"),
        ({"freeze_ent_coef": "yes"}, "late_phase.freeze_ent_coef"),
        ({"after": 0.5}, "changes nothing"),
        ({"tau": 0.005, "lr": 1e-4}, "unknown key"),
    ],
)
def test_late_phase_config_names_the_bad_field(section, message):
    with pytest.raises(ValueError, match=message):
        LatePhaseConfig.from_any(section)


def test_late_phase_only_where_it_means_something():
    with pytest.raises(ValueError, match="not ppo"):
        TrainConfig(algo="ppo", late_phase={"tau": 0.005})
    with pytest.raises(ValueError, match="crossq has no target networks"):
        TrainConfig(algo="crossq", late_phase={"tau": 0.005})
    cfg = TrainConfig(algo="sac", late_phase={"after": 0.25, "batch_size": 64, "freeze_ent_coef": True})
    assert cfg.to_dict()["late_phase"] == {"after": 0.25, "batch_size": 64, "freeze_ent_coef": True}
    assert TrainConfig(**cfg.to_dict()) == cfg  # the run folder's config.yaml reads back
    assert "late_phase" not in TrainConfig(algo="sac").to_dict()  # absent from the configs without one


def _sac(**kw):
    from stable_baselines3 import SAC

    # a small gymnasium task: what is tested is the learner's settings, not the rig
    import gymnasium as gym

    venv = gym.make("Pendulum-v1", max_episode_steps=50)
    kw = {"learning_starts": 20, "buffer_size": 500, "batch_size": 16, "tau": 0.01, **kw}
    return SAC("MlpPolicy", venv, seed=0, device="cpu", policy_kwargs={"net_arch": [16, 16]}, **kw)


def test_the_late_phase_switches_once_at_its_fraction_of_the_run():
    model = _sac(gradient_steps=4)
    seen: list[tuple[int, int, int, float]] = []

    from stable_baselines3.common.callbacks import BaseCallback

    class _Record(BaseCallback):
        def _on_step(self) -> bool:
            m = self.model
            seen.append((self.num_timesteps, m.batch_size, m.gradient_steps, m.tau))
            return True

    late = LatePhaseConfig(after=0.5, batch_size=32, gradient_steps=2, tau=0.005, freeze_ent_coef=True)
    cb = late_phase_callback(late, 200)
    model.learn(200, callback=[cb, _Record()])
    before = [s for s in seen if s[0] < 100]
    after = [s for s in seen if s[0] >= 100]
    assert before and after
    assert all(s[1:] == (16, 4, 0.01) for s in before)
    assert all(s[1:] == (32, 2, 0.005) for s in after)
    assert cb.switched["at_timesteps"] == 100
    # the entropy coefficient is held at the value it had when the late phase began
    assert model.ent_coef_optimizer is None
    assert float(model.ent_coef_tensor) == pytest.approx(cb.switched["ent_coef"])
    assert late_phase_callback(None, 200) is None


def test_a_frozen_entropy_coefficient_stays_put_and_is_what_sac_trains_with():
    model = _sac(gradient_steps=1)
    model.learn(60)
    with torch.no_grad():
        model.log_ent_coef.fill_(math.log(0.123))
    done = apply_late_phase(model, LatePhaseConfig(after=0.5, freeze_ent_coef=True))
    assert done == {"ent_coef": pytest.approx(0.123)}
    model.learn(60, reset_num_timesteps=False)
    assert float(model.ent_coef_tensor) == pytest.approx(0.123)
    assert model.logger.name_to_value["train/ent_coef"] == pytest.approx(0.123)
    # without the freeze the coefficient keeps adapting
    free = _sac(gradient_steps=1)
    free.learn(60)
    with torch.no_grad():
        free.log_ent_coef.fill_(math.log(0.123))
    free.learn(60, reset_num_timesteps=False)
    assert not np.isclose(float(torch.exp(free.log_ent_coef.detach())), 0.123, rtol=1e-4)


def test_the_late_phase_recipe_on_the_rig_without_the_brake_loads():
    cfg = load_config(CONFIGS / "experiments" / "sac_late_no_brake.yaml")
    assert cfg.late_phase is not None and cfg.algo == "sac"
    base = load_config(CONFIGS / "sac_no_brake.yaml").to_dict()
    trial = cfg.to_dict()
    trial.pop("late_phase")
    assert trial == base  # the shipped recipe with a late phase, nothing else


def test_the_averaged_actor_is_the_polyak_average_and_is_swapped_in_only_inside():
    from stable_baselines3.common.callbacks import BaseCallback

    from drill_env.agents.learning.late_phase import averaged_actor

    model = _sac(gradient_steps=1)
    late = LatePhaseConfig(after=0.4, actor_average=0.2)
    cb = late_phase_callback(late, 150)
    snapshots: list[list[torch.Tensor]] = []

    class _Record(BaseCallback):  # runs after the late phase's callback, before the same train call
        def _on_step(self) -> bool:
            if self.num_timesteps >= 60:
                snapshots.append([p.detach().clone() for p in self.model.actor.parameters()])
            return True

    with averaged_actor(model, cb):  # before the switch: nothing to swap in
        pass
    model.learn(150, callback=[cb, _Record()])
    expected = [t.clone() for t in snapshots[0]]  # the actor at the switch
    for snap in snapshots[1:]:
        expected = [0.8 * e + 0.2 * s for e, s in zip(expected, snap, strict=True)]
    for a, e in zip(cb.average, expected, strict=True):
        torch.testing.assert_close(a, e, rtol=1e-5, atol=1e-6)
    own = [p.detach().clone() for p in model.actor.parameters()]
    assert any(not torch.equal(a, o) for a, o in zip(cb.average, own, strict=True))
    with averaged_actor(model, cb):
        for p, a in zip(model.actor.parameters(), cb.average, strict=True):
            assert torch.equal(p, a)
    for p, o in zip(model.actor.parameters(), own, strict=True):
        assert torch.equal(p, o)
    with pytest.raises(RuntimeError, match="inside"), averaged_actor(model, cb):
        raise RuntimeError("inside")
    for p, o in zip(model.actor.parameters(), own, strict=True):
        assert torch.equal(p, o)  # restored after an error too


def test_train_evaluates_and_saves_the_averaged_actor(tmp_path):
    """With the average started before the first gradient step and a rate of ~0 it stays the
    initial actor: every evaluation scores that same policy, and the saved files hold it."""
    from drill_env.agents.learning.rl import load_policy, train

    cfg = load_config(CONFIGS / "experiments" / "sac_v1.yaml").to_dict()
    cfg.update(total_timesteps=300, n_envs=1)
    cfg["evaluation"] = {"every_steps": 100, "episodes_per_regime": 1, "seed": 7}
    cfg["env_kwargs"] = {"warmup_time": 2.0, "warmup_jitter": 0.5}
    cfg["hyperparameters"].update(learning_starts=100, buffer_size=1000, batch_size=32)
    cfg["late_phase"] = {"after": 0.01, "actor_average": 1e-12}
    train(TrainConfig(**cfg), 3, tmp_path / "out", tmp_path / "run", progress_bar=False)
    curve = np.genfromtxt(tmp_path / "out" / "eval.csv", delimiter=",", names=True)
    assert len(curve) >= 4 and np.ptp(curve["mean_return"]) < 1e-6 * abs(curve["mean_return"][0])
    kept = load_policy(tmp_path / "out" / "policy.zip", trusted=True)  # made by this test
    final = load_policy(tmp_path / "run" / "final_policy.zip", trusted=True)
    obs = np.random.default_rng(0).uniform(-1, 1, (16, kept.observation_space.shape[0])).astype(np.float32)
    np.testing.assert_allclose(kept.predict(obs)[0], final.predict(obs)[0], atol=1e-6)
    # the same run without the average trains its actor away from the initial one
    cfg.pop("late_phase")
    train(TrainConfig(**cfg), 3, tmp_path / "out2", tmp_path / "run2", progress_bar=False)
    moved = load_policy(tmp_path / "run2" / "final_policy.zip", trusted=True)
    assert np.max(np.abs(moved.predict(obs)[0] - final.predict(obs)[0])) > 1e-4


def test_a_learning_rate_that_decays_and_is_then_held():
    from drill_env.agents.learning.rl import algo_kwargs

    lr = algo_kwargs({"learning_rate": {"start": 1.0e-3, "end": 1.0e-4, "end_fraction": 0.6}})["learning_rate"]
    # progress_remaining runs from 1 to 0 over the run: the slope of lin_1.0e-3 over 0.6 of a 0.9 M run
    for done, value in ((0.0, 1.0e-3), (0.3, 5.5e-4), (0.6, 1.0e-4), (0.8, 1.0e-4), (1.0, 1.0e-4)):
        assert lr(1.0 - done) == pytest.approx(value, rel=1e-9)
    slope = (lr(1.0) - lr(1.0 - 0.1)) / (0.1 * 900_000)
    assert slope == pytest.approx(1.0e-3 / 600_000, rel=1e-9)
    for bad, message in (
        ({"start": 1e-3, "end": 1e-4}, "exactly the keys"),
        ({"start": 1e-3, "end": 2e-3, "end_fraction": 0.5}, "0 <= end <= start"),
        ({"start": 0.0, "end": 0.0, "end_fraction": 0.5}, "start > 0"),
        ({"start": 1e-3, "end": 0.0, "end_fraction": 0.0}, "end_fraction"),
        ({"start": "fast", "end": 0.0, "end_fraction": 0.5}, "learning_rate.start"),
    ):
        with pytest.raises(ValueError, match=message):
            algo_kwargs({"learning_rate": bad})
    cfg = load_config(CONFIGS / "experiments" / "sac_floor_no_brake.yaml")
    assert TrainConfig(**cfg.to_dict()) == cfg
