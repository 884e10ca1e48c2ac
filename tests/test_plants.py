"""Plants that differ from the design model: the standard family, the benchmark on it and the
robustness report (nominal / mean / worst across plants)."""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drill_env.agents.evaluation.benchmark import BenchmarkConfig, load_results, run_benchmark
from drill_env.agents.evaluation.episodes import EpisodeSettings, make_env
from drill_env.agents.evaluation.plants import NOMINAL, Plant, standard_family
from drill_env.agents.evaluation.robustness import (
    robust_pairs,
    robustness_lines,
    robustness_rows,
    worst_by_voltage,
    worst_case_verdict,
)
from drill_env.analysis import limit_cycle
from drill_env.cli import app
from drill_env.params import RigParams, load_params

FAMILY = {p.name: p for p in standard_family()}
SETTLED = EpisodeSettings(duration=25.0, window=12.0, warmup_time=40.0, warmup_jitter=1.0)
TINY = EpisodeSettings(duration=6.0, window=3.0, warmup_time=4.0, warmup_jitter=1.0)


def test_the_family_is_what_its_documentation_lists():
    names = list(FAMILY)
    assert names[0] == NOMINAL and len(names) == len(set(names)) == 18
    # the minimum: each identified parameter both ways, each library effect, delay, noise
    expected_scale = {
        "lower_inertia": 0.10,
        "string_stiffness": 0.10,
        "lower_static": 0.20,
        "lower_hump_1": 0.20,
        "lower_hump_2": 0.20,
        "motor_constant": 0.05,
    }
    seen: dict[str, set[float]] = {}
    for p in FAMILY.values():
        for k, f in p.scale.items():
            seen.setdefault(k, set()).add(round(f, 6))
    assert seen == {k: {round(1 - r, 6), round(1 + r, 6)} for k, r in expected_scale.items()}
    effects = {k: v for p in FAMILY.values() for k, v in p.effects.items()}
    assert effects == {
        "lower_position_amp_1": 0.12,
        "upper_position_amp_1": 0.12,
        "string_damping": 2e-3,
        "motor_lag": 0.02,
        "friction_lag": 0.1,
    }
    assert FAMILY["delay_10ms"].sensors == {"delay_samples": 10}
    assert FAMILY["angle_noise_3mrad"].sensors == {"angle_noise_std": 3e-3}
    import drill_env.agents.evaluation.plants as doc

    for name in names[1:]:  # every plant is described in the module docstring
        stem = name.rsplit("_x", 1)[0]
        assert stem in doc.__doc__, name


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_every_family_plant_is_the_preset_with_exactly_its_change(preset):
    base = load_params(preset)
    numeric = [f.name for f in fields(RigParams) if f.name not in ("effects", "name", "description")]
    for p in FAMILY.values():
        rig = p.rig(preset)
        if not p.scale and not p.effects:
            assert rig is None  # the preset's own rig
            continue
        assert isinstance(rig, RigParams)  # valid: friction dissipative etc.
        for k in numeric:
            want = getattr(base, k) * p.scale.get(k, 1.0)
            assert getattr(rig, k) == pytest.approx(want, rel=1e-12), (p.name, k)
        active = {k: getattr(rig.effects, k) for k in rig.effects.active}
        assert active == pytest.approx(dict(p.effects)), p.name


def test_the_measurement_chain_of_a_plant_reaches_its_env_and_not_the_design_env():
    delay, noise = FAMILY["delay_10ms"], FAMILY["angle_noise_3mrad"]
    env = make_env("brake", TINY, 1, params=delay.rig("brake"), overrides=delay.env_overrides())
    assert env.unwrapped.settings.sensors.delay_samples == 10
    env = make_env("brake", TINY, 1, overrides=noise.env_overrides({"sensors": {"counts_per_rev": 4000}}))
    s = env.unwrapped.settings.sensors
    assert s.angle_noise_std == 3e-3 and s.counts_per_rev == 4000  # merged, not replaced
    assert make_env("brake", TINY, 1).unwrapped.settings.sensors.delay_samples == 0


@pytest.mark.parametrize(("preset", "voltage"), [("brake", 2.0), ("brake", 1.0), ("no_brake", 0.85)])
def test_a_plants_open_loop_reference_is_the_cycle_the_analysis_finds_on_that_plant(
    tmp_path, preset, voltage
):
    # oracle: the bifurcation analysis (shooting on the nonsmooth model) run on the perturbed
    # rig, not the benchmark's simulated episode
    plants = tuple(FAMILY[n] for n in ("nominal", "km_x1.05", "hump_x0.80", "Jl_x1.10"))
    cfg = BenchmarkConfig(
        presets=(preset,),
        controllers=("open_loop",),
        voltages={preset: (voltage,)},
        seeds=(0,),
        episode=SETTLED,
        plants=plants,
    )
    run_benchmark(cfg, tmp_path, backend="sequential", report=False)
    df = load_results(tmp_path / "benchmark.csv").set_index("plant")
    nominal_cycle = limit_cycle(load_params(preset), voltage)
    for p in plants[1:]:
        cyc = limit_cycle(p.rig(preset), voltage)
        expected = cyc.x3_max - cyc.x3_min
        assert df.loc[p.name, "open_loop_amplitude"] == pytest.approx(expected, rel=2e-3), p.name
    # km and the hump change the cycle by more than the tolerance: a plant not applied is caught
    for name in ("km_x1.05", "hump_x0.80"):
        assert (
            abs(df.loc[name, "open_loop_amplitude"] / (nominal_cycle.x3_max - nominal_cycle.x3_min) - 1)
            > 0.02
        )


def _frame(rows):
    base = dict(preset="brake", seed=0, error="", regime="limit_cycle", stick_fraction=0.0, rms_error=0.0)
    return pd.DataFrame([{**base, **r} for r in rows])


def test_robustness_rows_weigh_plants_equally_and_name_the_worst_run():
    df = _frame(
        [
            dict(controller="lqi", plant="nominal", voltage=1.0, suppression=0.99, rms_error=0.01),
            dict(controller="lqi", plant="nominal", voltage=1.5, suppression=0.97, rms_error=0.03),
            dict(controller="lqi", plant="a", voltage=1.0, suppression=0.50, rms_error=0.30),
            dict(controller="lqi", plant="b", voltage=1.0, suppression=0.90, rms_error=0.02),
            dict(controller="lqi", plant="b", voltage=1.5, suppression=math.nan, rms_error=0.05),
        ]
    )
    rows = {r["metric"]: r for r in robustness_rows(df, "brake") if r["controller"] == "lqi"}
    sup = rows["suppression"]
    assert sup["nominal"] == pytest.approx(0.98)
    assert sup["mean"] == pytest.approx((0.98 + 0.50 + 0.90) / 3)  # per plant first, NaN left out
    assert (sup["worst"], sup["worst_plant"], sup["worst_voltage"]) == (0.5, "a", 1.0)
    err = rows["rms_error"]
    assert (err["worst"], err["worst_plant"]) == (0.30, "a")  # larger is worse
    assert err["mean"] == pytest.approx((0.02 + 0.30 + 0.035) / 3)
    assert not rows["stick_fraction"]["spread"]
    text = "\n".join(robustness_lines(df, "brake"))
    assert "0.500 (a, 1)" in text and "0.0 (every run)" in text


def test_the_worst_case_over_the_plants_at_each_voltage_sets_a_robust_policy_against_its_nominal_one():
    runs = [
        # voltage 1: ppo's worst is plant a (0.40), ppo_robust's plant b (0.95): ahead by 0.55
        ("ppo", "nominal", 1.0, 0, 0.99),
        ("ppo", "a", 1.0, 0, 0.40),
        ("ppo", "a", 1.0, 1, 0.70),
        ("ppo_robust", "nominal", 1.0, 0, 0.98),
        ("ppo_robust", "a", 1.0, 0, 0.97),
        ("ppo_robust", "b", 1.0, 1, 0.95),
        # voltage 2: behind by 0.01; a run without a cycle (NaN) is not a worst case
        ("ppo", "nominal", 2.0, 0, 0.995),
        ("ppo", "b", 2.0, 0, math.nan),
        ("ppo_robust", "nominal", 2.0, 0, 0.985),
        ("ppo_robust", "b", 2.0, 0, math.nan),
        # the reference, and a controller without a robust counterpart
        ("open_loop", "a", 1.0, 0, 0.0),
        ("lqi", "a", 2.0, 0, 0.5),
        # no cycle anywhere at 3 V: no column
        ("ppo", "a", 3.0, 0, math.nan),
        ("ppo_robust", "a", 3.0, 0, math.nan),
    ]
    df = _frame([dict(controller=c, plant=p, voltage=v, seed=s, suppression=x) for c, p, v, s, x in runs])
    worst = worst_by_voltage(df, "brake")
    assert list(worst) == ["lqi", "ppo", "ppo_robust"]  # the registry's order, no open loop
    assert worst["ppo"] == {1.0: (0.40, "a"), 2.0: (0.995, "nominal")}
    assert worst["ppo_robust"] == {1.0: (0.95, "b"), 2.0: (0.985, "nominal")}
    assert robust_pairs(worst) == [("ppo_robust", "ppo")]
    v = worst_case_verdict(worst, "ppo_robust", "ppo")
    assert (v["voltages"], v["at_least"]) == (2, 1)
    assert v["behind"] == {2.0: pytest.approx(-0.01)}
    assert v["smallest"] == (pytest.approx(-0.01), 2.0)
    text = "\n".join(robustness_lines(df, "brake"))
    assert (
        "- `ppo_robust` against `ppo`: its worst case is at least `ppo`'s at 1 of 2 voltages; behind at 2 V by 0.0100."
        in text
    )
    assert (
        "| controller | 1 V | 2 V |" in text
        and "| ppo | 0.400 / 0.000 | 0.995 / 0.000 |" in text  # suppression / RMS error
        and "| lqi | - | 0.500 / 0.000 |" in text
    )
    # ahead everywhere: the smallest margin is named
    ahead = df[df["voltage"] == 1.0]
    assert "at 1 of 1 voltages; smallest margin +0.5500 at 1 V." in "\n".join(
        robustness_lines(ahead, "brake")
    )


def test_open_loop_has_no_suppression_row_it_is_the_reference():
    df = _frame(
        [dict(controller="open_loop", plant=p, voltage=1.0, suppression=0.0) for p in ("nominal", "a")]
    )
    assert {r["metric"] for r in robustness_rows(df, "brake")} == {"stick_fraction", "rms_error"}


def test_a_benchmark_on_several_plants_reports_robustness(tmp_path):
    plants = (Plant(), FAMILY["position_friction_lower"], FAMILY["km_x1.05"])
    cfg = BenchmarkConfig(
        presets=("brake",),
        controllers=("open_loop", "lqi"),
        voltages={"brake": (1.0,)},
        seeds=(0,),
        episode=TINY,
        plants=plants,
    )
    run_benchmark(cfg, tmp_path, backend="sequential")
    summary = (tmp_path / "summary.md").read_text()
    assert "## brake: robustness across 3 plants" in summary
    assert "| `position_friction_lower` | lower friction modulated once per revolution" in summary
    assert "## brake, plant `km_x1.05`" in summary and "motor constant k_m +5 %" in summary
    assert (tmp_path / "robustness_brake.png").stat().st_size > 20_000
    assert "### worst case over the plants at each voltage" in summary and "| lqi | " in summary
    assert (tmp_path / "worst_case_brake.png").stat().st_size > 20_000
    # a fresh run removes the figures of plants it no longer has
    (tmp_path / "suppression_brake_gone.png").write_bytes(b"x")
    run_benchmark(
        BenchmarkConfig(
            presets=("brake",),
            controllers=("open_loop",),
            voltages={"brake": (1.0,)},
            seeds=(0,),
            episode=TINY,
        ),
        tmp_path,
        backend="sequential",
        fresh=True,
    )
    assert not (tmp_path / "suppression_brake_gone.png").exists()
    assert not (tmp_path / "robustness_brake.png").exists()
    assert not (tmp_path / "worst_case_brake.png").exists()


def test_cli_plants_family_and_its_errors(tmp_path):
    runner = CliRunner()
    args = ["benchmark", "--preset", "brake", "--controllers", "open_loop", "--voltages", "2", "--seeds", "1"]
    args += ["--duration", "4", "--window", "2", "--warmup", "2", "--backend", "sequential"]
    res = runner.invoke(app, [*args, "--plants", "family", "--out", str(tmp_path / "f")])
    assert res.exit_code == 0, res.output
    # not a terminal: progress as plain lines, every 5 % of the runs
    assert "18/18 runs," in res.output and "9/18 runs," in res.output, res.output
    df = load_results(tmp_path / "f" / "benchmark.csv")
    assert list(df["plant"]) == list(FAMILY)
    assert np.isfinite(df["amplitude"]).all()
    for bad, msg in ((["--plants", "all"], "--plants: 'all'"), (["--plant", "family"], "--plants family")):
        res = runner.invoke(app, [*args, *bad, "--out", str(tmp_path / "e")])
        assert res.exit_code == 2 and msg in res.output and "Traceback" not in res.output, res.output


def test_a_plant_name_must_be_usable_as_a_file_name():
    with pytest.raises(ValueError, match="file-name-safe"):
        Plant("a/b", scale={"lower_inertia": 1.1})
    with pytest.raises(ValueError, match="scale.lower_inertia"):
        Plant("x", scale={"lower_inertia": -1.0})
    with pytest.raises(ValueError, match="unknown effect"):
        Plant("x", effects={"gremlins": 1.0})
    with pytest.raises(ValueError, match="unknown field"):
        Plant("x", sensors={"lens": 1})


def test_time_series_show_every_plant_one_figure_per_plant_and_controller_group(tmp_path):
    from drill_env.agents.evaluation.timeseries import run_trace, timeseries_figures

    paper = FAMILY["position_friction_lower"]
    episode = EpisodeSettings(duration=20.0, window=5.0, warmup_time=20.0, warmup_jitter=1.0)
    paths = timeseries_figures(
        ["open_loop", "lqi"], "brake", 1.0, (Plant(), paper), tmp_path, episode=episode
    )
    assert [p.name for p in paths] == [
        "timeseries_brake_nominal_classical.png",
        "timeseries_brake_position_friction_lower_classical.png",
    ]
    assert all(p.stat().st_size > 20_000 for p in paths)
    # the traces are the benchmark's runs: the LQI settles on the nominal rig, not on the plant
    # whose friction varies once per revolution (the paper's Sec. 4.1 effect)
    nominal, plant = (run_trace("lqi", "brake", 1.0, 0, episode, q) for q in (Plant(), paper))
    n = nominal.window_t.size
    assert n == 1000 * 20  # 1 kHz over the whole closed-loop episode
    last = slice(n // 2, None)
    spread = [np.ptp(tr.window_lower_speed[last]) for tr in (nominal, plant)]
    assert spread[0] < 0.05 < 0.5 < spread[1], spread
    with pytest.raises(ValueError, match="no time series"):
        timeseries_figures(
            ["ppo"], "brake", 1.0, (Plant(),), tmp_path, episode=episode, agents_dir=str(tmp_path)
        )


def test_cli_quick_benchmark_writes_time_series(tmp_path):
    runner = CliRunner()
    args = ["benchmark", "--quick", "--preset", "brake", "--controllers", "open_loop,torque_feedback"]
    args += ["--duration", "6", "--window", "3", "--warmup", "4", "--backend", "sequential"]
    res = runner.invoke(app, [*args, "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "wrote 1 time-series figures of brake" in res.output
    assert (tmp_path / "timeseries_brake_nominal_classical.png").is_file()
    res = runner.invoke(app, [*args, "--no-timeseries", "--fresh", "--out", str(tmp_path)])
    assert res.exit_code == 0 and not list(tmp_path.glob("timeseries_*.png")), res.output
