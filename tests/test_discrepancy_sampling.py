"""Recordings from a DAQ whose sample clock jitters, or that lost samples: accepted within the
stated bounds (brought onto the uniform grid, angles kept on the encoder grid) with the same
verdicts as uniformly sampled data; beyond them refused with the line, the size, the limit and
what to do."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from drill_env.discrepancy.scoring import DecisionRule
from drill_env.discrepancy.workflow import analyse
from drill_env.recordings.dataset import (
    MAX_JITTER,
    DatasetError,
    load_dataset,
    regularise_run,
    write_dataset,
)
from drill_env.recordings.synth import SynthConfig, make_dataset

COUNTS = 2000
STEP = 2 * np.pi / COUNTS


def _write(folder: Path, t: np.ndarray, speed: float = 3.0, **meta) -> np.ndarray:
    """A run turning at ``speed`` rad/s sampled at the instants ``t``: angles on the encoder grid."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "dataset.json").write_text(
        json.dumps({"preset": "brake", "encoder_counts_per_rev": COUNTS, **meta})
    )
    theta = np.floor(speed * (t - t[0]) / STEP) * STEP
    lines = ["t,u,theta_u,theta_l"] + [
        f"{ti:.9f},1.5,{th + 40 * STEP:.12g},{th:.12g}" for ti, th in zip(t, theta, strict=True)
    ]
    (folder / "run01.csv").write_text("\n".join(lines) + "\n")
    return theta


def _error(folder: Path) -> str:
    with pytest.raises(DatasetError) as exc:
        load_dataset(folder)
    return str(exc.value)


@pytest.mark.parametrize(("rate", "jitter"), [(250.0, 0.01), (250.0, 0.1), (1000.0, 0.05)])
def test_jittered_time_stamps_are_brought_onto_the_uniform_grid(tmp_path, rate, jitter):
    rng = np.random.default_rng(int(rate * 10 + jitter * 100))
    n = int(12 * rate)
    grid = 5.0 + np.arange(n) / rate
    t = grid + rng.uniform(-jitter, jitter, n) / rate
    theta_recorded = _write(tmp_path, t, speed=30.0)
    (run,) = load_dataset(tmp_path).runs
    np.testing.assert_allclose(run.t, grid, atol=0.02 / rate)  # the grid through the stamps
    assert np.ptp(np.diff(run.t)) < 1e-9
    assert run.time_jitter == pytest.approx(jitter, abs=0.02)
    for th in (run.theta_u, run.theta_l):
        np.testing.assert_allclose(th / STEP, np.round(th / STEP), atol=1e-6)  # whole counts
    # at the grid instants, the true angle to within the encoder's count (floor quantisation:
    # up to one count) and half a count of the correction's rounding; the recorded angles,
    # taken at the jittered instants, are off by up to the speed times the jitter
    truth = 30.0 * (run.t - t[0])
    assert np.max(np.abs(run.theta_l - truth)) <= 1.5 * STEP + 1e-9
    raw_error = np.max(np.abs(theta_recorded - truth))
    if 30.0 * jitter / rate > 2 * STEP:
        assert raw_error > 2 * STEP


def test_a_run_already_on_its_grid_is_unchanged():
    syn = make_dataset(
        "none", seed=1, config=SynthConfig(voltages=(1.0,), random_runs=0, duration_s=10.0, pre_roll_s=5.0)
    )
    run = syn.runs[0]
    assert regularise_run(run, COUNTS) is run


def test_time_stamps_beyond_the_jitter_bound_are_refused(tmp_path):
    rate = 500.0
    rng = np.random.default_rng(3)
    n = int(12 * rate)
    t = 1.0 + np.arange(n) / rate + rng.uniform(-0.05, 0.05, n) / rate
    t_spike = t.copy()
    t_spike[3000] += 0.3 / rate  # one stamp 30 % of a period off its place
    _write(tmp_path, t_spike)
    msg = _error(tmp_path)
    assert "run01.csv: line 3002, column 't'" in msg and "not a whole number of periods" in msg
    assert "within 10% of the period" in msg
    # a clock whose rate wanders: every step is fine, but the stamps leave the uniform grid
    t_wander = t + 0.4 / rate * np.sin(2 * np.pi * np.arange(n) / n)
    _write(tmp_path, t_wander)
    msg = _error(tmp_path)
    assert "run01.csv: line" in msg and "off the uniform grid" in msg and "rate drifting" in msg


def test_a_gap_is_refused_with_its_remedy_and_split_on_request(tmp_path):
    rate = 200.0
    t = 2.0 + np.arange(int(25 * rate)) / rate
    t[2400:] += 5 / rate  # five samples lost before data row 2400 (line 2402)
    _write(tmp_path, t)
    msg = _error(tmp_path)
    assert "line 2402, column 't'" in msg and "6 sample periods" in msg and "5 sample(s) lost" in msg
    assert '"split_at_gaps": true' in msg
    _write(tmp_path, t, split_at_gaps=True)
    runs = load_dataset(tmp_path).runs
    assert [r.name for r in runs] == ["run01@1", "run01@2"]
    assert runs[0].t.size == 2400 and runs[1].t[0] == pytest.approx(t[2400])
    # a file named like one of the parts is refused, naming both
    (tmp_path / "run01@2.csv").write_text(
        "\n".join((tmp_path / "run01.csv").read_text().splitlines()[:2401]) + "\n"
    )
    msg = _error(tmp_path)
    assert "two runs named 'run01@2'" in msg and "rename the other file" in msg
    (tmp_path / "run01@2.csv").unlink()
    # a part shorter than a run may be is refused, naming its lines
    t2 = 2.0 + np.arange(int(25 * rate)) / rate
    t2[int(20 * rate) :] += 3 / rate
    _write(tmp_path, t2, split_at_gaps=True)
    msg = _error(tmp_path)
    assert "lines 4002-5001" in msg and "at least 10 s" in msg


def test_a_glitch_of_the_clock_is_refused(tmp_path):
    rate = 250.0
    rng = np.random.default_rng(5)
    n = int(12 * rate)
    t = np.arange(n) / rate + rng.uniform(-0.05, 0.05, n) / rate
    t[1500:] += 0.5 / rate  # half a period: neither jitter nor lost samples
    _write(tmp_path, t)
    msg = _error(tmp_path)
    assert "line 1502, column 't'" in msg and "not a whole number of periods" in msg and "Cut the run" in msg


def test_split_at_gaps_must_be_a_boolean(tmp_path):
    _write(tmp_path, np.arange(3000) / 250.0, split_at_gaps="yes")
    assert "'split_at_gaps' = 'yes'; expected true or false" in _error(tmp_path)


SMALL = SynthConfig(voltages=(0.5, 1.0, 2.0, 4.5), random_runs=2, duration_s=40.0, pre_roll_s=30.0)


def _verdict(tmp_path: Path, effect: str, seed: int, rate: float, jitter: float, magnitude=None):
    cfg = dataclasses.replace(SMALL, sample_rate_hz=rate, time_jitter=jitter)
    syn = make_dataset(effect, seed=seed, magnitude=magnitude, config=cfg)
    folder = tmp_path / f"{effect}_{seed}_{rate:g}_{jitter:g}"
    write_dataset(folder, syn.runs, preset="brake", encoder_counts_per_rev=cfg.encoder_counts_per_rev)
    ds = load_dataset(folder)  # what a user's recording goes through
    res = analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=20))
    return res.effect, res.effects


@pytest.mark.parametrize(("effect", "seed", "rate"), [("position_friction_lower", 31, 250.0)])
def test_jittered_recording_gives_the_verdict_of_the_uniform_one(tmp_path, effect, seed, rate):
    uniform = _verdict(tmp_path, effect, seed, rate, 0.0, magnitude=0.1)
    jittered = _verdict(tmp_path, effect, seed, rate, MAX_JITTER, magnitude=0.1)
    assert uniform[0] == effect
    assert jittered == uniform


@pytest.mark.slow
@pytest.mark.parametrize(
    ("effect", "seed", "rate", "jitter"),
    [
        ("none", 32, 250.0, 0.1),
        ("none", 33, 1000.0, 0.05),
        ("friction_drift", 34, 500.0, 0.1),
        ("motor_inductance", 35, 1000.0, 0.1),
    ],
)
def test_jittered_recordings_at_several_seeds_and_rates(tmp_path, effect, seed, rate, jitter):
    assert _verdict(tmp_path, effect, seed, rate, jitter) == _verdict(tmp_path, effect, seed, rate, 0.0)


def test_synth_command_writes_a_jittered_recording(tmp_path):
    from typer.testing import CliRunner

    from drill_env.cli import app

    args = ["synth", "--effect", "none", "--seed", "3", "--duration", "12", "--voltages", "1.0,2.0"]
    args += ["--random-runs", "0", "--rate", "250", "--answer", str(tmp_path / "a.json")]
    r = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "bad"), "--time-jitter", "0.2"])
    assert r.exit_code == 2 and "time_jitter: 0.2 is outside [0, 0.1] periods" in r.output
    r = CliRunner().invoke(app, [*args, "--out", str(tmp_path / "data"), "--time-jitter", "0.08"])
    assert r.exit_code == 0, r.output
    runs = load_dataset(tmp_path / "data").runs
    assert all(0.05 < run.time_jitter <= 0.08 + 0.02 for run in runs)
    assert all(np.ptp(np.diff(run.t)) < 1e-9 for run in runs)
