"""The output rule, probe by probe: nothing is written where it was not asked.

Each test runs a command as a user runs it (the CLI) or calls the library writer it goes
through, then looks at the file system: planted links are refused and their targets left
alone, a folder holding another command's outputs or a dataset is refused, an unusable
partial file is one line naming ``--fresh``, a write error (a full disk, simulated) names the
path and leaves no lock, temporary or 0-byte file behind.
"""

from __future__ import annotations

import errno
import json
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from file_tree import one_error_line, tree
from typer.testing import CliRunner

from drill_env.cli import app
from drill_env.outputs import (
    LOCK_NAME,
    MARKER_NAME,
    OutputFolderError,
    OutputWriteError,
    atomic_path,
    atomic_write_json,
    atomic_write_text,
    check_output_file,
    command_folder,
    output_lock,
    save_figure,
)


@pytest.fixture
def runner() -> CliRunner:
    return CliRunner()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A small recorded-like dataset (two constant-voltage runs) written as `synth` writes one."""
    from drill_env.recordings.synth import SynthConfig, make_dataset, write_synthetic

    root = tmp_path_factory.mktemp("data")
    cfg = SynthConfig(voltages=(1.0, 3.0), random_runs=0, duration_s=10.0, pre_roll_s=2.0)
    res = make_dataset("none", seed=3, config=cfg)
    write_synthetic(res, root / "data", root / "answer.json", preset="brake")
    return root / "data"


def _victim(tmp_path: Path) -> Path:
    victim = tmp_path / "elsewhere" / "victim.txt"
    victim.parent.mkdir()
    victim.write_text("the user's own file\n")
    return victim


# -- planted links ---------------------------------------------------------------------------------


def test_identify_refuses_a_planted_link_and_leaves_its_target(tmp_path, runner, dataset):
    victim = _victim(tmp_path)
    out = tmp_path / "o2"
    out.mkdir()
    (out / "friction.png").symlink_to(victim)
    res = runner.invoke(app, ["identify", str(dataset), "--out", str(out), "--no-bifurcation"])
    line = one_error_line(res)
    assert "friction.png" in line and "symbolic link" in line
    assert victim.read_text() == "the user's own file\n"
    assert tree(out) == {"friction.png": f"link -> {victim}"}  # nothing added, nothing replaced


@pytest.mark.parametrize(
    "command",
    [
        ["train", "--algo", "ppo", "--config", "ppo", "--out", "{out}", "--run-dir", "{out}/../logs"],
        ["benchmark", "--out", "{out}", "--controllers", "open_loop", "--quick"],
        ["bifurcation", "--out", "{out}"],
        ["discrepancy", "{data}", "--out", "{out}"],
        ["discrepancy-study", "--out", "{out}", "--fresh", "--skip-paper-case"],
        ["sim-to-real", "--quick", "--out", "{out}"],
    ],
    ids=lambda c: c[0],
)
def test_every_command_refuses_a_link_in_its_output_folder(tmp_path, runner, dataset, command):
    victim = _victim(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    names = {
        "train": "policy.zip",
        "benchmark": "summary.md",
        "bifurcation": "bifurcation.json",
        "discrepancy": "model.yaml",
        "discrepancy-study": "study_rows.partial.jsonl",
        "sim-to-real": "truth.yaml",
    }
    (out / names[command[0]]).symlink_to(victim)
    args = [a.format(out=out, data=dataset) for a in command]
    line = one_error_line(runner.invoke(app, args))
    assert "symbolic link" in line and names[command[0]] in line
    assert victim.read_text() == "the user's own file\n"
    assert tree(out) == {names[command[0]]: f"link -> {victim}"}


def test_train_refuses_a_link_in_its_logs_folder(tmp_path, runner):
    victim = _victim(tmp_path)
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "final_policy.zip").symlink_to(victim)
    args = [
        "train",
        "--algo",
        "ppo",
        "--config",
        "ppo",
        "--out",
        str(tmp_path / "ppo"),
        "--run-dir",
        str(logs),
    ]
    line = one_error_line(runner.invoke(app, args))
    assert "--run-dir" in line and "final_policy.zip" in line
    assert victim.read_text() == "the user's own file\n"
    assert not (tmp_path / "ppo").exists()  # nothing created before the inputs were checked


@pytest.mark.parametrize("command", ["simulate", "rig-comparison"])
def test_a_link_as_the_output_file_is_refused(tmp_path, runner, command):
    victim = _victim(tmp_path)
    link = tmp_path / ("run.csv" if command == "simulate" else "rc.md")
    link.symlink_to(victim)
    args = [command, "--out", str(link)] + (["--duration", "1"] if command == "simulate" else [])
    line = one_error_line(runner.invoke(app, args))
    assert "symbolic link" in line
    assert victim.read_text() == "the user's own file\n"


def _write_figure(path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 2))
    fig.add_subplot().plot([0, 1], [0, 1])
    save_figure(fig, path, dpi=50)


def _write_policy_like(path: Path) -> None:
    with atomic_path(path, suffix=".zip") as tmp:
        tmp.write_bytes(b"PK")


@pytest.mark.parametrize(
    "write",
    [
        _write_figure,
        lambda p: atomic_write_text(p, "text"),
        lambda p: atomic_write_json(p, {"a": 1}),
        _write_policy_like,
        lambda p: __import__("drill_env.params", fromlist=["x"]).resolve_params("brake").to_yaml(p),
        lambda p: check_output_file(p),
    ],
    ids=["figure", "text", "json", "zip", "rig-yaml", "checked-file"],
)
def test_no_writer_follows_a_link(tmp_path, write):
    victim = _victim(tmp_path)
    link = tmp_path / "out.png"
    link.symlink_to(victim)
    with pytest.raises(OutputFolderError, match="symbolic link"):
        write(link)
    assert victim.read_text() == "the user's own file\n"
    assert link.is_symlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere", "out.png"]  # no temporary left


def test_the_writers_write_whole_files(tmp_path):
    _write_figure(tmp_path / "f.png")
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    _write_figure(tmp_path / "f.svg")
    assert b"<svg" in (tmp_path / "f.svg").read_bytes()[:400]
    atomic_write_json(tmp_path / "a.json", {"k": [1, 2]})
    assert json.loads((tmp_path / "a.json").read_text()) == {"k": [1, 2]}
    _write_policy_like(tmp_path / "p.zip")
    assert (tmp_path / "p.zip").read_bytes() == b"PK"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "f.png", "f.svg", "p.zip"]


# -- one command's outputs per folder --------------------------------------------------------------


def test_sim_to_real_data_refuses_an_existing_dataset(tmp_path, runner, dataset):
    data = tmp_path / "mixdata"
    data.mkdir()
    for p in dataset.iterdir():
        (data / p.name).write_bytes(p.read_bytes())
    (data / "notes.txt").write_text("x\n")
    before = tree(data)
    res = runner.invoke(app, ["sim-to-real", "--quick", "--data", str(data), "--out", str(tmp_path / "s2r")])
    line = one_error_line(res)
    assert "--data" in line and "not empty" in line
    assert tree(data) == before  # no run replaced, none added
    assert not (tmp_path / "s2r").exists()


def test_a_folder_of_another_command_or_a_dataset_is_refused(tmp_path, runner, dataset):
    ident = tmp_path / "shared"
    ident.mkdir()
    (ident / MARKER_NAME).write_text(json.dumps({"command": "identify"}))
    (ident / "report.md").write_text("identify's report\n")
    res = runner.invoke(app, ["discrepancy", str(dataset), "--out", str(ident)])
    line = one_error_line(res)
    assert "`drill-env identify`" in line
    assert (ident / "report.md").read_text() == "identify's report\n"
    # a discrepancy output from before folders had markers: its files tell
    legacy = tmp_path / "legacy"
    legacy.mkdir()
    (legacy / "report.md").write_text("discrepancy's report\n")
    (legacy / "result.json").write_text("{}\n")
    line = one_error_line(runner.invoke(app, ["identify", str(dataset), "--out", str(legacy)]))
    assert "result.json" in line
    assert (legacy / "report.md").read_text() == "discrepancy's report\n"
    # a dataset is never an output folder
    before = tree(dataset)
    line = one_error_line(runner.invoke(app, ["bifurcation", "--out", str(dataset)]))
    assert "holds a dataset" in line
    assert tree(dataset) == before


def test_a_refused_run_leaves_no_output_folder(tmp_path, runner):
    empty = tmp_path / "not_a_dataset"
    empty.mkdir()
    for command in (["identify", str(empty)], ["discrepancy", str(empty)]):
        out = tmp_path / f"out_{command[0]}"
        res = runner.invoke(app, [*command, "--out", str(out)])
        assert res.exit_code == 2, res.output
        assert not out.exists(), sorted(p.name for p in out.iterdir())


def test_command_folder_marks_its_folder_and_removes_it_when_left_empty(tmp_path):
    with command_folder(tmp_path / "a" / "b", "identify") as folder:
        assert json.loads((folder / MARKER_NAME).read_text())["command"] == "identify"
        atomic_write_text(folder / "report.md", "r")
    assert sorted(p.name for p in folder.iterdir()) == [MARKER_NAME, "report.md"]
    with command_folder(folder, "identify"):  # its own folder again: accepted
        pass
    with pytest.raises(OutputFolderError, match="`drill-env identify`"):
        with command_folder(folder, "discrepancy"):
            pass
    with pytest.raises(ValueError, match="refused inside"):
        with command_folder(tmp_path / "c" / "d", "identify"):
            raise ValueError("refused inside")
    assert not (tmp_path / "c").exists()


# -- faults leave nothing that misleads ------------------------------------------------------------


def _full_disk(monkeypatch) -> None:
    """Every file write of the output layer fails as on a full disk (at its flush to disk)."""
    import drill_env.outputs as outputs

    def fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(outputs.os, "fsync", fsync)


def test_a_full_disk_removes_what_the_run_created(tmp_path, monkeypatch):
    old = tmp_path / "old"
    with command_folder(old, "identify"):
        atomic_write_text(old / "report.md", "the earlier report\n")
    with command_folder(old, "identify"):  # a second run: its report cannot be written
        _full_disk(monkeypatch)
        with pytest.raises(OutputWriteError, match=r"cannot write .*report\.md: No space left on device"):
            atomic_write_text(old / "report.md", "the new report\n")
        monkeypatch.undo()
    assert (old / "report.md").read_text() == "the earlier report\n"  # replaced whole or not at all
    assert sorted(p.name for p in old.iterdir()) == [MARKER_NAME, "report.md"]  # no lock, no temporary
    new = tmp_path / "new"
    with pytest.raises(OutputWriteError, match="figure.png"):
        with command_folder(new, "identify"):
            atomic_write_text(new / "rig.yaml", "a: 1\n")
            _full_disk(monkeypatch)
            _write_figure(new / "figure.png")
    monkeypatch.undo()
    assert not new.exists()  # rig.yaml, the marker, the lock and the folder: all gone
    _full_disk(monkeypatch)
    with pytest.raises(OutputWriteError, match=LOCK_NAME):
        with command_folder(tmp_path / "fresh", "identify"):
            pass
    assert not (tmp_path / "fresh").exists()


def test_a_full_disk_in_a_command_names_the_path_and_leaves_no_file(tmp_path, runner, monkeypatch):
    _full_disk(monkeypatch)
    out = tmp_path / "sim" / "run.csv"
    res = runner.invoke(app, ["simulate", "--duration", "2", "--out", str(out)])
    line = one_error_line(res)
    assert str(out) in line and "No space left on device" in line
    assert list(tmp_path.rglob("*")) == []  # the folder it made is gone too
    assert not out.exists()


def test_a_real_write_error_is_named_and_leaves_no_temporary(tmp_path):
    """A genuine write error of the OS: a file-size limit (RLIMIT_FSIZE) below the file's size."""
    resource = pytest.importorskip("resource")
    script = textwrap.dedent(
        f"""
        import resource, signal
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
        from drill_env.outputs import atomic_write_bytes, OutputWriteError
        try:
            atomic_write_bytes({str(tmp_path / "big.bin")!r}, b"x" * 100_000)
        except OutputWriteError as exc:
            print("ERR", exc)
        """
    )
    assert resource  # used by the child
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.stdout.startswith("ERR cannot write"), proc.stdout + proc.stderr
    assert "big.bin" in proc.stdout
    assert list(tmp_path.iterdir()) == []


def test_a_lock_that_cannot_be_written_is_not_left_behind(tmp_path, monkeypatch):
    import drill_env.outputs as outputs

    def write_all(fd, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(outputs, "_write_all", write_all)
    with pytest.raises(OutputWriteError, match=rf"{LOCK_NAME}: No space left on device"):
        with output_lock(tmp_path / "out", "benchmark"):
            pass
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("content", [b"", b"\x00\x00garbage"])
def test_an_empty_or_unreadable_lock_of_a_dead_run_is_taken_over(tmp_path, content):
    (tmp_path / LOCK_NAME).write_bytes(content)  # a full disk's 0-byte lock, or a damaged one
    with pytest.warns(RuntimeWarning, match="taking over the lock"):
        with output_lock(tmp_path, "next run"):
            holder = json.loads((tmp_path / LOCK_NAME).read_text())
            assert holder["pid"] == os.getpid()
    assert list(tmp_path.iterdir()) == []


def test_an_empty_lock_held_by_a_live_run_is_not_taken_over(tmp_path):
    """A run that holds the kernel lock (another process) keeps its folder, empty file or not."""
    import fcntl

    lock = tmp_path / LOCK_NAME
    lock.write_bytes(b"")
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import fcntl, sys, time; f = open(sys.argv[1], 'rb'); fcntl.flock(f, fcntl.LOCK_EX); "
            "print('held', flush=True); time.sleep(60)",
            str(lock),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        from drill_env.outputs import OutputFolderBusy

        with pytest.raises(OutputFolderBusy, match="unknown run"):
            with output_lock(tmp_path, "second"):
                pass
        assert lock.exists()
    finally:
        holder.kill()
        holder.wait()
    assert fcntl  # POSIX only


# -- resume that cannot crash ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "content",
    [
        b"",
        b"garbage, not JSON\n",
        b"\xff\xfe\x00binary\n",
        b'["a", "list"]\n',
        b'{"design": {"seeds": 99}, "code": "0123456789abcdef"}\n{"index": 0, "row": {}}\n',
    ],
    ids=["empty", "garbage", "binary", "foreign", "other-grid"],
)
def test_discrepancy_study_refuses_an_unusable_partial_file_in_one_line(tmp_path, runner, content):
    out = tmp_path / "study"
    out.mkdir()
    partial = out / "study_rows.partial.jsonl"
    partial.write_bytes(content)
    args = ["discrepancy-study", "--out", str(out), "--seeds", "1", "--sweep-seeds", "1"]
    line = one_error_line(runner.invoke(app, [*args, "--workers", "1", "--skip-paper-case"]))
    assert str(partial) in line and "--fresh" in line
    assert partial.read_bytes() == content  # kept for the user to decide
    assert not (out / LOCK_NAME).exists()


def test_the_partial_file_starts_with_its_header_before_the_first_row(tmp_path, monkeypatch):
    """A study killed before its first dataset lands leaves a file the same command resumes."""
    import drill_env.discrepancy.study as study

    seen = {}

    def stop(jobs, *args, **kwargs):
        seen["text"] = (tmp_path / study.PARTIAL_ROWS).read_text()
        raise KeyboardInterrupt

    monkeypatch.setattr(study, "_run_jobs", stop)
    with pytest.raises(KeyboardInterrupt):
        study.run_study(tmp_path, seeds=1, sweep_seeds=1, workers=1)
    header = json.loads(seen["text"].splitlines()[0])
    assert set(header) == {"design", "code"}
    monkeypatch.setattr(study, "_run_jobs", stop)
    with pytest.raises(KeyboardInterrupt):  # resumes from it: no error about the file
        study.run_study(tmp_path, seeds=1, sweep_seeds=1, workers=1, resume=True)


# -- an unreachable Ray address --------------------------------------------------------------------


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("command", ["discrepancy-study", "benchmark"])
def test_a_ray_address_nothing_answers_at_is_refused(tmp_path, runner, command):
    address = f"127.0.0.1:{_closed_port()}"
    args = [command, "--out", str(tmp_path / "o"), "--backend", "ray", "--ray-address", address]
    if command == "benchmark":
        args += ["--quick", "--controllers", "open_loop"]
    line = one_error_line(runner.invoke(app, args))
    assert "--ray-address" in line and address in line
    assert not (tmp_path / "o").exists()


def test_a_ray_address_that_does_not_answer_is_named_with_the_wait(monkeypatch):
    import drill_env.ray_cluster as rc

    waited = []

    def silent(address, timeout):
        waited.append(timeout)
        raise TimeoutError("timed out")

    monkeypatch.setattr(socket, "create_connection", silent)
    with pytest.raises(
        ValueError, match=r"nothing answers at ray://10\.0\.0\.9:6379 \(no answer within 10 s\)"
    ):
        rc.check_ray_address("ray://10.0.0.9:6379")
    assert waited == [rc.CONNECT_TIMEOUT_S] and rc.CONNECT_TIMEOUT_S <= 30


class _DeafRayAddress:
    """A local address where no Ray cluster answers, as a user meets one: ``blackhole`` (an
    unreachable host: the connection is never accepted -- a listening socket whose backlog is
    full drops every new SYN) or ``silent`` (a host that accepts and never says anything)."""

    def __init__(self, kind: str):
        import threading

        self.kind = kind
        self.accepted = 0
        self._server = socket.socket()
        self._server.bind(("127.0.0.1", 0))
        self.port = self._server.getsockname()[1]
        self._held: list[socket.socket] = []
        if kind == "blackhole":
            self._server.listen(0)
            filler = socket.socket()
            filler.connect(("127.0.0.1", self.port))  # fills the backlog; never accepted
            self._held.append(filler)
        else:
            self._server.listen(8)
            threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self._server.accept()
            except OSError:
                return
            self._held.append(conn)
            self.accepted += 1

    def waiting(self) -> bool:
        """True once the command waits on this address (connected, or trying to connect)."""
        if self.kind == "silent":
            return self.accepted >= 2  # the connection check, then Ray's request
        try:
            table = Path("/proc/net/tcp").read_text()
        except OSError:
            pytest.skip("no /proc/net/tcp to see a connection being tried")
        port = f":{self.port:04X}"
        return any(
            line.split()[2].endswith(port) and line.split()[3] == "02"  # SYN_SENT
            for line in table.splitlines()[1:]
        )

    def close(self) -> None:
        for c in self._held:
            c.close()
        self._server.close()


def _ray_command(command: str, address: str, out: Path) -> list[str]:
    args = [sys.executable, "-m", "drill_env", command, "--out", str(out), "--backend", "ray"]
    args += ["--ray-address", address]
    if command == "benchmark":
        args += ["--quick", "--controllers", "open_loop"]
    else:
        args += ["--skip-paper-case"]
    return args


ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("kind", ["blackhole", "silent"])
@pytest.mark.parametrize("command", ["discrepancy-study", "benchmark"])
def test_a_ray_address_that_never_answers_fails_within_30_s_in_one_line(tmp_path, command, kind):
    import time

    deaf = _DeafRayAddress(kind)
    try:
        address = f"127.0.0.1:{deaf.port}"
        proc = subprocess.Popen(
            _ray_command(command, address, tmp_path / "o"),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        deadline = time.monotonic() + 120  # the start of the command (imports) on a loaded machine
        while not deaf.waiting() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        t0 = time.monotonic()
        _, err = proc.communicate(timeout=120)
        waited = time.monotonic() - t0
    finally:
        deaf.close()
    assert proc.returncode == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: --ray-address:"), err
    assert address in lines[0]
    assert ("no answer within 10 s" if kind == "blackhole" else "does not answer Ray's request") in lines[0]
    assert waited < 30.0, waited  # about 10 s (Ray's own wait: ~14 min)
    assert not (tmp_path / "o").exists()  # checked before the output folder is touched


@pytest.mark.parametrize(("command", "kind"), [("discrepancy-study", "blackhole"), ("benchmark", "silent")])
def test_ctrl_c_while_waiting_for_a_ray_address_exits_130_within_2_s(tmp_path, command, kind):
    import signal
    import time

    deaf = _DeafRayAddress(kind)
    try:
        proc = subprocess.Popen(
            _ray_command(command, f"127.0.0.1:{deaf.port}", tmp_path / "o"),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        deadline = time.monotonic() + 120
        while not deaf.waiting() and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.02)
        time.sleep(0.5)  # well inside the wait
        assert proc.poll() is None
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        took = time.monotonic() - t0
    finally:
        deaf.close()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted (Ctrl-C)" in err
    assert took < 2.0, took
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("answers", [True, False], ids=["ray-cluster", "other-grpc-service"])
def test_a_ray_address_is_accepted_only_where_a_ray_cluster_answers(answers):
    """What answers Ray's first request (the cluster id) is taken as a cluster; a gRPC server
    that does not know it (a proxy, another service) is refused naming what answered."""
    grpc = pytest.importorskip("grpc")
    pytest.importorskip("ray.core.generated.gcs_service_pb2_grpc")
    from concurrent import futures

    import drill_env.ray_cluster as rc

    server = grpc.server(futures.ThreadPoolExecutor(max_workers=2))
    if answers:
        handler = grpc.unary_unary_rpc_method_handler(lambda request, context: b"")
        server.add_generic_rpc_handlers(
            (grpc.method_handlers_generic_handler("ray.rpc.NodeInfoGcsService", {"GetClusterId": handler}),)
        )
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    try:
        if answers:
            rc.check_ray_address(f"127.0.0.1:{port}", timeout=10)
        else:
            with pytest.raises(
                ValueError, match=r"no Ray cluster answers at 127\.0\.0\.1:\d+ \(what answers is not"
            ):
                rc.check_ray_address(f"127.0.0.1:{port}", timeout=10)
    finally:
        server.stop(0)


# -- a duplicate key ----------------------------------------------------------------------------------


def test_a_duplicate_key_in_dataset_json_is_refused_with_the_key(tmp_path, runner, dataset):
    data = tmp_path / "dup"
    data.mkdir()
    for p in dataset.iterdir():
        (data / p.name).write_bytes(p.read_bytes())
    meta = (data / "dataset.json").read_text()
    # a braked recording that would be read as no_brake: json keeps the last value silently
    assert '"preset": "brake"' in meta
    (data / "dataset.json").write_text(
        meta.replace('"preset": "brake"', '"preset": "brake",\n  "preset": "no_brake"')
    )
    out = tmp_path / "id"
    line = one_error_line(runner.invoke(app, ["identify", str(data), "--out", str(out)]))
    assert "'preset' appears twice (line" in line and "dataset.json" in line
    assert not out.exists()


# -- Ctrl-C at any moment ---------------------------------------------------------------------------


def test_a_ctrl_c_that_python_swallows_still_exits_130():
    """A Ctrl-C that lands in a finaliser is printed as "Exception ignored" and the run goes on:
    the command still ends with exit code 130, never 0."""
    script = textwrap.dedent(
        """
        import signal, sys
        import drill_env.cli as cli

        class Finaliser:
            def __del__(self):
                signal.raise_signal(signal.SIGINT)  # Ctrl-C while an object is cleaned up
                sum(range(1000))

        def command():
            Finaliser()
            print("finished", flush=True)
            sys.exit(0)

        cli.app = command
        cli.main()
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.stdout.strip() == "finished"
    assert "Exception ignored" in proc.stderr  # Python swallowed it ...
    assert proc.returncode == 130, proc.stderr  # ... the command did not
    assert "interrupted (Ctrl-C)" in proc.stderr


# -- the committed results stay regenerable --------------------------------------------------------


def test_every_committed_results_folder_is_accepted_by_the_command_that_writes_it():
    """results/README.md's commands write into folders made before folders had markers: each is
    accepted by its own command (and refused by another one)."""
    import re

    from drill_env.agents.commands.benchmark import BENCHMARK_FILES
    from drill_env.agents.commands.train import TRAIN_FILES
    from drill_env.agents.evaluation.sim_to_real import SIM_TO_REAL_FILES
    from drill_env.commands.bifurcation import BIFURCATION_FILES
    from drill_env.commands.discrepancy import STUDY_FILES
    from drill_env.commands.identify import IDENTIFY_FILES
    from drill_env.outputs import check_command_folder

    root = Path(__file__).resolve().parents[1]
    own = {
        "benchmark": BENCHMARK_FILES,
        "bifurcation": BIFURCATION_FILES,
        "discrepancy-study": STUDY_FILES,
        "train": TRAIN_FILES,
        "sim-to-real": SIM_TO_REAL_FILES,
    }
    text = (root / "results" / "README.md").read_text()
    found = set(re.findall(r"drill-env ([a-z-]+) [^`\n]*?--out (results/[^\s`]+)", text))
    checked = 0
    for command, folder in sorted(found):
        if command not in own or not (root / folder).is_dir():
            continue
        check_command_folder(root / folder, command, own=own[command])
        checked += 1
        if command != "bifurcation":
            with pytest.raises(OutputFolderError):
                check_command_folder(root / folder, "identify", own=IDENTIFY_FILES)
    assert checked >= 10
