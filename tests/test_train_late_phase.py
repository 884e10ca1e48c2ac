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
