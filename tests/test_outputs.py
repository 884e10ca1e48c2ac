"""Results are never lost: one writer per output folder, files replaced whole, arguments
checked before anything is written, and a compiled-kernel cache that cannot go stale."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numba
import pytest
from typer.testing import CliRunner

import drill_env
from drill_env import _cache
from drill_env.agents.evaluation.benchmark import BenchmarkConfig, load_results, run_benchmark
from drill_env.agents.evaluation.episodes import EpisodeSettings
from drill_env.cli import app
from drill_env.outputs import (
    LOCK_NAME,
    OutputFolderBusy,
    OutputFolderError,
    atomic_file,
    atomic_write_text,
    output_lock,
)

ROOT = Path(__file__).resolve().parents[1]
TINY_EPISODE = EpisodeSettings(duration=6.0, window=3.0, warmup_time=4.0, warmup_jitter=1.0)


@pytest.fixture(scope="module")
def runner() -> CliRunner:
    return CliRunner()


class HeldInThread:
    """Holds ``output_lock(folder)`` in another thread (another writer) until released."""

    def __init__(self, folder: Path, what: str = "other run"):
        self.folder, self.what = folder, what
        self.held, self.done = threading.Event(), threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with output_lock(self.folder, self.what):
            self.held.set()
            self.done.wait(60)

    def __enter__(self) -> HeldInThread:
        self.thread.start()
        assert self.held.wait(10)
        return self

    def __exit__(self, *exc) -> None:
        self.done.set()
        self.thread.join(10)


def snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    return {
        str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


# -- the lock --------------------------------------------------------------------------------------


def test_lock_file_names_its_holder_and_is_removed_at_the_end(tmp_path):
    folder = tmp_path / "new" / "out"
    with output_lock(folder, "benchmark") as got:
        assert got == folder and folder.is_dir()
        holder = json.loads((folder / LOCK_NAME).read_text())
        assert holder["pid"] == os.getpid() and holder["host"] == socket.gethostname()
        assert holder["what"] == "benchmark" and holder["command"] and holder["started"]
        with output_lock(folder, "nested"):  # the same thread may nest
            pass
        assert (folder / LOCK_NAME).is_file()
    assert not (folder / LOCK_NAME).exists()


def test_a_second_writer_is_refused_with_the_folder_and_the_holder(tmp_path):
    with HeldInThread(tmp_path, "first benchmark"):
        with pytest.raises(OutputFolderBusy) as err:
            with output_lock(tmp_path, "second"):
                pytest.fail("entered a held folder")
        msg = str(err.value)
        assert isinstance(err.value, ValueError) and "\n" not in msg
        assert str(tmp_path) in msg and f"pid {os.getpid()}" in msg and "first benchmark" in msg
        assert str(tmp_path / LOCK_NAME) in msg  # what to delete if the holder is gone
        assert (tmp_path / LOCK_NAME).is_file()  # the holder's lock is untouched
    assert not (tmp_path / LOCK_NAME).exists()


def test_the_lock_is_released_after_an_exception(tmp_path):
    with pytest.raises(RuntimeError, match="boom"):
        with output_lock(tmp_path, "failing run"):
            raise RuntimeError("boom")
    assert not (tmp_path / LOCK_NAME).exists()
    with output_lock(tmp_path, "next run"):  # free again
        pass


def test_a_benchmark_that_fails_releases_its_folder(tmp_path):
    cfg = BenchmarkConfig(
        presets=("brake",),
        controllers=("open_loop",),
        voltages={"brake": (2.0,)},
        seeds=(0,),
        episode=TINY_EPISODE,
    )
    (tmp_path / "benchmark.csv").write_text("x\n")
    (tmp_path / "benchmark_config.json").write_text(json.dumps({"episode": {"duration": 1.0}}))
    with pytest.raises(ValueError, match="episode settings"):
        run_benchmark(cfg, tmp_path, backend="sequential")
    assert not (tmp_path / LOCK_NAME).exists()


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def _write_lock(folder: Path, **fields) -> None:
    record = {
        "pid": 1,
        "host": socket.gethostname(),
        "command": "drill-env benchmark --out x",
        "started": "2020-01-01 00:00:00 +0000",
        "what": "benchmark",
    }
    record.update(fields)
    (folder / LOCK_NAME).write_text(json.dumps(record))


def test_a_stale_lock_is_taken_over_with_a_warning(tmp_path):
    pid = _dead_pid()
    _write_lock(tmp_path, pid=pid)
    with pytest.warns(RuntimeWarning, match=rf"taking over the lock .*pid {pid}"):
        with output_lock(tmp_path, "new run"):
            assert json.loads((tmp_path / LOCK_NAME).read_text())["pid"] == os.getpid()
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no lock, nothing set aside left over
    # a lock with this very pid that this process does not hold: left by an earlier process
    # with the same pid (containers reuse pids)
    _write_lock(tmp_path, pid=os.getpid())
    with pytest.warns(RuntimeWarning, match="taking over"):
        with output_lock(tmp_path, "new run"):
            pass


def test_a_live_or_foreign_lock_is_not_taken_over(tmp_path):
    _write_lock(tmp_path, pid=_dead_pid(), host="another-host.example")  # cannot tell: refuse
    with pytest.raises(OutputFolderBusy, match="another-host.example"):
        with output_lock(tmp_path):
            pass
    parent = os.getppid()  # alive, not this process
    _write_lock(tmp_path, pid=parent, process_start=None)
    with pytest.raises(OutputFolderBusy, match=f"pid {parent}"):
        with output_lock(tmp_path):
            pass
    assert json.loads((tmp_path / LOCK_NAME).read_text())["pid"] == parent  # left as it was


def test_an_output_folder_that_cannot_be_made_is_a_clear_error(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputFolderError, match="cannot create the output folder"):
        with output_lock(tmp_path / "file" / "out"):
            pass


# -- files replaced whole --------------------------------------------------------------------------


def test_atomic_writes_use_unique_temporary_files_and_keep_the_old_file_on_error(tmp_path):
    target = tmp_path / "benchmark.csv"
    atomic_write_text(target, "old\n")
    os.chmod(target, 0o640)
    with atomic_file(target) as a, atomic_file(target) as b:  # two writers at once
        assert a.name != b.name and Path(a.name).parent == tmp_path
        a.write("from a\n")
        b.write("from b\n")
    assert target.read_text() == "from a\n"  # whole files only; a finished last and wins
    assert target.stat().st_mode & 0o777 == 0o640
    with pytest.raises(RuntimeError):
        with atomic_file(target) as f:
            f.write("half a file")
            raise RuntimeError("interrupted")
    assert target.read_text() == "from a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["benchmark.csv"]  # no temporary left


# -- the commands ----------------------------------------------------------------------------------


def test_concurrent_benchmarks_the_second_fails_and_the_first_is_complete(tmp_path, runner):
    cfg = BenchmarkConfig(
        presets=("brake",),
        controllers=("open_loop", "pi_upper"),
        voltages={"brake": (2.0,)},
        seeds=(0,),
        episode=TINY_EPISODE,
    )
    started, tried = threading.Event(), threading.Event()
    errors: list[BaseException] = []

    def progress(done, total, row):
        if not started.is_set():
            started.set()
            assert tried.wait(60)  # the other writer tries while this one runs

    def first():
        try:
            run_benchmark(cfg, tmp_path, backend="sequential", report=False, progress=progress)
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)

    thread = threading.Thread(target=first)
    thread.start()
    try:
        assert started.wait(60)
        with pytest.raises(OutputFolderBusy, match=str(tmp_path)):
            run_benchmark(cfg, tmp_path, backend="sequential", report=False, fresh=True)
        res = runner.invoke(
            app,
            [
                "benchmark",
                "--out",
                str(tmp_path),
                "--preset",
                "brake",
                "--controllers",
                "open_loop",
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
                "--fresh",
            ],
        )
        assert res.exit_code == 2, res.output
        assert "error:" in res.stderr and str(tmp_path) in res.stderr and "in use by another" in res.stderr
        assert "Traceback" not in res.output
    finally:
        tried.set()
        thread.join(120)
    assert not errors, errors
    df = load_results(tmp_path / "benchmark.csv")
    assert list(df["controller"]) == ["open_loop", "pi_upper"] and (df["error"] == "").all()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "benchmark.csv",
        "benchmark_config.json",
        "provenance.json",
    ]


@pytest.mark.parametrize(
    ("args", "mentions"),
    [
        (["--seeds", "0"], "--seeds must be an integer from 1 to 100"),
        (["--seeds", "-1"], "--seeds must be an integer from 1 to 100"),
        (["--seeds", "101"], "--seeds must be an integer from 1 to 100,"),
        (["--sweep-seeds", "0"], "--sweep-seeds must be an integer from 1 to 100"),
        (["--first-seed", "-1"], "--first-seed must be an integer from 0 to 97"),
        (["--seeds", "5", "--first-seed", "96"], "--first-seed must be an integer from 0 to 95"),
        (["--workers", "-1"], "--workers must be an integer from 0 (one per CPU core) to 256"),
        (["--workers", "257"], "--workers must be an integer from 0 (one per CPU core) to 256"),
        (["--paper-case-only", "--skip-paper-case"], "nothing to do"),
    ],
)
def test_discrepancy_study_refuses_bad_arguments_before_writing(tmp_path, runner, args, mentions):
    out = tmp_path / "discrepancy"
    (out / "paper_case").mkdir(parents=True)
    (out / "study.json").write_text('{"rows": [1, 2, 3]}\n')
    (out / "confusion.md").write_text("# committed\n")
    (out / "paper_case" / "paper_case.md").write_text("# committed\n")
    before = snapshot(out)
    time.sleep(0.01)
    res = runner.invoke(app, ["discrepancy-study", "--out", str(out), *args])
    assert res.exit_code == 2, res.output
    assert mentions in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert snapshot(out) == before  # untouched: same files, same bytes, same times


def test_discrepancy_study_on_a_held_folder_exits_2(tmp_path, runner):
    with HeldInThread(tmp_path, "discrepancy-study"):
        res = runner.invoke(app, ["discrepancy-study", "--out", str(tmp_path), "--skip-paper-case"])
    assert res.exit_code == 2, res.output
    assert str(tmp_path) in res.stderr and "in use by another" in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# -- the compiled-kernel cache ---------------------------------------------------------------------


def test_an_unusable_cache_dir_falls_back_to_a_private_one(tmp_path, monkeypatch):
    (tmp_path / "file").write_text("")
    bad = tmp_path / "file" / "cache"
    monkeypatch.setenv(_cache.ENV_VAR, str(bad))
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(numba.config, "CACHE_DIR", numba.config.CACHE_DIR)
    if hasattr(numba.config, "CACHE_LOCATOR_CLASSES"):
        monkeypatch.setattr(numba.config, "CACHE_LOCATOR_CLASSES", numba.config.CACHE_LOCATOR_CLASSES)
    monkeypatch.setattr("tempfile.tempdir", None)
    with pytest.warns(RuntimeWarning, match=rf"cannot use the numba cache directory {bad}.*Not a directory"):
        path = _cache.configure()
    assert numba.config.CACHE_DIR == str(path) and path.is_dir()
    assert path.parent.parent == tmp_path / "tmp" and path.name == _cache.source_hash()
    assert os.environ[_cache.ENV_VAR] == str(path.parent)  # worker processes share it


@pytest.mark.slow  # compiles every kernel of a simulation afresh (the in-process check above is in the default run)
def test_an_unusable_cache_dir_gives_a_warning_and_current_results_in_a_process(tmp_path):
    (tmp_path / "file").write_text("")
    bad = tmp_path / "file" / "cache"  # mkdir fails here, even as root
    (tmp_path / "tmp").mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update({_cache.ENV_VAR: str(bad), "TMPDIR": str(tmp_path / "tmp")})
    code = (
        "import json, numba, drill_env\n"
        "r = drill_env.simulate('brake', 2.0, 5.0)\n"
        "print(json.dumps({'cache': numba.config.CACHE_DIR, 'x3': r.x3.tolist()}))\n"
    )
    t0 = time.time()
    proc = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert "RuntimeWarning" in proc.stderr and f"cannot use the numba cache directory {bad}" in proc.stderr
    assert "Not a directory" in proc.stderr and "private temporary cache" in proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["cache"] and got["cache"].startswith(str(tmp_path / "tmp" / "drill-env-numba-"))
    assert got["x3"] == drill_env.simulate("brake", 2.0, 5.0).x3.tolist()
    assert list((tmp_path / "tmp").iterdir()) == []  # the private cache is gone at exit
    # nothing compiled into numba's default place beside the source (not keyed by the source hash)
    stray = [p for p in (ROOT / "drill_env").rglob("*.nb[ic]") if p.stat().st_mtime >= t0 - 1]
    assert stray == []


def test_fresh_run_folder_never_returns_an_existing_folder(tmp_path):
    from drill_env.outputs import OutputFolderError, fresh_run_folder

    made = [fresh_run_folder(tmp_path / "runs", "controllers") for _ in range(3)]
    assert len(set(made)) == 3 and all(p.is_dir() and not any(p.iterdir()) for p in made)
    assert all(p.parent == tmp_path / "runs" and p.name.startswith("controllers_") for p in made)
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputFolderError, match="cannot create the run folder"):
        fresh_run_folder(tmp_path / "file", "x")
