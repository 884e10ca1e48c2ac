"""The scenario suite's runner and ``drill-env scenarios``."""

from __future__ import annotations

import json

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


def _nominal_ranking(path, scores: dict[str, float]):
    """A nominal benchmark's ranking.json with these mean suppressions (key ``all``)."""
    rows = [{"controller": c, "score": v} for c, v in sorted(scores.items(), key=lambda kv: -kv[1])]
    path.write_text(
        json.dumps(
            {
                "rankings": [
                    {"key": "brake", "scores": rows[:1]},
                    {"key": "all", "score": "suppression", "scores": rows},
                ]
            }
        )
    )
    return path


def test_scenarios_command_scores_paired_runs(tmp_path):
    out = tmp_path / "suite"
    nominal = _nominal_ranking(
        tmp_path / "ranking.json", {"z_torque": 0.995, "pi_upper": 0.999, "lqi": 0.998}
    )
    res = runner.invoke(
        app,
        [
            "scenarios", "--out", str(out), "--controllers", "z_torque,pi_upper", "--scenarios", "start_up",
            "--preset", "all", "--seeds", "1", "--workers", "1", "--nominal-ranking", str(nominal),
        ],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    for name in (
        "runs.csv",
        "scenarios.csv",
        "summary.md",
        "scores.png",
        "ranking.json",
        "ranking.md",
        "ranking_suite.png",
    ):
        assert (out / name).is_file(), name
    runs = pd.read_csv(out / "runs.csv", keep_default_na=False, na_values=[""])
    assert tuple(runs.columns) == RUN_COLUMNS
    assert sorted(runs["controller"]) == ["open_loop"] * 2 + ["pi_upper"] * 2 + ["z_torque"] * 2
    # the paired statistics of the suite score (units: scenario x preset x seed, here 2)
    record = json.loads((out / "ranking.json").read_text())
    suite = next(r for r in record["rankings"] if r["key"] == "suite")
    assert suite["units"] == ["scenario", "preset", "seed"] and suite["n_units"] == 2
    table = scenario_table(runs)
    got = {r["controller"]: r for r in suite["scores"]}
    for name in ("z_torque", "pi_upper", "open_loop"):
        assert got[name]["score"] == pytest.approx(
            table.loc[name, "suite_score"], rel=1e-5, abs=1e-9
        )  # CSV: 6 digits
        assert got[name]["low"] <= got[name]["score"] <= got[name]["high"]
    assert [r["controller"] for r in suite["scores"]] == list(table.index)
    assert {r["key"] for r in record["rankings"]} == {"suite", "start_up"}
    # the nominal leaders present in the suite: z_torque and pi_upper (lqi did not run), one pair
    lead = record["nominal_leaders"]
    assert list(lead["controllers"]) == ["pi_upper", "z_torque"] and lead["n_pairs"] == 1
    pair = next(q for q in suite["pairs"] if {q["a"], q["b"]} == {"z_torque", "pi_upper"})
    assert lead["resolved"] == int(pair["resolved"]) and lead["pairs"][0]["difference"] == pytest.approx(
        pair["difference"], abs=1e-9
    )
    summary = (out / "summary.md").read_text()
    assert "## Suite score with paired intervals" in summary and "## Rank on each scenario" in summary
    assert f"Of their 1 pairs the suite's paired intervals resolve **{lead['resolved']}**" in summary
    assert "headroom start_up" in res.output and "pairs resolved" in res.output
    runs = runs[(runs["preset"] == "brake")]
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
        (
            ["--nominal-ranking", "missing/ranking.json"],
            "--nominal-ranking: 'missing/ranking.json' is no ranking.json",
        ),
        (
            ["--nominal-ranking", "pyproject.toml"],
            "--nominal-ranking: 'pyproject.toml' is not a benchmark's ranking.json",
        ),
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


def _synthetic_runs(seed: int = 0) -> pd.DataFrame:
    """Runs of four controllers on 3 scenarios x 2 presets x 4 seeds: ``b`` beats ``c`` by 0.05 on
    every unit (up to noise), ``a`` and ``b`` differ by noise only."""
    rng = np.random.default_rng(seed)
    rows = []
    for s in ("start_up", "friction_step", "effort"):
        for p in ("brake", "no_brake"):
            for k in range(4):
                base = rng.uniform(0.5, 0.9)  # the unit's difficulty, shared by every controller
                for c, offset in (("open_loop", None), ("a", 0.0), ("b", 0.0), ("c", -0.05)):
                    score = 0.0 if offset is None else base + offset + rng.normal(0, 0.002)
                    rows.append({"controller": c, "scenario": s, "preset": p, "seed": k, "score": score})
    return pd.DataFrame(rows)


def test_the_suite_ranking_is_the_benchmarks_statistics_on_scenario_units():
    from drill_env.agents.evaluation.benchmark import ranking
    from drill_env.agents.evaluation.benchmark.statistics import paired_bootstrap
    from drill_env.agents.evaluation.scenario_report import suite_rankings

    runs = _synthetic_runs()
    got = dict((k, st) for k, _t, st in suite_rankings(runs))
    assert list(got) == ["suite", "start_up", "friction_step", "effort"]
    suite = got["suite"]
    same = paired_bootstrap(
        runs, score="score", units=("scenario", "preset", "seed"), confidence=ranking.CONFIDENCE,
        n_resamples=ranking.N_RESAMPLES, method=ranking.METHOD, seed=ranking.SEED,
    )  # fmt: skip
    pd.testing.assert_frame_equal(suite.scores, same.scores)
    pd.testing.assert_frame_equal(suite.pairs, same.pairs)
    table = scenario_table(runs)
    for r in suite.scores.to_dict("records"):
        assert r["score"] == pytest.approx(table.loc[r["controller"], "suite_score"], abs=1e-12)
    pairs = {(q["a"], q["b"]): q for q in suite.pairs.to_dict("records")}
    # a shared difficulty cancels in the paired difference: 0.05 resolved on 24 units, noise not
    assert pairs[("b", "c")]["resolved"] and pairs[("b", "c")]["difference"] == pytest.approx(0.05, abs=0.002)
    ab = pairs.get(("a", "b")) or pairs[("b", "a")]
    assert not ab["resolved"] and abs(ab["difference"]) < 0.002
    assert got["effort"].units == ("preset", "seed") and got["effort"].n_units == 8


def test_an_unbalanced_suite_is_refused():
    from drill_env.agents.evaluation.scenario_report import suite_rankings

    runs = _synthetic_runs()
    runs = runs[~((runs["scenario"] == "effort") & (runs["seed"] == 3))]
    with pytest.raises(ValueError, match="different numbers of preset x seed units"):
        suite_rankings(runs)


def test_the_nominal_leaders_pairs_are_counted(tmp_path):
    from drill_env.agents.evaluation.scenario_report import (
        nominal_leaders,
        read_nominal_ranking,
        suite_rankings,
    )

    suite = suite_rankings(_synthetic_runs())[0][2]
    nominal = read_nominal_ranking(
        _nominal_ranking(
            tmp_path / "ranking.json", {"a": 0.999, "b": 0.995, "c": 0.991, "open_loop": 0.0, "x": 0.999}
        )
    )
    assert nominal["key"] == "all"
    lead = nominal_leaders(suite, nominal)
    assert list(lead["controllers"]) == ["a", "b", "c"]  # x did not run in the suite
    assert lead["n_pairs"] == 3
    # b > c and a > c by 0.05 resolved, a vs b not
    assert lead["resolved"] == 2
    assert {(q["a"], q["b"]) for q in lead["pairs"] if q["resolved"]} == {("a", "c"), ("b", "c")}
    assert read_nominal_ranking(tmp_path)["source"].endswith("ranking.json")  # the folder works too
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(ValueError, match="is not a benchmark's ranking.json"):
        read_nominal_ranking(tmp_path / "bad.json")
