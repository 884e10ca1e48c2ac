"""Everything downstream of ``drill-env identify`` takes the rig it writes, however far from the
paper's: one that sticks above the quick grid's lowest voltage, one without an equilibrium (or
limit-cycle) regime. Operating points come from the rig's own analysis; a run that cannot be
made is one line, the others go on; a regime the rig lacks is named and the others scored."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd
import pytest
import yaml
from identified_rigs import FACTORS, identified_rig, write_rig
from typer.testing import CliRunner

from drill_env.agents.evaluation.benchmark.grid import QUICK_GRID, design_grid, design_regimes
from drill_env.cli import app
from drill_env.envs.equilibrium import equilibrium_speed, hopf_voltages, stable_at_speed
from drill_env.envs.task import OperatingPointSampler, RegimeAbsentWarning, TaskConfig
from drill_env.params import load_params

TINY = ["--duration", "6", "--window", "3", "--warmup", "5", "--backend", "sequential", "--no-timeseries"]


def test_the_rigs_are_what_their_names_say():
    # closed form, independent of the simulation that splits the voltage axis into regimes
    for name in ("brake_sticky", "no_brake_sticky"):
        assert identified_rig(name).uc1 > 0.5 > min(QUICK_GRID[FACTORS[name][0]])
    ss = identified_rig("brake_all_stick_slip")
    assert hopf_voltages(ss) == ()
    assert not stable_at_speed(ss, 0.1) and not stable_at_speed(ss, equilibrium_speed(ss, 5.0))
    for name, (preset, factors) in FACTORS.items():
        assert all(0.35 <= f <= 3.0 for f in factors.values()), name
        assert identified_rig(name).name == name and load_params(preset).uc1 < 0.2


@pytest.mark.parametrize("name", sorted(FACTORS))
def test_the_design_grid_lies_in_the_rigs_own_regimes(name):
    rig = identified_rig(name)
    intervals = design_regimes(rig)
    present = {r for r, _, _ in intervals}
    for n in (4, 15):
        volts = design_grid(rig, n)
        assert len(volts) == n and list(volts) == sorted(volts)
        assert all(rig.uc1 < v <= 5.0 for v in volts)
        # every voltage inside an interval, every regime the rig has at least once
        where = [next(r for r, lo, hi in intervals if lo <= v <= hi) for v in volts]
        assert set(where) == present
        assert all(equilibrium_speed(rig, v) >= 0.1 - 1e-9 for v in volts)
    if name == "brake_all_stick_slip":
        assert present == {"stick_slip"}


def test_the_design_grid_of_the_papers_rig_has_a_point_in_each_regime():
    b = load_params("brake")
    volts = design_grid(b, 4)
    # the paper's boundaries: Hopf B = 0.583 V, stick-slip from D = 1.781 V
    assert any(v < 0.583 for v in volts) and any(0.583 < v < 1.781 for v in volts)
    assert any(v > 1.781 for v in volts)


def test_the_env_scores_the_regimes_a_rig_has_and_names_the_others(tmp_path):
    import gymnasium as gym

    path = write_rig("brake_all_stick_slip", tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make("DrillString-v3", params=str(path))
    msgs = [str(w.message) for w in caught if issubclass(w.category, RegimeAbsentWarning)]
    assert len(msgs) == 1 and "equilibrium, limit_cycle do not occur" in msgs[0], msgs
    regimes = set()
    for seed in range(6):
        _, info = env.reset(seed=seed)
        regimes.add(info["regime"])
        assert info["nominal_voltage"] > identified_rig("brake_all_stick_slip").uc1
    assert regimes == {"stick_slip"}
    with pytest.raises(ValueError, match="'equilibrium' does not occur"):
        env.reset(seed=0, options={"regime": "equilibrium"})
    _, info = env.reset(seed=1, options={"nominal_voltage": 1.0})  # the env is still usable
    assert info["regime"] == "stick_slip"
    env.close()
    # only absent regimes asked for: refused, naming what the rig has
    with pytest.raises(ValueError, match="regimes found: stick_slip"):
        OperatingPointSampler(identified_rig("brake_all_stick_slip"), TaskConfig(regimes=("equilibrium",)))


def _rows(out) -> pd.DataFrame:
    return pd.read_csv(out / "benchmark.csv", keep_default_na=False)


def test_benchmark_quick_on_a_rig_that_sticks_above_the_quick_grid(tmp_path):
    rig = write_rig("brake_sticky", tmp_path)
    out = tmp_path / "out"
    res = CliRunner().invoke(
        app,
        ["benchmark", "--quick", "--preset", "brake", "--design-params", str(rig), "--out", str(out)]
        + ["--controllers", "open_loop,lqi", *TINY],
    )
    assert res.exit_code == 0, res.output
    rows = _rows(out)
    assert len(rows) == 2 * 4 and (rows["error"] == "").all(), rows["error"].tolist()
    uc1 = identified_rig("brake_sticky").uc1
    assert (rows["voltage"] > uc1).all() and np.isfinite(rows["amplitude"]).all()
    # the labels are the rig's regimes, all three of them on the quick grid
    assert set(rows["regime"]) == {"equilibrium", "limit_cycle", "stick_slip"}
    summary = (out / "summary.md").read_text()
    assert "Regimes of the design model (its own analysis): equilibrium 0." in summary


def test_benchmark_names_the_runs_it_cannot_make_and_makes_the_others(tmp_path):
    rig = write_rig("brake_all_stick_slip", tmp_path)
    out = tmp_path / "out"
    res = CliRunner().invoke(
        app,
        ["benchmark", "--preset", "brake", "--design-params", str(rig), "--out", str(out)]
        + ["--controllers", "open_loop,lqi", "--voltages", "0.15,1.0,3.0", "--seeds", "1", *TINY],
    )
    assert res.exit_code == 0, res.output
    rows = _rows(out)
    assert len(rows) == 6
    skipped = rows[rows["error"] != ""]
    assert set(skipped["voltage"]) == {0.15} and len(skipped) == 2
    assert skipped["error"].str.startswith("not made: the design model sticks up to uc1 = 0.1691 V").all()
    made = rows[rows["error"] == ""]
    assert (
        len(made) == 4
        and np.isfinite(made["amplitude"].astype(float)).all()
        and set(made["regime"]) == {"stick_slip"}
    )
    lines = [x for x in res.output.splitlines() if x.startswith("not made:")]
    assert len(lines) == 1 and "2 run(s) at 0.15 V" in lines[0], res.output
    summary = (out / "summary.md").read_text()
    assert "no equilibrium and no limit_cycle regime on this model" in summary
    assert "## runs not made" in summary and "## runs that failed" not in summary
    assert "- lqi brake 0.15 V seed 0: the design model sticks up to" in summary


@pytest.mark.slow
def test_bifurcation_of_identified_rigs(tmp_path):
    for name in ("no_brake_sticky", "brake_all_stick_slip"):
        rig = write_rig(name, tmp_path)
        out = tmp_path / name
        res = CliRunner().invoke(app, ["bifurcation", "--preset", str(rig), "--out", str(out), "--no-check"])
        assert res.exit_code == 0, res.output
        record = yaml.safe_load((out / "bifurcation.json").read_text())
        a = record["points"]["A"]["u"] if isinstance(record["points"]["A"], dict) else record["points"]["A"]
        assert math.isclose(float(a), identified_rig(name).uc1, rel_tol=1e-6)


@pytest.mark.slow
def test_train_on_a_rig_without_two_of_the_regimes(tmp_path):
    from test_train import small_config

    config = tmp_path / "tiny_ppo.yaml"
    config.write_text(yaml.safe_dump(small_config("ppo", 256).to_dict()))
    rig = write_rig("brake_all_stick_slip", tmp_path)
    out = tmp_path / "agents" / "ppo"
    res = CliRunner().invoke(
        app,
        ["train", "--algo", "ppo", "--config", str(config), "--params", str(rig), "--out", str(out)]
        + ["--no-progress"],
    )
    assert res.exit_code == 0, res.output
    curve = pd.read_csv(out / "eval.csv")
    assert len(curve) >= 3 and np.isfinite(curve["return_stick_slip"]).all()
    assert curve["return_equilibrium"].isna().all() and curve["return_limit_cycle"].isna().all()
    assert np.allclose(curve["mean_return"], curve["return_stick_slip"])


def test_the_learning_curve_evaluates_the_regimes_the_rig_has():
    from drill_env.agents.learning.rl import EvalConfig, evaluation_episodes

    cfg = EvalConfig(every_steps=100, episodes_per_regime=2, seed=5)
    every = evaluation_episodes(cfg)
    some = evaluation_episodes(cfg, ("stick_slip",))
    assert [o["regime"] for _, o in every] == ["equilibrium"] * 2 + ["limit_cycle"] * 2 + ["stick_slip"] * 2
    assert some == every[4:]  # a regime's seeds do not depend on the others


def test_sim_to_real_on_a_rig_takes_its_voltages_from_the_rigs_analysis(tmp_path):
    from drill_env.agents.evaluation.sim_to_real import SimToRealConfig, for_rig, quick_config

    for name in ("brake_sticky", "brake_all_stick_slip"):
        rig = identified_rig(name)
        path = write_rig(name, tmp_path)
        cfg = for_rig(quick_config(), path)
        cycles = [(lo, hi) for r, lo, hi in design_regimes(rig) if r in ("limit_cycle", "stick_slip")]
        assert cfg.params_file == str(path) and cfg.nominal_model() == load_params(path)
        assert all(any(lo <= v <= hi for lo, hi in cycles) for v in cfg.voltages)
        assert cfg.timeseries_voltage == cfg.voltages[0]
        assert len(cfg.synth.voltages) == 3 and all(v > rig.uc1 for v in cfg.synth.voltages)
        full = for_rig(SimToRealConfig(), path)
        assert len(full.voltages) == 5 and all(v > rig.uc1 for v in full.voltages)
    # a voltage the rig's model does not turn at is refused, naming its range
    with pytest.raises(ValueError, match=r"voltages: 0.4 V is outside the allowed range \(0.5371"):
        for_rig(
            quick_config(voltages=(0.4,)),
            write_rig("brake_sticky", tmp_path),
            voltages=False,
        )


def test_sim_to_real_params_that_are_not_a_rig_file_is_one_line(tmp_path):
    bad = tmp_path / "rig.yaml"
    bad.write_text("motor_constant: -1\n")
    for arg in (str(bad), str(tmp_path / "none.yaml")):
        res = CliRunner().invoke(
            app, ["sim-to-real", "--quick", "--params", arg, "--out", str(tmp_path / "o")]
        )
        assert res.exit_code == 2, res.output
        lines = [x for x in res.output.strip().splitlines() if x.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: --params"), res.output


@pytest.mark.slow  # a minute or two: recording, discrepancy, two tunings, the closed loops
def test_sim_to_real_quick_on_a_rig_that_sticks_above_its_default_voltages(tmp_path):
    rig = write_rig("brake_sticky", tmp_path)
    out = tmp_path / "out"
    res = CliRunner().invoke(
        app,
        ["sim-to-real", "--quick", "--params", str(rig), "--controllers", "lqi", "--out", str(out)],
    )
    assert res.exit_code == 0, res.output
    rows = pd.read_csv(out / "results.csv")
    uc1 = identified_rig("brake_sticky").uc1
    assert (rows["voltage"] > uc1).all() and set(rows["design"]) == {"-", "nominal", "corrected"}
    assert np.isfinite(rows["amplitude"]).all()
    result = yaml.safe_load((out / "discrepancy" / "result.json").read_text())
    assert result["effect"] == "position_friction_lower"  # the hidden effect, against the rig's model
    # the recalibration is relative to the rig's model: the truth's +3 % / +5 % errors
    for name, rel in (("motor_constant", 0.03), ("lower_inertia", 0.05)):
        got = result["recalibrated"][name]["value"] / getattr(identified_rig("brake_sticky"), name) - 1.0
        assert abs(got - rel) < 0.01, (name, got)
    assert (out / "gains_nominal.yaml").is_file()


@pytest.mark.slow  # half a minute: the continuation to 1.5 V
def test_bifurcation_of_a_rig_file_with_an_effect_section_analyses_its_base_model(tmp_path):
    rig = identified_rig("brake_sticky").replace(lower_position_amp_1=0.1)
    path = tmp_path / "rig.yaml"
    path.write_text("# written by `drill-env identify`\n" + yaml.safe_dump(rig.to_dict(), sort_keys=False))
    out = tmp_path / "out"
    res = CliRunner().invoke(
        app, ["bifurcation", "--preset", str(path), "--out", str(out), "--umax", "1.5", "--no-check"]
    )
    assert res.exit_code == 0, res.output
    assert "the effects ['lower_position_amp_1'] of rig.yaml are left out" in res.output
    record = yaml.safe_load((out / "bifurcation.json").read_text())
    assert any("left out" in w for w in record["validity_warnings"])
    a = record["points"]["A"]["u"] if isinstance(record["points"]["A"], dict) else record["points"]["A"]
    assert math.isclose(float(a), rig.uc1, rel_tol=1e-6)
