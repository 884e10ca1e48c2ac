"""``--max-wall-time`` holds for every algorithm: training stops inside a rollout while the last
evaluation still fits, and the summary records the budget, the wall time and the overrun."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drill_env.agents.learning.rl import TrainConfig, load_config, train
from drill_env.cli import app

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs" / "agents"
# [s] allowed beyond the budget: the clock is read at every step of the rigs
TOLERANCE_S = 3.0


def _shipped_with_a_long_run(name: str) -> TrainConfig:
    """A shipped recipe (its rigs, rollouts and updates) set to run far longer than the budget,
    its evaluation shortened to one episode per regime."""
    cfg = load_config(CONFIGS / f"{name}.yaml").to_dict()
    cfg.update(total_timesteps=50_000_000)
    cfg["evaluation"] = {"every_steps": 30_000, "episodes_per_regime": 1, "seed": 7}
    return TrainConfig(**cfg)


# budgets above what building the rigs and the first evaluations cost on a loaded machine
# (15-20 s at a load of 20 on 2 cores): the budget is what must hold, not the start
@pytest.mark.slow
@pytest.mark.parametrize(("name", "budget"), [("ppo", 40.0), ("sac_no_brake", 40.0)])
def test_training_stops_within_seconds_of_the_budget(tmp_path, name, budget):
    cfg = _shipped_with_a_long_run(name)
    t0 = time.perf_counter()
    summary = train(cfg, 5, tmp_path / "out", tmp_path / "run", progress_bar=False, max_wall_time_s=budget)
    elapsed = time.perf_counter() - t0
    assert summary["stopped_by"] == "max_wall_time"
    assert elapsed <= budget + TOLERANCE_S, elapsed
    assert elapsed - 0.1 <= summary["wall_time_s"] <= elapsed + 0.1
    on_disk = json.loads((tmp_path / "out" / "training_summary.json").read_text())
    assert on_disk["max_wall_time_s"] == budget
    assert on_disk["overrun_s"] == pytest.approx(on_disk["wall_time_s"] - budget, abs=0.11)
    assert on_disk["overrun_s"] <= TOLERANCE_S
    assert 0 < on_disk["env_steps"] < cfg.total_timesteps


@pytest.mark.slow
def test_the_command_holds_its_budget(tmp_path):
    cfg = _shipped_with_a_long_run("ppo_no_brake")
    config = tmp_path / "long.yaml"
    import yaml

    config.write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
    budget = 40.0
    t0 = time.perf_counter()
    res = CliRunner().invoke(
        app,
        [
            "train",
            "--algo",
            "ppo",
            "--config",
            str(config),
            "--out",
            str(tmp_path / "ppo_no_brake"),
            "--max-wall-time",
            str(budget),
            "--no-progress",
        ],
    )
    elapsed = time.perf_counter() - t0
    assert res.exit_code == 0, res.output
    assert "stopped at the wall-time budget" in res.output
    assert elapsed <= budget + TOLERANCE_S, elapsed
    summary = json.loads((tmp_path / "ppo_no_brake" / "training_summary.json").read_text())
    assert summary["overrun_s"] <= TOLERANCE_S and summary["stopped_by"] == "max_wall_time"


@pytest.mark.slow
def test_early_stopping_keeps_the_best_policy_by_the_target_check(tmp_path):
    # the shipped PPO recipe on the unbraked rig, checked every 16 384 steps and stopped at the
    # first check meeting the target (or at 90 s): the kept policy is the one of the best margin
    import numpy as np
    import pandas as pd

    from drill_env.agents.evaluation.target_check import TargetCheck
    from drill_env.agents.learning.rl import load_policy

    cfg = load_config(CONFIGS / "ppo_no_brake.yaml").to_dict()
    cfg["evaluation"] = {
        "every_steps": 16_384,
        "episodes_per_regime": 1,
        "seed": 7,
        "target_check": True,
        "stop_at_target": True,
    }
    cfg = TrainConfig(**cfg)
    summary = train(cfg, 2, tmp_path / "out", tmp_path / "run", progress_bar=False, max_wall_time_s=90.0)
    curve = pd.read_csv(tmp_path / "out" / "eval.csv")
    assert {"target_met", "target_margin", "rms_error_equilibrium", "suppression_stick_slip"} <= set(curve)
    assert summary["kept_by"] == "target_check"
    best = summary["best_target_check"]
    assert best["margin"] == pytest.approx(curve["target_margin"].max())
    assert summary["best_at_timesteps"] == int(curve["timesteps"][curve["target_margin"].idxmax()])
    if summary["stopped_by"] == "target":
        assert bool(curve["target_met"].iloc[-1]) and best["met"]
    else:
        # stopped by the budget: no check before the last one met the target
        assert summary["stopped_by"] == "max_wall_time" and not curve["target_met"].iloc[:-1].any()
    # the kept file is that policy: the check run again on it gives the same margin
    policy = load_policy(tmp_path / "out" / "policy.zip", trusted=True)
    again = TargetCheck("no_brake", 3)(policy)
    assert again.margin == pytest.approx(best["margin"], abs=1e-4)
    assert np.isfinite(again.margin)
