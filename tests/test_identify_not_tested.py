"""A base fit refused (T_sl not determined) leaves the structure untested: the verdict says so
(``not_tested``, never ``none``) in the CLI output, report.md and identification.json, with the
run that would determine what the fit lacks."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from drill_env.cli import app
from drill_env.recordings.synth import SynthConfig, make_dataset, write_synthetic

# constant runs far above the stick boundary, recorded after a settle: the lower disk always
# slips fast, so its static level is extrapolated and the base fit is refused
FAST_ONLY = SynthConfig(
    voltages=(2.0, 3.0, 4.5), random_runs=0, duration_s=30.0, pre_roll_s=30.0, sample_rate_hz=250.0
)


def test_a_refused_base_fit_is_not_tested_never_none(tmp_path):
    syn = make_dataset("position_friction_lower", seed=3, config=FAST_ONLY, magnitude=0.15)
    write_synthetic(syn, tmp_path / "data", tmp_path / "answer.json", preset="brake")
    out = tmp_path / "id"
    r = CliRunner().invoke(
        app,
        ["identify", str(tmp_path / "data"), "--out", str(out), "--no-figures", "--no-bifurcation",
         "--known", f"string_stiffness={syn.truth.string_stiffness!r}"],
    )  # fmt: skip
    assert r.exit_code == 1, r.output  # no rig.yaml: the refusal
    assert "structure: not_tested (0 round(s)" in r.output, r.output
    assert "structure: none" not in r.output
    assert "a hidden effect is not ruled out" in r.output
    record = json.loads((out / "identification.json").read_text())
    search = record["structure_search"]
    assert search["verdict"] == "not_tested" and search["tested"] is False and search["rounds"] == []
    assert "lower_static" in search["stopped"] and "stick boundary" in search["stopped"], search["stopped"]
    report = (out / "report.md").read_text()
    assert "**Not tested (verdict `not_tested`)" in report
    assert "the run that determines it" in report
