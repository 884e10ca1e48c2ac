"""Every command that writes files goes through the one output rule, command by command:
`tune`, `rig-comparison`, `simulate`, `emulate-rig --truth` (named files), `scenarios` (a folder
of its own), `policy-cards` and `upgrade-policies` (files rewritten in a policy folder).

Each is run as a user runs it (the CLI) and the file system is looked at afterwards: a folder
holding another command's outputs or a dataset is refused, a planted link is refused and its
target left alone, nothing is created when a run is refused, and a write error removes what
the run created.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import pytest
from file_tree import one_error_line, tree
from typer.testing import CliRunner

from drill_env.cli import app
from drill_env.outputs import MARKER_NAME, OutputFolderError, check_tree_files

ROOT = Path(__file__).resolve().parents[1]
KEPT = "the user's own file\n"


@pytest.fixture
def runner() -> CliRunner:
    return CliRunner()


# the commands whose output is one or two named files: their arguments with the file {out}
FILE_COMMANDS = {
    "tune": ["tune", "--preset", "brake", "--out", "{out}"],
    "rig-comparison": ["rig-comparison", "--out", "{out}"],
    "simulate": ["simulate", "--duration", "2", "--out", "{out}"],
    "emulate-rig": ["emulate-rig", "--port", "0", "--truth", "{out}"],
}
FILE_NAMES = {
    "tune": "gains.yaml",
    "rig-comparison": "rc.md",
    "simulate": "run.csv",
    "emulate-rig": "truth.csv",
}


def _folder_of(kind: str, where: Path) -> Path:
    """A folder a file command must not write into: another command's outputs or a dataset."""
    where.mkdir()
    if kind == "benchmark-outputs":
        (where / MARKER_NAME).write_text(json.dumps({"command": "benchmark", "written_by": "drill-env"}))
        (where / "summary.md").write_text("# a benchmark\n")
    else:
        (where / "dataset.json").write_text('{"preset": "brake", "encoder_counts_per_rev": 2000}\n')
        (where / "run01.csv").write_text("t,u,theta_u,theta_l\n")
    return where


@pytest.mark.parametrize("kind", ["benchmark-outputs", "dataset"])
@pytest.mark.parametrize("command", sorted(FILE_COMMANDS))
def test_a_file_command_refuses_a_folder_of_another_command_or_a_dataset(tmp_path, runner, command, kind):
    folder = _folder_of(kind, tmp_path / "there")
    before = tree(folder)
    out = folder / FILE_NAMES[command]
    line = one_error_line(runner.invoke(app, [a.format(out=out) for a in FILE_COMMANDS[command]]))
    assert str(folder) in line
    assert ("`drill-env benchmark`" if kind == "benchmark-outputs" else "holds a dataset") in line
    assert tree(folder) == before  # nothing written, nothing replaced


@pytest.mark.parametrize("command", sorted(FILE_COMMANDS))
def test_a_file_command_refuses_a_planted_link_and_leaves_its_target(tmp_path, runner, command):
    victim = tmp_path / "elsewhere" / "victim.txt"
    victim.parent.mkdir()
    victim.write_text(KEPT)
    out = tmp_path / "o" / FILE_NAMES[command]
    out.parent.mkdir()
    out.symlink_to(victim)
    line = one_error_line(runner.invoke(app, [a.format(out=out) for a in FILE_COMMANDS[command]]))
    assert "symbolic link" in line and str(out) in line
    assert victim.read_text() == KEPT
    assert tree(out.parent) == {out.name: f"link -> {victim}"}


def _enospc(monkeypatch) -> None:
    import drill_env.outputs as outputs

    def fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(outputs.os, "fsync", fsync)


@pytest.mark.parametrize("command", ["rig-comparison", "simulate"])
def test_a_write_error_of_a_file_command_leaves_nothing_behind(tmp_path, runner, monkeypatch, command):
    _enospc(monkeypatch)
    out = tmp_path / "new" / "deeper" / FILE_NAMES[command]
    line = one_error_line(runner.invoke(app, [a.format(out=out) for a in FILE_COMMANDS[command]]))
    assert str(out) in line and "No space left on device" in line
    assert list(tmp_path.iterdir()) == []  # the folders it made are gone, no temporary, no 0-byte file


def test_rig_comparison_replaces_its_two_files_and_keeps_the_folder_s_other_files(tmp_path, runner):
    folder = tmp_path / "results"
    folder.mkdir()
    (folder / "notes.txt").write_text(KEPT)  # a folder of a user's files: a named file may go there
    res = runner.invoke(app, ["rig-comparison", "--out", str(folder / "rc.md")])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt", "rc.json", "rc.md"]
    assert json.loads((folder / "rc.json").read_text())  # a whole JSON file
    assert (folder / "notes.txt").read_text() == KEPT


# -- scenarios: a folder of its own ------------------------------------------------------------------

SCENARIOS = ["scenarios", "--scenarios", "start_up", "--controllers", "open_loop", "--preset", "brake"]
SCENARIOS += ["--seeds", "1", "--workers", "1"]


@pytest.mark.parametrize("kind", ["benchmark-outputs", "dataset", "link"])
def test_scenarios_refuses_another_command_s_folder_a_dataset_and_a_link(tmp_path, runner, kind):
    if kind == "link":
        folder = tmp_path / "there"
        folder.mkdir()
        (tmp_path / "victim.txt").write_text(KEPT)
        (folder / "summary.md").symlink_to(tmp_path / "victim.txt")
    else:
        folder = _folder_of(kind, tmp_path / "there")
    before = tree(folder)
    line = one_error_line(runner.invoke(app, [*SCENARIOS, "--out", str(folder)]))
    assert "--out" in line and str(folder) in line
    assert tree(folder) == before
    if kind == "link":
        assert "symbolic link" in line and (tmp_path / "victim.txt").read_text() == KEPT


def test_the_committed_scenarios_folder_is_accepted_by_scenarios_only():
    from drill_env.agents.commands.scenarios import SCENARIO_FILES
    from drill_env.outputs import check_command_folder

    folder = ROOT / "results" / "scenarios"
    if not folder.is_dir():
        pytest.skip("no committed results/scenarios")
    check_command_folder(folder, "scenarios", own=SCENARIO_FILES)
    with pytest.raises(OutputFolderError, match="does not write"):
        check_command_folder(folder, "identify", own=("report.md",))


# -- policy-cards and upgrade-policies: files rewritten in a policy folder ---------------------------


@pytest.fixture
def policies(tmp_path) -> Path:
    """A folder of one trained policy, copied from the committed results (as train writes one)."""
    source = ROOT / "results" / "agents" / "ppo"
    if not (source / "policy.zip").is_file():
        pytest.skip("no committed results/agents/ppo")
    root = tmp_path / "agents"
    shutil.copytree(source, root / "ppo")
    return root


@pytest.mark.parametrize(
    ("command", "planted"),
    [
        (["policy-cards"], "README.md"),
        (["policy-cards"], "ppo/policy.md"),
        (["upgrade-policies", "--trusted"], "ppo/policy.zip"),
    ],
    ids=["cards-readme", "cards-card", "upgrade-zip"],
)
def test_policy_commands_refuse_a_planted_link_before_writing_anything(
    tmp_path, runner, policies, command, planted
):
    victim = tmp_path / "victim"
    target = policies / planted
    if target.exists():
        shutil.move(target, victim)  # the link leads to what was there (a real policy for the zip)
    else:
        victim.write_text(KEPT)
    target.symlink_to(victim)
    kept = victim.read_bytes()
    before = tree(policies)
    line = one_error_line(runner.invoke(app, [*command, str(policies)]))
    assert "symbolic link" in line and str(target) in line
    assert tree(policies) == before  # not one card written before the refusal
    assert victim.read_bytes() == kept


@pytest.mark.parametrize("command", [["policy-cards"], ["upgrade-policies", "--trusted"]])
@pytest.mark.parametrize("kind", ["benchmark-outputs", "dataset"])
def test_policy_commands_refuse_a_dataset_or_another_command_s_folder(
    tmp_path, runner, policies, command, kind
):
    if kind == "dataset":
        (policies / "dataset.json").write_text('{"preset": "brake", "encoder_counts_per_rev": 2000}\n')
        words = "holds a dataset"
    else:
        marker = {"command": "benchmark", "written_by": "drill-env"}
        (policies / "ppo" / MARKER_NAME).write_text(json.dumps(marker))
        words = "`drill-env benchmark`"
    before = tree(policies)
    line = one_error_line(runner.invoke(app, [*command, str(policies)]))
    assert words in line
    assert tree(policies) == before


def test_policy_cards_accept_a_folder_train_wrote(tmp_path, runner, policies):
    marker = {"command": "train", "written_by": "drill-env"}
    (policies / "ppo" / MARKER_NAME).write_text(json.dumps(marker))
    (policies / "ppo" / "policy.md").unlink()
    res = runner.invoke(app, ["policy-cards", str(policies)])
    assert res.exit_code == 0, res.output
    assert (policies / "ppo" / "policy.md").read_text().startswith("#")
    assert (policies / "README.md").is_file()


def test_a_policy_folder_reached_through_a_link_is_never_written(tmp_path):
    """A linked folder inside the folder named that leads elsewhere is refused (whatever lists
    the policy folders, a link is never a way out of the folder)."""
    root = tmp_path / "agents"
    (root / "own").mkdir(parents=True)
    outside = tmp_path / "outside" / "evil"
    outside.mkdir(parents=True)
    (root / "linked").symlink_to(outside)
    with pytest.raises(OutputFolderError, match=r"leads outside it \(to .*outside/evil, through a link\)"):
        check_tree_files(
            root, [root / "own" / "policy.md", root / "linked" / "policy.md"], "policy-cards", "X"
        )
    check_tree_files(root, [root / "own" / "policy.md", root / "README.md"], "policy-cards", "X")


# -- a stale lock, taken over as a user sees it ------------------------------------------------------


@pytest.mark.parametrize("content", ["dead-pid", "empty"])
def test_a_stale_lock_is_taken_over_with_one_warning_line(tmp_path, content):
    """The lock of a run that is gone (a dead pid on this host, or a 0-byte lock no process
    holds) is taken over by the next run, which says so in one `warning:` line, and leaves no
    lock behind."""
    import socket
    import subprocess
    import sys

    out = tmp_path / "rc"
    out.mkdir()
    lock = out / ".drill-env.lock"
    if content == "empty":
        lock.write_bytes(b"")
    else:
        record = {"pid": 2**22 + 12345, "host": socket.gethostname(), "command": "drill-env x", "what": "x"}
        lock.write_text(json.dumps(record))
    code = (
        "import warnings, sys; from drill_env.cli import _one_line_warnings; _one_line_warnings()\n"
        "from drill_env.outputs import output_lock\n"
        f"with output_lock({str(out)!r}, 'probe'): print('held', flush=True)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "held"
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("warning: ") and "taking over the lock" in lines[0], lines
    assert not lock.exists()


# -- a full disk for real: a small tmpfs in a private mount namespace -------------------------------


def _in_small_tmpfs(tmp_path: Path, script: str, size: str = "64k"):
    """Run ``script`` (sh) with a tmpfs of ``size`` mounted at $FULL, in a private user and mount
    namespace (nothing is mounted outside it); skipped where the machine does not allow one."""
    import subprocess

    if shutil.which("unshare") is None:
        pytest.skip("no unshare(1) for a private tmpfs")
    full = tmp_path / "full"
    full.mkdir()
    probe = subprocess.run(
        [
            "unshare",
            "--user",
            "--map-root-user",
            "--mount",
            "sh",
            "-c",
            f"mount -t tmpfs -o size={size} tmpfs {full}",
        ],
        capture_output=True,
        text=True,
    )
    if probe.returncode != 0:
        pytest.skip(f"no private tmpfs on this machine ({probe.stderr.strip()[:80]})")
    body = f"mount -t tmpfs -o size={size} tmpfs {full} || exit 97; export FULL={full}; {script}"
    return subprocess.run(
        ["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", body],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_a_full_tmpfs_names_the_path_and_leaves_nothing(tmp_path):
    """simulate's CSV (about 1.5 MB) on a 64 KiB file system: the error names the file, and the
    file system is left as empty as it was (no temporary, no 0-byte file, no folder)."""
    import sys

    run = f"{sys.executable} -m drill_env simulate --duration 100 --out $FULL/sim/run.csv; echo rc=$?"
    res = _in_small_tmpfs(tmp_path, f"{run}; echo left:; find $FULL -mindepth 1")
    out = res.stdout.split("left:")
    assert "rc=2" in out[0], (res.stdout, res.stderr)
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and "sim/run.csv" in errors[0] and "No space left on device" in errors[0], (
        res.stderr
    )
    assert out[1].strip() == "", out[1]


def test_a_full_tmpfs_leaves_no_lock_behind(tmp_path):
    """A file system with no space at all: the lock itself cannot be written; the error names it
    and no 0-byte lock (which would block every later run) or folder is left."""
    import sys

    from drill_env.recordings.synth import SynthConfig, make_dataset, write_synthetic

    cfg = SynthConfig(voltages=(1.0, 3.0), random_runs=0, duration_s=10.0, pre_roll_s=2.0)
    write_synthetic(
        make_dataset("none", seed=3, config=cfg), tmp_path / "d", tmp_path / "a.json", preset="brake"
    )
    fill = "head -c 200000 /dev/zero > $FULL/filler 2>/dev/null || true"
    run = f"{sys.executable} -m drill_env identify {tmp_path / 'd'} --out $FULL/id; echo rc=$?"
    res = _in_small_tmpfs(tmp_path, f"{fill}; {run}; echo left:; find $FULL -mindepth 1")
    out = res.stdout.split("left:")
    assert "rc=2" in out[0], (res.stdout, res.stderr)
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and "No space left on device" in errors[0], res.stderr
    assert "id/" in errors[0]  # the path of what could not be written
    assert out[1].split() == [f"{tmp_path / 'full' / 'filler'}"], out[1]
