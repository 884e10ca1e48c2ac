"""The sim-to-real example: truth plant -> synth data -> discrepancy -> retune -> benchmark on
the truth plant, before and after. A reduced pipeline runs end to end; bad input exits 2.
(That ``tune --params`` changes the gains when the model changes is tested in test_agents.)"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drill_env.agents.evaluation.episodes import EpisodeSettings
from drill_env.agents.evaluation.sim_to_real import SimToRealConfig, quick_config, run_sim_to_real
from drill_env.cli import app
from drill_env.params import load_params
from drill_env.recordings.synth import SynthConfig

runner = CliRunner()


def _reduced() -> SimToRealConfig:
    """Short recordings (3 constant-voltage runs and 1 quasi-random, 20 s), a coarse tuning,
    short episodes, one voltage and seed; a data seed and parameter errors of their own."""
    return dataclasses.replace(
        quick_config(controllers=("lqi", "lqi_angle_ff"), voltages=(1.0,)),
        data_seed=3,
        parameter_errors={"motor_constant": -0.04, "lower_inertia": 0.06},
        synth=SynthConfig(
            preset="brake",
            voltages=(0.5, 1.0, 2.0),
            random_runs=1,
            duration_s=20.0,
            pre_roll_s=5.0,
            angle_noise_std=0.0,
        ),
        episode=EpisodeSettings(duration=8.0, window=4.0, warmup_time=5.0, warmup_jitter=1.0),
    )


@pytest.mark.slow  # 30-40 s on two shared cores: the tuning and the discrepancy dominate
def test_reduced_pipeline_end_to_end(tmp_path: Path):
    cfg = _reduced()
    lines: list[str] = []
    res = run_sim_to_real(tmp_path / "out", cfg, progress=lines.append)
    out = tmp_path / "out"
    for name in (
        "truth.yaml",
        "truth_answer.json",
        "discrepancy/result.json",
        "discrepancy/model.yaml",
        "discrepancy/report.md",
        "gains_corrected.yaml",
        "results.csv",
        "summary.md",
        "timeseries_1V.png",
        "suppression.png",
        "config.json",
    ):
        assert (out / name).is_file(), name
    assert [ln[:5] for ln in lines if ln.startswith("[")] == ["[1/5]", "[2/5]", "[3/5]", "[4/5]", "[5/5]"]

    # the truth plant is the preset with the effect and the parameter errors asked for
    nominal = load_params("brake")
    truth = load_params(out / "truth.yaml")
    assert truth.effects.lower_position_amp_1 == pytest.approx(0.12)
    assert truth.motor_constant == pytest.approx(0.96 * nominal.motor_constant, rel=1e-9)
    assert truth.lower_inertia == pytest.approx(1.06 * nominal.lower_inertia, rel=1e-9)

    # the discrepancy found the effect and the parameter errors from the data alone
    disc = json.loads((out / "discrepancy" / "result.json").read_text())
    assert "position_friction_lower" in disc["effects"]
    model = load_params(out / "discrepancy" / "model.yaml")
    assert model.motor_constant == pytest.approx(truth.motor_constant, rel=0.01)
    assert model.lower_inertia == pytest.approx(truth.lower_inertia, rel=0.01)
    assert model.effects.lower_position_amp_1 == pytest.approx(0.12, rel=0.05)

    # the corrected design was tuned on that model and written for benchmark --gains
    from drill_env.agents.controllers.gains import load_gains

    gains = load_gains(out / "gains_corrected.yaml")
    assert gains["design_model"]["params"] == "discrepancy/model.yaml"
    assert set(gains["presets"]["brake"]) == {"lqi"}  # lqi_angle_ff runs on the LQI's gains
    assert res.gains["corrected"]["lqi"] == gains["presets"]["brake"]["lqi"]["gains"]

    # one row per design x controller (+ the open loop) x voltage x seed, all on the truth plant
    df = pd.read_csv(out / "results.csv")
    assert len(df) == 1 + 2 * 2
    assert sorted(df.design.astype(str)) == ["-", "corrected", "corrected", "nominal", "nominal"]
    assert (df.plant == "truth").all()
    ol = df[df.controller == "open_loop"].iloc[0]
    # the reference is the open-loop run on the truth plant, the same for every controller
    assert np.allclose(df.open_loop_amplitude, ol.amplitude)
    closed = df[df.controller != "open_loop"]
    assert np.allclose(closed.suppression, 1.0 - closed.amplitude / ol.amplitude)
    summary = (out / "summary.md").read_text()
    assert "position_friction_lower" in summary and "→" in summary


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--voltages", "9"], "--voltages"),
        (["--voltages", "0.05"], "--voltages"),
        (["--voltages", "1,x"], "--voltages"),
        (["--seeds", "0"], "--seeds"),
        (["--magnitude", "0.5"], "--magnitude"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path: Path, args: list[str], needle: str):
    r = runner.invoke(app, ["sim-to-real", "--out", str(tmp_path / "out"), *args])
    assert r.exit_code == 2, r.output
    err = r.stderr.strip() if hasattr(r, "stderr") else r.output.strip()
    assert err.startswith("error:") and needle in err and "\n" not in err
    assert not (tmp_path / "out").exists()  # nothing was started


def test_out_is_a_file_exits_2(tmp_path: Path):
    f = tmp_path / "file.txt"
    f.write_text("keep me\n")
    r = runner.invoke(app, ["sim-to-real", "--out", str(f)])
    assert r.exit_code == 2
    assert f.read_text() == "keep me\n"


def test_config_validation_names_the_field():
    with pytest.raises(ValueError, match="parameter_errors.motor_constant"):
        SimToRealConfig(parameter_errors={"motor_constant": 0.5})
    with pytest.raises(ValueError, match="parameter_errors: 'string_damping'"):
        SimToRealConfig(parameter_errors={"string_damping": 0.1})
    with pytest.raises(ValueError, match="controllers: 'ppo'"):
        SimToRealConfig(controllers=("ppo",))
    with pytest.raises(ValueError, match="design_points"):
        SimToRealConfig(design_points=1)


def test_summary_reports_before_and_after_from_the_rows():
    """The before → after cells are the rows' means per design (never swapped), the worst case
    their minimum, and a change within 0.02 is called no material change."""
    from drill_env.agents.evaluation.episodes import METRIC_COLUMNS
    from drill_env.agents.evaluation.sim_to_real import SimToRealResult, summary_markdown

    cfg = dataclasses.replace(quick_config(controllers=("lqi",), voltages=(0.85, 1.25)), seeds=(0, 1))
    supp = {("nominal", 0.85): (0.20, 0.30), ("corrected", 0.85): (0.60, 0.70), ("nominal", 1.25): (0.9, 0.9)}
    supp[("corrected", 1.25)] = (0.91, 0.91)
    rows = []
    for v in cfg.voltages:
        for s in cfg.seeds:
            base = {c: 0.0 for c in METRIC_COLUMNS}
            base.update(preset="brake", voltage=v, seed=s, plant="truth", amplitude=2.0, target_speed=1.0)
            rows.append({**base, "design": "-", "controller": "open_loop", "suppression": 0.0})
            for d in ("nominal", "corrected"):
                x = supp[(d, v)][s]
                rows.append({**base, "design": d, "controller": "lqi", "suppression": x, "rms_error": 1 - x})
    nominal = load_params("brake")
    res = SimToRealResult(
        config=cfg,
        truth=nominal,
        answer={"model_effects": {}, "parameters_at_nominal_string_stiffness": {}},
        discrepancy={"effect": "recalibrated", "confidence": 0.9, "effects": [], "recalibrated": {}},
        corrected=nominal,
        gains={"nominal": {"lqi": {"voltage_scale": 0.1}}, "corrected": {"lqi": {"voltage_scale": 0.11}}},
        decay_rates={"nominal": {"lqi": 0.03}, "corrected": {"lqi": 0.031}},
        rows=rows,
        files=[],
        timings={},
    )
    text = summary_markdown(res)
    line = next(ln for ln in text.splitlines() if ln.startswith("| `lqi` | suppression"))
    assert "0.250 → 0.650" in line and "0.900 → 0.910" in line
    assert line.endswith("| 0.200 → 0.600 |")  # the worst run of each design
    rms = next(ln for ln in text.splitlines() if ln.startswith("| `lqi` | RMS"))
    assert "0.750 → 0.350" in rms and rms.endswith("| 0.800 → 0.400 |")
    assert "`lqi`: 0.200 → 0.600: the corrected model helps." in text
    assert "moves the gains by at most 10.0%" in text


@pytest.mark.slow  # about a minute: recording, discrepancy, tuning, then the benchmark
def test_a_truth_plant_file_and_the_after_rows_are_one_benchmark_command(tmp_path: Path):
    """sim-to-real --truth FILE (effects, actuator delay and sensors in the file) runs, the
    corrected lqi feeds the identified friction forward and beats the nominal one, and
    `benchmark --plant truth.yaml --design-params discrepancy/model.yaml --gains
    gains_corrected.yaml` reproduces the after rows run for run."""
    import yaml

    from drill_env.agents.evaluation.benchmark import BenchmarkConfig, load_results, run_benchmark
    from drill_env.agents.evaluation.plants import Plant

    nominal = load_params("brake")
    data = nominal.to_dict()
    data.update(
        motor_constant=nominal.motor_constant * 1.04,
        effects={"lower_position_amp_1": 0.12, "lower_position_phase_1": 1.3},
        actuator_delay=0.005,
        sensors={"counts_per_rev": 4000},
    )
    truth_file = tmp_path / "my_truth.yaml"
    truth_file.write_text(yaml.safe_dump(data))
    cfg = dataclasses.replace(_reduced(), truth_file=str(truth_file))
    out = tmp_path / "out"
    run_sim_to_real(out, cfg)
    answer = json.loads((out / "truth_answer.json").read_text())
    assert answer["effects"] == ["position_friction_lower"] and answer["actuator_delay"] == 0.005
    assert answer["design"]["encoder_counts_per_rev"] == 4000
    df = pd.read_csv(out / "results.csv")
    lqi = df[df.controller == "lqi"].set_index("design")
    assert lqi.loc["corrected", "suppression"] > lqi.loc["nominal", "suppression"] + 0.1
    written = Plant.from_path(out / "truth.yaml")
    assert written.sensors == {"counts_per_rev": 4000, "delay_samples": 5}
    bench = BenchmarkConfig(
        presets=("brake",),
        controllers=cfg.controllers,
        voltages={"brake": cfg.voltages},
        seeds=cfg.seeds,
        episode=cfg.episode,
        gains_file=str(out / "gains_corrected.yaml"),
        plants=(written,),
        design_params=str(out / "discrepancy" / "model.yaml"),
    )
    run_benchmark(bench, tmp_path / "bench", backend="sequential")
    rows = load_results(tmp_path / "bench" / "benchmark.csv").set_index("controller")
    after = df[df.design == "corrected"].set_index("controller")
    for c in cfg.controllers:
        for col in ("amplitude", "suppression", "rms_error", "target_speed"):
            # results.csv keeps 6 significant digits
            assert rows.loc[c, col] == pytest.approx(after.loc[c, col], rel=1e-5, abs=1e-9), (c, col)
