"""The ``bifurcation`` and ``rig-comparison`` commands and the comparison with the rig."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import drill_env
from drill_env.analysis import rig_comparison
from drill_env.cli import app

runner = CliRunner()


def test_bifurcation_command_writes_json_and_figures(tmp_path):
    out = tmp_path / "nb"
    res = runner.invoke(
        app, ["bifurcation", "--preset", "no_brake", "--umax", "2.5", "--no-check", "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    for name in (
        "bifurcation.json",
        "fig6_equilibria.png",
        "fig8_bifurcation.png",
        "period.png",
        "fig9_limit_cycles.png",
    ):
        assert (out / name).stat().st_size > 1000, name
    data = json.loads((out / "bifurcation.json").read_text())
    assert data["preset"] == "no_brake"
    assert data["validity_warnings"] == []  # inside +-5 V; no identified speed limit for no_brake
    assert list(data["points"]) == ["A", "B", "C", "D", "E", "F"]
    assert {b["name"] for b in data["branches"]} == {"e1", "e2", "e3", "e4", "p1", "p2", "p3", "p4"}
    assert "fold_periodic" in res.output


def test_bifurcation_command_rejects_an_empty_range(tmp_path):
    res = runner.invoke(app, ["bifurcation", "--umin", "2", "--umax", "1", "--out", str(tmp_path)])
    assert res.exit_code == 2
    assert "--umin < --umax" in res.output


def test_bifurcation_command_analyses_the_base_model_of_a_rig_with_effects(tmp_path):
    # a rig file with an effect section (what identify and discrepancy write) is analysed
    # without its effects, and says so (as the env's regimes are those of the base model)
    p = drill_env.load_params("brake", string_damping=0.01)
    cfg = tmp_path / "damped.yaml"
    p.to_yaml(cfg)
    res = runner.invoke(
        app,
        ["bifurcation", "--preset", str(cfg), "--out", str(tmp_path / "o"), "--no-check", "--umax", "0.5"],
    )
    assert res.exit_code == 0, res.output
    assert "paper's model only: the effects ['string_damping'] of damped.yaml are left out" in res.output


@pytest.fixture(scope="module")
def comparison():
    return rig_comparison("brake")


def test_rig_comparison_rows(comparison):
    rows = {(r.quantity, r.u): r for r in comparison.rows}
    assert len(rows) == 7
    # The model's qualitative verdicts match the rig: quiet at 0.5 V, a limit cycle at 0.7 V.
    assert rows[("torsional vibration", 0.5)].agrees
    assert rows[("torsional vibration", 0.7)].agrees
    assert 0.5 < comparison.hopf_u < 0.7
    # The numbers in the table are consistent with the relative errors quoted.
    for (q, u), r in rows.items():
        if r.relative_error is None:
            continue
        model = float(r.model.split()[0])
        rig = r.rig.split()[0]
        ref = np.mean([float(x) for x in rig.split("-")])
        # the model value is printed to 4 decimals
        assert r.relative_error == pytest.approx((model - ref) / ref, abs=6e-5 / ref), (q, u)
    text = comparison.to_markdown()
    assert text.count("\n| ") == 8  # header + 7 rows


def test_rig_comparison_mean_speed_of_the_cycle_is_the_long_run_mean(comparison):
    c = comparison.cycles[0.7]
    res = drill_env.simulate("brake", 0.7, 1500.0, dt=0.001)
    n_periods = 80
    tail = res.t >= res.t[-1] - n_periods * c.period
    mean = (res.theta_l[-1] - res.theta_l[tail][0]) / (res.t[-1] - res.t[tail][0])
    row = next(r for r in comparison.rows if r.quantity == "mean lower-disk speed" and r.u == 0.7)
    assert float(row.model.split()[0]) == pytest.approx(mean, rel=1e-3)


def test_rig_comparison_command(tmp_path):
    out = tmp_path / "rig.md"
    res = runner.invoke(app, ["rig-comparison", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert out.read_text().startswith("# The model against the rig")
    assert json.loads(out.with_suffix(".json").read_text())["preset"] == "brake"


def test_rig_comparison_names_the_preset_equations(comparison):
    import dataclasses

    assert "eq. 11, 13, 15, 17" in comparison.to_markdown()
    assert "eq. 11, 13, 15, 16" in dataclasses.replace(comparison, preset="no_brake").to_markdown()
    assert "not from the paper" in dataclasses.replace(comparison, preset="my_rig").to_markdown()
