"""The benchmark: the documented CSV schema on a tiny grid, the report, resume, the process
pool and Ray backends agreeing with the sequential one, and the command line."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drill_env.agents.evaluation.benchmark import (
    COLUMNS,
    OPEN_LOOP_FLOOR,
    BenchmarkConfig,
    Job,
    Plant,
    load_results,
    run_benchmark,
)
from drill_env.agents.evaluation.episodes import EpisodeSettings
from drill_env.cli import app

ROOT = Path(__file__).resolve().parent.parent
TINY_EPISODE = EpisodeSettings(duration=6.0, window=3.0, warmup_time=4.0, warmup_jitter=1.0)
DOCUMENTED = [
    "controller",
    "preset",
    "plant",
    "voltage",
    "seed",
    "regime",
    "plant_open_loop_regime",
    "target_speed",
    "stalled",
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
    "x3_peak_abs",
    "beyond_identified_range",
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
    # the episode's peak covers the window; nothing here reaches the brake's 12.6 rad/s
    assert (df["x3_peak_abs"] >= np.maximum(df["x3_max"].abs(), df["x3_min"].abs()) - 1e-12).all()
    assert not df["beyond_identified_range"].any()
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


def test_resume_upgrades_a_csv_of_the_older_layout(tmp_path, sequential):
    # a folder from before the x3_peak_abs / beyond_identified_range columns: resumed, the
    # CSV is rewritten in the current layout (peak from the window) and the rest appended
    df = pd.read_csv(sequential / "benchmark.csv", keep_default_na=False)
    old = df.drop(columns=["x3_peak_abs", "beyond_identified_range"]).iloc[:4]
    old.to_csv(tmp_path / "benchmark.csv", index=False)
    (tmp_path / "benchmark_config.json").write_text(json.dumps(tiny().settings_record()))
    run_benchmark(tiny(), tmp_path, backend="sequential", report=False)
    again = pd.read_csv(tmp_path / "benchmark.csv", keep_default_na=False)
    assert list(again.columns) == DOCUMENTED and len(again) == 6
    again = load_results(tmp_path / "benchmark.csv")
    window_peak = np.maximum(again["x3_max"].abs(), again["x3_min"].abs())
    assert (again["x3_peak_abs"] >= window_peak - 1e-12).all()


def test_runs_beyond_the_identified_friction_range_are_flagged(tmp_path):
    # the lower-speed PI drives the brake far beyond 12.6 rad/s at 2 V (peak to peak ~136 rad/s)
    cfg = tiny(controllers=("open_loop", "pi_lower"), voltages={"brake": (2.0,)})
    run_benchmark(cfg, tmp_path, backend="sequential")
    df = load_results(tmp_path / "benchmark.csv").set_index("controller")
    assert df.loc["pi_lower", "beyond_identified_range"] and df.loc["pi_lower", "x3_peak_abs"] > 12.6
    assert not df.loc["open_loop", "beyond_identified_range"]
    assert df.loc["open_loop", "x3_peak_abs"] < 12.6
    summary = (tmp_path / "summary.md").read_text()
    assert "beyond 12.6 rad/s [runs]" in summary and "*severity*" in summary
    row = next(line for line in summary.splitlines() if line.startswith("| pi_lower |"))
    assert row.endswith("| **1** |")


def test_process_pool_matches_sequential(tmp_path, sequential):
    run_benchmark(tiny(), tmp_path, backend="process", workers=2, report=False)
    pd.testing.assert_frame_equal(
        metrics(load_results(tmp_path / "benchmark.csv")), metrics(load_results(sequential / "benchmark.csv"))
    )


def test_the_pool_computes_each_open_loop_cycle_once_for_its_workers():
    from drill_env.agents.evaluation import episodes
    from drill_env.agents.evaluation.benchmark.runs import open_loop_cycles_of
    from drill_env.agents.evaluation.plants import standard_family

    lag = next(p for p in standard_family() if p.name == "motor_lag")
    cfg = tiny(voltages={"brake": (1.0, 2.0)}, plants=(Plant(), lag))
    cycles = open_loop_cycles_of(cfg.jobs(), cfg)
    # one per operating point of the design plant, as the analysis gives it in a fresh process
    assert sorted(cycles) == [("brake", 1.0), ("brake", 2.0)]
    for (preset, v), cycle in cycles.items():
        assert cycle == episodes._analysed_open_loop_cycle(preset, v)
    assert cycles[("brake", 2.0)]["amplitude"] > 1.0  # the stick-slip cycle at 2 V
    # a worker takes them as they are: a planted value is what it then scores against
    planted = dict(cycles[("brake", 1.0)], amplitude=123.0)
    saved = dict(episodes._OPEN_LOOP_CYCLES)
    try:
        episodes.known_open_loop_cycles({("brake", 1.0): planted})
        assert episodes.open_loop_cycle("brake", 1.0)["amplitude"] == 123.0
    finally:
        episodes._OPEN_LOOP_CYCLES.clear()
        episodes._OPEN_LOOP_CYCLES.update(saved)


@pytest.mark.slow  # starts a local Ray instance (its own server, raylet and worker processes)
def test_ray_backend_on_a_local_instance(tmp_path, sequential):
    ray = pytest.importorskip("ray")
    from drill_env.agents.evaluation.plants import standard_family

    lag = next(p for p in standard_family() if p.name == "motor_lag")
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        cfg = tiny(controllers=("open_loop", "lqi"), voltages={"brake": (2.0,)}, plants=(Plant(), lag))
        run_benchmark(cfg, tmp_path / "ray", backend="ray", report=False)
    finally:
        ray.shutdown()
    got = load_results(tmp_path / "ray" / "benchmark.csv")
    ref = load_results(sequential / "benchmark.csv")
    ref = ref[(ref["voltage"] == 2.0) & ref["controller"].isin(["open_loop", "lqi"])]
    pd.testing.assert_frame_equal(metrics(got[got["plant"] == "nominal"]), metrics(ref))
    # a family plant runs the same on Ray as in this process
    run_benchmark(
        tiny(controllers=("open_loop", "lqi"), voltages={"brake": (2.0,)}, plants=(lag,)),
        tmp_path / "seq",
        backend="sequential",
        report=False,
    )
    pd.testing.assert_frame_equal(
        metrics(got[got["plant"] == "motor_lag"]), metrics(load_results(tmp_path / "seq" / "benchmark.csv"))
    )


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
    # a missing policy is bad input, refused before any run
    res = runner.invoke(
        app, [*args, "--controllers", "open_loop,ppo", "--agents-dir", str(tmp_path / "none")]
    )
    assert res.exit_code == 2 and "--agents-dir" in res.output
    # a file that is no policy at all is bad input too, refused before any run
    agents = tmp_path / "agents"
    (agents / "ppo").mkdir(parents=True)
    (agents / "ppo" / "policy.zip").write_bytes(b"PK\x03\x04 not a policy")
    res = runner.invoke(
        app, [*args, "--controllers", "open_loop,ppo", "--agents-dir", str(agents), "--trust-policies"]
    )
    assert res.exit_code == 2 and "policy" in res.output
    # one run more, one from before; the learned one fails: its weights are damaged (the file
    # says what it was trained on, so it passes the checks made before the runs)
    import zipfile

    with zipfile.ZipFile(
        Path(__file__).resolve().parents[1] / "results" / "agents" / "ppo" / "policy.zip"
    ) as zf:
        members = [(i, zf.read(i.filename)) for i in zf.infolist()]
    with zipfile.ZipFile(agents / "ppo" / "policy.zip", "w") as zf:
        for info, content in members:
            zf.writestr(info, b"not the weights" if info.filename == "policy.pth" else content)
    res = runner.invoke(
        app, [*args, "--controllers", "open_loop,ppo", "--agents-dir", str(agents), "--trust-policies"]
    )
    assert res.exit_code == 1
    assert "1 resumed from an earlier run" in res.output
    assert "1 of 2 runs failed" in res.output and "first: ppo brake" in res.output
    df = load_results(tmp_path / "benchmark.csv")
    assert len(df) == 2 and np.isfinite(df.loc[df["controller"] == "open_loop", "amplitude"]).all()


# -- plants that differ from the design model --------------------------------------------------------


def _plant_yaml(path, **changes):
    import yaml as _yaml

    data = load_params_dict("brake")
    effects = changes.pop("effects", None)
    data.update(changes)
    if effects:
        data["effects"] = effects
    path.write_text(_yaml.safe_dump(data))
    return path


def test_a_plant_runs_every_controller_with_its_own_open_loop_reference(tmp_path):
    # the paper's Sec. 4.1 lower-disk position friction on the braked rig
    plant = Plant.from_path(_plant_yaml(tmp_path / "a1.yaml", effects={"lower_position_amp_1": 0.12}))
    cfg = tiny(controllers=("open_loop", "lqi"), voltages={"brake": (0.4, 1.0)}, plants=(Plant(), plant))
    run_benchmark(cfg, tmp_path / "out", backend="sequential")
    df = load_results(tmp_path / "out" / "benchmark.csv")
    assert list(df.columns[:3]) == ["controller", "preset", "plant"] and len(df) == 2 * 2 * 2
    nom, a1 = df[df["plant"] == "nominal"], df[df["plant"] == "a1"]
    # nominal: the analysis' reference; the plant: its own open-loop run at the same voltage/seed
    ol = a1[a1["controller"] == "open_loop"].set_index("voltage")
    for _, r in a1.iterrows():
        assert r["open_loop_amplitude"] == pytest.approx(ol.loc[r["voltage"], "amplitude"])
    assert (ol["suppression"].abs() < 1e-9).all()
    assert (ol["amplitude"] != nom[nom["controller"] == "open_loop"].set_index("voltage")["amplitude"]).all()
    # at 0.4 V the nominal rig rests at an equilibrium, the plant's speed varies once per
    # revolution; suppression is defined exactly where the plant's open loop reaches the floor
    assert np.isnan(nom[nom["voltage"] == 0.4]["suppression"]).all()
    assert ol.loc[0.4, "amplitude"] > 0.01 and ol.loc[1.0, "amplitude"] > 1.0
    for _, r in a1.iterrows():
        assert np.isfinite(r["suppression"]) == (r["open_loop_amplitude"] >= OPEN_LOOP_FLOOR)
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "## brake, plant `nominal`" in summary and "## brake, plant `a1`" in summary
    assert "lower_position_amp_1" in summary
    assert (tmp_path / "out" / "suppression_brake_a1.png").stat().st_size > 10_000


def test_a_plant_of_the_other_family_is_stated_and_a_changed_plant_is_not_resumed(tmp_path):
    nb = load_params_dict("no_brake")
    path = tmp_path / "nb.yaml"
    import yaml as _yaml

    path.write_text(_yaml.safe_dump(nb))
    cfg = tiny(controllers=("open_loop",), voltages={"brake": (2.0,)}, plants=(Plant.from_path(path),))
    run_benchmark(cfg, tmp_path / "out", backend="sequential")
    assert "closer to the `no_brake` preset" in (tmp_path / "out" / "summary.md").read_text()
    nb["lower_static"] *= 1.1
    path.write_text(_yaml.safe_dump(nb))
    changed = tiny(controllers=("open_loop",), voltages={"brake": (2.0,)}, plants=(Plant.from_path(path),))
    with pytest.raises(ValueError, match="'nb' .* other parameters"):
        run_benchmark(changed, tmp_path / "out", backend="sequential")


def load_params_dict(preset: str) -> dict:
    import yaml as _yaml

    return _yaml.safe_load((ROOT / "configs" / "rig" / f"{preset}.yaml").read_text())


def test_cli_plant_errors_name_the_field(tmp_path):
    import yaml as _yaml

    bad = load_params_dict("brake")
    bad["lower_inertia"] = -1.0
    (tmp_path / "bad.yaml").write_text(_yaml.safe_dump(bad))
    eff = load_params_dict("brake")
    eff["effects"] = {"lower_position_amp_1": 1.5}
    (tmp_path / "eff.yaml").write_text(_yaml.safe_dump(eff))
    runner = CliRunner()
    for name, field in (
        ("bad.yaml", "lower_inertia"),
        ("eff.yaml", "lower_position_amp_1"),
        ("none.yaml", "not a file"),
    ):
        res = runner.invoke(
            app, ["benchmark", "--quick", "--plant", str(tmp_path / name), "--out", str(tmp_path / "o")]
        )
        assert res.exit_code == 2 and field in res.output, res.output
        assert "Traceback" not in res.output


def test_the_report_names_each_learned_policy_by_its_path_and_how_it_started(
    tmp_path, monkeypatch, sequential
):
    import shutil

    from drill_env.agents.evaluation.benchmark.backends import _policies_used, _policy_starts
    from drill_env.agents.evaluation.benchmark.report import summary_tables
    from drill_env.agents.registry import AGENTS_DIR_ENV

    monkeypatch.delenv(AGENTS_DIR_ENV, raising=False)
    cfg = tiny(
        controllers=("lqi", "ppo_lqi_clone", "ppo_robust"),
        presets=("brake", "no_brake"),
        voltages={"brake": (1.0,), "no_brake": (1.0,)},
    )
    # the committed policies: relative to the project root, whatever the working folder
    monkeypatch.chdir(tmp_path)
    assert _policies_used(cfg) == {
        "ppo_lqi_clone/brake": "results/agents/ppo_lqi_clone/policy.zip on DrillString-v1",
        "ppo_lqi_clone/no_brake": "results/agents/ppo_lqi_clone_no_brake/policy.zip on DrillStringNoBrake-v1",
        "ppo_robust/brake": "results/agents/ppo_robust/policy.zip on DrillString-v1",
        "ppo_robust/no_brake": "results/agents/ppo_robust_no_brake/policy.zip on DrillStringNoBrake-v1",
    }
    assert _policy_starts(cfg) == {
        "ppo_lqi_clone/brake": "clone of lqi",
        "ppo_lqi_clone/no_brake": "clone of lqi",
        "ppo_robust/brake": "residual on lqi_angle_ff",
        "ppo_robust/no_brake": "residual on lqi_angle_ff, distilled from ppo_lqi_clone",
    }
    # a folder of the user's: as given (absolute or relative), not relative to some parent of it
    deep = tmp_path / "a" / "b" / "agents"
    shutil.copytree(ROOT / "results" / "agents" / "ppo_lqi_clone", deep / "ppo_lqi_clone")
    cfg = tiny(controllers=("ppo_lqi_clone",), agents_dir=str(deep))
    assert _policies_used(cfg) == {
        "ppo_lqi_clone/brake": f"{deep}/ppo_lqi_clone/policy.zip on DrillString-v1"
    }
    cfg = tiny(controllers=("ppo_lqi_clone",), agents_dir="a/b/agents")
    assert _policies_used(cfg) == {
        "ppo_lqi_clone/brake": "a/b/agents/ppo_lqi_clone/policy.zip on DrillString-v1"
    }
    assert _policy_starts(cfg) == {"ppo_lqi_clone/brake": "clone of lqi"}
    text = summary_tables(
        load_results(sequential / "benchmark.csv"), _policies_used(cfg), None, _policy_starts(cfg)
    )
    assert (
        "Learned policies: ppo_lqi_clone: `a/b/agents/ppo_lqi_clone/policy.zip` on `DrillString-v1` "
        "(clone of lqi).\n" in text
    )


@pytest.mark.parametrize("controller", ["ppo", "sac"])
def test_the_committed_from_scratch_rows_meet_the_targets(controller):
    """The committed benchmark's from-scratch learned rows, on each rig: suppression >= 0.99 on
    average where a cycle is predicted and never below the open loop's (0), and an RMS speed
    error within twice the LQI's plus 0.01 rad/s in every regime."""
    out = ROOT / "results" / "benchmark"
    config = json.loads((out / "benchmark_config.json").read_text())
    df = load_results(out / "benchmark.csv")
    df = df[df["plant"] == "nominal"]
    for preset in ("brake", "no_brake"):
        assert config["policy_starts"][f"{controller}/{preset}"] == "from scratch"
        rows = df[(df["preset"] == preset) & (df["controller"] == controller)]
        lqi = df[(df["preset"] == preset) & (df["controller"] == "lqi")]
        assert len(rows) == len(lqi) > 0 and not rows["stalled"].any()
        for regime, runs in rows.groupby("regime"):
            limit = 2.0 * lqi[lqi["regime"] == regime]["rms_error"].mean() + 0.01
            assert runs["rms_error"].mean() <= limit, (preset, regime)
            if regime != "equilibrium":
                assert runs["suppression"].mean() >= 0.99, (preset, regime)
                assert runs["suppression"].min() >= 0.0, (preset, regime)
