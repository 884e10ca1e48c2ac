"""The docs' leaderboard, rendered from ranking.json by docs/_ext/results_pages.py: the
ranks, intervals and differences to the leader of rankings with a known answer."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pandas as pd

from drill_env.agents.evaluation.benchmark.ranking import ranking_record
from drill_env.agents.evaluation.benchmark.statistics import paired_bootstrap

ROOT = Path(__file__).resolve().parent.parent


def _pages():
    spec = importlib.util.spec_from_file_location(
        "results_pages", ROOT / "docs" / "_ext" / "results_pages.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _record():
    rng = np.random.default_rng(4)
    unit = rng.normal(0, 0.004, 50)
    scores = {"best": 0.999 + unit, "close": 0.998 + unit + rng.normal(0, 1e-4, 50), "tie": 0.998 + unit}
    scores["tie"] = scores["close"] + rng.normal(0, 1e-4, 50)  # not resolved from "close"
    scores["weak"] = 0.5 + rng.normal(0, 0.1, 50)
    rows = pd.DataFrame(
        [
            {"controller": c, "voltage": i // 5, "seed": i % 5, "score": float(v)}
            for c, s in scores.items()
            for i, v in enumerate(s)
        ]
    )
    st = paired_bootstrap(
        rows.rename(columns={"score": "suppression"}), score="suppression", n_resamples=2000
    )
    return {"rankings": [ranking_record("brake", "brake: test", st)]}, st


def test_leaderboard_tables_show_ranks_intervals_and_the_resolved_leading_pairs():
    pages = _pages()
    record, st = _record()
    text = pages.leaderboard_tables(json.loads(json.dumps(record)), "benchmark")
    rows = [line for line in text.splitlines() if line.startswith("| ") and "controller" not in line]
    assert [r.split("|")[2].strip() for r in rows] == list(st.scores["controller"])
    assert rows[0].split("|")[2].strip() == "best" and rows[0].split("|")[5].strip() == "1"
    first = st.scores.iloc[0]
    assert f"[{first['low']:.4f}, {first['high']:.4f}]" in rows[0]
    ranks = {r.split("|")[2].strip(): r.split("|")[5].strip() for r in rows}
    assert ranks["close"] == ranks["tie"] == "2-3" and ranks["weak"] == "4"
    # the leading three (0.99 or more): best resolved from both others, close and tie not
    assert "Among the controllers at 0.99 or more (3), 2 of 3 pairs are resolved" in text
    assert "best > close" in text and "best > tie" in text


def test_leaderboard_ranks_lists_every_controller_in_every_ranking():
    pages = _pages()
    record, _ = _record()
    text = pages.leaderboard_ranks({"benchmark": record, "plant_family": record})
    assert text.splitlines()[0] == "| controller | `benchmark` brake | `plant_family` brake |"
    assert "| weak | 4 (4) | 4 (4) |" in text


def test_a_scenario_suite_shows_its_suite_ranking_headroom_ranks_and_the_nominal_leaders(tmp_path):
    from drill_env.agents.evaluation.scenario_report import nominal_leaders, suite_rankings

    rng = np.random.default_rng(2)
    rows = []
    for s in ("start_up", "effort"):
        for p in ("brake", "no_brake"):
            for k in range(3):
                base = rng.uniform(0.6, 0.9)
                for c, off in (("open_loop", None), ("good", 0.05), ("fair", 0.0), ("same", 0.0)):
                    v = 0.0 if off is None else base + off + rng.normal(0, 1e-3)
                    rows.append({"controller": c, "scenario": s, "preset": p, "seed": k, "score": v})
    runs = pd.DataFrame(rows)
    rankings = suite_rankings(runs)
    nominal = {"source": "b/ranking.json", "key": "all", "score": "suppression",
               "scores": {"good": 0.999, "fair": 0.995, "same": 0.994, "open_loop": 0.0}}  # fmt: skip
    lead = nominal_leaders(rankings[0][2], nominal)
    record = json.loads(json.dumps({
        "rankings": [ranking_record(k, t, st) for k, t, st in rankings],
        "headroom": [{"scenario": "start_up", "best_controller": "good", "best_score": 0.9, "low": 0.85,
                      "high": 0.95, "room": 0.1}],
        "nominal_leaders": lead,
    }))  # fmt: skip
    pages = _pages()
    # the leaderboard's tables and ranks: the suite score's ranking only
    text = pages.leaderboard_tables(record, "scenarios")
    assert text.count("### `scenarios`") == 1 and "scenario suite: every scenario, preset and seed" in text
    ranks = pages.leaderboard_ranks({"scenarios": record})
    assert ranks.splitlines()[0] == "| controller | `scenarios` suite |"
    suite = pages.suite_tables(record, "scenarios")
    assert "| start_up | good | 0.900 | [0.850, 0.950] | 0.100 |" in suite
    # good beats fair and same by 0.05 on every unit; fair and same differ by noise
    assert lead["n_pairs"] == 3 and lead["resolved"] == 2
    assert "Of their 3 pairs the suite's paired intervals resolve **2**" in suite
    import re

    for other in ("fair", "same"):
        (by,) = re.findall(rf"good > {other} by (-?[0-9]+\.[0-9]+)", suite)
        assert abs(float(by) - 0.05) < 0.003
    row = next(line for line in suite.splitlines() if line.startswith("| good |"))
    assert row == "| good | 1 (1) | 1 (1) | 1 (1) |"
