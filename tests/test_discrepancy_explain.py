"""An ``unexplained`` verdict says what to look for: the clock its line keeps, its torque, where."""

from __future__ import annotations

import json

import numpy as np
import pytest

import drill_env
from drill_env.discrepancy.report import write_report
from drill_env.discrepancy.scoring import DecisionRule
from drill_env.discrepancy.spectral_lines import line_scan, line_signature
from drill_env.discrepancy.workflow import analyse
from drill_env.recordings.dataset import MeasuredDataset
from drill_env.recordings.equation_error import RunEquations, estimate_angle_noise
from drill_env.recordings.synth import SynthConfig, make_dataset

NOMINAL = drill_env.load_params("brake")
# five constant voltages and one quasi-random run of 60 s at 500 Hz, an undithered encoder
CONFIG = SynthConfig(
    voltages=(0.5, 0.7, 1.0, 2.0, 3.0), random_runs=1, duration_s=60.0, pre_roll_s=30.0, angle_noise_std=0.0
)


def _signature(effect, seed, magnitude):
    syn = make_dataset(effect, seed=seed, magnitude=magnitude, config=CONFIG)
    noise = estimate_angle_noise(syn.runs, 2 * np.pi / CONFIG.encoder_counts_per_rev)
    eqs = [RunEquations(r, NOMINAL, noise) for r in syn.runs]
    line = line_scan(eqs, DecisionRule())
    return line, line_signature(eqs, line.frequency_hz), syn


@pytest.mark.parametrize(("seed", "amp"), [(11, 0.015), (12, 0.008)])
def test_external_torque_is_locked_to_time_with_its_amplitude(seed, amp):
    line, sig, syn = _signature("external_torque", seed, amp)
    truth = syn.answer["model_effects"]
    f_true = truth["disturbance_freq"] / (2 * np.pi)
    assert line.significant
    assert sig.locked_to == "time"
    assert sig.frequency_hz == pytest.approx(f_true, rel=0.02)
    assert sig.amplitude_nm["lower"] == pytest.approx(truth["disturbance_amp"], rel=0.3)
    # the torque acts on the lower disk: what shows on the upper one is much smaller
    assert sig.amplitude_nm.get("upper", 0.0) < 0.2 * sig.amplitude_nm["lower"]
    assert sum(r["shown"] for r in sig.runs) >= len(sig.runs) - 1
    assert sig.significant and sig.drops["time"] > sig.threshold
    assert "locked to time" in sig.summary()


def test_no_effect_gives_no_significant_line():
    cfg = SynthConfig(
        voltages=(0.5, 1.0, 2.0), random_runs=1, duration_s=60.0, pre_roll_s=30.0, angle_noise_std=1e-3
    )
    syn = make_dataset("none", seed=31, config=cfg)
    noise = estimate_angle_noise(syn.runs, 2 * np.pi / cfg.encoder_counts_per_rev)
    eqs = [RunEquations(r, NOMINAL, noise) for r in syn.runs]
    sig = line_signature(eqs, line_scan(eqs, DecisionRule()).frequency_hz)
    assert not sig.significant
    assert sig.summary().startswith("no line stands out")


@pytest.mark.parametrize("seed", [13, 14])
def test_position_locked_line_is_locked_to_the_lower_disk_rotation(seed):
    # position friction outside the candidates considered here: only the signature is asked
    _, sig, syn = _signature("position_friction_lower", seed, 0.12)
    assert sig.locked_to == "lower disk rotation" and sig.significant
    assert sig.harmonic == 1
    assert np.isnan(sig.frequency_hz)
    # the runs turn at different rates, so a fixed frequency cannot carry the line
    assert sig.drops["lower_rotation_1"] > 1.5 * sig.drops["time"]
    # amplitude: a1 times the lower friction level T_sl + S(w) at the runs' speeds, within 50 %
    a1 = syn.answer["model_effects"]["lower_position_amp_1"]
    level = NOMINAL.lower_static + NOMINAL.lower_hump_1 * np.tanh(0.5 * NOMINAL.lower_hump_rate_1 * 1.0)
    level += NOMINAL.lower_hump_2 * np.tanh(0.5 * NOMINAL.lower_hump_rate_2 * 1.0)
    assert sig.amplitude_nm["lower"] == pytest.approx(a1 * level, rel=0.5)


def test_unexplained_external_torque_names_its_clock_in_result_and_report(tmp_path):
    syn = make_dataset("external_torque", seed=21, magnitude=0.015, config=CONFIG)
    ds = MeasuredDataset(
        preset="brake", encoder_counts_per_rev=CONFIG.encoder_counts_per_rev, runs=tuple(syn.runs)
    )
    res = analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=20))
    assert res.effect == "unexplained", res.decision.reason
    out = json.loads(json.dumps(res.result_json()))
    sig = out["evidence"]["spectral_line"]["signature"]
    assert sig["locked_to"] == "time"
    truth = syn.answer["model_effects"]
    assert sig["amplitude_nm"]["lower"] == pytest.approx(truth["disturbance_amp"], rel=0.3)
    assert "locked to time" in res.verdict_line()
    path = write_report(res, tmp_path, figures=False)
    text = path.read_text()
    assert "## What to look for" in text and "lower torque [N m]" in text


def test_data_beyond_the_identified_speed_are_flagged():
    """Measured lower speeds above the brake friction's identified 12.6 rad/s are named in a
    warning (result.json evidence, report, command line); below it, or without the brake, not."""
    from types import SimpleNamespace

    from drill_env.discrepancy.workflow import DiscrepancyResult

    t = np.arange(0.0, 10.0, 0.002)

    def fake(preset, speed):
        run = SimpleNamespace(t=t, theta_l=speed * t + 0.3 * np.sin(t))
        # the model the warnings speak of is the nominal one, named after its preset
        return SimpleNamespace(
            dataset=SimpleNamespace(preset=preset, runs=[run]),
            params=SimpleNamespace(name=preset),
            left_out={},
        )

    top = DiscrepancyResult.max_lower_speed.fget(fake("brake", 13.0))
    assert top == pytest.approx(13.3, abs=2e-3)  # 13 + 0.3 cos(t) at its peak, over 0.1 s windows

    def warnings(preset, speed):
        r = fake(preset, speed)
        r.max_lower_speed = DiscrepancyResult.max_lower_speed.fget(r)
        return DiscrepancyResult.validity_warnings.fget(r)

    (note,) = warnings("brake", 13.0)
    assert "12.6 rad/s" in note and "13.3 rad/s" in note
    assert warnings("brake", 12.0) == []
    assert warnings("no_brake", 30.0) == []
