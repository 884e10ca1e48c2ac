"""Hardening: output folders never mixed or rewritten by a subset, files never written through
links, bounds on every count and size (refused before any work), Ctrl-C that stops, synth
writing only what the loader reads, full time precision at a late t0, untrusted policies
refused without a terminal. Each reproducer of the issue is a test here."""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

import drill_env
from drill_env.cli import app

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]


def _ctrl_c_after(proc: subprocess.Popen, seconds: float) -> tuple[str, float]:
    """Send Ctrl-C to a command still running after ``seconds``; its stderr and the seconds it
    took to end after the signal."""
    time.sleep(seconds)
    assert proc.poll() is None, proc.communicate()
    t = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    return err, time.perf_counter() - t


def _one_error_line(res, code: int = 2) -> str:
    assert res.exit_code == code, (res.exit_code, res.output)
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    errors = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1, res.output
    return errors[0]


def _digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != ".drill-env.lock"
    }


# -- 1. output folders never mixed or rewritten --------------------------------------------------------

SYNTH = ["synth", "--duration", "10", "--rate", "100", "--random-runs", "0"]


def test_synth_refuses_a_folder_holding_a_dataset_and_fresh_replaces_it_whole(tmp_path):
    d = tmp_path / "d"
    res = runner.invoke(
        app,
        [
            *SYNTH,
            "--effect",
            "none",
            "--voltages",
            "1,2",
            "--out",
            str(d),
            "--answer",
            str(tmp_path / "a1.json"),
        ],
    )
    assert res.exit_code == 0, res.output
    before = _digest(d)
    assert sorted(before) == ["dataset.json", "run01.csv", "run02.csv"]
    # the reproducer: a second dataset into the same folder
    again = [*SYNTH, "--effect", "position_friction_lower", "--magnitude", "0.3", "--voltages", "0.5"]
    again += ["--out", str(d), "--answer", str(tmp_path / "a2.json")]
    line = _one_error_line(runner.invoke(app, again))
    assert "--out" in line and "not empty" in line and "--fresh" in line
    assert _digest(d) == before and not (tmp_path / "a2.json").exists()
    # --fresh: the new dataset alone
    res = runner.invoke(app, [*again, "--fresh"])
    assert res.exit_code == 0, res.output
    assert sorted(_digest(d)) == ["dataset.json", "run01.csv"]
    from drill_env.recordings.dataset import load_dataset

    ds = load_dataset(d)
    assert [r.name for r in ds.runs] == ["run01"] and np.allclose(ds.runs[0].u, 0.5)
    # --fresh never removes what synth did not write
    (d / "notes.txt").write_text("mine\n")
    line = _one_error_line(runner.invoke(app, [*again, "--fresh"]))
    assert "notes.txt" in line and (d / "notes.txt").read_text() == "mine\n"


def test_synth_writes_what_the_loader_reads_at_the_shortest_duration(tmp_path):
    # the reproducer: "synth --duration 10" was refused by the loader ("lasts 10 s; at least 10 s")
    from drill_env.recordings.dataset import MIN_DURATION_S, load_dataset

    for rate in ("100", "333", "1000"):
        d = tmp_path / f"d{rate}"
        args = ["synth", "--effect", "none", "--duration", str(MIN_DURATION_S), "--rate", rate]
        args += [
            "--voltages",
            "1",
            "--random-runs",
            "0",
            "--out",
            str(d),
            "--answer",
            str(tmp_path / f"{rate}.json"),
        ]
        res = runner.invoke(app, args)
        assert res.exit_code == 0, res.output
        run = load_dataset(d).runs[0]
        assert run.t[-1] - run.t[0] == pytest.approx(MIN_DURATION_S, abs=1e-6)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--duration", "3100", "--rate", "10000"], ["duration", "GiB", "at most 1342 s"]),
        (["--duration", "9.99"], ["duration", "[10, 3600]"]),
        (["--rate", "20000"], ["sample_rate_hz", "[100, 10000]"]),
        (["--angle-noise", "1e300"], ["angle_noise_std", "[0, 1] rad"]),
        (["--random-runs", "1000000000"], ["random_runs", "at most 100"]),
    ],
)
def test_synth_refuses_what_the_loader_would_refuse_before_any_run(tmp_path, args, words):
    t = time.perf_counter()
    res = runner.invoke(
        app,
        [
            "synth",
            "--effect",
            "none",
            "--out",
            str(tmp_path / "d"),
            "--answer",
            str(tmp_path / "a.json"),
            *args,
        ],
    )
    line = _one_error_line(res)
    for w in words:
        assert w in line, line
    assert time.perf_counter() - t < 10
    assert not (tmp_path / "d").exists() or not any((tmp_path / "d").iterdir())


def test_the_synth_bounds_follow_the_loader():
    from drill_env.recordings import dataset
    from drill_env.recordings.synth import CSV_ROW_BYTES, SynthConfig

    SynthConfig(duration_s=dataset.MIN_DURATION_S, sample_rate_hz=dataset.MIN_RATE_HZ)
    SynthConfig(duration_s=60.0, sample_rate_hz=dataset.MAX_RATE_HZ)
    longest = (dataset.MAX_RUN_BYTES // CSV_ROW_BYTES - 1) / dataset.MAX_RATE_HZ
    SynthConfig(duration_s=math.floor(longest), sample_rate_hz=dataset.MAX_RATE_HZ)
    with pytest.raises(ValueError, match="duration_s"):
        SynthConfig(duration_s=math.floor(longest) + 1, sample_rate_hz=dataset.MAX_RATE_HZ)
    # a CSV row of synth's format never exceeds the bound the size check uses
    row = ",".join(
        [f"{v:.12g}" for v in (-3699.99999999, -4.99999999999, -123456.789012, -1.23456789012e-05)]
    )
    assert len(row) + 1 <= CSV_ROW_BYTES


def test_discrepancy_refuses_its_own_data_folder_as_output(tmp_path):
    d = tmp_path / "d"
    res = runner.invoke(
        app,
        [
            *SYNTH,
            "--effect",
            "none",
            "--voltages",
            "1",
            "--out",
            str(d),
            "--answer",
            str(tmp_path / "a.json"),
        ],
    )
    assert res.exit_code == 0
    before = _digest(d)
    for out in (d, d / "analysis"):
        line = _one_error_line(runner.invoke(app, ["discrepancy", str(d), "--out", str(out)]))
        assert "--out" in line and "dataset folder" in line
    assert _digest(d) == before


BENCH = ["benchmark", "--preset", "brake", "--voltages", "1.0", "--seeds", "1", "--duration", "2"]
BENCH += ["--window", "1", "--warmup", "0", "--backend", "sequential", "--no-timeseries"]


def test_a_benchmark_resumes_only_its_own_grid(tmp_path):
    out = tmp_path / "bench"
    res = runner.invoke(app, [*BENCH, "--controllers", "open_loop,pi_upper", "--out", str(out)])
    assert res.exit_code == 0, res.output
    before = _digest(out)
    # the reproducer: a subset resumed into the folder rewrote its config and summary
    line = _one_error_line(runner.invoke(app, [*BENCH, "--controllers", "open_loop", "--out", str(out)]))
    assert "another grid" in line and "controllers ['pi_upper']" in line and "--fresh" in line
    # another grid: other voltages, other seeds
    other = [a if a != "1.0" else "2.0" for a in BENCH]
    line = _one_error_line(
        runner.invoke(app, [*other, "--controllers", "open_loop,pi_upper", "--out", str(out)])
    )
    assert "voltages ['brake 1 V']" in line
    assert _digest(out) == before
    # the same grid resumes (nothing to run) and leaves the results as they were
    res = runner.invoke(app, [*BENCH, "--controllers", "open_loop,pi_upper", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "2 resumed" in res.output
    assert _digest(out)["benchmark.csv"] == before["benchmark.csv"]
    cfg = json.loads((out / "benchmark_config.json").read_text())
    assert cfg["controllers"] == ["open_loop", "pi_upper"]


def test_benchmark_files_are_never_written_through_links(tmp_path):
    out = tmp_path / "bench"
    res = runner.invoke(app, [*BENCH, "--controllers", "open_loop", "--out", str(out)])
    assert res.exit_code == 0, res.output
    target = tmp_path / "elsewhere.csv"
    shutil.move(out / "benchmark.csv", target)
    (out / "benchmark.csv").symlink_to(target)
    before = target.read_bytes()
    line = _one_error_line(runner.invoke(app, [*BENCH, "--controllers", "open_loop", "--out", str(out)]))
    assert "benchmark.csv is a symbolic link" in line
    assert target.read_bytes() == before
    # the appending writer itself never follows a link either
    from drill_env.outputs import OutputFolderError, open_append

    with pytest.raises(OutputFolderError, match="symbolic link"):
        open_append(out / "benchmark.csv")
    assert target.read_bytes() == before


def test_discrepancy_study_by_default_writes_a_fresh_run_folder_not_the_committed_results(
    tmp_path, monkeypatch
):
    """The reproducer: --paper-case-only in a checkout rewrote results/discrepancy/paper_case."""
    import drill_env.discrepancy.study as study

    written: list[Path] = []

    def paper_case(out):  # where the command sends the paper's case (its content is tested elsewhere)
        written.append(Path(out))
        return {"verdict": "-", "confidence": 1.0}

    monkeypatch.setattr(study, "paper_case", paper_case)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results" / "discrepancy").mkdir(parents=True)
    res = runner.invoke(app, ["discrepancy-study", "--paper-case-only"])
    assert res.exit_code == 0, res.output
    assert len(written) == 1 and written[0].parts[:2] == ("runs", "discrepancy-study")
    assert not any((tmp_path / "results" / "discrepancy").iterdir())
    # named explicitly, the committed folder is regenerated
    res = runner.invoke(app, ["discrepancy-study", "--paper-case-only", "--out", "results/discrepancy"])
    assert res.exit_code == 0 and written[-1] == Path("results/discrepancy/paper_case")


# -- 3. bounds up front -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["benchmark", "--seeds", "1000000000"], ["--seeds", "1 to 1000"]),
        (["benchmark", "--duration", "1e9"], ["--duration", "(0, 10000] s"]),
        (["benchmark", "--warmup", "-1"], ["--warmup"]),
        (["benchmark", "--workers", "0"], ["--workers", "1 to 256"]),
        (["benchmark", "--seeds", "1000", "--plants", "family"], ["runs", "at most 1,000,000"]),
        (["simulate", "--duration", "1e306", "--dt", "1e305"], ["--duration", "at most 1e+07"]),
        (["simulate", "--duration", "1", "--dt", "1e-12"], ["--dt", "1e-09"]),
        (["bifurcation", "--umax", "1e308", "--no-check"], ["--umax", "[-100, 100] V"]),
        (["synth", "--effect", "none", "--seed", "-1", "--answer", "a.json"], ["--seed"]),
        (["synth", "--effect", "none", "--angle-noise", "1e300", "--answer", "a.json"], ["angle_noise_std"]),
    ],
)
def test_counts_and_sizes_are_refused_before_any_work(tmp_path, args, words):
    t = time.perf_counter()
    res = runner.invoke(app, [*args, "--out", str(tmp_path / "o")])
    assert time.perf_counter() - t < 30
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    for w in words:
        assert w in res.output, res.output
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(t_final=1e306), "t_final"),
        (dict(t_final=1.0, dt=5e-324), "dt"),
        (dict(t_final=1.0, dt=1e-300), "dt"),
        (dict(t_final=1.0, u=[1.0] * 10, control_dt=5e-324), "control_dt"),
        (dict(t_final=1.0, u=[1.0] * 10, control_dt=1e300), "control_dt"),
        (dict(t_final=1.0, event_capacity=10**15), "event_capacity"),
        (dict(t_final=1.0, event_capacity=0), "event_capacity"),
        (dict(t_final=1.0, event_capacity=2.5), "event_capacity"),
        (dict(t_final=1.0, max_steps=10**30), "max_steps"),
        (dict(t_final=2e6, t0=1.5e6, dt=1e3, u=lambda t: 1.0), "t0"),
        (dict(t_final=1e300, t0=1e299), "t_final"),
    ],
)
def test_the_api_names_the_argument_of_an_extreme_number(kwargs, name):
    kwargs = dict(kwargs)
    u = kwargs.pop("u", 1.0)
    t_final = kwargs.pop("t_final")
    with pytest.raises(ValueError, match=rf"^{name}: "):
        drill_env.simulate("brake", u, t_final, **kwargs)


def test_batch_and_sensor_and_episode_bounds_name_the_argument():
    from drill_env.agents.evaluation.episodes import EpisodeSettings
    from drill_env.sensors import SensorConfig

    with pytest.raises(ValueError, match="^t_final: "):
        drill_env.simulate_batch("brake", [1.0, 2.0], 1e300)
    with pytest.raises(ValueError, match="^sample_rate_hz: "):
        SensorConfig(sample_rate_hz=1e9)
    with pytest.raises(ValueError, match="^speed_noise_std: "):
        SensorConfig(speed_noise_std=1e300)
    with pytest.raises(ValueError, match="^angle_noise_std: "):
        SensorConfig(angle_noise_std=1e300)
    with pytest.raises(ValueError, match="^duration: "):
        EpisodeSettings(duration=1e9)
    import gymnasium as gym

    with pytest.raises(ValueError, match="^control_dt: .*at most 100000 per control step"):
        gym.make("DrillString-v1", control_dt=1.0, sensors={"sample_rate_hz": 1e6, "cutoff_rad_s": 200.0})


_number_text = st.one_of(
    st.sampled_from(
        [
            "0",
            "-0",
            "-1",
            "1e-320",
            "5e-324",
            "1e-12",
            "1e308",
            "1e309",
            "-1e308",
            "nan",
            "inf",
            "-inf",
            "1e7",
            "1e9",
        ]
    ),
    st.integers(-(10**6), 10**40).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.just("1" + "0" * 5000),
)

# (command line, option, whether a value is valid); a valid value is skipped (it would start work)
_NUMERIC = {
    "simulate --duration": (["simulate"], "--duration", lambda v: 1e-2 <= v <= 1e5 + 1),
    "simulate --dt": (["simulate", "--duration", "1"], "--dt", lambda v: 9.9e-8 <= v <= 1),
    "simulate --summary-window": (
        ["simulate", "--duration", "1"],
        "--summary-window",
        lambda v: 0 < v <= 1e7,
    ),
    "bifurcation --umax": (["bifurcation", "--no-check"], "--umax", lambda v: 0 < v <= 100),
    "benchmark --seeds": (["benchmark"], "--seeds", lambda v: v == int(v) and 1 <= v <= 1000),
    "benchmark --duration": (["benchmark"], "--duration", lambda v: 0.05 <= v <= 1e4),
    "benchmark --warmup": (["benchmark"], "--warmup", lambda v: 0 <= v <= 1e4),
    "benchmark --workers": (["benchmark"], "--workers", lambda v: v == int(v) and 1 <= v <= 256),
    "synth --duration": (["synth", "--effect", "none"], "--duration", lambda v: 10 <= v <= 3600),
    "synth --rate": (["synth", "--effect", "none"], "--rate", lambda v: 100 <= v <= 10_000),
    "synth --angle-noise": (["synth", "--effect", "none"], "--angle-noise", lambda v: 0 <= v <= 1),
    "synth --random-runs": (
        ["synth", "--effect", "none"],
        "--random-runs",
        lambda v: v == int(v) and 0 <= v <= 93,
    ),
    "synth --counts": (["synth", "--effect", "none"], "--counts", lambda v: v == int(v) and 1 <= v <= 2**26),
    "discrepancy-study --seeds": (["discrepancy-study"], "--seeds", lambda v: v == int(v) and 1 <= v <= 100),
    "discrepancy-study --workers": (
        ["discrepancy-study"],
        "--workers",
        lambda v: v == int(v) and 0 <= v <= 256,
    ),
}


def _valid(text: str, ok) -> bool:
    try:
        v = float(text)
    except (ValueError, OverflowError):
        return False
    if not math.isfinite(v):
        return False
    try:
        return bool(ok(v))
    except (ValueError, OverflowError):
        return False


@settings(
    max_examples=120,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(option=st.sampled_from(sorted(_NUMERIC)), text=_number_text)
def test_fuzz_numeric_options_refuse_bad_numbers_in_one_line(tmp_path, option, text):
    cmd, flag, ok = _NUMERIC[option]
    assume(not _valid(text, ok))
    args = [*cmd, f"{flag}={text}", "--out", str(tmp_path / "o")]
    if cmd[0] == "synth":
        args += ["--answer", str(tmp_path / "a.json")]
    res = runner.invoke(app, args)
    assert res.exit_code == 2, (option, text, res.output)
    assert "Traceback" not in res.output and (res.exception is None or isinstance(res.exception, SystemExit))
    assert (
        flag in res.output or flag.lstrip("-").replace("-", "_") in res.output or "voltage" in res.output
    ), res.output
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    name=st.sampled_from(["dt", "control_dt", "event_capacity", "max_steps", "t_final", "t0"]),
    value=st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(-(10**30), 10**30),
        st.sampled_from([5e-324, 1e-300, 1e300, 10**15, 0, -1]),
    ),
)
def test_fuzz_the_api_numbers_give_a_result_or_a_value_error_naming_the_argument(name, value):
    kwargs: dict = {"t0": 0.0, "dt": 0.05}
    u: object = 1.0
    t_final = 0.2
    if isinstance(value, float) and math.isfinite(value) or isinstance(value, int):
        # values that are valid but costly are not run: long runs, big allocations
        assume(not (name == "t0" and -1e7 <= value < -10))
        assume(not (name == "t_final" and 10 < value <= 1e7))
        assume(not (name == "dt" and 1e-9 <= value < 1e-4))
        assume(not (name == "event_capacity" and 1e4 < value <= 1e6))
    if name == "control_dt":
        u = [1.0] * 5
        kwargs["control_dt"] = value
    elif name == "t_final":
        t_final = value
    else:
        kwargs[name] = value
    try:
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                res = drill_env.simulate("brake", u, t_final, **kwargs)
    except ValueError as exc:
        assert str(exc).startswith((f"{name}:", "t_final:", "u:")), str(exc)
        return
    assert res.t.size >= 1 and np.isfinite(res.x3).all()


# -- 4. Ctrl-C ----------------------------------------------------------------------------------------


@pytest.fixture
def pythons_sigint_handler():
    """Python's own SIGINT handler (KeyboardInterrupt), as in a terminal: a process started as a
    shell script's background job inherits SIGINT ignored, and Python then installs none."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


@pytest.mark.usefixtures("pythons_sigint_handler")
def test_ctrl_c_stops_a_long_simulation_in_the_api_within_a_second():
    drill_env.simulate("brake", 2.0, 60.0)  # compiled
    sent: list[float] = []

    def interrupt():
        time.sleep(1.0)
        sent.append(time.perf_counter())
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=interrupt, daemon=True).start()
    with pytest.raises(KeyboardInterrupt):
        drill_env.simulate("brake", 2.0, 1e7, dt=1e6)
    assert time.perf_counter() - sent[0] < 1.0


@pytest.mark.usefixtures("pythons_sigint_handler")
def test_ctrl_c_stops_a_long_batch_simulation_in_the_api_within_a_second():
    from drill_env.simulator import simulate_batch

    simulate_batch("brake", [1.0, 2.0], 60.0)  # compiled
    sent: list[float] = []

    def interrupt():
        time.sleep(1.0)
        sent.append(time.perf_counter())
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=interrupt, daemon=True).start()
    with pytest.raises(KeyboardInterrupt):
        simulate_batch("brake", [1.0, 2.0, 3.0, 4.0], 1e6, dt=1e4)
    assert time.perf_counter() - sent[0] < 1.0


def test_ctrl_c_stops_the_simulate_command_and_says_so():
    """The reproducer: `drill-env simulate --duration 1e9 --dt 1e8` kept running after SIGINT
    (1e9 s is now refused; the longest run allowed, 1e7 s, takes hours)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    code = "import sys; from drill_env.cli import main; print('ready', flush=True); main()"
    args = [sys.executable, "-c", code, "simulate", "--duration", "1e7", "--dt", "1e6"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(4.0)  # in the run (or compiling it)
    assert proc.poll() is None
    t = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert time.perf_counter() - t < 5.0
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == "interrupted (Ctrl-C): the simulation was stopped; nothing written"


def test_ctrl_c_stops_python_m_drill_env_within_2_s_and_exits_130():
    """`python -m drill_env` ends a Ctrl-C as `drill-env` does (it called the app directly, without
    the entry point's handling), and the process ends at once after it: the interpreter's
    teardown (seconds with the compiled kernels loaded) is skipped."""
    drill_env.simulate("brake", 2.0, 60.0)  # the kernels in the cache the command reads
    args = [sys.executable, "-m", "drill_env", "simulate", "--duration", "1e7", "--dt", "10"]
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err, took = _ctrl_c_after(proc, 8.0)  # started and in the run (hours long)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted (Ctrl-C)" in err
    assert took < 2.0, took


# -- 6. time precision at a late start ---------------------------------------------------------------------


def test_a_late_start_gives_the_same_run_as_a_start_at_zero():
    early = drill_env.simulate("brake", 2.0, 60.0, dt=0.01)
    for t0 in (1e4, 1e9, 1e12):
        late = drill_env.simulate("brake", 2.0, t0 + 60.0, dt=0.01, t0=t0)
        np.testing.assert_array_equal(late.x3, early.x3)
        np.testing.assert_allclose(late.events.t - t0, early.events.t, rtol=0, atol=1e-12 * t0)
        assert late.t[0] == t0 and late.t[-1] == t0 + 60.0
    # a held sequence too; with a function of time the clock is absolute and bounded
    seq = [1.0, 2.0, 3.0] * 10
    a = drill_env.simulate("brake", seq, 3.0, dt=0.01, control_dt=0.1)
    b = drill_env.simulate("brake", seq, 1e9 + 3.0, dt=0.01, control_dt=0.1, t0=1e9)
    np.testing.assert_array_equal(a.x3, b.x3)
    # what the amplifier was asked for, before its limit, at the same instants
    a = drill_env.simulate("brake", [1.0, 7.0, 3.0] * 10, 3.0, dt=0.01, control_dt=0.1, voltage_limit=5.0)
    b = drill_env.simulate(
        "brake", [1.0, 7.0, 3.0] * 10, 1e9 + 3.0, dt=0.01, control_dt=0.1, voltage_limit=5.0, t0=1e9
    )
    np.testing.assert_array_equal(a.u_requested, b.u_requested)
    np.testing.assert_array_equal(a.u, b.u)
    assert a.u_requested.max() == 7.0 and a.u.max() == 5.0
    with pytest.raises(ValueError, match=r"^t0: .*full precision only up to 1e\+06 s"):
        drill_env.simulate("brake", lambda t: 1.0, 1e7 + 1.0, t0=1e7)


# -- 7. untrusted policies without a terminal -------------------------------------------------------------


def test_a_run_without_a_terminal_refuses_an_untrusted_policy(tmp_path, monkeypatch):
    from drill_env.agents.registry import policy_path

    agents = tmp_path / "agents"
    shutil.copytree(policy_path("ppo_lqi_clone", "brake").parent, agents / "ppo_lqi_clone")
    args = [
        *BENCH,
        "--controllers",
        "open_loop,ppo_lqi_clone",
        "--agents-dir",
        str(agents),
        "--out",
        str(tmp_path / "o"),
    ]
    monkeypatch.delenv("DRILL_ENV_TRUST_POLICIES", raising=False)
    line = _one_error_line(runner.invoke(app, args))  # CliRunner: no terminal
    assert "--agents-dir" in line and "--trust-policies" in line and "DRILL_ENV_TRUST_POLICIES" in line
    assert not (tmp_path / "o").exists()


def test_a_policy_zip_that_inflates_beyond_the_bound_is_refused_before_reading(tmp_path):
    from drill_env.agents.learning.rl import (
        MAX_POLICY_INFLATED_BYTES,
        load_policy,
        policy_observation_version,
    )

    bomb = tmp_path / "ppo" / "policy.zip"
    bomb.parent.mkdir()
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        with zf.open("data", "w", force_zip64=True) as f:
            chunk = b"\0" * (1 << 20)
            for _ in range(MAX_POLICY_INFLATED_BYTES // len(chunk) + 1):
                f.write(chunk)
    assert bomb.stat().st_size < 2 * 2**20
    for call in (
        lambda: load_policy(bomb, algo="ppo", trusted=True),
        lambda: policy_observation_version(bomb),
    ):
        with pytest.raises(ValueError, match=r"^policy: .* inflates to 65 MiB; allowed: at most 64 MiB"):
            call()
    args = [*BENCH, "--controllers", "ppo", "--agents-dir", str(tmp_path), "--trust-policies"]
    line = _one_error_line(runner.invoke(app, [*args, "--out", str(tmp_path / "o")]))
    assert "inflates" in line


# -- minor items -----------------------------------------------------------------------------------------


def test_sb3_vec_env_names_a_foreign_env_id():
    from drill_env.envs.sb3 import sb3_vec_env

    with pytest.raises(ValueError, match=r"^env_id: 'CartPole-v1' is not a drill-env id"):
        sb3_vec_env("CartPole-v1", 2)


def test_negative_seeds_are_refused_naming_the_option(tmp_path):
    for args in (
        [
            "synth",
            "--effect",
            "none",
            "--seed",
            "-1",
            "--out",
            str(tmp_path / "d"),
            "--answer",
            str(tmp_path / "a"),
        ],
        ["discrepancy", str(tmp_path), "--seed", "-1", "--out", str(tmp_path / "r")],
        ["train", "--algo", "ppo", "--seed", "-1"],
    ):
        res = runner.invoke(app, args)
        assert res.exit_code == 2 and "'--seed'" in res.output, res.output


# -- round 3: an interrupted synth leaves no folder that loads as a complete dataset ----------------


def test_an_interrupted_dataset_write_leaves_no_loadable_dataset(tmp_path, monkeypatch):
    from drill_env.recordings import dataset as D

    runner.invoke(
        app,
        [
            "synth",
            "--effect",
            "none",
            "--voltages",
            "1,2,3",
            "--random-runs",
            "0",
            "--duration",
            "10",
            "--rate",
            "100",
            "--out",
            str(tmp_path / "d"),
            "--answer",
            str(tmp_path / "a.json"),
        ],
    )
    full = D.load_dataset(tmp_path / "d")
    assert len(full.runs) == 3
    real = D.atomic_file
    written: list[str] = []

    def interrupted_after_one(path, *args, **kwargs):
        if written:
            raise KeyboardInterrupt
        written.append(str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(D, "atomic_file", interrupted_after_one)
    with pytest.raises(KeyboardInterrupt):  # rewriting the same runs, Ctrl-C after the first
        D.write_dataset(tmp_path / "d", list(full.runs), preset="brake", encoder_counts_per_rev=2000)
    with pytest.raises(D.DatasetError, match=r"dataset.json: missing"):
        D.load_dataset(tmp_path / "d")


def test_ctrl_c_in_synth_exits_130_and_leaves_no_dataset(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    code = "import sys; from drill_env.cli import main; print('ready', flush=True); main()"
    args = [sys.executable, "-c", code, "synth", "--effect", "none", "--voltages", "0.5,1,2,3,4"]
    args += ["--random-runs", "20", "--duration", "3600", "--out", str(tmp_path / "d")]
    args += ["--answer", str(tmp_path / "a.json")]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(3.0)
    assert proc.poll() is None
    t = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert time.perf_counter() - t < 5.0  # 2 s on a quiet machine; a loaded CI gets slack
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert not (tmp_path / "d" / "dataset.json").exists()
    assert not (tmp_path / "a.json").exists()


# -- a motionless dataset: what the data lack, in one line ------------------------------------------


def _hand_written_run(path: Path, volts: float, speed: float) -> None:
    """A run in the data format, written by hand: 12 s at 100 Hz, both disks at ``speed``
    [rad/s] (0: standing still), the angles whole encoder counts."""
    step = 2 * np.pi / 2000
    t = 5.0 + 0.01 * np.arange(1201)
    theta = np.floor((1.0 + speed * (t - t[0])) / step) * step
    rows = [f"{ti:.2f},{volts:g},{th + 40 * step:.12g},{th:.12g}" for ti, th in zip(t, theta, strict=True)]
    path.write_text("t,u,theta_u,theta_l\n" + "\n".join(rows) + "\n")


@pytest.mark.parametrize(
    ("moving", "words"),
    [((), ["no run in which the rig turns", "run01 (0 V)", "run02 (0 V)"])],
    ids=["every-run-still"],
)
def test_discrepancy_on_a_motionless_dataset_names_the_runs_and_what_they_lack(tmp_path, moving, words):
    data = tmp_path / "still"
    data.mkdir()
    (data / "dataset.json").write_text('{"preset": "brake", "encoder_counts_per_rev": 2000}')
    for name in ("run01", "run02"):
        turning = name in moving
        _hand_written_run(data / f"{name}.csv", 2.0 if turning else 0.0, 0.7 if turning else 0.0)
    res = runner.invoke(app, ["discrepancy", str(data), "--out", str(tmp_path / "o"), "--no-figures"])
    line = _one_error_line(res)
    for w in words:
        assert w in line, line
    assert "neither disk turns" in line and "between 0 and 1" not in line
    if moving:
        assert "run02" not in line  # the run that turns is not named
    assert not (tmp_path / "o").exists()  # refused before anything was written


def test_a_run_that_never_turns_is_left_out_of_the_discrepancy_comparison_and_named(tmp_path):
    """A stuck run among turning ones (a lab's 0.05 V run below the break-away, as the
    identification plan records for the stick boundary) holds nothing to compare: the workflow
    leaves it out, says so in the output, the report and result.json, and analyses the rest."""
    from drill_env.recordings.synth import SynthConfig, make_dataset, write_synthetic

    cfg = SynthConfig(preset="brake", voltages=(0.05, 0.5, 1.0, 2.0, 3.0), random_runs=1, duration_s=30.0)
    write_synthetic(
        make_dataset("none", seed=3, config=cfg), tmp_path / "d", tmp_path / "a.json", preset="brake"
    )
    res = runner.invoke(
        app, ["discrepancy", str(tmp_path / "d"), "--out", str(tmp_path / "o"), "--no-figures"]
    )
    assert res.exit_code == 0, res.output
    assert "verdict: none" in res.output
    assert "1 run(s) left out of the comparison: run01 (0.05 V): stuck throughout" in res.output
    result = json.loads((tmp_path / "o" / "result.json").read_text())
    assert list(result["left_out"]) == ["run01"]
    assert "left out of the comparison: run01 (0.05 V)" in (tmp_path / "o" / "report.md").read_text()
    # a stuck run among the held-out ones is left out as well; holding out only stuck runs is refused
    res = runner.invoke(
        app, ["discrepancy", str(tmp_path / "d"), "--out", str(tmp_path / "o2"), "--heldout", "run01,run03"]
    )
    assert res.exit_code == 0, res.output
    assert "Held-out runs: run03." in (tmp_path / "o2" / "report.md").read_text()
    res = runner.invoke(
        app, ["discrepancy", str(tmp_path / "d"), "--out", str(tmp_path / "o3"), "--heldout", "run01"]
    )
    assert res.exit_code == 2 and "run01 never turn(s)" in _one_error_line(res)


def test_identify_on_runs_that_barely_excite_the_rig_reports_instead_of_a_traceback(tmp_path):
    """Three short runs just above the break-away (0.2-0.4 V): the fit's covariance is not
    finite, which broke the flat-direction analysis with numpy's "Eigenvalues did not
    converge"; now the report names the parameters as unbounded and no rig file is written."""
    from drill_env.recordings.synth import SynthConfig, make_dataset, write_synthetic

    cfg = SynthConfig(preset="brake", voltages=(0.2, 0.3, 0.4), random_runs=0, duration_s=20.0)
    write_synthetic(
        make_dataset("none", seed=0, config=cfg), tmp_path / "d", tmp_path / "a.json", preset="brake"
    )
    res = runner.invoke(app, ["identify", str(tmp_path / "d"), "--out", str(tmp_path / "o"), "--no-effects"])
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert res.exit_code in (0, 1, 2), res.output
    if res.exit_code == 2 and not (tmp_path / "o").exists():
        # refused before the fit: too few windows in which a disk turns one way (one line)
        (line,) = res.output.strip().splitlines()
        assert line.startswith("error:") and "turns one way" in line and "identify --plan" in line, line
        return
    assert (tmp_path / "o" / "report.md").is_file()
    if "a 95 % half-width of inf" in (tmp_path / "o" / "report.md").read_text():  # unbounded parameters
        assert "error: no rig.yaml" in res.output and not (tmp_path / "o" / "rig.yaml").exists()


@pytest.mark.parametrize("command", ["benchmark", "discrepancy", "sim-to-real"])
def test_ctrl_c_ends_a_long_command_within_2_s_with_exit_130(tmp_path, command):
    """Ctrl-C in the middle of the work (after the start-up, in the runs or the analysis) ends
    the command within 2 s, exit code 130, one line, no traceback."""
    data = tmp_path / "data"
    if command == "discrepancy":
        from drill_env.recordings.synth import SynthConfig, make_dataset, write_synthetic

        # long enough to be in the analysis at the signal on a quiet machine (about a minute)
        cfg = SynthConfig(voltages=(0.5, 1.0, 2.0, 3.0, 4.0), random_runs=2, duration_s=120.0, pre_roll_s=2.0)
        write_synthetic(make_dataset("none", seed=1, config=cfg), data, tmp_path / "a.json", preset="brake")
    args = {
        "benchmark": ["benchmark", "--quick", "--controllers", "open_loop,pi_upper", "--workers", "1"],
        "discrepancy": ["discrepancy", str(data)],
        "sim-to-real": ["sim-to-real", "--quick"],
    }[command]
    proc = subprocess.Popen(
        [sys.executable, "-m", "drill_env", *args, "--out", str(tmp_path / "o")],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    err, took = _ctrl_c_after(proc, 10.0)  # past the start-up, in the work (each takes minutes)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "Exception ignored" not in err
    assert [ln for ln in err.splitlines() if ln.startswith("interrupted (Ctrl-C)")], err
    assert took < 2.0, took


def test_identify_names_why_no_rig_file_when_the_fit_makes_no_valid_rig(tmp_path, monkeypatch):
    """Every needed parameter identified, yet the fitted values make no valid rig (e.g. one
    closed-loop run): the error line says so and why, never an empty list of parameters."""
    from drill_env.identify import identification
    from drill_env.params import ParameterError
    from drill_env.recordings.synth import SynthConfig, make_dataset, write_synthetic

    cfg = SynthConfig(preset="brake", voltages=(0.5, 1.0, 2.0, 3.0), random_runs=1, duration_s=20.0)
    write_synthetic(
        make_dataset("none", seed=1, config=cfg), tmp_path / "d", tmp_path / "a.json", preset="brake"
    )

    def invalid(*args, **kwargs):
        raise ParameterError("lower_static: must be > 0 (got -0.01)")

    monkeypatch.setattr(identification, "fitted_params", invalid)
    res = runner.invoke(app, ["identify", str(tmp_path / "d"), "--out", str(tmp_path / "o"), "--no-effects"])
    assert res.exit_code == 1, res.output
    line = next(x for x in res.output.splitlines() if x.startswith("error: no rig.yaml"))
    assert "the fitted parameters make no valid rig (lower_static: must be > 0 (got -0.01))" in line
    assert "do not identify ;" not in res.output
    assert not (tmp_path / "o" / "rig.yaml").exists()
