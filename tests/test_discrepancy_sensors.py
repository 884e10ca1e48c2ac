"""Sensor effects are not read as friction: a noisy measured voltage keeps constant runs
constant (steady state and bifurcation points stay in the report), and a line locked to a
disk's rotation is offered both as position friction and as encoder eccentricity."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import drill_env
from drill_env.recordings.compare import compare_run
from drill_env.recordings.dataset import CONSTANT_VOLTAGE_TOL
from drill_env.recordings.equation_error import RunEquations, estimate_angle_noise
from drill_env.recordings.split import split_runs
from drill_env.recordings.synth import SynthConfig, make_dataset

NOMINAL = drill_env.load_params("brake")
STEP = 2 * np.pi / 2000


def _noisy_voltage(runs, rms: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    return [dataclasses.replace(r, u=r.u + rng.normal(0.0, rms, r.u.size)) for r in runs]


def test_a_noisy_measured_voltage_keeps_constant_runs_constant():
    """ADC noise of 10 mV rms on the measured voltage: the constant runs stay constant (their
    voltage the median), the split is the noise-free one, and the steady-state features of
    the comparison are there (slow test below)."""
    cfg = SynthConfig(
        voltages=(1.0, 2.0, 3.0), random_runs=1, duration_s=30.0, pre_roll_s=20.0, sample_rate_hz=250.0
    )
    syn = make_dataset("none", seed=5, config=cfg)
    noisy = _noisy_voltage(syn.runs, 0.010)
    for clean, r in zip(syn.runs, noisy, strict=True):
        assert r.is_constant_voltage == clean.is_constant_voltage
        if clean.is_constant_voltage:
            assert r.voltage == pytest.approx(clean.voltage, abs=1e-3)
    assert split_runs(noisy) == split_runs(syn.runs)
    # beyond the tolerance (a step of 0.1 V) the run is varying
    stepped = dataclasses.replace(
        syn.runs[0], u=syn.runs[0].u + 2 * CONSTANT_VOLTAGE_TOL * (np.arange(syn.runs[0].u.size) > 100)
    )
    assert not stepped.is_constant_voltage


def test_steady_state_features_survive_a_noisy_measured_voltage():
    cfg = SynthConfig(
        voltages=(1.0, 2.0, 3.0), random_runs=1, duration_s=30.0, pre_roll_s=20.0, sample_rate_hz=250.0
    )
    noisy = _noisy_voltage(make_dataset("none", seed=5, config=cfg).runs, 0.010)
    noise = estimate_angle_noise(noisy, STEP)
    eq = RunEquations(noisy[1], NOMINAL, noise)
    comp = compare_run(NOMINAL, eq, 2000)
    assert comp.features_measured is not None and comp.features_model is not None
    assert comp.voltage == pytest.approx(2.0, abs=1e-3)


ROT = SynthConfig(
    voltages=(0.5, 0.7, 1.0, 2.0), random_runs=0, duration_s=40.0, pre_roll_s=20.0, angle_noise_std=0.0
)


def _explanations(effect: str, seed: int, magnitude: float):
    from drill_env.discrepancy.sensor_effects import rotation_explanations

    syn = make_dataset(effect, seed=seed, magnitude=magnitude, config=ROT)
    noise = estimate_angle_noise(syn.runs, STEP)
    eqs = [RunEquations(r, NOMINAL, noise) for r in syn.runs]
    return rotation_explanations(eqs, "lower"), syn


def test_an_eccentric_lower_encoder_is_explained_as_a_sensor_effect():
    """A once-per-revolution reading error of the lower encoder (8 mrad): the sensor explanation
    scores far above position friction, with the truth's amplitude and phase."""
    rows, syn = _explanations("encoder_eccentricity_lower", 3, 0.008)
    assert [r["kind"] for r in rows] == ["sensor", "physical"]
    assert rows[0]["score"] > 10 * max(rows[1]["score"], 1.0)
    truth = syn.answer["measurement_effects"]
    fit = rows[0]["parameters"]
    assert fit["lower_encoder_eccentricity_rad"] == pytest.approx(
        truth["lower_encoder_eccentricity"], rel=0.05
    )
    dphi = (fit["lower_encoder_phase_rad"] - truth["lower_encoder_phase"] + np.pi) % (2 * np.pi) - np.pi
    assert abs(dphi) < 0.05
    assert syn.answer["model_effects"] == {}  # the plant is the preset's: only the readings err


def test_position_friction_is_explained_as_physical():
    rows, syn = _explanations("position_friction_lower", 4, 0.1)
    assert rows[0]["explanation"] == "position_friction_lower" and rows[0]["kind"] == "physical"
    assert rows[0]["score"] > 2 * max(rows[1]["score"], 1.0)
    truth = syn.answer["model_effects"]["lower_position_amp_1"]
    assert rows[0]["parameters"]["lower_position_amp_1"] == pytest.approx(truth, rel=0.2)


def test_an_eccentric_encoder_is_named_and_its_report_lists_position_friction_beside_it(tmp_path):
    """The workflow on an eccentric encoder: named as the measurement candidate (it is in the
    library now), the verdict calls it a sensor effect, and the report's "Sensor or friction?"
    lists it beside position friction with both held-out scores; nothing says both "locked" and
    "not locked"."""
    from drill_env.discrepancy.report import write_report
    from drill_env.discrepancy.scoring import DecisionRule
    from drill_env.discrepancy.workflow import analyse
    from drill_env.recordings.dataset import MeasuredDataset

    syn = make_dataset("encoder_eccentricity_lower", seed=21, magnitude=0.01, config=ROT)
    ds = MeasuredDataset(preset="brake", encoder_counts_per_rev=2000, runs=tuple(syn.runs))
    res = analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=20))
    assert res.effect == "encoder_eccentricity_lower", res.decision.reason
    assert "a sensor effect, no torque: the lower encoder reads wrong" in res.verdict_line()
    text = write_report(res, tmp_path, figures=False).read_text()
    section = text.split("## Sensor or friction?", 1)[1].split("\n## ", 1)[0]
    assert "| encoder_eccentricity_lower | sensor |" in section
    assert "| position_friction_lower | physical |" in section
    assert "look at the lower encoder's mounting" in section
    assert "not locked to rotation" not in text
