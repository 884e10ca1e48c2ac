"""The feedforward of an identified position-dependent friction
(agents/controllers/effect_feedforward.py): what a design on a corrected model does with the
effect the discrepancy workflow named."""

from __future__ import annotations

import numpy as np
import pytest

from drill_env.agents.controllers.base import ControllerSpec
from drill_env.agents.controllers.effect_feedforward import (
    LQIEffectFeedforward,
    has_position_effect,
    orbit_decay_rate,
)
from drill_env.agents.controllers.gains import classical_controller
from drill_env.agents.controllers.linear_model import design_point, sampled_rig, sampled_sinusoid_input
from drill_env.agents.controllers.lqi import LQI
from drill_env.agents.controllers.open_loop import OpenLoop
from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env
from drill_env.envs.task import equilibrium_speed
from drill_env.params import load_params

BRAKE = load_params("brake")
# the worked example's corrected model: the paper's lower position friction, k_m +3 %, J_l +5 %
MODEL = BRAKE.replace(
    motor_constant=BRAKE.motor_constant * 1.03,
    lower_inertia=BRAKE.lower_inertia * 1.05,
    lower_position_amp_1=0.12,
    lower_position_phase_1=4.0,
    lower_position_amp_2=0.016,
    lower_position_phase_2=0.26,
)
SETTINGS = EpisodeSettings(duration=40.0, window=12.0, warmup_time=40.0, warmup_jitter=1.0)


def _spec(design=MODEL, version=1) -> ControllerSpec:
    env = make_env("brake", SETTINGS, version, design_params=design)
    try:
        return ControllerSpec.from_env(env)
    finally:
        env.close()


def test_the_sinusoid_input_column_at_zero_frequency_is_the_held_voltages():
    """An independent check of the torque column: a constant torque km u on the upper disk is
    the held voltage u of sampled_rig."""
    eq = design_point(BRAKE, speed=1.6)
    rig = sampled_rig(BRAKE, eq, 0.05)
    col = BRAKE.motor_constant * sampled_sinusoid_input(BRAKE, eq, 0.05, None, "upper", 0.0)
    assert np.allclose(col[:-1], rig.G[:-1], rtol=1e-10, atol=1e-12)
    assert col[-1] == 0  # the torque is no voltage the controller remembers
    # a slow sinusoid is nearly held; a fast one is not
    slow = sampled_sinusoid_input(BRAKE, eq, 0.05, None, "lower", 1e-6)
    held = sampled_sinusoid_input(BRAKE, eq, 0.05, None, "lower", 0.0)
    assert np.allclose(slow, held, atol=1e-8)
    assert not np.allclose(sampled_sinusoid_input(BRAKE, eq, 0.05, None, "lower", 20.0), held, atol=1e-3)


def test_lqi_designed_on_a_model_with_position_friction_feeds_it_forward():
    spec = _spec()
    assert has_position_effect(spec.effects) and not spec.params.effects.active
    lqi = classical_controller("lqi", spec, "brake")
    assert isinstance(lqi, LQIEffectFeedforward)
    assert type(classical_controller("lqi", _spec(design=None), "brake")) is LQI  # the nominal design
    with pytest.raises(ValueError, match="encoder angles"):
        classical_controller("lqi", _spec(version=0), "brake")
    d = lqi.effect.design(equilibrium_speed(MODEL, 1.0))
    assert 0.05 < abs(d.lower[0]) < 1.0 and np.all(d.upper == 0)


@pytest.mark.parametrize("voltage", [0.3, 0.7, 1.0, 1.5, 3.0])
def test_the_rotation_with_the_feedforward_is_stable_on_the_corrected_model(voltage):
    """Floquet multipliers of the periodic linearisation over one revolution, the trivial one
    (the rotation's phase) left out: stable, and about as fast as the LQI without the effect."""
    lqi = classical_controller("lqi", _spec(), "brake")
    w = equilibrium_speed(MODEL, voltage)
    rate = lqi.effect.decay_rate(w)
    plain = orbit_decay_rate(lqi.spec.params, type(MODEL.effects)(), w, lqi.effect.feedback, None)
    assert rate > 0.03, rate
    assert abs(rate - plain) < 0.05, (rate, plain)


@pytest.mark.slow
def test_the_feedforward_cancels_the_identified_friction_in_simulation():
    """On the corrected model itself (it has the effect), from the open-loop cycle at 1 V: the
    LQI alone leaves most of the cycle, the LQI with the feedforward removes it, and the
    feedforward designed on a model without the effect is the LQI alone."""
    env = make_env("brake", SETTINGS, 1, params=MODEL, design_params=MODEL)
    try:
        ol = evaluate(
            OpenLoop(ControllerSpec.from_env(env)),
            "brake",
            1.0,
            0,
            SETTINGS,
            env=env,
            open_loop_amplitude=0.0,
        )
        after = evaluate(
            classical_controller("lqi", _spec(), "brake"),
            "brake",
            1.0,
            0,
            SETTINGS,
            env=env,
            open_loop_amplitude=ol.amplitude,
        )
        plain = LQI(_spec(), **{k: v for k, v in _gains().items()})
        assert not hasattr(plain, "effect")
        before = evaluate(plain, "brake", 1.0, 0, SETTINGS, env=env, open_loop_amplitude=ol.amplitude)
    finally:
        env.close()
    assert ol.amplitude > 1.0
    assert before.suppression < 0.8, before
    assert after.suppression > 0.95 and after.rms_error < 0.02 and not after.stalled, after


def _gains():
    from drill_env.agents.controllers.gains import load_gains

    return load_gains()["presets"]["brake"]["lqi"]["gains"]


def test_a_residual_policy_base_is_redesigned_on_the_design_model():
    from drill_env.agents.registry import build_controller

    env = make_env("brake", SETTINGS, 1, design_params=MODEL)
    nominal = make_env("brake", SETTINGS, 1)
    try:
        after = build_controller("ppo_robust", env, "brake")
        before = build_controller("ppo_robust", nominal, "brake")
    finally:
        env.close()
        nominal.close()
    assert after.base.effect is not None and before.base.effect is None
    assert after.base.spec.params.motor_constant == pytest.approx(MODEL.motor_constant)
    assert after.policy is not None and after.base.adaptation_time == before.base.adaptation_time


def test_upper_position_friction_is_fed_forward_in_the_upper_angle_and_stays_stable():
    model = BRAKE.replace(upper_position_amp_1=0.12, upper_position_phase_1=5.0, upper_position_amp_2=0.03)
    lqi = classical_controller("lqi", _spec(design=model), "brake")
    w = equilibrium_speed(model, 1.0)
    d = lqi.effect.design(w)
    assert np.all(d.lower == 0) and abs(d.upper[0]) > 0.005 and abs(d.upper[1]) > 0
    assert lqi.effect.decay_rate(w) > 0.03
    # the upper disk's friction modulation, pushed by the motor on the same disk: about
    # T_sup a1 / k_m at low frequency
    assert abs(d.upper[0]) == pytest.approx(BRAKE.upper_static_pos * 0.12 / BRAKE.motor_constant, rel=0.5)
