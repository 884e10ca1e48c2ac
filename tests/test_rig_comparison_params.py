"""``rig-comparison --params``: any model, effects included, against the rig's measurements."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from drill_env.analysis.rig_comparison import (
    dominant_frequency,
    rig_comparison,
    whole_revolution_mean,
)
from drill_env.cli import app
from drill_env.params import ModelEffects, load_params

runner = CliRunner()

# The paper's model by the equilibrium/shooting analysis (independent of the simulation path):
# equilibrium speeds at 0.2/0.5 V, limit-cycle mean and frequency at 0.7 V.
ANALYSIS = {("mean lower-disk speed", 0.2): 0.1351, ("mean lower-disk speed", 0.5): 0.6578}
ANALYSIS_CYCLE_07 = (1.0219, 0.2460)  # mean speed [rad/s], frequency [Hz]


def _rows(comp):
    return {(r.quantity, r.u): r for r in comp.rows}


def test_whole_revolution_mean_ignores_a_once_per_revolution_modulation():
    t = np.linspace(0.0, 200.0, 200001)
    w = 0.3
    theta = w * t + 0.5 * np.sin(w * t)  # periodic in one revolution, mean speed exactly w
    mean, turns = whole_revolution_mean(t, theta)
    assert turns == math.floor(theta[-1] / (2 * math.pi)) - 1  # from the first crossing of 2 pi
    assert mean == pytest.approx(w, rel=1e-4)
    # the record's plain mean is biased by the partial revolution at the end
    assert abs((theta[-1] - theta[0]) / 200.0 - w) > 5e-4


def test_dominant_frequency_refines_between_bins_and_excludes_lines():
    dt = 0.01
    t = np.arange(0.0, 300.0, dt)
    x = 1.0 + 0.8 * np.sin(2 * math.pi * 0.2137 * t) + 0.3 * np.sin(2 * math.pi * 0.0511 * t)
    assert dominant_frequency(x, dt) == pytest.approx(0.2137, abs=2e-4)
    assert dominant_frequency(x, dt, exclude_hz=(0.2137,)) == pytest.approx(0.0511, abs=2e-4)


def test_params_equal_to_the_preset_by_simulation_reproduces_the_analysis(tmp_path):
    path = tmp_path / "model.yaml"
    load_params("brake").to_yaml(path)
    comp = rig_comparison(path, method="simulation")
    rows = _rows(comp)
    assert {r.method for r in comp.rows} == {"simulation"}
    for key, value in ANALYSIS.items():
        assert float(rows[key].model.split()[0]) == pytest.approx(value, rel=5e-4), key
    mean07, f07 = ANALYSIS_CYCLE_07
    assert float(rows[("mean lower-disk speed", 0.7)].model.split()[0]) == pytest.approx(mean07, rel=1e-3)
    assert float(rows[("dominant frequency", 0.7)].model.split()[0]) == pytest.approx(f07, rel=2e-3)
    assert rows[("torsional vibration", 0.5)].agrees and rows[("torsional vibration", 0.7)].agrees
    assert rows[("mean lower-disk speed", 0.2)].relative_error == pytest.approx(0.483, abs=0.002)


def test_position_friction_moves_the_low_voltage_mean_speed(tmp_path):
    nominal = load_params("brake")
    model = dataclasses.replace(
        nominal, effects=ModelEffects(lower_position_amp_1=0.5, lower_position_phase_1=1.0)
    )
    path = tmp_path / "model.yaml"
    model.to_yaml(path)
    res = runner.invoke(app, ["rig-comparison", "--params", str(path), "--out", str(tmp_path / "c.md")])
    assert res.exit_code == 0, res.output
    assert "lower_position_amp_1 = 0.5" in res.output
    import json

    data = json.loads((tmp_path / "c.json").read_text())
    assert data["method"] == "simulation"
    row = next(r for r in data["rows"] if r["quantity"] == "mean lower-disk speed" and r["u"] == 0.2)
    mean = float(row["model"].split()[0])
    assert row["method"] == "simulation"
    assert mean < ANALYSIS[("mean lower-disk speed", 0.2)] * 0.99  # moved by more than 1 %
    # the position-locked modulation at 0.5 V is not taken for a torsional vibration
    quiet = next(r for r in data["rows"] if r["quantity"] == "torsional vibration" and r["u"] == 0.5)
    assert "rotation" in quiet["model"]


def test_a_model_without_the_cycle_reports_no_oscillation_against_the_band():
    model = dataclasses.replace(load_params("brake"), effects=ModelEffects(string_damping=0.01))
    rows = _rows(rig_comparison(model))
    row = rows[("dominant frequency", 0.7)]
    assert row.model == "no oscillation" and row.agrees is False and row.rig == "0.21-0.22 Hz"
    assert rows[("torsional vibration", 0.7)].agrees is False


def test_recalibrated_parameters_are_not_called_the_papers_model():
    model = load_params("brake").replace(lower_static=load_params("brake").lower_static * 1.05)
    comp = rig_comparison(model, method="simulation")
    assert comp.preset == "brake, modified"
    assert "not from the paper" in comp.to_markdown()
    # a higher static friction slows the lower disk at 0.2 V
    rows = _rows(comp)
    assert (
        float(rows[("mean lower-disk speed", 0.2)].model.split()[0])
        < ANALYSIS[("mean lower-disk speed", 0.2)]
    )


def test_params_bad_input_is_one_line(tmp_path):
    bad = tmp_path / "m.yaml"
    bad.write_text("motor_constant: -1\n")
    res = runner.invoke(app, ["rig-comparison", "--params", str(bad)])
    assert res.exit_code == 2
    assert "--params" in res.output and "Traceback" not in res.output
    res = runner.invoke(app, ["rig-comparison", "--params", str(tmp_path / "m.txt")])
    assert res.exit_code == 2


@pytest.mark.slow
def test_params_equal_to_the_preset_reproduces_the_nominal_table(tmp_path):
    path = tmp_path / "model.yaml"
    load_params("brake").to_yaml(path)
    res = runner.invoke(app, ["rig-comparison", "--params", str(path)])
    assert res.exit_code == 0, res.output
    ref = rig_comparison("brake")
    table = [ln for ln in res.output.splitlines() if ln.startswith("| ")]
    assert table == [ln for ln in ref.to_markdown().splitlines() if ln.startswith("| ")]
