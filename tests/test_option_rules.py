"""Option rules of adversarial round 3: each refused with one line ``error: ...`` naming the
option, exit code 2, before any work and with nothing written."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from drill_env.cli import app

runner = CliRunner()


def _one_error_line(res) -> str:
    assert res.exit_code == 2, (res.exit_code, res.output)
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    errors = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1, res.output
    return errors[0]


def _data(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    (data / "dataset.json").write_text('{"preset": "brake", "encoder_counts_per_rev": 2000}')
    return data


@pytest.mark.parametrize("where", [".", "inside", "inside/deeper"])
def test_identify_out_in_the_data_folder_is_refused(tmp_path, where):
    data = _data(tmp_path)
    out = data / where
    line = _one_error_line(runner.invoke(app, ["identify", str(data), "--out", str(out)]))
    assert line.startswith("error: --out") and "dataset folder" in line, line
    assert sorted(p.name for p in data.iterdir()) == ["dataset.json"]


@pytest.mark.parametrize("command", ["identify", "discrepancy"])
def test_heldout_runs_named_twice_are_refused(tmp_path, command):
    data = _data(tmp_path)
    args = [command, str(data), "--heldout", "run01, run02,run01", "--out", str(tmp_path / "o")]
    line = _one_error_line(runner.invoke(app, args))
    assert line == "error: --heldout: run 'run01' is named twice; name each held-out run once", line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(("first", "second"), [("identify", "discrepancy"), ("discrepancy", "identify")])
def test_identify_and_discrepancy_never_write_into_each_others_folder(tmp_path, first, second):
    from drill_env.outputs import command_folder

    data = _data(tmp_path)
    out = tmp_path / "o"
    with command_folder(out, first, "--out"):
        (out / "report.md").write_text("theirs\n")
    line = _one_error_line(runner.invoke(app, [second, str(data), "--out", str(out)]))
    assert "--out" in line and f"drill-env {first}" in line, line
    assert (out / "report.md").read_text() == "theirs\n"


BENCH = ["benchmark", "--quick", "--out"]


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--controllers", "open_loop,open_loop"], "--controllers: 'open_loop' is given twice"),
        (["--controllers", "lqi, pi_upper ,lqi"], "--controllers: 'lqi' is given twice"),
        (["--preset", "brake,brake"], "--preset: 'brake' is given twice"),
        (["--ray-address", "127.0.0.1:1"], "--ray-address: only with --backend ray"),
        (["--backend", "sequential", "--ray-address", "x:1"], "--ray-address: only with --backend ray"),
    ],
)
def test_benchmark_option_rules(tmp_path, args, words):
    line = _one_error_line(runner.invoke(app, [*BENCH, str(tmp_path / "b"), *args]))
    assert words in line, line
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (
            ["--seed", "99999999999999999999999"],
            "--seed: 99999999999999999999999; allowed: an integer from 0 to",
        ),
        (["--seed", str(2**63)], "--seed: 9223372036854775808; allowed"),
        (["--voltages", "1,,2"], "--voltages: an empty entry in '1,,2'"),
        (["--voltages", ",1"], "--voltages: an empty entry"),
        (["--plan", "full", "--voltages", "1,2"], "--voltages: cannot be given with --plan"),
        (["--plan", "minimum", "--random-runs", "3"], "--random-runs: cannot be given with --plan"),
        (["--plan", "full", "--duration", "20"], "--duration: cannot be given with --plan"),
    ],
)
def test_synth_option_rules(tmp_path, args, words):
    base = ["synth", "--effect", "none", "--out", str(tmp_path / "d"), "--answer", str(tmp_path / "a.json")]
    line = _one_error_line(runner.invoke(app, [*base, *args]))
    assert words in line, line
    assert not (tmp_path / "d").exists() and not (tmp_path / "a.json").exists()


def test_synth_takes_the_largest_seed_and_an_empty_voltage_list(tmp_path):
    args = [
        "synth",
        "--effect",
        "none",
        "--seed",
        str(2**63 - 1),
        "--voltages",
        "",
        "--random-runs",
        "1",
        "--duration",
        "10",
        "--rate",
        "100",
        "--out",
        str(tmp_path / "d"),
        "--answer",
        str(tmp_path / "a.json"),
    ]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    from drill_env.recordings.dataset import load_dataset

    assert len(load_dataset(tmp_path / "d").runs) == 1


def test_a_plant_file_with_ideal_angles_cannot_be_recorded(tmp_path):
    """``sensors: {counts_per_rev: null}`` is a rig model with ideal angles; a recording holds
    encoder counts, so ``synth --plant`` refuses it in one line (it was a TypeError)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    plant = tmp_path / "plant.yaml"
    plant.write_text(
        (root / "configs" / "rig" / "brake.yaml").read_text() + "sensors:\n  counts_per_rev: null\n"
    )
    out = tmp_path / "d"
    argv = [
        "synth",
        "--plant",
        str(plant),
        "--duration",
        "20",
        "--out",
        str(out),
        "--answer",
        str(tmp_path / "a.json"),
    ]
    line = _one_error_line(runner.invoke(app, argv))
    assert "sensors.counts_per_rev: null" in line and "integer from 1 to 2^26" in line, line
    assert not out.exists() and not (tmp_path / "a.json").exists()
