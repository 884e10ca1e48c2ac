"""The workflow names hidden effects it is not told, says none without one, unexplained outside the library."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import drill_env
from drill_env.cli import app
from drill_env.discrepancy.dataset import MeasuredDataset
from drill_env.discrepancy.decide import DecisionRule
from drill_env.discrepancy.equation_error import RunEquations, estimate_angle_noise
from drill_env.discrepancy.study import expected_verdict
from drill_env.discrepancy.synth import HIDDEN_EFFECTS, SynthConfig, make_dataset
from drill_env.discrepancy.workflow import RESULT_EFFECTS, analyse

# four constant voltages and two quasi-random runs of 60 s at 250 Hz: small but enough
SMALL = SynthConfig(voltages=(0.2, 0.7, 2.0, 4.5), random_runs=2, duration_s=60.0, pre_roll_s=40.0,
                    sample_rate_hz=250.0)


def _dataset(effect, seed, magnitude=None, config=SMALL):
    syn = make_dataset(effect, seed=seed, magnitude=magnitude, config=config)
    return MeasuredDataset(preset="brake", encoder_counts_per_rev=config.encoder_counts_per_rev,
                           runs=tuple(syn.runs)), syn


@pytest.mark.parametrize("effect", list(HIDDEN_EFFECTS))
@pytest.mark.parametrize("seed", [21, 22])
def test_hidden_effect_is_named(effect, seed):
    ds, syn = _dataset(effect, seed)
    res = analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=40))
    assert res.effect == expected_verdict(effect), (syn.answer, res.decision.reason)
    assert res.decision.confidence >= 0.8


def test_parameters_are_recovered():
    ds, syn = _dataset("position_friction_lower", 7, magnitude=0.08)
    res = analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=20))
    truth, found = syn.answer["model_effects"], res.decision.winner.parameters
    assert found["lower_position_amp_1"] == pytest.approx(truth["lower_position_amp_1"], rel=0.05)
    dphi = (found["lower_position_phase_1"] - truth["lower_position_phase_1"] + np.pi) % (2 * np.pi) - np.pi
    assert abs(dphi) < 0.1


def test_noise_floor_is_calibrated():
    ds, _ = _dataset("none", 3)
    noise = estimate_angle_noise(ds.runs, ds.encoder_step)
    z2 = []
    for r in ds.runs:
        eq = RunEquations(r, drill_env.load_params("brake"), noise)
        z2 += list(eq.upper.z**2) + list(eq.lower.z**2)
    assert 0.8 < np.mean(z2) < 1.2


def test_small_effect_below_detection_gives_none():
    # far below the documented range the rule must not invent an effect
    ds, _ = _dataset("position_friction_lower", 5, magnitude=1e-4)
    res = analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=20))
    assert res.effect == "none"


def test_cli_end_to_end(tmp_path):
    runner = CliRunner()
    data, ans, out = tmp_path / "data", tmp_path / "answer.json", tmp_path / "out"
    r = runner.invoke(app, ["synth", "--effect", "friction_drift", "--magnitude", "0.001", "--seed", "4",
                            "--out", str(data), "--answer", str(ans), "--duration", "40", "--voltages",
                            "0.5,2.0,4.5", "--random-runs", "2", "--rate", "200"])
    assert r.exit_code == 0, r.output
    ans.unlink()  # the workflow has nothing to peek at
    r = runner.invoke(app, ["discrepancy", str(data), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert r.output.strip().splitlines()[-1].startswith("verdict: friction_drift")
    result = json.loads((out / "result.json").read_text())
    assert set(result) == {"effect", "confidence", "parameters", "gap_before", "gap_after", "heldout_runs",
                           "evidence"}
    assert result["effect"] in RESULT_EFFECTS and result["effect"] == "friction_drift"
    assert abs(result["parameters"]["friction_drift"]) == pytest.approx(0.001, rel=0.1)
    assert result["gap_after"]["equation_error_ss_per_window"] < result["gap_before"]["equation_error_ss_per_window"]
    for fig in ("spectra.png", "bifurcation.png", "trajectories.png", "residual_spectra.png"):
        assert (out / fig).is_file()
    assert "![spectra.png](spectra.png)" in (out / "report.md").read_text()
    # the written model variant is accepted by the simulator
    p = drill_env.load_params(out / "model.yaml")
    assert p.effects.friction_drift == pytest.approx(result["parameters"]["friction_drift"])
    sim = drill_env.simulate(out / "model.yaml", 2.0, 10.0)
    assert sim.status == 0
    # bad input: a clear error, not a traceback
    (data / "run01.csv").write_text("t,u,theta_u\n0,1,2\n")
    r = runner.invoke(app, ["discrepancy", str(data), "--out", str(out)])
    assert r.exit_code == 2 and "run01.csv" in r.output and "theta_l" in r.output
