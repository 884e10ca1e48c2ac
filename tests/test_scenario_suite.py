"""The scenario suite's runner and ``drill-env scenarios``."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import drill_env  # noqa: F401
from drill_env.agents.evaluation.scenarios import RUN_COLUMNS, scenario_table, score_runs
from drill_env.agents.registry import build_controller
from drill_env.cli import app

runner = CliRunner()


def _own_iae(controller: str, scenario: str, preset: str, seed: int) -> float:
    """Mean |x3 - w*| over the closed loop, stepping the environment directly (not through the
    evaluation path): the oracle for the suite's IAE."""
    env_id = {"brake": "DrillString-v1", "no_brake": "DrillStringNoBrake-v1"}[preset]
    ctrl = build_controller(controller, gym.make(env_id), preset)
    env = gym.make(env_id, scenario=scenario, warmup_time=30.0, warmup_jitter=4.0, max_episode_steps=10**6)
    obs, info = env.reset(seed=seed)
    target = info["target_speed"]
    errs = []
    state, start = None, np.ones(1, dtype=bool)
    for _ in range(int(round(40.0 / env.unwrapped.control_dt))):
        action, state = ctrl.predict(obs, state=state, episode_start=start)
        start = np.zeros(1, dtype=bool)
        obs, _, _, _, info = env.step(action)
        errs.append(np.abs(env.unwrapped.last_step_samples()["lower_speed"] - target))
        target = info["target_speed"]  # in force from the next period on
    return float(np.mean(np.concatenate(errs)))


def test_scenarios_command_scores_paired_runs(tmp_path):
    out = tmp_path / "suite"
    res = runner.invoke(
        app,
        [
            "scenarios", "--out", str(out), "--controllers", "z_torque,pi_upper", "--scenarios", "start_up",
            "--preset", "brake", "--seeds", "1", "--workers", "1",
        ],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    for name in ("runs.csv", "scenarios.csv", "summary.md", "scores.png"):
        assert (out / name).is_file()
    runs = pd.read_csv(out / "runs.csv", keep_default_na=False, na_values=[""])
    assert tuple(runs.columns) == RUN_COLUMNS
    assert sorted(runs["controller"]) == ["open_loop", "pi_upper", "z_torque"]
    row = runs.set_index("controller")
    assert row.loc["open_loop", "score"] == 0.0
    # the IAE against the environment stepped by hand, and the score from it
    for name in ("z_torque", "pi_upper"):
        assert row.loc[name, "iae"] == pytest.approx(
            _own_iae(name, "start_up", "brake", 0), rel=1e-5
        )  # CSV: 6 digits
        expected = max(-1.0, 1.0 - row.loc[name, "iae"] / row.loc["open_loop", "iae"])
        assert row.loc[name, "score"] == pytest.approx(expected, rel=1e-5)
    assert row.loc["z_torque", "score"] > 0.8  # the impedance-matched top drive starts up cleanly
    assert "z_torque" in (out / "summary.md").read_text()


@pytest.mark.parametrize(
    "args,message",
    [
        (["--scenarios", "start_up,nope"], "--scenarios: ['nope'] not among"),
        (["--controllers", "lqi,my_ctrl"], "--controllers: ['my_ctrl'] not among"),
        (["--preset", "wet"], "--preset: 'wet'"),
        (["--seeds", "0"], "--seeds: 0"),
        (["--workers", "0"], "--workers: 0"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, message):
    res = runner.invoke(app, ["scenarios", "--out", str(tmp_path / "x"), *args])
    assert res.exit_code == 2
    assert message in res.output and "Traceback" not in res.output
    assert not (tmp_path / "x").exists()


def test_scores_floor_failures_and_aggregate_evenly():
    raw = []
    for scenario, iae_ol in (("start_up", 2.0), ("effort", 1.0)):
        raw.append({"controller": "open_loop", "scenario": scenario, "preset": "brake", "seed": 0,
                    "iae": iae_ol, "energy_j": 10.0, "energy_ref_j": 10.0, "sim_status": 0, "error": ""})  # fmt: skip
    raw.append({"controller": "lqi", "scenario": "start_up", "preset": "brake", "seed": 0, "iae": 0.5,
                "energy_j": 10.0, "energy_ref_j": 10.0, "sim_status": 0, "error": ""})  # fmt: skip
    # twice the energy the equilibrium needs halves the effort score
    raw.append({"controller": "lqi", "scenario": "effort", "preset": "brake", "seed": 0, "iae": 0.2,
                "energy_j": 20.0, "energy_ref_j": 10.0, "sim_status": 0, "error": ""})  # fmt: skip
    raw.append({"controller": "pi_upper", "scenario": "start_up", "preset": "brake", "seed": 0, "iae": 9.0,
                "energy_j": 10.0, "energy_ref_j": 10.0, "sim_status": 0, "error": ""})  # fmt: skip
    raw.append({"controller": "pi_upper", "scenario": "effort", "preset": "brake", "seed": 0,
                "sim_status": -1, "error": "RuntimeError: boom"})  # fmt: skip
    df = score_runs(raw).set_index(["controller", "scenario"])
    assert df.loc[("lqi", "start_up"), "score"] == pytest.approx(0.75)
    assert df.loc[("lqi", "effort"), "score"] == pytest.approx(0.8 * 0.5)
    assert df.loc[("pi_upper", "start_up"), "score"] == -1.0  # 1 - 4.5 floored
    assert df.loc[("pi_upper", "effort"), "score"] == -1.0  # a failed run is never dropped
    table = scenario_table(score_runs(raw))
    assert table.loc["lqi", "suite_score"] == pytest.approx((0.75 + 0.4) / 2)
    assert list(table.index) == ["lqi", "open_loop", "pi_upper"]
