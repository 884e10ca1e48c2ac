"""The ``drill-env simulate`` command: CSV, steady-state summary, voltage limit, errors."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import drill_env
from drill_env.cli import app
from drill_env.metrics import stick_slip_metrics

HEADER = "t,u,theta_u,theta_l,x1,x2,x3,stick_u,stick_l"


@pytest.fixture(scope="module")
def runner() -> CliRunner:
    return CliRunner()


def number_after(label: str, text: str) -> float:
    match = re.search(rf"{label}\s+(-?[0-9.]+)", text)
    assert match, f"no {label!r} in {text!r}"
    return float(match.group(1))


def test_simulate_writes_the_csv_and_summarises_the_last_100_s(runner, tmp_path):
    out = tmp_path / "runs" / "run.csv"
    args = ["simulate", "--preset", "brake", "--voltage", "2.0", "--duration", "300", "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert result.stderr == ""

    assert out.read_text().splitlines()[0] == HEADER
    df = pd.read_csv(out)
    assert list(df.columns) == HEADER.split(",")
    assert len(df) == 30001 and df.t.iloc[-1] == pytest.approx(300.0)
    assert set(df.stick_u.unique()) <= {0, 1} and set(df.stick_l.unique()) == {0, 1}
    api = drill_env.simulate("brake", 2.0, 300.0)
    for column in ("t", "u", "theta_u", "theta_l", "x1", "x2", "x3"):
        np.testing.assert_allclose(df[column], getattr(api, column), rtol=1e-9, atol=1e-12, err_msg=column)
    np.testing.assert_array_equal(df.stick_l.to_numpy() == 1, api.stick_l)

    text = result.stdout
    assert "last 100 s" in text and f"wrote {out}" in text
    last = api.window(100.0)
    m = stick_slip_metrics(last.t, last.x3, last.stick_l)
    assert number_after("mean", text) == pytest.approx(m.mean_speed, abs=1e-5)
    assert number_after("min", text) == pytest.approx(m.min_speed, abs=1e-5) == 0.0
    assert number_after("max", text) == pytest.approx(m.max_speed, abs=1e-5)
    assert number_after("lower disk", text) == pytest.approx(m.stick_fraction, abs=1e-4)
    assert 0.0 < number_after("lower disk", text) < 0.2  # stick-slip at 2 V (Fig. 9)
    assert number_after("dominant period:", text) == pytest.approx(m.period, abs=1e-3)
    assert 3.5 < m.period < 4.5  # near the resonance of the lower disk on the string


def test_summary_of_an_equilibrium_has_no_period(runner):
    result = runner.invoke(app, ["simulate", "--voltage", "0.5", "--duration", "300"])
    assert result.exit_code == 0, result.output
    assert "dominant period: none" in result.stdout
    assert number_after("lower disk", result.stdout) == 0.0
    assert "wrote" not in result.stdout


@pytest.mark.parametrize(("voltage", "applied"), [("7", 5.0), ("-6.5", -5.0)])
def test_voltage_outside_the_rig_range_is_clipped_with_a_warning(runner, tmp_path, voltage, applied):
    out = tmp_path / "clipped.csv"
    result = runner.invoke(app, ["simulate", "--voltage", voltage, "--duration", "20", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "warning" in result.stderr and f"clipped to {applied:g} V" in result.stderr
    assert f"u = {applied:g} V" in result.stdout
    np.testing.assert_array_equal(pd.read_csv(out).u, applied)


def test_no_voltage_limit_lifts_the_clip(runner, tmp_path):
    out = tmp_path / "free.csv"
    result = runner.invoke(
        app, ["simulate", "--voltage", "7", "--duration", "20", "--no-voltage-limit", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    # outside the model's validity: said, not refused
    warnings = result.stderr.splitlines()
    assert len(warnings) == 2 and all(w.startswith("warning: ") for w in warnings)
    assert "u = 7 V" in warnings[0] and "+-5 V" in warnings[0]
    assert "beyond the 12.6 rad/s" in warnings[1]
    np.testing.assert_array_equal(pd.read_csv(out).u, 7.0)


def test_voltage_inside_the_range_is_not_clipped(runner):
    result = runner.invoke(app, ["simulate", "--voltage", "5", "--duration", "10"])
    assert result.exit_code == 0 and "clipped" not in result.stderr and "u = 5 V" in result.stdout
    # at 5 V the brake's lower disk passes the speed its friction was identified up to
    assert result.stderr.startswith("warning: the lower disk reaches") and "12.6 rad/s" in result.stderr
    result = runner.invoke(app, ["simulate", "--voltage", "1", "--duration", "10"])
    assert result.exit_code == 0 and result.stderr == ""  # inside the identified range: no word


@pytest.mark.parametrize(
    ("args", "mentions"),
    [
        (["--duration", "nan"], "--duration"),
        (["--duration", "inf"], "--duration"),
        (["--duration", "0"], "--duration"),
        (["--duration", "-300"], "--duration"),
        (["--voltage", "nan"], "--voltage"),
        (["--voltage", "inf"], "--voltage"),
        (["--voltage", "-inf"], "--voltage"),
        (["--dt", "0"], "--dt"),
        (["--dt", "10", "--duration", "5"], "--dt"),
        (["--preset", "no_such_rig"], "no_such_rig"),
        (["--preset", "missing.yaml"], "missing.yaml"),
    ],
)
def test_bad_arguments_fail_with_a_clear_message(runner, args, mentions):
    result = runner.invoke(app, ["simulate", *args])
    assert result.exit_code != 0
    assert isinstance(result.exception, SystemExit)  # a message, not a traceback
    assert "error:" in result.stderr and mentions in result.stderr
    assert "Traceback" not in result.output


def test_a_non_number_is_refused_by_the_parser(runner):
    result = runner.invoke(app, ["simulate", "--voltage", "two"])
    assert result.exit_code != 0 and "--voltage" in result.stderr


def test_the_command_exits_non_zero_in_a_real_process():
    proc = subprocess.run(
        [sys.executable, "-m", "drill_env.cli", "simulate", "--duration", "nan"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode != 0
    assert "--duration" in proc.stderr and "Traceback" not in proc.stderr


def test_precompile_command_compiles_every_part():
    from typer.testing import CliRunner

    from drill_env.cli import app

    res = CliRunner().invoke(app, ["precompile"])
    assert res.exit_code == 0, res.output
    for part in ("simulator", "environment", "vector environment", "analysis", "rig", "done in"):
        assert part in res.output
    from drill_env import _cache

    assert f"compiling into {_cache.cache_dir()}" in res.output
    assert _cache.cache_dir().name == _cache.source_hash()
