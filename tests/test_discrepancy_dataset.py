"""The measured-data format: round trip, and every rejection names file, line and column."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drill_env.recordings.dataset import DatasetError, MeasuredRun, load_dataset, write_dataset

STEP = 2 * np.pi / 2000  # [rad] one count of the 2000-count encoder


def _run(name="run01", n=3001, dt=0.005, t0=12.5):
    t = t0 + dt * np.arange(n)
    th = np.floor(0.5 * (t - t0) / STEP) * STEP  # encoder readings: whole counts
    return MeasuredRun(name=name, t=t, u=np.full(n, 1.0), theta_u=th + 32 * STEP, theta_l=th)


@pytest.fixture
def folder(tmp_path):
    write_dataset(tmp_path, [_run("run01"), _run("run02")], preset="brake", encoder_counts_per_rev=2000)
    return tmp_path


def _rewrite(path, line_no, col, value):
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[line_no - 1].split(",")
    cells[header.index(col)] = value
    lines[line_no - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def test_round_trip(folder):
    ds = load_dataset(folder)
    assert ds.preset == "brake" and ds.encoder_counts_per_rev == 2000
    assert [r.name for r in ds.runs] == ["run01", "run02"]
    r = ds.runs[0]
    assert r.t[0] == pytest.approx(12.5) and r.dt == pytest.approx(0.005)
    assert r.is_constant_voltage and r.voltage == 1.0
    np.testing.assert_allclose(r.theta_u - r.theta_l, 32 * STEP, atol=1e-9)
    assert json.loads((folder / "dataset.json").read_text())["sample_rate_hz"] == pytest.approx(200.0)


@pytest.mark.parametrize(
    "line, col, value, words",
    [
        (10, "u", "nan", ["run01.csv", "line 10", "'u'", "not finite"]),
        (11, "theta_l", "inf", ["run01.csv", "line 11", "'theta_l'", "not finite"]),
        (12, "theta_u", "abc", ["run01.csv", "line 12", "'theta_u'", "not a number"]),
        (13, "theta_u", "", ["run01.csv", "line 13", "'theta_u'", "not a number"]),
        (20, "u", "5.5", ["run01.csv", "line 20", "'u'", "[-5, 5]"]),
        (30, "t", "12.0", ["run01.csv", "line 30", "'t'", "does not increase"]),
        (40, "t", f"{12.5 + 38 * 0.005 + 0.002:.6f}", ["run01.csv", "line 40", "'t'", "uniform"]),
        (50, "theta_l", "100.0", ["run01.csv", "line 50", "'theta_l'", "unwrapped"]),
    ],
)
def test_bad_cells_are_named(folder, line, col, value, words):
    _rewrite(folder / "run01.csv", line, col, value)
    with pytest.raises(DatasetError) as exc:
        load_dataset(folder)
    for w in words:
        assert w in str(exc.value), (w, str(exc.value))


def test_missing_and_unknown_columns(folder):
    p = folder / "run02.csv"
    text = p.read_text().splitlines()
    p.write_text("\n".join([",".join(c.split(",")[:3]) for c in text]) + "\n")
    with pytest.raises(
        DatasetError, match=r"run02.csv: line 1 \(header\): missing column\(s\) \['theta_l'\]"
    ):
        load_dataset(folder)
    p.write_text("\n".join([c + ",0" for c in text]).replace("theta_l,0", "theta_l,speed", 1) + "\n")
    with pytest.raises(DatasetError, match=r"unexpected column\(s\) \['speed'\]"):
        load_dataset(folder)


def test_ragged_row(folder):
    p = folder / "run01.csv"
    lines = p.read_text().splitlines()
    lines[5] += ",7"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="run01.csv: malformed CSV"):
        load_dataset(folder)


def test_sample_rate_limits(tmp_path):
    write_dataset(tmp_path, [_run(dt=0.02, n=1000)], preset="brake", encoder_counts_per_rev=2000)
    with pytest.raises(DatasetError, match=r"'sample_rate_hz' = 50.0; expected a number in \[100, 10000\]"):
        load_dataset(tmp_path)
    (tmp_path / "dataset.json").write_text('{"preset": "brake", "encoder_counts_per_rev": 2000}')
    with pytest.raises(
        DatasetError, match=r"sample rate 50 Hz is outside the allowed range \[100, 10000\] Hz"
    ):
        load_dataset(tmp_path)


def test_short_run(tmp_path):
    write_dataset(tmp_path, [_run(n=100)], preset="brake", encoder_counts_per_rev=2000)
    with pytest.raises(DatasetError, match="at least 10 s"):
        load_dataset(tmp_path)


@pytest.mark.parametrize(
    "meta, words",
    [
        ({"encoder_counts_per_rev": 2000}, ["dataset.json", "'preset' is missing"]),
        ({"preset": "brake"}, ["dataset.json", "'encoder_counts_per_rev' is missing"]),
        ({"preset": "rig9", "encoder_counts_per_rev": 2000}, ["'preset' = 'rig9'", "brake"]),
        ({"preset": "brake", "encoder_counts_per_rev": 20.5}, ["'encoder_counts_per_rev' = 20.5", "integer"]),
        ({"preset": "brake", "encoder_counts_per_rev": 2000, "sample_rate_hz": 300}, ["run01.csv", "300"]),
    ],
)
def test_bad_metadata(folder, meta, words):
    (folder / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError) as exc:
        load_dataset(folder)
    for w in words:
        assert w in str(exc.value), (w, str(exc.value))


def test_missing_metadata_and_runs(tmp_path):
    with pytest.raises(DatasetError, match="dataset.json: missing"):
        load_dataset(tmp_path)
    (tmp_path / "dataset.json").write_text('{"preset": "brake", "encoder_counts_per_rev": 2000}')
    with pytest.raises(DatasetError, match=r"no run files"):
        load_dataset(tmp_path)
    (tmp_path / "dataset.json").write_text('{"preset": "brake",')
    with pytest.raises(DatasetError, match="not valid JSON"):
        load_dataset(tmp_path)
