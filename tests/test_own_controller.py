"""A controller of the user's own in ``drill-env benchmark --controller``: the controllers of
this file scored by the command beside the shipped rows (a copy of open loop must give the
open loop's rows exactly; another must give what the one evaluation path gives), policy
zips and their trust, and bad specs refused in one line with exit code 2."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drill_env.agents.controllers.base import Controller
from drill_env.agents.evaluation.benchmark import load_results
from drill_env.agents.evaluation.controller_spec import controller_label, resolve_controller
from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env
from drill_env.cli import app

HERE = Path(__file__).resolve()
ROOT = HERE.parent.parent
EPISODE = ["--duration", "6", "--window", "3", "--warmup", "4"]


class HoldNominal(Controller):
    """Open loop written anew: the operating point's nominal voltage."""

    name = "hold_nominal"

    def control(self, y, state):
        return y[:, self._i_unom].copy(), state


class LowerSpeedP:
    """A controller outside the class hierarchy: proportional on the lower-disk speed error,
    made by ``from_env`` and reading the observation by its entries' names."""

    def __init__(self, gain: float, i_lower: int, i_target: int, i_unom: int, scales: np.ndarray):
        self.gain, self.i_lower, self.i_target, self.i_unom, self.scales = (
            gain,
            i_lower,
            i_target,
            i_unom,
            scales,
        )

    @classmethod
    def from_env(cls, env, preset):
        from drill_env.agents.controllers.base import ControllerSpec

        spec = ControllerSpec.from_env(env)
        return cls(
            0.3,
            spec.index("lower_speed"),
            spec.index("target_speed"),
            spec.index("nominal_voltage"),
            np.asarray(spec.observation_scales),
        )

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        y = np.atleast_2d(observation) * self.scales
        volts = y[:, self.i_unom] + self.gain * (y[:, self.i_target] - y[:, self.i_lower])
        action = (np.clip(volts, -5, 5) / 5.0).astype(np.float32).reshape(-1, 1)
        return (action[0] if np.ndim(observation) == 1 else action), state


class NoPredict:
    """A class that is no controller."""


def _bench(tmp_path, *extra, controllers="open_loop,lqi", voltages="2.0"):
    args = ["benchmark", "--out", str(tmp_path), "--preset", "brake", "--controllers", controllers]
    args += ["--voltages", voltages, "--seeds", "2", *EPISODE, "--backend", "sequential", *extra]
    return CliRunner().invoke(app, args)


def test_own_controllers_are_scored_beside_the_shipped_rows(tmp_path):
    res = _bench(
        tmp_path,
        "--controller",
        f"{HERE}:HoldNominal",
        "--controller",
        f"p_lower={HERE}:LowerSpeedP",
    )
    assert res.exit_code == 0, res.output
    df = load_results(tmp_path / "benchmark.csv")
    assert set(df["controller"]) == {"open_loop", "lqi", "HoldNominal", "p_lower"}
    assert (df["error"] == "").all() and len(df) == 4 * 2
    cols = ["amplitude", "suppression", "rms_error", "u_mean_abs", "stick_fraction"]
    ours = df[df["controller"] == "HoldNominal"].sort_values("seed")[cols].to_numpy()
    ol = df[df["controller"] == "open_loop"].sort_values("seed")[cols].to_numpy()
    np.testing.assert_array_equal(ours, ol)  # the same episodes: open loop, row for row
    # the other one through the evaluation path directly, on the same episode settings
    ep = EpisodeSettings(duration=6.0, window=3.0, warmup_time=4.0)
    env = make_env("brake", ep, 1)
    row = evaluate(LowerSpeedP.from_env(env, "brake"), "brake", 2.0, 1, ep, env=env).as_dict()
    mine = df[(df["controller"] == "p_lower") & (df["seed"] == 1)].iloc[0]
    for c in cols:
        assert mine[c] == pytest.approx(row[c], rel=1e-9, abs=1e-12), c
    assert (
        mine["suppression"]
        != df[(df["controller"] == "open_loop") & (df["seed"] == 1)].iloc[0]["suppression"]
    )
    # the report and its ranking name them; the provenance names their specs
    summary = (tmp_path / "summary.md").read_text()
    assert "| p_lower |" in summary and "| HoldNominal |" in summary
    import json

    ranking = json.loads((tmp_path / "ranking.json").read_text())["rankings"][0]
    (same,) = [q for q in ranking["pairs"] if {q["a"], q["b"]} == {"HoldNominal", "open_loop"}]
    assert same["difference"] == 0 and same["low"] == same["high"] == 0 and not same["resolved"]
    prov = json.loads((tmp_path / "provenance.json").read_text())
    from drill_env.agents.evaluation.benchmark.provenance import source_digest
    from drill_env.simulator import DEFAULT_ATOL, DEFAULT_RTOL

    session = prov["sessions"][-1]
    assert session["source_sha256"] == source_digest() and session["seeds"] == [0, 1]
    assert (session["solver"]["rtol"], session["solver"]["atol"]) == (DEFAULT_RTOL, DEFAULT_ATOL)
    assert prov["sessions"][-1]["custom_controllers"]["p_lower"] == f"p_lower={HERE}:LowerSpeedP"
    assert prov["sessions"][-1]["rows_run"] == 8
    # resumed with the same label for another controller: refused, nothing run
    again = _bench(
        tmp_path, "--controller", f"p_lower={HERE}:HoldNominal", "--controller", f"{HERE}:HoldNominal"
    )
    assert again.exit_code == 2 and "p_lower" in again.output


def test_a_module_on_the_path_and_a_committed_policy_zip(tmp_path, monkeypatch):
    pkg = tmp_path / "my_package"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "my_module.py").write_text(
        "from drill_env.agents.controllers.open_loop import OpenLoop\n\nclass MyController(OpenLoop):\n    pass\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    ep = EpisodeSettings(duration=6.0, window=3.0, warmup_time=4.0)
    env = make_env("brake", ep, 1)
    ctrl = resolve_controller("my_package.my_module:MyController", env, "brake")
    assert (
        type(ctrl).__name__ == "MyController"
        and controller_label("my_package.my_module:MyController") == "MyController"
    )
    committed = ROOT / "results" / "agents" / "ppo" / "policy.zip"
    env3 = make_env("brake", ep, 3)
    policy = resolve_controller(str(committed), env3, "brake")
    assert callable(policy.predict) and controller_label(str(committed)) == "ppo"
    outside = tmp_path / "mine" / "policy.zip"
    outside.parent.mkdir()
    shutil.copy(committed, outside)
    with pytest.raises(ValueError, match="--trust-policies"):
        resolve_controller(str(outside), env3, "brake")
    assert callable(resolve_controller(str(outside), env3, "brake", trust_policies=True).predict)


@pytest.mark.parametrize(
    "spec, words",
    [
        ("no_such_package.mod:Thing", "no module 'no_such_package'"),
        ("json:NoSuchClass", "has no attribute 'NoSuchClass'"),
        (f"{HERE}:NoPredict", "has no predict"),
        ("json:__doc__", "is not a controller"),
        ("missing/file.py:X", "no such file"),
        ("missing/policy.zip", "no such file"),
        ("lqi=json:dumps", "shipped controller"),
        ("just_words", "expected package.module:Name"),
    ],
)
def test_bad_specs_get_one_line_and_exit_2(tmp_path, spec, words):
    res = _bench(tmp_path, "--controller", spec)
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: --controller") and words in lines[0], res.output
    assert not (tmp_path / "benchmark.csv").exists()


def test_a_policy_zip_from_outside_needs_trust_on_the_command_line(tmp_path):
    outside = tmp_path / "mine" / "policy.zip"
    outside.parent.mkdir()
    shutil.copy(ROOT / "results" / "agents" / "ppo" / "policy.zip", outside)
    res = _bench(tmp_path / "out", "--controller", str(outside))
    assert res.exit_code == 2 and "--trust-policies" in res.output
