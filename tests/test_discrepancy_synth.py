"""Synthetic measured-like data: format, reproducibility, and the answer kept out of the data."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from drill_env.cli import app
from drill_env.recordings.dataset import load_dataset
from drill_env.recordings.synth import HIDDEN_EFFECTS, SynthConfig, make_dataset, write_synthetic

SMALL = SynthConfig(
    voltages=(0.5, 2.0), random_runs=1, duration_s=20.0, pre_roll_s=20.0, sample_rate_hz=200.0
)


def test_runs_look_measured():
    res = make_dataset("none", seed=3, config=SMALL)
    assert len(res.runs) == 3
    q = 2 * np.pi / SMALL.encoder_counts_per_rev
    for r in res.runs:
        assert r.dt == pytest.approx(1 / 200.0)
        assert r.duration == pytest.approx(20.0)
        # encoder readings are whole counts
        np.testing.assert_allclose(np.round(r.theta_l / q) * q, r.theta_l, atol=1e-9)
    assert res.runs[0].is_constant_voltage and res.runs[0].voltage == 0.5
    varying = res.runs[2]
    assert not varying.is_constant_voltage
    assert 0.0 <= varying.u.min() and varying.u.max() <= 5.0


def test_reproducible_and_seeded():
    a = make_dataset("string_damping", seed=5, config=SMALL)
    b = make_dataset("string_damping", seed=5, config=SMALL)
    c = make_dataset("string_damping", seed=6, config=SMALL)
    np.testing.assert_array_equal(a.runs[2].theta_l, b.runs[2].theta_l)
    assert a.answer == b.answer
    assert a.answer["magnitude"] != c.answer["magnitude"]
    lo, hi = HIDDEN_EFFECTS["string_damping"].low, HIDDEN_EFFECTS["string_damping"].high
    assert lo <= a.answer["magnitude"] <= hi


def test_magnitude_validation():
    with pytest.raises(ValueError, match="outside the allowed range"):
        make_dataset("position_friction_lower", seed=1, magnitude=0.9, config=SMALL)
    with pytest.raises(ValueError, match="unknown effect"):
        make_dataset("gremlins", seed=1, config=SMALL)


def test_answer_never_in_data_folder(tmp_path):
    res = make_dataset("friction_drift", seed=2, config=SMALL)
    data = tmp_path / "data"
    write_synthetic(res, data, tmp_path / "answer.json", preset="brake")
    meta = json.loads((data / "dataset.json").read_text())
    assert set(meta) == {"preset", "encoder_counts_per_rev", "sample_rate_hz"}
    rate = f"{res.answer['model_effects']['friction_drift']:.6g}"
    for f in data.iterdir():
        text = f.read_text()
        assert "drift" not in text and "friction" not in text and rate not in text, f
    assert json.loads((tmp_path / "answer.json").read_text())["effect"] == "friction_drift"
    with pytest.raises(ValueError, match="inside the data folder"):
        write_synthetic(res, data, data / "answer.json", preset="brake")
    assert len(load_dataset(data).runs) == 3


def test_cli_synth(tmp_path):
    out, ans = tmp_path / "d", tmp_path / "a.json"
    r = CliRunner().invoke(
        app,
        [
            "synth",
            "--effect",
            "motor_inductance",
            "--magnitude",
            "0.01",
            "--seed",
            "1",
            "--out",
            str(out),
            "--answer",
            str(ans),
            "--duration",
            "20",
            "--voltages",
            "1.0",
            "--random-runs",
            "1",
            "--rate",
            "200",
        ],
    )
    assert r.exit_code == 0, r.output
    assert json.loads(ans.read_text())["model_effects"] == {"motor_lag": 0.01}
    assert len(load_dataset(out).runs) == 2
    bad = CliRunner().invoke(app, ["synth", "--effect", "nope", "--out", str(out), "--answer", str(ans)])
    assert bad.exit_code == 2 and "unknown effect" in bad.output
