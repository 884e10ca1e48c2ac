"""The measured-data loader on hostile files: every one is named, none hangs or is read whole,
time stamps are judged at the resolution they are printed with, and the angles must be whole
encoder counts. Byte-level corruptions either load or raise DatasetError (hypothesis)."""

from __future__ import annotations

import json
import os
import signal
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drill_env.recordings.dataset import (
    MAX_RUN_BYTES,
    DatasetError,
    MeasuredDataset,
    MeasuredRun,
    load_dataset,
    write_dataset,
)

COUNTS = 2000
STEP = 2 * np.pi / COUNTS  # [rad] one encoder count


def _angles(t: np.ndarray, speed: float = 0.7) -> np.ndarray:
    """Encoder readings of a disk turning at ``speed`` [rad/s] with a wobble: whole counts."""
    th = speed * (t - t[0]) + 0.05 * np.sin(3.0 * (t - t[0]))
    return np.floor(th / STEP) * STEP


def _write_csv(path: Path, t: np.ndarray, t_fmt: str = "%.12g", theta_u=None, theta_l=None) -> None:
    theta_l = _angles(t) if theta_l is None else theta_l
    theta_u = theta_l + 40 * STEP if theta_u is None else theta_u
    lines = ["t,u,theta_u,theta_l"]
    lines += [f"{t_fmt % ti},1.5,{tu:.12g},{tl:.12g}" for ti, tu, tl in zip(t, theta_u, theta_l, strict=True)]
    path.write_text("\n".join(lines) + "\n")


def _meta(folder: Path, **extra) -> None:
    (folder / "dataset.json").write_text(
        json.dumps({"preset": "brake", "encoder_counts_per_rev": COUNTS, **extra})
    )


@pytest.fixture
def folder(tmp_path):
    _meta(tmp_path)
    t = 3.0 + 0.01 * np.arange(1201)  # 100 Hz, 12 s
    _write_csv(tmp_path / "run01.csv", t)
    return tmp_path


def _error(folder) -> str:
    with pytest.raises(DatasetError) as exc:
        load_dataset(folder)
    msg = str(exc.value)
    assert "\n" not in msg and "np.float64" not in msg, msg
    return msg


# -- file names and kinds ----------------------------------------------------------------------


def test_an_upper_case_suffix_is_a_run(folder):
    (folder / "run01.csv").rename(folder / "RUN01.CSV")
    assert [r.name for r in load_dataset(folder).runs] == ["RUN01"]


def test_two_files_of_one_run_name_are_refused(folder):
    (folder / "run01.CSV").write_bytes((folder / "run01.csv").read_bytes())
    if len(list(folder.iterdir())) < 3:
        pytest.skip("case-insensitive file system")
    assert "two run files named 'run01'" in _error(folder)


@pytest.mark.parametrize(
    ("name", "content", "words"),
    [
        ("run02.csv", b"t,u,theta_u,theta_l\n\x00\x01\x02\x03", ["run02.csv", "binary", "line 2"]),
        ("run02.csv", "t,u,theta_u,theta_l\n0,1,2,3\n".encode("utf-16"), ["run02.csv", "UTF-16"]),
        ("run02.csv", b"t,u,theta_u,theta_l\n0,1,\xe9,3\n", ["run02.csv", "not UTF-8", "line 2"]),
        # the metadata file macOS leaves beside a copied file
        ("._run01.csv", b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X", ["._run01.csv", "macOS metadata"]),
    ],
)
def test_files_that_are_not_utf8_text_are_named(folder, name, content, words):
    (folder / name).write_bytes(content)
    msg = _error(folder)
    for w in words:
        assert w in msg, (w, msg)


def test_a_folder_named_like_a_run(folder):
    (folder / "x.csv").mkdir()
    msg = _error(folder)
    assert "x.csv" in msg and "a folder" in msg


def test_a_dangling_link(folder):
    (folder / "gone.csv").symlink_to(folder / "nowhere.csv")
    msg = _error(folder)
    assert "gone.csv" in msg and "dangling link" in msg


@pytest.fixture
def alarm():
    """Fail instead of hanging: a reader blocked on a FIFO is interrupted after 20 s."""

    def stop(*_):
        raise TimeoutError("the loader blocked")

    old = signal.signal(signal.SIGALRM, stop)
    signal.alarm(20)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_is_refused_without_blocking(folder, alarm):
    os.mkfifo(folder / "live.csv")
    msg = _error(folder)
    assert "live.csv" in msg and "not a regular file" in msg
    (folder / "live.csv").unlink()
    os.mkfifo(folder / "dataset.json.tmp")
    (folder / "dataset.json").unlink()
    (folder / "dataset.json").symlink_to(folder / "dataset.json.tmp")
    msg = _error(folder)
    assert "dataset.json" in msg and "not a regular file" in msg


def test_a_huge_sparse_file_is_refused_unread(folder):
    with open(folder / "run02.csv", "wb") as f:
        f.truncate(MAX_RUN_BYTES + 1)  # sparse: no disk used, and never read
    msg = _error(folder)
    assert "run02.csv" in msg and str(MAX_RUN_BYTES + 1) in msg


@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda p: p.write_bytes(b"\xff\xfe{\x00}\x00"), ["dataset.json", "UTF-16"]),
        (lambda p: p.write_bytes(b'{"preset": "brake\xe9"}'), ["dataset.json", "not UTF-8"]),
        (lambda p: p.mkdir(), ["dataset.json", "a folder"]),
        (lambda p: p.write_text("[" * 100_000), ["dataset.json", "not valid JSON"]),
        (
            lambda p: p.write_text('{"preset": "brake", "encoder_counts_per_rev": 1' + "0" * 5000 + "}"),
            ["dataset.json"],
        ),
        (lambda p: p.write_text('{"preset": ["brake"], "encoder_counts_per_rev": 2000}'), ["'preset'"]),
    ],
)
def test_bad_metadata_files_are_named(folder, make, words):
    (folder / "dataset.json").unlink()
    make(folder / "dataset.json")
    msg = _error(folder)
    for w in words:
        assert w in msg, (w, msg)


# -- line numbers ------------------------------------------------------------------------------


@pytest.mark.parametrize("end", ["\n", "\r\n"])
def test_blank_lines_keep_the_line_numbers_of_the_file(folder, end):
    p = folder / "run01.csv"
    lines = p.read_text().splitlines()
    lines[20] = lines[20].replace(",1.5,", ",7.5,")  # line 21 of the file as written
    lines.insert(5, "")
    lines.insert(9, " \t ")
    lines.insert(0, "")
    p.write_bytes((end.join(lines) + end + "  " + end).encode())
    msg = _error(folder)
    assert "line 24, column 'u'" in msg and "7.5 V" in msg


def test_a_gap_in_time_is_named_where_it_is(folder):
    t = 3.0 + 0.01 * np.arange(6001)
    t[4998:] += 0.5  # data row 4998 is line 5000
    _write_csv(folder / "run01.csv", t)
    msg = _error(folder)
    assert "line 5000, column 't'" in msg and "0.51 s" in msg and "line 4999" in msg


def test_a_repeated_time_stamp_prints_plain_numbers(folder):
    t = 40.0 + 0.004 * np.arange(3001)
    t[2083] = t[2082]
    _write_csv(folder / "run01.csv", t)
    msg = _error(folder)
    assert f"time {float(t[2082])!r} s does not increase" in msg and "line 2085" in msg


# -- the time stamps' resolution ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("rate", "t0", "fmt"),
    [
        (5000.0, 1_700_000_000.0, "%.6f"),  # Unix time at 5 kHz: float resolution 2.4e-7 s
        (10_000.0, 1_700_000_000.0, "%.6f"),
        (2048.0, 0.0, "%.6f"),  # 2048 Hz, printed with 6 decimals
        (2048.0, 1_700_000_000.0, "%.6f"),
        (1000.0, 1_700_000_000.0, "%.17g"),  # every digit of the double
    ],
)
def test_uniform_time_stamps_at_their_printed_resolution_are_accepted(tmp_path, rate, t0, fmt):
    _meta(tmp_path)
    n = int(10.5 * rate)
    t = t0 + np.arange(n) / rate
    _write_csv(tmp_path / "run01.csv", t, t_fmt=fmt)
    run = load_dataset(tmp_path).runs[0]
    assert 1.0 / run.dt == pytest.approx(rate, rel=1e-6)
    # a real glitch of 10 % of a period is still found, on its line
    t_bad = t.copy()
    t_bad[n // 2 :] += 0.1 / rate
    _write_csv(tmp_path / "run01.csv", t_bad, t_fmt=fmt)
    assert f"line {n // 2 + 2}, column 't'" in _error(tmp_path)


def test_time_stamps_printed_too_coarsely_for_the_rate(tmp_path):
    _meta(tmp_path)
    t = 1_700_000_000.0 + np.arange(21000) / 2000.0
    _write_csv(tmp_path / "run01.csv", t, t_fmt="%.3f")  # 1 ms digits at 0.5 ms sampling
    msg = _error(tmp_path)
    assert "column 't'" in msg


# -- the encoder grid ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("counts", "words"),
    [
        (1, ["not a whole number", "'encoder_counts_per_rev' = 1"]),
        (1000, ["not a whole number", "'encoder_counts_per_rev' = 1000"]),
        (3000, ["not a whole number"]),
        (4000, ["multiple of 2 counts", "2000 counts per revolution"]),
        (10_000, ["multiple of 5 counts", "2000 counts per revolution"]),
    ],
)
def test_a_wrong_encoder_count_does_not_fit_the_angles(folder, counts, words):
    _meta(folder, encoder_counts_per_rev=counts)
    msg = _error(folder)
    for w in words:
        assert w in msg, (w, msg)


def test_the_right_encoder_count_loads_angles_printed_with_6_decimals(tmp_path):
    _meta(tmp_path)
    t = 0.002 * np.arange(6001)
    th = _angles(t)
    lines = ["t,u,theta_u,theta_l"] + [
        f"{a:.3f},1,{b + 9 * STEP:.6f},{b:.6f}" for a, b in zip(t, th, strict=True)
    ]
    (tmp_path / "run01.csv").write_text("\n".join(lines) + "\n")
    ds = load_dataset(tmp_path)
    assert ds.encoder_counts_per_rev == COUNTS
    np.testing.assert_allclose(ds.runs[0].theta_l, th, atol=5e-7)


def test_synthetic_data_of_other_encoders_loads(tmp_path):
    # encoder grids the loader was not written against: 4096 and 1024 counts
    for counts in (4096, 1024):
        step = 2 * np.pi / counts
        t = 5.0 + 0.002 * np.arange(6001)
        th = np.floor((0.9 * t + 0.3) / step) * step
        run = MeasuredRun(name=f"c{counts}", t=t, u=np.full(t.size, 2.0), theta_u=th + 5 * step, theta_l=th)
        write_dataset(tmp_path / str(counts), [run], preset="no_brake", encoder_counts_per_rev=counts)
        assert load_dataset(tmp_path / str(counts)).encoder_counts_per_rev == counts


# -- random corruption -----------------------------------------------------------------------------


def _valid_dataset() -> tuple[bytes, bytes]:
    with tempfile.TemporaryDirectory() as d:
        t = 7.25 + 0.01 * np.arange(1051)
        _write_csv(Path(d) / "run01.csv", t)
        csv = (Path(d) / "run01.csv").read_bytes()
    meta = json.dumps({"preset": "brake", "encoder_counts_per_rev": COUNTS, "sample_rate_hz": 100}).encode()
    return csv, meta


CSV, META = _valid_dataset()

_edits = st.lists(
    st.tuples(
        st.sampled_from(["flip", "set", "insert", "delete", "truncate", "duplicate_line"]),
        st.floats(0.0, 1.0, allow_nan=False),
        st.binary(min_size=1, max_size=8),
    ),
    min_size=1,
    max_size=4,
)


def _corrupt(data: bytes, edits) -> bytes:
    b = bytearray(data)
    for kind, where, payload in edits:
        i = min(int(where * len(b)), max(len(b) - 1, 0))
        if kind == "flip" and b:
            b[i] ^= 1 << (payload[0] % 8)
        elif kind == "set" and b:
            b[i] = payload[0]
        elif kind == "insert":
            b[i:i] = payload
        elif kind == "delete":
            del b[i : i + 1 + payload[0] % 64]
        elif kind == "truncate":
            del b[i:]
        elif kind == "duplicate_line":
            start = b.rfind(b"\n", 0, i) + 1
            end = b.find(b"\n", i)
            end = len(b) if end < 0 else end + 1
            b[end:end] = b[start:end]
    return bytes(b)


def _load_corrupted(edits_csv, edits_meta) -> None:
    with tempfile.TemporaryDirectory() as d:
        Path(d, "run01.csv").write_bytes(_corrupt(CSV, edits_csv))
        Path(d, "dataset.json").write_bytes(_corrupt(META, edits_meta))
        try:
            ds = load_dataset(d)
        except DatasetError as exc:
            assert str(exc) and "\n" not in str(exc) and "np.float64" not in str(exc)
        else:
            assert isinstance(ds, MeasuredDataset) and ds.runs[0].t.size >= 2


def test_the_uncorrupted_dataset_loads():
    _load_corrupted([], [])
    with tempfile.TemporaryDirectory() as d:
        Path(d, "run01.csv").write_bytes(CSV)
        Path(d, "dataset.json").write_bytes(META)
        assert load_dataset(d).runs[0].t.size == 1051


@settings(max_examples=60)
@given(edits_csv=_edits, edits_meta=st.one_of(st.just([]), _edits))
def test_corrupted_files_load_or_raise_the_documented_error(edits_csv, edits_meta):
    _load_corrupted(edits_csv, edits_meta)


@pytest.mark.slow
@settings(max_examples=2000)
@given(edits_csv=_edits, edits_meta=st.one_of(st.just([]), _edits))
def test_corrupted_files_load_or_raise_the_documented_error_long(edits_csv, edits_meta):
    _load_corrupted(edits_csv, edits_meta)


# -- probes of adversarial round 3: refused naming the line -------------------------------------------


def test_cr_only_line_ends_are_refused_naming_the_line(folder):
    p = folder / "run01.csv"
    p.write_bytes(p.read_bytes().replace(b"\n", b"\r"))
    msg = _error(folder)
    assert msg.startswith("run01.csv: line 1, column 20: a CR that ends no CR LF pair"), msg
    # a stray CR inside an LF file: its own line
    lines = (folder / "run01.csv").read_bytes().replace(b"\r", b"\n").split(b"\n")
    lines[6] = lines[6].replace(b",1.5,", b",1.5\r,")
    p.write_bytes(b"\n".join(lines))
    assert "line 7," in _error(folder)


def test_quoted_numbers_are_refused_naming_the_line(folder):
    p = folder / "run01.csv"
    lines = p.read_text().splitlines()
    lines[11] = lines[11].replace(",1.5,", ',"1.5",')
    p.write_text("\n".join(lines) + "\n")
    msg = _error(folder)
    assert msg.startswith("run01.csv: line 12, column ") and "quoted field" in msg, msg


def test_quoted_numbers_and_duplicate_keys_in_dataset_json_are_refused(folder):
    (folder / "dataset.json").write_text('{"preset": "brake", "encoder_counts_per_rev": "2000"}')
    assert "'encoder_counts_per_rev' = '2000'; expected an integer" in _error(folder)
    (folder / "dataset.json").write_text(
        '{"preset": "brake",\n "encoder_counts_per_rev": 2000,\n "encoder_counts_per_rev": 4000}'
    )
    msg = _error(folder)
    assert "'encoder_counts_per_rev' appears twice (line 3)" in msg, msg


@pytest.mark.parametrize("command", ["identify", "discrepancy"])
def test_identify_and_discrepancy_refuse_such_datasets_in_one_line(folder, command):
    from typer.testing import CliRunner

    from drill_env.cli import app

    p = folder / "run01.csv"
    p.write_bytes(p.read_bytes().replace(b"\n", b"\r"))
    res = CliRunner().invoke(app, [command, str(folder), "--out", str(folder.parent / "out")])
    assert res.exit_code == 2, res.output
    errors = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and "CR LF" in errors[0] and "line 1" in errors[0], res.output
    assert "Traceback" not in res.output
