"""The benchmark: the documented CSV schema on a tiny grid, the report, resume, the process
pool and Ray backends agreeing with the sequential one, and the command line."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from agents.benchmark import COLUMNS, BenchmarkConfig, Job, load_results, run_benchmark
from agents.evaluation import EpisodeSettings
from drill_env.cli import app

TINY_EPISODE = EpisodeSettings(duration=6.0, window=3.0, warmup_time=4.0, warmup_jitter=1.0)
DOCUMENTED = [
    "controller",
    "preset",
    "voltage",
    "seed",
    "regime",
    "target_speed",
    "amplitude",
    "open_loop_amplitude",
    "suppression",
    "stick_fraction",
    "severity",
    "rms_error",
    "mean_speed",
    "x3_min",
    "x3_max",
    "period",
    "u_mean_abs",
    "u_peak_abs",
    "u_limit_fraction",
    "episode_return",
    "sim_status",
    "wall_time",
    "error",
]


def tiny(**kwargs) -> BenchmarkConfig:
    args = dict(
        presets=("brake",),
        controllers=("open_loop", "pi_upper", "lqi"),
        voltages={"brake": (0.4, 2.0)},
        seeds=(0,),
        episode=TINY_EPISODE,
    )
    args.update(kwargs)
    return BenchmarkConfig(**args)


def metrics(df: pd.DataFrame) -> pd.DataFrame:
    return (
        df.drop(columns=["wall_time"]).sort_values(["controller", "voltage", "seed"]).reset_index(drop=True)
    )


@pytest.fixture(scope="module")
def sequential(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq")
    run_benchmark(tiny(), out, backend="sequential")
    return out


def test_tiny_grid_writes_the_documented_schema(sequential):
    assert list(COLUMNS) == DOCUMENTED
    df = pd.read_csv(sequential / "benchmark.csv", keep_default_na=False)
    assert list(df.columns) == DOCUMENTED
    assert len(df) == 3 * 2  # controllers x voltages x seeds
    df = load_results(sequential / "benchmark.csv")
    assert (df["error"] == "").all() and (df["sim_status"] == 0).all()
    assert set(df["regime"]) == {"equilibrium", "stick_slip"}
    eq = df[df["voltage"] == 0.4]
    assert (eq["open_loop_amplitude"] == 0).all() and eq["suppression"].isna().all()
    ss = df[df["voltage"] == 2.0]
    assert (ss["open_loop_amplitude"] > 5).all()
    np.testing.assert_allclose(ss["suppression"], 1 - ss["amplitude"] / ss["open_loop_amplitude"])
    np.testing.assert_allclose(df["amplitude"], df["x3_max"] - df["x3_min"])
    for col in ("stick_fraction", "u_limit_fraction"):
        assert df[col].between(0, 1).all()
    summary = (sequential / "summary.md").read_text()
    assert "### stable equilibrium" in summary and "### stick-slip" in summary
    for name in ("open_loop", "pi_upper", "lqi"):
        assert f"| {name} |" in summary
    for fig in ("bifurcation_brake.png", "suppression_brake.png"):
        assert (sequential / fig).stat().st_size > 10_000
    cfg = json.loads((sequential / "benchmark_config.json").read_text())
    assert cfg["episode"]["duration"] == 6.0 and cfg["seeds"] == [0]


def test_resume_runs_only_what_is_missing(tmp_path, sequential):
    df = pd.read_csv(sequential / "benchmark.csv", keep_default_na=False)
    # an interrupted benchmark: two finished rows and one that failed
    part = df.iloc[:3].copy()
    part.loc[part.index[2], "error"] = "RuntimeError: interrupted"
    part.to_csv(tmp_path / "benchmark.csv", index=False)
    (tmp_path / "benchmark_config.json").write_text(json.dumps(tiny().settings_record()))
    calls = []
    run_benchmark(
        tiny(), tmp_path, backend="sequential", progress=lambda d, t, r: calls.append((d, t, dict(r)))
    )
    assert calls[0][:2] == (2, 6)  # two done rows skipped, the failed one is run again
    assert [c[0] for c in calls[1:]] == [3, 4, 5, 6]
    again = load_results(tmp_path / "benchmark.csv")
    assert len(again) == 6 and (again["error"] == "").all()
    pd.testing.assert_frame_equal(metrics(again), metrics(load_results(sequential / "benchmark.csv")))
    # nothing left to do
    calls.clear()
    run_benchmark(
        tiny(), tmp_path, backend="sequential", progress=lambda d, t, r: calls.append(d), report=False
    )
    assert calls == [6]
    # other episode settings are refused; --fresh starts over
    other = tiny(episode=EpisodeSettings(duration=8.0, window=3.0, warmup_time=4.0, warmup_jitter=1.0))
    with pytest.raises(ValueError, match="episode settings"):
        run_benchmark(other, tmp_path, backend="sequential")


def test_process_pool_matches_sequential(tmp_path, sequential):
    run_benchmark(tiny(), tmp_path, backend="process", workers=2, report=False)
    pd.testing.assert_frame_equal(
        metrics(load_results(tmp_path / "benchmark.csv")), metrics(load_results(sequential / "benchmark.csv"))
    )


def test_ray_backend_on_a_local_instance(tmp_path, sequential):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        cfg = tiny(controllers=("open_loop", "lqi"), voltages={"brake": (2.0,)})
        run_benchmark(cfg, tmp_path, backend="ray", report=False)
    finally:
        ray.shutdown()
    ref = load_results(sequential / "benchmark.csv")
    ref = ref[(ref["voltage"] == 2.0) & ref["controller"].isin(["open_loop", "lqi"])]
    pd.testing.assert_frame_equal(metrics(load_results(tmp_path / "benchmark.csv")), metrics(ref))


def test_failing_run_is_recorded_not_fatal(tmp_path):
    cfg = tiny(controllers=("ppo",), voltages={"brake": (1.0,)}, agents_dir=str(tmp_path / "nowhere"))
    run_benchmark(cfg, tmp_path, backend="sequential")
    df = load_results(tmp_path / "benchmark.csv")
    assert len(df) == 1 and "no trained ppo policy" in df["error"].iloc[0]
    assert math.isnan(df["amplitude"].iloc[0])
    assert "runs that failed" in (tmp_path / "summary.md").read_text()


def test_config_validation_names_the_field():
    with pytest.raises(ValueError, match="voltages"):
        tiny(voltages={"brake": (0.05,)})
    with pytest.raises(ValueError, match="controllers"):
        tiny(controllers=("pid",))
    with pytest.raises(ValueError, match="presets"):
        tiny(presets=("ice",))
    with pytest.raises(ValueError, match="seeds"):
        tiny(seeds=(-1,))
    with pytest.raises(ValueError, match="backend"):
        run_benchmark(tiny(), "unused", backend="cluster")
    jobs = tiny().jobs()
    assert len(jobs) == 6 and jobs[0] == Job("open_loop", "brake", 0.4, 0)


def test_cli_benchmark(tmp_path):
    runner = CliRunner()
    args = [
        "benchmark",
        "--out",
        str(tmp_path),
        "--preset",
        "no_brake",
        "--controllers",
        "open_loop,torque_feedback",
        "--voltages",
        "1.0",
        "--seeds",
        "1",
        "--duration",
        "6",
        "--window",
        "3",
        "--warmup",
        "4",
        "--backend",
        "sequential",
    ]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    df = load_results(tmp_path / "benchmark.csv")
    assert list(df["controller"]) == ["open_loop", "torque_feedback"] and set(df["preset"]) == {"no_brake"}
    assert "## no_brake" in res.output
    bad = runner.invoke(app, ["benchmark", "--out", str(tmp_path), "--preset", "ice"])
    assert bad.exit_code == 2 and "--preset" in bad.output
    bad = runner.invoke(app, ["benchmark", "--out", str(tmp_path), "--voltages", "9"])
    assert bad.exit_code == 2 and "voltages" in bad.output


def test_cli_benchmark_says_what_was_resumed_and_fails_when_a_run_failed(tmp_path):
    runner = CliRunner()
    args = ["benchmark", "--out", str(tmp_path), "--preset", "brake", "--voltages", "1.0", "--seeds", "1"]
    args += ["--duration", "4", "--window", "2", "--warmup", "2", "--backend", "sequential"]
    res = runner.invoke(app, [*args, "--controllers", "open_loop"])
    assert res.exit_code == 0, res.output
    assert "resumed" not in res.output
    # one run more, one from before; the learned one fails: no policy where it is looked for
    res = runner.invoke(
        app, [*args, "--controllers", "open_loop,ppo", "--agents-dir", str(tmp_path / "none")]
    )
    assert res.exit_code == 1
    assert "1 resumed from an earlier run" in res.output
    assert "1 of 2 runs failed" in res.output and "no trained ppo policy" in res.output
    df = load_results(tmp_path / "benchmark.csv")
    assert len(df) == 2 and np.isfinite(df.loc[df["controller"] == "open_loop", "amplitude"]).all()
