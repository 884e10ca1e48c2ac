"""The learned controllers' target check: the benchmark's runs on a small grid, suppression and
tracking together, against the committed benchmark and controllers that do and do not meet it."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from drill_env.agents.evaluation.episodes import EpisodeSettings, make_env
from drill_env.agents.evaluation.target_check import (
    CHECK_SEEDS,
    CHECK_VOLTAGES,
    CYCLE_REGIMES,
    TargetCheck,
    tracking_limits,
)

ROOT = Path(__file__).resolve().parent.parent
BENCHMARK = ROOT / "results" / "benchmark" / "benchmark.csv"
CLASSICAL_VERSION = 1  # the env the benchmark runs the classical controllers on (registry)


def _classical(name: str, preset: str):
    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.gains import classical_controller

    env = make_env(preset, EpisodeSettings(), CLASSICAL_VERSION)
    ctrl = classical_controller(name, ControllerSpec.from_env(env), preset)
    env.close()
    return ctrl


def test_the_grid_has_three_voltages_per_regime_5_v_and_two_seeds_off_the_benchmarks():
    for regimes in CHECK_VOLTAGES.values():
        assert set(regimes) == {"equilibrium", "limit_cycle", "stick_slip"}
        assert all(len(v) >= 3 for v in regimes.values())
        assert 5.0 in {v for vs in regimes.values() for v in vs}
    assert len(CHECK_SEEDS) >= 2 and not set(CHECK_SEEDS) & {0, 1, 2, 3, 4}


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_the_lqi_runs_are_the_committed_benchmarks_and_set_the_limit(preset):
    # seed 0 is a benchmark seed: the check's LQI runs are the committed benchmark's rows
    bench = pd.read_csv(BENCHMARK)
    bench = bench[(bench.controller == "lqi") & (bench.preset == preset) & (bench.plant == "nominal")]
    bench = bench[bench.seed == 0]
    result = TargetCheck(preset, CLASSICAL_VERSION, seeds=(0,))(_classical("lqi", preset))
    for row in result.runs:
        ref = bench[(bench.voltage - row["voltage"]).abs() < 1e-9]
        assert len(ref) == 1, row["voltage"]
        assert row["regime"] == ref["regime"].iloc[0]
        assert row["rms_error"] == pytest.approx(ref["rms_error"].iloc[0], rel=1e-6, abs=1e-9)
        if math.isfinite(ref["suppression"].iloc[0]):
            assert row["suppression"] == pytest.approx(ref["suppression"].iloc[0], rel=1e-6, abs=1e-9)
    limits = tracking_limits(preset, (0,))
    for regime in CHECK_VOLTAGES[preset]:
        mine = [r["rms_error"] for r in result.runs if r["regime"] == regime]
        assert limits[regime] == pytest.approx(2 * sum(mine) / len(mine) + 0.01)
        # the LQI meets its own tracking limit
        assert result.rms_error[regime] < result.rms_limit[regime]


def test_the_open_loop_misses_it_and_the_margin_says_by_how_much():
    result = TargetCheck("brake", CLASSICAL_VERSION)(_classical("open_loop", "brake"))
    assert not result.met and result.margin < -50  # suppression 0 in the cycle regimes
    assert all(result.suppression[r] < 0.1 for r in CYCLE_REGIMES)


def test_a_committed_learned_policy_that_meets_the_full_benchmark_meets_the_check():
    from drill_env.agents.registry import build_controller

    env = make_env("brake", EpisodeSettings(), 3)
    ppo = build_controller("ppo", env, "brake")
    env.close()
    result = TargetCheck("brake", 3)(ppo)
    assert result.met, result.to_dict()
    assert 0 <= result.margin <= 1 and result.stalled == 0
    assert result.wall_s < 30  # cheap: a few seconds at most on a loaded machine
