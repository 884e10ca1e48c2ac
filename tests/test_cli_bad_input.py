"""Bad input on the command line: exit code 2 and one line ``error: ...`` naming the file,
field or option, before any work, never a traceback; failed work exits 1."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

import drill_env
from drill_env.cli import app

runner = CliRunner()
ON_LINUX = Path("/proc/self").is_dir()


def _broken_yaml(d: Path) -> str:
    (d / "broken.yaml").write_text("motor_constant: [1, 2\nupper_inertia: }\n")
    return str(d / "broken.yaml")


def _binary_yaml(d: Path) -> str:
    (d / "binary.yaml").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe")
    return str(d / "binary.yaml")


def _utf16_yaml(d: Path) -> str:
    (d / "wide.yaml").write_bytes("motor_constant: 3.5\n".encode("utf-16"))
    return str(d / "wide.yaml")


def _folder(d: Path) -> str:
    (d / "dir").mkdir(exist_ok=True)
    return str(d / "dir")


def _file(d: Path) -> str:
    (d / "file.txt").write_text("keep me\n")
    return str(d / "file.txt")


def _fifo_yaml(d: Path) -> str:
    os.mkfifo(d / "pipe.yaml")
    return str(d / "pipe.yaml")


def _dataset_with(d: Path, name: str, content: bytes | None) -> str:
    """A valid one-run dataset plus a bad file ``name`` (None: a FIFO)."""
    data = d / "data"
    data.mkdir()
    step = 2 * np.pi / 2000
    t = 0.01 * np.arange(1201)
    th = np.floor(0.8 * t / step) * step
    rows = ["t,u,theta_u,theta_l"] + [
        f"{a:.2f},1,{b + 3 * step:.12g},{b:.12g}" for a, b in zip(t, th, strict=True)
    ]
    (data / "run01.csv").write_text("\n".join(rows) + "\n")
    (data / "dataset.json").write_text(json.dumps({"preset": "brake", "encoder_counts_per_rev": 2000}))
    if content is None:
        os.mkfifo(data / name)
    else:
        (data / name).write_bytes(content)
    return str(data)


def _benchmark_folder(d: Path, csv_text: str, config_text: str) -> str:
    out = d / "bench"
    out.mkdir()
    (out / "benchmark.csv").write_text(csv_text)
    (out / "benchmark_config.json").write_text(config_text)
    return str(out)


def _benchmark_settings() -> str:
    """The settings record of the benchmark BENCH describes, as a resumable folder holds it."""
    from drill_env.agents.evaluation.benchmark import BenchmarkConfig
    from drill_env.agents.evaluation.episodes import EpisodeSettings

    cfg = BenchmarkConfig(
        presets=("brake",),
        controllers=("open_loop",),
        voltages={"brake": (1.0,)},
        seeds=(0,),
        episode=EpisodeSettings(duration=2.0, window=1.0, warmup_time=0.0),
    )
    return json.dumps(cfg.settings_record())


def _benchmark_csv() -> str:
    from drill_env.agents.evaluation.benchmark import COLUMNS

    return ",".join(COLUMNS) + "\n"


SIM = ["simulate", "--duration", "1"]
BENCH = ["benchmark", "--preset", "brake", "--controllers", "open_loop", "--voltages", "1", "--seeds", "1"]
BENCH += ["--backend", "sequential", "--duration", "2", "--window", "1", "--warmup", "0"]
SYNTH = ["synth", "--effect", "none", "--duration", "10", "--voltages", "1", "--random-runs", "0"]

# (id, arguments: a function of the temporary folder, words the one error line must hold)
CASES = [
    (
        "simulate-yaml-syntax",
        lambda d: [*SIM, "--preset", _broken_yaml(d)],
        ["broken.yaml", "line 2", "YAML"],
    ),
    ("simulate-yaml-binary", lambda d: [*SIM, "--preset", _binary_yaml(d)], ["binary.yaml", "UTF-8"]),
    ("simulate-yaml-utf16", lambda d: [*SIM, "--preset", _utf16_yaml(d)], ["wide.yaml", "UTF-8"]),
    ("simulate-yaml-folder", lambda d: [*SIM, "--preset", _folder(d) + ".yaml"], ["preset", "dir.yaml"]),
    ("simulate-out-folder", lambda d: [*SIM, "--out", _folder(d)], ["--out", "folder"]),
    ("simulate-out-under-file", lambda d: [*SIM, "--out", _file(d) + "/x.csv"], ["--out", "file.txt"]),
    (
        "simulate-size-duration",
        lambda d: ["simulate", "--duration", "1e7", "--out", "x.csv"],
        ["--dt", "1e+09"],
    ),
    (
        "simulate-size-dt",
        lambda d: ["simulate", "--duration", "10", "--dt", "1e-7"],
        ["--dt", "1e+08", "GiB"],
    ),
    (
        "bifurcation-yaml",
        lambda d: ["bifurcation", "--preset", _broken_yaml(d), "--out", str(d / "b")],
        ["broken.yaml"],
    ),
    (
        "bifurcation-out-file",
        lambda d: ["bifurcation", "--out", _file(d), "--no-check"],
        ["--out", "file.txt"],
    ),
    ("rig-comparison-out-folder", lambda d: ["rig-comparison", "--out", _folder(d)], ["--out", "folder"]),
    (
        "rig-comparison-out-json",
        lambda d: ["rig-comparison", "--out", str(d / "c.json")],
        ["--out", "Markdown"],
    ),
    (
        "synth-out-file",
        lambda d: [*SYNTH, "--out", _file(d), "--answer", str(d / "a.json")],
        ["--out", "file.txt"],
    ),
    (
        "synth-answer-folder",
        lambda d: [*SYNTH, "--out", str(d / "s"), "--answer", _folder(d)],
        ["--answer", "folder"],
    ),
    (
        "synth-answer-inside",
        lambda d: [*SYNTH, "--out", str(d / "s"), "--answer", str(d / "s" / "a.json")],
        ["--answer", "inside"],
    ),
    (
        "discrepancy-out-file",
        lambda d: ["discrepancy", _dataset_with(d, "x.txt", b""), "--out", _file(d)],
        ["--out"],
    ),
    (
        "discrepancy-binary-run",
        lambda d: [
            "discrepancy",
            _dataset_with(d, "._run01.csv", b"\x00\x05\x16\x07"),
            "--out",
            str(d / "o"),
        ],
        ["._run01.csv", "binary"],
    ),
    (
        "discrepancy-utf16-run",
        lambda d: [
            "discrepancy",
            _dataset_with(d, "run02.CSV", "t,u\n".encode("utf-16")),
            "--out",
            str(d / "o"),
        ],
        ["run02.CSV", "UTF-16"],
    ),
    (
        "discrepancy-fifo-run",
        lambda d: ["discrepancy", _dataset_with(d, "live.csv", None), "--out", str(d / "o")],
        ["live.csv", "not a regular file"],
    ),
    (
        "discrepancy-json-binary",
        lambda d: [
            "discrepancy",
            _dataset_with(d, "dataset.json", b"\xff\xd8\xff\xe0"),
            "--out",
            str(d / "o"),
        ],
        ["dataset.json", "UTF-8"],
    ),
    (
        "benchmark-duration",
        lambda d: [*BENCH, "--duration", "0.01", "--out", str(d / "b")],
        ["--duration", "control period"],
    ),
    (
        "benchmark-agents-dir",
        lambda d: [*BENCH, "--controllers", "ppo", "--agents-dir", str(d / "none"), "--out", str(d / "b")],
        ["--agents-dir", "none"],
    ),
    (
        "benchmark-agents-dir-empty",
        lambda d: [*BENCH, "--controllers", "sac", "--agents-dir", _folder(d), "--out", str(d / "b")],
        ["--agents-dir", "policy.zip"],
    ),
    (
        "benchmark-gains",
        lambda d: [*BENCH, "--gains", _binary_yaml(d), "--out", str(d / "b")],
        ["--gains", "binary.yaml"],
    ),
    ("benchmark-out-file", lambda d: [*BENCH, "--out", _file(d)], ["--out", "file.txt"]),
    (
        "benchmark-resume-config",
        lambda d: [*BENCH, "--out", _benchmark_folder(d, _benchmark_csv(), '{"episode": {"dur')],
        ["benchmark_config.json", "--fresh"],
    ),
    (
        "benchmark-resume-csv",
        lambda d: [
            *BENCH,
            "--out",
            _benchmark_folder(
                d, _benchmark_csv() + "open_loop,brake,nominal,1,zero\n", _benchmark_settings()
            ),
        ],
        ["benchmark.csv", "cannot resume", "--fresh"],
    ),
    (
        "benchmark-resume-csv-no-columns",
        lambda d: [*BENCH, "--out", _benchmark_folder(d, "x\n", _benchmark_settings())],
        ["benchmark.csv", "cannot resume", "--fresh"],
    ),
    ("tune-control-dt", lambda d: ["tune", "--control-dt", "0.0505"], ["--control-dt", "sensor periods"]),
    ("tune-out-folder", lambda d: ["tune", "--out", _folder(d)], ["--out", "dir"]),
    (
        "train-config-yaml",
        lambda d: ["train", "--algo", "ppo", "--config", _broken_yaml(d), "--out", str(d / "t")],
        ["broken.yaml", "line 2"],
    ),
    (
        "train-config-binary",
        lambda d: ["train", "--algo", "ppo", "--config", _binary_yaml(d), "--out", str(d / "t")],
        ["binary.yaml", "UTF-8"],
    ),
]
if ON_LINUX:
    CASES += [
        (f"{cmd[0]}-out-proc", lambda d, cmd=cmd: [*cmd, "--out", "/proc/drill-env-x"], ["--out", "/proc"])
        for cmd in (
            SIM,
            ["bifurcation", "--no-check"],
            ["rig-comparison"],
            [*SYNTH, "--answer", "a.json"],
            BENCH,
        )
    ]
    CASES += [
        ("simulate-yaml-fifo", lambda d: [*SIM, "--preset", _fifo_yaml(d)], ["pipe.yaml", "regular file"])
    ]


def _assert_one_line_error(result, code: int, words) -> str:
    assert result.exit_code == code, result.output
    assert isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


@pytest.mark.parametrize(("args", "words"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_and_exit_code_2(tmp_path, monkeypatch, args, words):
    monkeypatch.chdir(tmp_path)  # a relative default output lands here, if anywhere
    before = sorted(p.name for p in tmp_path.rglob("*"))
    result = runner.invoke(app, args(tmp_path))
    _assert_one_line_error(result, 2, words)
    made = sorted(p.name for p in tmp_path.rglob("*"))
    assert "x.csv" not in made and "a.json" not in made  # refused before any work
    if "--fresh" in words:  # the damaged benchmark folder is left as it was
        assert (tmp_path / "bench" / "benchmark.csv").stat().st_size > 0
    del before


def test_a_failed_simulation_exits_1_and_writes_nothing(tmp_path):
    out = tmp_path / "x.csv"
    args = ["simulate", "--voltage", "1e308", "--no-voltage-limit", "--duration", "1", "--out", str(out)]
    line = _assert_one_line_error(runner.invoke(app, args), 1, ["1e+308 V", "failed", "nothing written"])
    assert "stuck" not in line and not out.exists()


def test_yaml_exponents_without_a_dot_are_numbers(tmp_path):
    # YAML 1.1 reads 5e-4 and 1e300 as strings; YAML 1.2 (and this loader) as numbers
    from drill_env.params import load_yaml

    (tmp_path / "n.yaml").write_text("a: 5e-4\nb: 1e300\nc: -2E+3\nd: 1.5\ne: 12\nf: e5\ng: 1e\n")
    assert load_yaml(tmp_path / "n.yaml") == {
        "a": 5e-4,
        "b": 1e300,
        "c": -2000.0,
        "d": 1.5,
        "e": 12,
        "f": "e5",
        "g": "1e",
    }
    assert yaml.safe_load("a: 5e-4") == {"a": "5e-4"}  # PyYAML itself is left as it is
    p = drill_env.load_params("brake")
    data = p.to_dict()
    data["lower_viscous"] = "LV"
    data["motor_constant"] = "KM"
    text = yaml.safe_dump(data, sort_keys=False)
    text = text.replace("LV", "42e-4").replace("KM", f"{p.motor_constant * 1e3:.6g}e-3")
    (tmp_path / "rig.yaml").write_text(text)
    q = drill_env.load_params(tmp_path / "rig.yaml")
    assert q.lower_viscous == 42e-4 == p.lower_viscous
    assert q.motor_constant == pytest.approx(p.motor_constant, rel=1e-5)
    # and the command line accepts it
    res = runner.invoke(
        app, ["simulate", "--preset", str(tmp_path / "rig.yaml"), "--duration", "2", "--voltage", "1"]
    )
    assert res.exit_code == 0, res.output


def test_yaml_text_values_are_still_refused(tmp_path):
    data = drill_env.load_params("brake").to_dict()
    data["lower_viscous"] = "e5"  # not a number in any YAML
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(data))
    res = runner.invoke(app, ["simulate", "--preset", str(tmp_path / "rig.yaml"), "--duration", "1"])
    _assert_one_line_error(res, 2, ["lower_viscous", "expected a number", "'e5'"])


def test_a_real_process_gets_no_traceback(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "drill_env.cli", "simulate", "--preset", _broken_yaml(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: ") and "broken.yaml" in proc.stderr


def test_an_unexpected_error_keeps_its_traceback(monkeypatch):
    # the handler is for bad input only: a bug is not turned into a one-line message
    import drill_env.simulator

    def broken(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(drill_env.simulator, "simulate", broken)
    result = runner.invoke(app, ["simulate", "--duration", "1"])
    assert isinstance(result.exception, ZeroDivisionError)


@pytest.mark.slow
def test_a_truth_model_that_cannot_be_simulated_is_refused(tmp_path):
    args = [*SYNTH, "--effect", "string_damping", "--magnitude", "1e9", "--out", str(tmp_path / "s")]
    args += ["--answer", str(tmp_path / "a.json")]
    _assert_one_line_error(runner.invoke(app, args), 2, ["magnitude", "could not be simulated"])
    assert not list((tmp_path / "s").glob("*.csv")) and not (tmp_path / "a.json").exists()


def test_bifurcation_outside_the_validated_range_says_so(tmp_path):
    out = tmp_path / "bif"
    res = runner.invoke(app, ["bifurcation", "--umin", "7", "--umax", "8", "--no-check", "--out", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads((out / "bifurcation.json").read_text())
    notes = data["validity_warnings"]
    assert len(notes) == 2 and "+-5 V" in notes[0] and "12.6 rad/s" in notes[1]
    for note in notes:
        assert f"warning: {note}" in res.stderr.replace("\n", " ")
    # the speeds it reports are those of the diagram
    x3 = [abs(v) for b in data["branches"] for v in b["x3_max"]]
    assert max(x3) > 12.6


def test_a_row_cut_by_an_interrupted_run_is_run_again(tmp_path):
    from drill_env.agents.evaluation.benchmark import (
        BenchmarkConfig,
        check_resumable,
        load_results,
        run_benchmark,
    )
    from drill_env.agents.evaluation.episodes import EpisodeSettings

    cfg = BenchmarkConfig(
        presets=("brake",),
        controllers=("open_loop", "pi_upper"),
        voltages={"brake": (1.0,)},
        seeds=(3,),
        episode=EpisodeSettings(duration=3.0, window=1.0, warmup_time=1.0),
    )
    csv_path = run_benchmark(cfg, tmp_path, backend="sequential", report=False)
    whole = load_results(csv_path)
    text = csv_path.read_bytes()
    csv_path.write_bytes(text[: text.rfind(b",", 0, len(text) - 40)])  # the last row cut mid-way
    assert check_resumable(cfg, tmp_path) is not None  # resumable, and nothing written by the check
    assert not csv_path.read_bytes().endswith(b"\n")
    done: list[int] = []
    with pytest.warns(RuntimeWarning, match=r"benchmark.csv: the last row is incomplete"):
        run_benchmark(
            cfg, tmp_path, backend="sequential", report=False, progress=lambda i, n, row: done.append(i)
        )
    assert done[0] == 1  # one run kept, the cut one run again
    again = load_results(csv_path)
    cols = ["controller", "voltage", "seed", "amplitude", "mean_speed", "stick_fraction"]
    pd_testing = pytest.importorskip("pandas.testing")
    pd_testing.assert_frame_equal(again[cols], whole[cols])


def test_output_checks_leave_nothing_behind(tmp_path):
    from drill_env.outputs import OutputFolderError, check_output_file, check_output_folder

    check_output_file(tmp_path / "a" / "b" / "run.csv")
    check_output_folder(tmp_path / "c" / "d")
    assert list(tmp_path.iterdir()) == []  # tried, then undone
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputFolderError, match=r"--out .*f/g/run.csv: .*f is not a folder"):
        check_output_file(tmp_path / "f" / "g" / "run.csv")
    with pytest.raises(OutputFolderError, match=r"--here .*f: exists and is not a folder"):
        check_output_folder(tmp_path / "f", "--here")
    (tmp_path / "link").symlink_to(tmp_path / "gone")
    with pytest.raises(OutputFolderError, match="dangling link"):
        check_output_file(tmp_path / "link")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f", "link"]
