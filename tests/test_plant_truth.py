"""The benchmark on a user's plant tells the truth: a plant file runs alone, the controller and
the task know only the design model, a plant file holds its delay and sensors, and a disk
that stalls is a failure (drill-env benchmark --plant / --plants / --design-params)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from drill_env.agents.evaluation.benchmark import load_results
from drill_env.agents.evaluation.episodes import (
    STALL_SPEED_ERROR,
    STALL_STUCK_FRACTION,
    EpisodeSettings,
    evaluate,
    is_stalled,
    make_env,
)
from drill_env.agents.evaluation.plants import Plant, plants_in, standard_family, write_family
from drill_env.cli import app
from drill_env.envs.task import equilibrium_speed
from drill_env.params import load_params

ROOT = Path(__file__).resolve().parents[1]
TINY = ["--duration", "6", "--window", "3", "--warmup", "5", "--backend", "sequential", "--seeds", "1"]


def _plant_file(path: Path, **changes) -> Path:
    """The braked rig with ``changes`` (parameters, ``effects``, ``actuator_delay``, ``sensors``)."""
    data = load_params("brake").to_dict()
    data.update(changes)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def rig_run(tmp_path_factory):
    """``benchmark --plant FILE`` alone: a rig with k_m +5 %, J_l -6 %, lower position friction
    a1 = 0.15, 10 ms delay and 3 mrad angle noise, at 0.5 V (the design model's equilibrium)
    and 1 V."""
    d = tmp_path_factory.mktemp("rig")
    b = load_params("brake")
    rig = _plant_file(
        d / "my_rig.yaml",
        motor_constant=b.motor_constant * 1.05,
        lower_inertia=b.lower_inertia * 0.94,
        effects={"lower_position_amp_1": 0.15},
        actuator_delay=0.01,
        sensors={"angle_noise_std": 0.003},
    )
    out = d / "out"
    res = CliRunner().invoke(
        app,
        ["benchmark", "--out", str(out), "--preset", "brake", "--plant", str(rig)]
        + ["--controllers", "open_loop,lqi", "--voltages", "0.5,1.0", *TINY],
    )
    return res, out


def test_a_plant_file_runs_alone_and_every_run_succeeds(rig_run):
    res, out = rig_run
    assert res.exit_code == 0, res.output
    df = load_results(out / "benchmark.csv")
    assert set(df["plant"]) == {"my_rig"}  # nominal only when asked
    assert len(df) == 4 and (df["error"] == "").all()
    numeric = ["target_speed", "amplitude", "open_loop_amplitude", "rms_error", "mean_speed", "x3_peak_abs"]
    assert np.isfinite(df[numeric].to_numpy(dtype=float)).all()
    assert np.isfinite(df[df["voltage"] == 1.0]["suppression"]).all()


def test_the_target_speed_on_a_plant_file_is_the_design_models(rig_run):
    """One rule: the target speed and the regime label come from the design model (the preset's
    here); the plant's own open loop is measured and reported beside it."""
    _, out = rig_run
    df = load_results(out / "benchmark.csv")
    nominal = load_params("brake")
    truth = load_params("brake").replace(motor_constant=nominal.motor_constant * 1.05)
    for v, w in df.groupby("voltage")["target_speed"]:
        assert np.allclose(w, equilibrium_speed(nominal, v), rtol=1e-9)
        assert abs(equilibrium_speed(truth, v) / equilibrium_speed(nominal, v) - 1) > 0.02  # would differ
    low = df[df["voltage"] == 0.5]
    # the design model predicts an equilibrium at 0.5 V; the plant's position friction oscillates
    assert set(low["regime"]) == {"equilibrium"}
    assert set(low["plant_open_loop_regime"]) == {"limit_cycle"}
    assert (low["open_loop_amplitude"] > 0.1).all()
    assert set(df[df["voltage"] == 1.0]["plant_open_loop_regime"]) == {"limit_cycle"}


def test_make_env_takes_the_set_point_from_the_design_model():
    settings = EpisodeSettings(duration=0.1, window=0.05, warmup_time=0.0, warmup_jitter=0.0)
    b = load_params("brake")
    truth = b.replace(motor_constant=b.motor_constant * 1.08)
    env = make_env("brake", settings, params=truth)
    try:
        _, info = env.reset(seed=0, options={"nominal_voltage": 1.0})
        assert info["target_speed"] == pytest.approx(equilibrium_speed(b, 1.0), rel=1e-12)
        assert env.unwrapped.settings.params.motor_constant == truth.motor_constant  # simulated
    finally:
        env.close()
    design = b.replace(lower_inertia=b.lower_inertia * 1.05, lower_static=b.lower_static * 1.1)
    env = make_env("brake", settings, params=truth, design_params=design)
    try:
        _, info = env.reset(seed=0, options={"nominal_voltage": 1.0})
        assert info["target_speed"] == pytest.approx(equilibrium_speed(design, 1.0), rel=1e-12)
    finally:
        env.close()


def test_a_plant_file_holds_its_delay_and_sensors(tmp_path):
    p = Plant.from_path(
        _plant_file(
            tmp_path / "rig.yaml",
            actuator_delay=0.015,
            sensors={
                "angle_noise_std": 0.002,
                "speed_noise_std": 0.01,
                "counts_per_rev": 4096,
                "cutoff_rad_s": 150.0,
            },
        )
    )
    assert p.sensors == {
        "angle_noise_std": 0.002,
        "speed_noise_std": 0.01,
        "counts_per_rev": 4096,
        "cutoff_rad_s": 150.0,
        "delay_samples": 15,
    }
    env = make_env(
        "brake", EpisodeSettings(duration=1, window=0.5), params=p.rig("brake"), overrides=p.env_overrides()
    )
    try:
        s = env.unwrapped.settings.sensors
        assert (s.delay_samples, s.counts_per_rev, s.angle_noise_std, s.cutoff_rad_s) == (
            15,
            4096,
            0.002,
            150.0,
        )
    finally:
        env.close()


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"actuator_delay": -0.01}, "actuator_delay"),
        ({"actuator_delay": 0.0105}, "actuator_delay"),
        ({"actuator_delay": "10 ms"}, "actuator_delay"),
        ({"sensors": {"angle_noise_std": -1.0}}, "sensors.angle_noise_std"),
        ({"sensors": {"counts_per_rev": 0}}, "sensors.counts_per_rev"),
        ({"sensors": {"cutoff_rad_s": 1e6}}, "sensors.cutoff_rad_s"),
        ({"sensors": {"delay_samples": 10}}, "sensors"),
        ({"sensors": {"noise": 1}}, "sensors"),
        ({"sensors": [1, 2]}, "sensors"),
        ({"lower_inertia": -1.0}, "lower_inertia"),
        ({"amplifier": {"gain": 3.0}}, "amplifier.gain"),
        ({"amplifier": {"offset_v": "0.1 V"}}, "amplifier.offset_v"),
        ({"amplifier": {"offset": 0.1}}, "amplifier"),
        # a valid amplifier the benchmark cannot apply (it applies the voltage asked for)
        ({"amplifier": {"offset_v": 0.05}}, "amplifier"),
    ],
)
def test_a_bad_plant_file_is_one_line_naming_the_field(tmp_path, changes, field):
    rig = _plant_file(tmp_path / "bad.yaml", **changes)
    res = CliRunner().invoke(
        app, ["benchmark", "--out", str(tmp_path / "out"), "--preset", "brake", "--plant", str(rig), *TINY]
    )
    assert res.exit_code == 2, res.output
    lines = [x for x in res.output.strip().splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: --plant") and field in lines[0], res.output
    assert "Traceback" not in res.output


def test_design_params_that_are_not_a_rig_file_is_one_line(tmp_path):
    bad = tmp_path / "model.yaml"
    bad.write_text("presets: {}\n")
    for arg, preset in ((str(bad), "brake"), (str(tmp_path / "none.yaml"), "brake"), (str(bad), "all")):
        res = CliRunner().invoke(
            app,
            ["benchmark", "--out", str(tmp_path / "o"), "--preset", preset, "--design-params", arg, *TINY],
        )
        assert res.exit_code == 2, res.output
        lines = [x for x in res.output.strip().splitlines() if x.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: --design-params"), res.output


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_the_standard_family_is_expressible_as_plant_files(tmp_path, preset):
    files = write_family(tmp_path, preset)
    family = {q.name: q for q in standard_family() if not q.is_nominal}
    read = {q.name: q for q in plants_in(tmp_path)}
    assert len(files) == len(family) == len(read) == 17
    for name, q in family.items():
        r = read[name]
        a, b = (q.rig(preset) or load_params(preset)), r.rig(preset)
        assert np.array_equal(a.as_array(), b.as_array()), name
        assert r.sensors == q.sensors, name
    assert yaml.safe_load((tmp_path / "delay_10ms.yaml").read_text())["actuator_delay"] == 0.01


def test_the_stalled_rule():
    assert not is_stalled(0.0, 1.0, 1.0)
    assert is_stalled(STALL_STUCK_FRACTION + 0.01, 1.0, 1.0)
    assert not is_stalled(STALL_STUCK_FRACTION - 0.01, 1.0, 1.0)
    assert is_stalled(0.0, (1 - STALL_SPEED_ERROR) - 0.01, 1.0)
    assert is_stalled(0.0, (1 + STALL_SPEED_ERROR) + 0.01, 1.0)
    assert not is_stalled(0.0, (1 - STALL_SPEED_ERROR) + 0.01, 1.0)
    assert is_stalled(0.0, math.nan, 1.0)


class _Brake:
    """Switches the motor off: the lower disk stops and sticks."""

    name = "motor_off"

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.zeros((1,), dtype=np.float32), state


def test_a_disk_that_stalls_scores_as_a_failure_not_a_perfect_suppression():
    settings = EpisodeSettings(duration=12.0, window=6.0, warmup_time=20.0, warmup_jitter=1.0)
    env = make_env("brake", settings)
    try:
        m = evaluate(_Brake(), "brake", 1.0, 0, settings, env=env)
    finally:
        env.close()
    assert m.open_loop_amplitude > 1.0  # a cycle to suppress
    assert m.stick_fraction > 0.9 and m.amplitude < 0.05 * m.open_loop_amplitude  # raw: ~1
    assert m.stalled and m.suppression == 0.0
    assert m.rms_error > 1.0


@pytest.mark.slow
def test_the_hidden_plant_numbers_hold_with_the_design_models_set_point(tmp_path):
    """A plant the project never saw: lower position friction a1 0.15 (second harmonic 0.05),
    upper a1 0.12, 15 ms motor lag, parameters 6 % off in directions outside the family. With
    the target speed of the design model (the preset's), lqi_angle_ff and ppo_robust keep a
    worst-case suppression of at least 0.95 over 0.7-1.5 V, without stalling, while the LQI
    does not."""
    from drill_env.agents.evaluation.benchmark import BenchmarkConfig, run_benchmark

    b = load_params("brake")
    rig = _plant_file(
        tmp_path / "hidden.yaml",
        motor_constant=b.motor_constant * 1.06,
        lower_inertia=b.lower_inertia * 0.94,
        string_stiffness=b.string_stiffness * 1.06,
        lower_static=b.lower_static * 0.94,
        upper_viscous_pos=b.upper_viscous_pos * 1.06,
        upper_inertia=b.upper_inertia * 0.94,
        effects={
            "lower_position_amp_1": 0.15,
            "lower_position_phase_1": 2.0,
            "lower_position_amp_2": 0.05,
            "lower_position_phase_2": 0.7,
            "upper_position_amp_1": 0.12,
            "upper_position_phase_1": 5.0,
            "motor_lag": 0.015,
        },
    )
    volts = (0.7, 0.85, 1.0, 1.25, 1.5)
    cfg = BenchmarkConfig(
        presets=("brake",),
        controllers=("lqi", "lqi_angle_ff", "ppo_robust"),
        voltages={"brake": volts},
        seeds=(0,),
        plants=(Plant.from_path(rig),),
    )
    run_benchmark(cfg, tmp_path / "out", backend="sequential")
    df = load_results(tmp_path / "out" / "benchmark.csv")
    assert (df["error"] == "").all() and len(df) == 15
    nominal = load_params("brake")
    for v, w in df.groupby("voltage")["target_speed"]:
        assert np.allclose(w, equilibrium_speed(nominal, v), rtol=1e-9)
    worst = df.groupby("controller")["suppression"].min()
    assert worst["lqi_angle_ff"] >= 0.95 and worst["ppo_robust"] >= 0.95, worst
    assert worst["lqi"] < 0.5, worst
    assert not df[df["controller"] != "lqi"]["stalled"].any()


def test_plants_folder_runs_every_plant_file_in_it(tmp_path):
    folder = tmp_path / "plants"
    folder.mkdir()
    b = load_params("brake")
    _plant_file(folder / "rig_a.yaml", lower_inertia=b.lower_inertia * 1.05)
    _plant_file(folder / "rig_b.yaml", actuator_delay=0.01)
    out = tmp_path / "out"
    res = CliRunner().invoke(
        app,
        ["benchmark", "--out", str(out), "--preset", "brake", "--plants", str(folder)]
        + ["--controllers", "open_loop", "--voltages", "1.0", *TINY],
    )
    assert res.exit_code == 0, res.output
    df = load_results(out / "benchmark.csv")
    assert sorted(df["plant"]) == ["rig_a", "rig_b"] and (df["error"] == "").all()
    empty = tmp_path / "empty"
    empty.mkdir()
    res = CliRunner().invoke(app, ["benchmark", "--out", str(tmp_path / "o2"), "--plants", str(empty), *TINY])
    assert res.exit_code == 2 and "holds no plant file" in res.output
