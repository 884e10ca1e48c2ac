"""``benchmarks/bench_training.py --time-to-policy``: the time to a suppressing policy and the
learning curves, run as a user runs it, and the committed ``results/training`` checked
against its own rows."""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parent.parent
TRAINING = ROOT / "results" / "training"


def _meets(p: dict) -> bool:
    """The target, recomputed from a check's own numbers: suppression >= 0.99 in both cycle
    regimes, RMS error within its limit in every regime, no run stalled."""
    return (
        all(p["suppression"][r] >= 0.99 for r in ("limit_cycle", "stick_slip"))
        and all(p["rms_error"][r] <= p["rms_limit"][r] for r in p["rms_limit"])
        and p["stalled"] == 0
    )


def _suppresses(p: dict) -> bool:
    """The former target (suppression alone), of the studies measured before tracking counted."""
    return min(p["suppression"]["limit_cycle"], p["suppression"]["stick_slip"]) >= 0.99


def bench_training(*args: str, timeout: float) -> subprocess.CompletedProcess:
    """``python benchmarks/bench_training.py ARGS`` from the checkout, as a user runs it."""
    return subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_training.py"), *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.slow  # trains PPO to the quick check's end (about 20 s of CPU)
def test_time_to_policy_writes_the_json_curves_and_figures(tmp_path):
    out = tmp_path / "training"
    res = bench_training(
        "--quick",
        "--no-throughput",
        "--time-to-policy",
        "--from-scratch",
        "--algos",
        "ppo",
        "--presets",
        "no_brake",
        "--seeds",
        "3",
        "--clock",
        "cpu",
        "--out",
        str(out),
        timeout=600,
    )
    assert res.returncode in (0, 1) and "Traceback" not in res.stderr, res.stderr[-3000:]
    result = json.loads((out / "time_to_policy.json").read_text())
    (run,) = result["runs"]
    assert (run["algo"], run["preset"], run["seed"]) == ("ppo", "no_brake", 3)
    assert run["config"] == "configs/agents/ppo_no_brake.yaml"
    curve = run["curve"]
    assert curve and all(p["steps"] > 0 and p["wall_s"] > 0 for p in curve)
    steps = [p["steps"] for p in curve]
    assert steps == sorted(steps)
    for p in curve:  # the target check ran: both cycle regimes scored, tracking in every regime
        assert set(p["suppression"]) == {"limit_cycle", "stick_slip"}
        assert set(p["rms_error"]) == set(p["rms_limit"]) == {"equilibrium", "limit_cycle", "stick_slip"}
        assert p["met"] == _meets(p) and p["cpu_s"] > 0
    first = next((p for p in curve if _meets(p)), None)
    assert run["time_to_target_s"] == (None if first is None else first["wall_s"])
    assert run["cpu_to_target_s"] == (None if first is None else first["cpu_s"])
    (s,) = result["summary"]
    assert s["reached"] == (first is not None) and s["seeds"] == [3]
    # --clock cpu: the 5-minute target counted in the training's CPU seconds
    assert result["clock"] == s["clock"] == run["clock"] == "cpu"
    assert s["reached_within_target"] == (first is not None and first["cpu_s"] <= 300.0)
    assert len(result["baseline"]) == 2 and all(b["wall_s"] > 0 for b in result["baseline"])
    rows = pd.read_csv(out / "curves.csv")
    assert len(rows) == len(curve)
    assert rows["suppression_stick_slip"].tolist() == pytest.approx(
        [p["suppression"]["stick_slip"] for p in curve]
    )
    assert (out / "learning_curves_no_brake.png").stat().st_size > 10_000
    assert "| ppo | no_brake | `configs/agents/ppo_no_brake.yaml` |" in (out / "summary.md").read_text()
    # bad input: exit 2 with the field named
    for seeds in ("1,x", "9-3"):
        bad = bench_training("--seeds", seeds, timeout=60)
        assert bad.returncode == 2 and "--seeds" in bad.stderr and "Traceback" not in bad.stderr


@pytest.mark.skipif(not (TRAINING / "time_to_policy.json").is_file(), reason="results/training not generated")
def test_committed_time_to_policy_follows_from_its_curves():
    """The committed summary is what its own checks give: the first check at or above 0.99 in
    both cycle regimes, the median over seeds, and the rows of curves.csv."""
    result = json.loads((TRAINING / "time_to_policy.json").read_text())
    rows = pd.read_csv(TRAINING / "curves.csv")
    assert result["from_scratch"] is True
    for s in result["summary"]:
        runs = [r for r in result["runs"] if (r["algo"], r["preset"]) == (s["algo"], s["preset"])]
        assert len(runs) >= 3 and 0 not in s["seeds"]  # seeds other than the tuning seed 0
        times = []
        for r in runs:
            # the target of the bench that wrote it: with tracking since the runs carry its limits
            reached = _meets if "baseline" in result else _suppresses
            first = next((p for p in r["curve"] if reached(p)), None)
            times.append(float("inf") if first is None else first["wall_s"])
            mine = rows[(rows.algo == r["algo"]) & (rows.preset == r["preset"]) & (rows.seed == r["seed"])]
            assert len(mine) == len(r["curve"])
        median = statistics.median(times)
        assert (s["median_time_to_target_s"] is None) == (median == float("inf"))
        if s["median_time_to_target_s"] is not None:
            assert s["median_time_to_target_s"] == pytest.approx(median)
        assert s["met"] == (median < 300.0)


TIME_TO_TARGET = ROOT / "results" / "time_to_target"


@pytest.mark.skipif(
    not (TIME_TO_TARGET / "time_to_policy.json").is_file(), reason="results/time_to_target not generated"
)
def test_committed_time_to_target_follows_from_its_checks():
    """The committed study: seeds not used in tuning (0-9), the counts, medians and worst times
    what its own checks give by the target recomputed from their numbers."""
    result = json.loads((TIME_TO_TARGET / "time_to_policy.json").read_text())
    assert len(result["baseline"]) >= 1
    clock = result.get("clock", "wall")  # the training time the 5-minute target counts
    for s in result["summary"]:
        runs = [r for r in result["runs"] if (r["algo"], r["preset"]) == (s["algo"], s["preset"])]
        assert len(runs) == len(s["seeds"]) and not set(s["seeds"]) & set(range(10))
        times, counted = [], []
        for r in runs:
            first = next((p for p in r["curve"] if _meets(p)), None)
            assert all(p["met"] == _meets(p) for p in r["curve"])
            times.append(None if first is None else first["wall_s"])
            counted.append(None if first is None else first[f"{clock}_s"])
            assert r["time_to_target_s"] == times[-1]
        assert s["reached"] == sum(t is not None for t in times)
        median = statistics.median(float("inf") if t is None else t for t in times)
        assert (s["median_time_to_target_s"] is None) == (median == float("inf"))
        if s["median_time_to_target_s"] is not None:
            assert s["median_time_to_target_s"] == pytest.approx(median)
        reached = [t for t in times if t is not None]
        if len(reached) == len(times):
            assert s["worst_time_to_target_s"] == pytest.approx(max(reached))
        within = sum(t is not None and t <= 300.0 for t in counted)
        assert s["reached_within_target"] == within
        assert s["met"] == (within >= 0.9 * len(times))


@pytest.mark.slow
def test_contrib_throughput_is_timed_against_the_same_sac_baseline():
    res = bench_training("--quick", "--algos", "sac", "--contrib", timeout=900)
    assert res.returncode in (0, 1) and "Traceback" not in res.stderr, res.stderr[-3000:]
    result = json.loads(res.stdout.strip().splitlines()[-1])["throughput"]
    assert set(result) == {"sac", "tqc", "crossq"}  # --algos sac: no PPO case
    sac = result["sac"]
    for algo in ("tqc", "crossq"):
        r = result[algo]
        assert r["config"] == f"experiments/{algo}.yaml" and r["baseline"] == sac["baseline"]
        assert r["steps_per_s"] > 0
        assert r["ratio"] == pytest.approx(r["steps_per_s"] / sac["baseline"])
        assert r["vs_shipped_sac"] == pytest.approx(r["steps_per_s"] / sac["shipped"])
    bad = bench_training("--algos", "ppo", "--contrib", timeout=60)
    assert bad.returncode == 2 and "--contrib" in bad.stderr and "Traceback" not in bad.stderr


def _bench_training_module():
    import importlib

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        return importlib.import_module("bench_training")
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


@pytest.mark.skipif(not (TRAINING / "curves.csv").is_file(), reason="results/training not generated")
@pytest.mark.parametrize("seeds", ["all", "one"])
def test_the_learning_curves_are_legible_at_the_docs_width(tmp_path, monkeypatch, seeds):
    """The learning curves drawn from the committed curves.csv (every seed, and the first seed
    alone) pass the size rule of the docs, one legend entry per algorithm."""
    from matplotlib.figure import Figure

    from drill_env._figures import MAX_WIDTH_IN, legibility_problems

    drawn = []
    save = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: (drawn.append(self), save(self, *a, **k)))
    df = pd.read_csv(TRAINING / "curves.csv")
    if seeds == "one":
        df = df[df["seed"] == df["seed"].min()]
    runs = json.loads((TRAINING / "time_to_policy.json").read_text())["runs"]
    paths = _bench_training_module().draw_curves(df, runs, tmp_path)
    assert [p.name for p in paths] == ["learning_curves_brake.png", "learning_curves_no_brake.png"]
    assert len(drawn) == 2
    for fig in drawn:
        assert fig.get_figwidth() <= MAX_WIDTH_IN
        assert legibility_problems(fig) == [], fig.get_suptitle()
        assert len(fig.legends[0].get_texts()) == df["algo"].nunique()


@pytest.mark.skipif(not (TRAINING / "curves.csv").is_file(), reason="results/training not generated")
def test_figures_only_draws_the_learning_curves_and_nothing_else(tmp_path):
    """`bench_training.py --figures-only --out DIR` draws learning_curves_*.png from DIR's
    curves.csv and leaves every other file as it was; a folder without curves.csv is refused
    with exit code 2."""
    import shutil

    from PIL import Image

    out = tmp_path / "training"
    out.mkdir()
    for name in ("curves.csv", "time_to_policy.json"):
        shutil.copy(TRAINING / name, out / name)
    res = bench_training("--figures-only", "--out", str(out), timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    assert f"from {out / 'curves.csv'}" in res.stdout
    assert sorted(p.name for p in out.iterdir()) == [
        "curves.csv",
        "learning_curves_brake.png",
        "learning_curves_no_brake.png",
        "time_to_policy.json",
    ]
    for name in ("curves.csv", "time_to_policy.json"):
        assert (out / name).read_bytes() == (TRAINING / name).read_bytes()
    for preset in ("brake", "no_brake"):
        with Image.open(out / f"learning_curves_{preset}.png") as im:
            assert im.width == 8 * 110
    (out / "curves.csv").unlink()
    bad = bench_training("--figures-only", "--out", str(out), timeout=60)
    assert bad.returncode == 2 and "--figures-only: --out must name a folder holding curves.csv" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_the_summary_line_says_when_a_missed_seed_leaves_no_median_or_worst_time():
    """A seed that missed counts as infinitely slow: the line names the missing median or worst
    time instead of printing "missed s wall"; with every seed in, both are the seconds."""
    bench = _bench_training_module()
    summarise, summary_line = bench.summarise, bench.summary_line

    def run(seed, t):
        return {
            "algo": "ppo",
            "preset": "brake",
            "seed": seed,
            "config": "configs/agents/ppo.yaml",
            "time_to_target_s": t,
            "cpu_to_target_s": None if t is None else t / 2,
            "steps_to_target": None if t is None else 1000,
        }

    one_missed = summary_line(summarise([run(1, 10.0), run(2, None), run(3, 30.0)])[0])
    assert "median 30 s wall / 15 s CPU" in one_missed and "no worst time (a seed missed)" in one_missed
    assert "missed s" not in one_missed and "seeds [2]" in one_missed
    most_missed = summary_line(summarise([run(1, 10.0), run(2, None), run(3, None)])[0])
    assert "no median (half or more of the seeds missed)" in most_missed
    all_in = summary_line(summarise([run(1, 10.0), run(2, 20.0), run(3, 40.0)])[0])
    assert "median 20 s wall / 10 s CPU, worst 40 s wall / 20 s CPU" in all_in
