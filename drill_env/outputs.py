"""Output folders whose results are never lost: one writer per folder, files replaced whole.

* :func:`output_lock` -- a run that writes a results folder (a benchmark, a study, a
  report) holds ``<folder>/.drill-env.lock`` for as long as it writes. The lock file is
  created atomically and names its holder (pid, host, command line, start time); a second
  run on the same folder stops at once with :class:`OutputFolderBusy`, before it writes
  anything. A lock left behind by a run that is gone (same host, process no longer alive)
  is taken over with a warning. The lock is removed when the run ends, also on an error.
  Nested locks on the same folder in the same thread are allowed (a command that locks its
  folder may call a function that locks it too).
* :func:`check_new_folder` -- an output folder must be new or empty (``synth``): what a
  command writes is never mixed with what was there; with ``--fresh`` a folder of the
  command's own files is replaced whole. :func:`refuse_links` and :func:`open_append` --
  an output file is never written through a symbolic link.
* :func:`fresh_run_folder` -- the default output of a command that produces results
  (``train``, ``tune``, ``discrepancy-study``): a new folder ``<parent>/<name>_<YYYYmmdd-HHMMSS>`` created
  atomically, never an existing one, so a default run never replaces committed results.
* :func:`atomic_write_text`, :func:`atomic_write_bytes` and :func:`atomic_file` -- a file
  is written to a temporary file of its own (a unique name) in the same folder and moved
  over the target in one step, so a reader never sees half a file and two writers never
  share a temporary file.

Errors are :class:`ValueError` subclasses with a one-line message; the commands turn them
into ``error: ...`` and exit code 2.
"""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import socket
import sys
import tempfile
import threading
import time
import uuid
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = [
    "LOCK_NAME",
    "OutputFolderError",
    "OutputFolderBusy",
    "output_lock",
    "atomic_file",
    "atomic_write_text",
    "atomic_write_bytes",
    "fresh_run_folder",
    "check_output_file",
    "check_output_folder",
    "check_new_folder",
    "MARKER_NAME",
    "OutputWriteError",
    "StaleLockWarning",
    "ResumeError",
    "check_command_folder",
    "command_folder",
    "check_command_file",
    "check_tree_files",
    "command_files",
    "refuse_link",
    "save_figure",
    "atomic_write_json",
    "track_created",
    "keep_on_error",
    "atomic_path",
    "clear_folder",
    "refuse_links",
    "open_append",
    "open_new",
]

LOCK_NAME = ".drill-env.lock"
MARKER_NAME = ".drill-env-output.json"  # names the command whose outputs a folder holds


class OutputFolderError(ValueError):
    """An output folder cannot be used (not creatable, or in use by another run)."""


class OutputFolderBusy(OutputFolderError):
    """Another run is writing into the output folder."""


class ResumeError(OutputFolderError):
    """A partial file left by an interrupted run cannot be resumed from (empty, truncated,
    foreign, another version's): the message names it and the choice (``--fresh``)."""


class StaleLockWarning(RuntimeWarning):
    """A lock left by a run that is gone was taken over (shown by the CLI as one line)."""

    one_line = True


class OutputWriteError(OutputFolderError):
    """A file could not be written (a full disk, a write error): the message names the path."""


# -- output paths checked before any work ----------------------------------------------------------


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def _check_parent(path: Path, option: str, shown: Path | None = None) -> None:
    """The folder that will hold ``path`` can be created and written in: tried, then undone
    (folders this check creates are removed again). Messages name ``shown`` (default ``path``)."""
    parent = path.parent
    path = shown if shown is not None else path
    missing: list[Path] = []
    probe = parent
    while not probe.exists():  # the nearest existing ancestor decides
        if probe.is_symlink():
            raise OutputFolderError(f"{option} {path}: {probe} is a dangling link")
        missing.append(probe)
        probe = probe.parent
    if not probe.is_dir():
        raise OutputFolderError(f"{option} {path}: {probe} is not a folder")
    try:
        parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=parent, prefix=".drill-env-probe.", suffix=".tmp")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise OutputFolderError(f"{option} {path}: cannot write in {parent}: {_reason(exc)}") from None
    finally:
        for folder in missing:  # innermost first
            with contextlib.suppress(OSError):
                folder.rmdir()


def check_output_file(path: str | os.PathLike[str], option: str = "--out") -> Path:
    """Check, before any work, that a result file can be written at ``path``.

    ``path`` must not be a folder or another special file (an existing regular file is
    replaced); its folder must exist or be creatable, and writable (tried, and undone).
    Raises :class:`OutputFolderError` naming ``option`` and the path.
    """
    path = Path(path)
    if path.is_symlink():
        dangling = "a dangling link" if not path.exists() else "a symbolic link"
        raise OutputFolderError(
            f"{option} {path}: is {dangling} (to {os.readlink(path)}); output files are never written "
            "through links: remove the link or choose another path"
        )
    if path.is_dir():
        raise OutputFolderError(f"{option} {path}: is a folder; expected a file path")
    if path.exists() and not path.is_file():
        raise OutputFolderError(f"{option} {path}: exists and is not a regular file")
    if path.is_symlink() and not path.exists():
        raise OutputFolderError(f"{option} {path}: is a dangling link")
    _check_parent(path, option)
    return path


def check_output_folder(path: str | os.PathLike[str], option: str = "--out") -> Path:
    """Check, before any work, that ``path`` is (or can be created as) a writable folder.

    Leaves nothing behind (a folder created to try is removed). Raises
    :class:`OutputFolderError` naming ``option`` and the path.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputFolderError(f"{option} {path}: exists and is not a folder")
    if path.is_symlink() and not path.exists():
        raise OutputFolderError(f"{option} {path}: is a dangling link")
    _check_parent(path / ".probe", option, shown=path)
    return path


# -- folders never mixed, files never written through links ----------------------------------------


def check_new_folder(
    path: str | os.PathLike[str],
    option: str = "--out",
    *,
    fresh: bool = False,
    replaceable: tuple[str, ...] = (),
    what: str = "output",
) -> list[Path]:
    """Check, before any work, that ``path`` is empty or absent, so that what a command writes
    is never mixed with what was there.

    With ``fresh`` a folder whose every entry matches one of the glob patterns
    ``replaceable`` (what an earlier run of the same command wrote) may be replaced whole:
    the entries to remove are returned (remove them with :func:`clear_folder` once the new
    content is ready). A folder holding anything else is refused even with ``fresh``.
    Raises :class:`OutputFolderError` naming ``option``.
    """
    import fnmatch

    path = Path(path)
    check_output_folder(path, option)
    if not path.is_dir():
        return []
    entries = sorted(p for p in path.iterdir() if p.name not in (LOCK_NAME, MARKER_NAME))
    if not entries:
        return []
    shown = ", ".join(p.name for p in entries[:3]) + (
        f" and {len(entries) - 3} more" if len(entries) > 3 else ""
    )
    if not fresh:
        hint = " or --fresh to replace it whole" if replaceable else ""
        raise OutputFolderError(
            f"{option} {path}: not empty ({shown}); the {what} is written only into a new or empty "
            f"folder, never mixed with what is there: choose another folder{hint}"
        )
    foreign = [
        p
        for p in entries
        if p.is_symlink() or not p.is_file() or not any(fnmatch.fnmatch(p.name, pat) for pat in replaceable)
    ]
    if foreign:
        raise OutputFolderError(
            f"{option} {path}: --fresh replaces only a folder written by this command; "
            f"{foreign[0].name} is not one of its files ({', '.join(replaceable)}): choose another folder"
        )
    return entries


def clear_folder(entries: list[Path]) -> None:
    """Remove the files :func:`check_new_folder` returned (a ``--fresh`` replacement)."""
    for p in entries:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def refuse_links(folder: str | os.PathLike[str], names: tuple[str, ...], option: str = "--out") -> None:
    """Refuse output files of ``folder`` that are symbolic links: a result is never written
    through a link to a file elsewhere."""
    folder = Path(folder)
    for name in names:
        p = folder / name
        if p.is_symlink():
            raise OutputFolderError(
                f"{option} {folder}: {name} is a symbolic link (to {os.readlink(p)}); output files are "
                "never written through links: remove the link or choose another folder"
            )


def _open_no_link(
    path: str | os.PathLike[str], flags: int, mode: str, open_kwargs: dict[str, Any]
) -> IO[Any]:
    """Open ``path`` as text with ``os.open`` ``flags``, never through a symbolic link
    (``O_NOFOLLOW``; a link is refused in one line)."""
    try:
        fd = os.open(path, flags | os.O_WRONLY | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o666)
    except OSError:
        if Path(path).is_symlink():
            raise OutputFolderError(
                f"{path}: is a symbolic link; output files are never written through links"
            ) from None
        raise
    open_kwargs.setdefault("encoding", "utf-8")
    return os.fdopen(fd, mode, **open_kwargs)


def open_append(path: str | os.PathLike[str], **open_kwargs: Any) -> IO[Any]:
    """Open ``path`` for appending text, never through a symbolic link (``O_NOFOLLOW``)."""
    return _open_no_link(path, os.O_APPEND, "a", open_kwargs)


def open_new(path: str | os.PathLike[str], **open_kwargs: Any) -> IO[Any]:
    """Open ``path`` for writing text from its start (a log written as it runs), never through
    a symbolic link (``O_NOFOLLOW``)."""
    return _open_no_link(path, os.O_TRUNC, "w", open_kwargs)


# -- one writer per folder -------------------------------------------------------------------------

_HELD: dict[str, dict[int, int]] = {}  # real folder path -> {thread id: nesting depth}
_HELD_GUARD = threading.Lock()


def _process_start(pid: int) -> str | None:
    """The kernel's start time of a process (Linux), to tell a reused pid from the holder."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    try:
        return stat.rsplit(")", 1)[1].split()[19]  # field 22 of proc(5)
    except IndexError:
        return None


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    if os.name != "posix":
        return True  # cannot tell safely: never take the lock over
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # alive, another user's
    except OSError:
        return True
    return True


def _read_holder(path: Path) -> tuple[dict[str, Any] | None, tuple[int, int] | None]:
    """The lock's content and identity (device, inode); (None, None) when it is gone.

    A lock being created may be empty for an instant: read again for a little while.
    """
    holder: dict[str, Any] | None = None
    ident: tuple[int, int] | None = None
    for _ in range(20):
        try:
            st = path.stat()
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None, None
        except OSError:
            text, st = "", None
        ident = (st.st_dev, st.st_ino) if st is not None else None
        try:
            holder = json.loads(text)
            if isinstance(holder, dict):
                return holder, ident
        except ValueError:
            pass
        time.sleep(0.025)
    return {}, ident  # unreadable


def _describe(holder: dict[str, Any]) -> str:
    if not holder:
        return "an unknown run (the lock file is unreadable)"
    cmd = str(holder.get("command", "?"))
    if len(cmd) > 160:
        cmd = cmd[:157] + "..."
    return (
        f"pid {holder.get('pid', '?')} on {holder.get('host', '?')}, "
        f"started {holder.get('started', '?')}: {holder.get('what', '?')} ({cmd})"
    )


def _is_stale(holder: dict[str, Any], folder_key: str) -> bool:
    """Left by a run on this host that is gone (never guessed for another host)."""
    if not holder or holder.get("host") != socket.gethostname():
        return False
    try:
        pid = int(holder["pid"])
    except (KeyError, TypeError, ValueError):
        return False
    if pid == os.getpid():
        # our pid: held by another thread of this process, or left by an earlier
        # process that had the same pid (containers reuse pids)
        with _HELD_GUARD:
            return not _HELD.get(folder_key)
    if not _pid_alive(pid):
        return True
    start = holder.get("process_start")
    now = _process_start(pid)
    return start is not None and now is not None and start != now  # the pid was reused


def _take_over(path: Path, ident: tuple[int, int] | None) -> None:
    """Move the stale lock aside, unless another run replaced it in the meantime."""
    aside = path.with_name(f"{LOCK_NAME}.stale-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    try:
        os.rename(path, aside)
    except FileNotFoundError:
        return
    st = os.stat(aside)
    if ident is not None and (st.st_dev, st.st_ino) != ident:
        # not the lock we judged stale: a new holder's; put it back
        with contextlib.suppress(OSError):
            os.link(aside, path)
    os.unlink(aside)


def _flock_free(path: Path) -> bool:
    """True when no process holds the kernel lock (``flock``) on the lock file ``path``.

    A run of this version holds it while it writes; the kernel releases it when that run
    ends in any way (killed included), so a lock file nobody holds is left by a run that is
    gone."""
    try:
        import fcntl
    except ImportError:  # not POSIX: cannot tell
        return False
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return True
    finally:
        os.close(fd)


def _hold(fd: int) -> None:
    """Take the kernel lock on a lock file just created (released by the kernel if we die)."""
    try:
        import fcntl
    except ImportError:
        return
    with contextlib.suppress(OSError):
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


def _acquire(folder: Path, what: str, folder_key: str) -> tuple[Path, str, int]:
    path = folder / LOCK_NAME
    token = uuid.uuid4().hex
    record = {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "command": shlex.join(sys.argv) if sys.argv else sys.executable,
        "started": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "what": what,
        "process_start": _process_start(os.getpid()),
        "token": token,
    }
    data = (json.dumps(record, indent=1) + "\n").encode()
    for _ in range(5):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY | getattr(os, "O_NOFOLLOW", 0), 0o644)
        except FileExistsError:
            holder, ident = _read_holder(path)
            if holder is None:
                continue  # released in the meantime: try again
            if _is_stale(holder, folder_key) or (not holder and _flock_free(path)):
                gone = _describe(holder) if holder else "an empty or unreadable lock that no run holds"
                warnings.warn(
                    f"{folder}: taking over the lock left by a run that is gone ({gone}); "
                    "its results in this folder may be incomplete",
                    StaleLockWarning,
                    stacklevel=4,
                )
                _take_over(path, ident)
                continue
            raise OutputFolderBusy(
                f"{folder} is in use by another drill-env run ({_describe(holder)}); wait for it to finish "
                f"or write elsewhere; if that run is gone, delete {path}"
            ) from None
        except OSError as exc:
            raise OutputFolderError(
                f"cannot lock the output folder {folder}: {exc.strerror or exc}"
            ) from None
        _hold(fd)
        try:
            _write_all(fd, data)
            os.fsync(fd)
        except OSError as exc:  # a full disk: no 0-byte lock is left to block the next run
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(path)
            raise OutputWriteError(f"cannot write {path}: {_reason(exc)}; nothing was written") from None
        return path, token, fd
    raise OutputFolderBusy(f"{folder} is in use by another drill-env run (its lock {path} keeps changing)")


def _release(path: Path, token: str, fd: int) -> None:
    try:
        try:
            holder = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return
        if isinstance(holder, dict) and holder.get("token") == token:  # still ours
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
    finally:
        with contextlib.suppress(OSError):
            os.close(fd)  # releases the kernel lock


@contextlib.contextmanager
def output_lock(folder: str | os.PathLike[str], what: str = "drill-env") -> Iterator[Path]:
    """Hold ``folder`` (created if missing) for one writer while the block runs; yields the folder.

    ``what`` names the run in the lock file and in the message another run gets. Raises
    :class:`OutputFolderBusy` if another run holds the folder, :class:`OutputFolderError` if
    it cannot be created. Folders created here are removed again at the end when they are
    left empty (a run refused or failed before it wrote anything leaves no empty folder).
    """
    folder = Path(folder)
    made: list[Path] = []
    probe = folder
    while not probe.exists() and not probe.is_symlink() and probe != probe.parent:
        made.append(probe)
        probe = probe.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFolderError(f"cannot create the output folder {folder}: {exc.strerror or exc}") from None
    try:
        with _locked(folder, what) as held:
            yield held
    finally:
        for p in made:  # innermost first
            with contextlib.suppress(OSError):
                p.rmdir()


@contextlib.contextmanager
def _locked(folder: Path, what: str) -> Iterator[Path]:
    key = os.path.realpath(folder)
    me = threading.get_ident()
    with _HELD_GUARD:
        depth = _HELD.get(key, {}).get(me, 0)
        if depth:
            _HELD[key][me] = depth + 1
    if depth:  # nested in this thread: already ours
        try:
            yield folder
        finally:
            with _HELD_GUARD:
                _HELD[key][me] -= 1
        return
    path, token, fd = _acquire(folder, what, key)
    with _HELD_GUARD:
        _HELD.setdefault(key, {})[me] = 1
    try:
        yield folder
    finally:
        with _HELD_GUARD:
            threads = _HELD.get(key, {})
            threads.pop(me, None)
            if not threads:
                _HELD.pop(key, None)
        _release(path, token, fd)


# -- files replaced whole --------------------------------------------------------------------------

_UMASK = os.umask(0o022)
os.umask(_UMASK)


def refuse_link(path: str | os.PathLike[str]) -> Path:
    """Refuse an output path that is a symbolic link (checked with ``lstat``, never followed):
    a result is never written through a link to a file elsewhere."""
    path = Path(path)
    if path.is_symlink():
        raise OutputFolderError(
            f"{path}: is a symbolic link (to {os.readlink(path)}); output files are never written "
            "through links: remove the link or choose another folder"
        )
    return path


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike[str], mode: str = "w", **open_kwargs: Any) -> Iterator[IO[Any]]:
    """Open a unique temporary file beside ``path``; on success it replaces ``path`` in one step.

    ``path`` must not be a symbolic link (refused, never followed). On an error the temporary
    file is removed and ``path`` is left as it was; a write error (a full disk) is raised as
    :class:`OutputWriteError` naming ``path``. ``mode`` is ``"w"`` or ``"wb"``;
    ``open_kwargs`` go to :func:`open` (``encoding``, ``newline``).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode: expected 'w' or 'wb', got {mode!r}")
    if mode == "w":
        open_kwargs.setdefault("encoding", "utf-8")
    with atomic_path(path) as tmp, open(tmp, mode, **open_kwargs) as f:  # f.name: the temporary file
        yield f


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], suffix: str = ".tmp") -> Iterator[Path]:
    """A unique temporary file name beside ``path`` (for a library that writes by file name, as
    stable-baselines3's ``model.save``); on success it is synced and replaces ``path`` in one
    step, keeping the permissions of the file it replaces. On an error it is removed and
    ``path`` is left as it was; a write error (a full disk) is raised as
    :class:`OutputWriteError` naming ``path``. ``path`` must not be a link (refused, never
    followed, also when one is planted while the file is written)."""
    path = refuse_link(path)
    existed = path.exists()
    try:
        perms = path.stat().st_mode & 0o7777
    except OSError:
        perms = 0o666 & ~_UMASK
    try:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
        os.close(fd)
    except OSError as exc:
        raise OutputWriteError(f"cannot write {path}: {_reason(exc)}") from None
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as f:  # what was written (and closed) reaches the disk
            os.fsync(f.fileno())
        os.chmod(tmp, perms)
        refuse_link(path)  # a link planted while the file was written
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, ValueError):
            raise OutputWriteError(
                f"cannot write {path}: {_reason(exc)}; {path} was left as it was"
            ) from None
        raise
    if not existed:
        _created(path)


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` through a unique temporary file and an atomic replace."""
    with atomic_file(path, "w", encoding=encoding) as f:
        f.write(text)
    return Path(path)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` through a unique temporary file and an atomic replace."""
    with atomic_file(path, "wb") as f:
        f.write(data)
    return Path(path)


def atomic_write_json(path: str | os.PathLike[str], data: Any, **dump_kwargs: Any) -> Path:
    """Write ``data`` as JSON (``indent=2`` unless given) atomically, never through a link."""
    dump_kwargs.setdefault("indent", 2)
    return atomic_write_text(path, json.dumps(data, **dump_kwargs) + "\n")


def save_figure(fig: Any, path: str | os.PathLike[str], **savefig_kwargs: Any) -> Path:
    """Save a Matplotlib figure to ``path`` atomically and never through a link.

    The format comes from the suffix (``.png``, ``.svg``, ``.pdf``); ``savefig_kwargs`` go to
    :meth:`matplotlib.figure.Figure.savefig` (``dpi``). A figure made with ``Figure()`` gets
    an Agg canvas: the user's pyplot backend is never touched.
    """
    path = Path(path)
    canvas = getattr(fig, "canvas", None)
    if canvas is None or type(canvas).__name__ == "FigureCanvasBase":
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig)
    savefig_kwargs.setdefault("format", path.suffix.lstrip(".") or "png")
    with atomic_file(path, "wb") as f:
        fig.savefig(f, **savefig_kwargs)
    return path


# -- one command's outputs per folder --------------------------------------------------------------


def _marker_command(folder: Path) -> str | None:
    """The command named by ``folder``'s marker (None: no marker; ``"?"``: unreadable)."""
    marker = folder / MARKER_NAME
    if marker.is_symlink():
        return "?"
    if not marker.exists():
        return None
    try:
        data = json.loads(marker.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return "?"
    return str(data.get("command", "?")) if isinstance(data, dict) else "?"


def check_command_folder(
    path: str | os.PathLike[str],
    command: str,
    option: str = "--out",
    *,
    own: tuple[str, ...] = (),
) -> Path:
    """Check, before any work and writing nothing, that ``path`` may hold ``command``'s outputs.

    An output folder holds one command's outputs, named by its marker file
    (:data:`MARKER_NAME`): a folder that is absent or empty, or whose marker names
    ``command``, is accepted. Refused with one line naming ``option``: a folder whose marker
    names another command, a dataset (``dataset.json``), and a folder without a marker that
    holds anything but regular files matching the glob patterns ``own`` (what ``command``
    wrote before folders had markers).
    """
    import fnmatch

    path = check_output_folder(path, option)
    if not path.is_dir():
        return path
    marked = _marker_command(path)
    if marked == command:
        return path
    _refuse_foreign_folder(path, command, option, path)
    entries = sorted(p for p in path.iterdir() if p.name != LOCK_NAME)
    for p in entries:
        if p.is_symlink():
            raise OutputFolderError(
                f"{option} {path}: {p.name} is a symbolic link (to {os.readlink(p)}); output files are never "
                "written through links: remove the link or choose another folder"
            )
    foreign = [
        p
        for p in entries
        if p.is_symlink() or (p.is_file() and not any(fnmatch.fnmatch(p.name, pat) for pat in own))
    ]  # a subfolder is an output folder of its own, checked when it is written
    if foreign:
        shown = ", ".join(p.name for p in foreign[:3]) + (
            f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        )
        raise OutputFolderError(
            f"{option} {path}: holds what `drill-env {command}` does not write ({shown}); a folder holds "
            "one command's outputs, never mixed: choose a new or empty folder"
        )
    return path


class _Session:
    """What one command created in its output folder (removed again on a write error)."""

    def __init__(self, folder: Path) -> None:
        self.folder = os.path.realpath(folder)
        self.created: list[Path] = []


_SESSIONS: list[_Session] = []


def _created(path: Path) -> None:
    """Record a new file in the innermost :func:`command_folder` holding it."""
    where = os.path.realpath(path.parent)
    with _HELD_GUARD:
        for session in reversed(_SESSIONS):
            if where == session.folder or where.startswith(session.folder + os.sep):
                session.created.append(path)
                return


def track_created(path: str | os.PathLike[str]) -> None:
    """Record a file a writer outside this module created (an append file), so that a write
    error in the enclosing :func:`command_folder` removes it."""
    _created(Path(path))


def keep_on_error(path: str | os.PathLike[str]) -> None:
    """Keep ``path`` (a resume file: the rows finished so far) when a write error ends the
    enclosing :func:`command_folder`; every other file the run created is removed then."""
    path = Path(path)
    with _HELD_GUARD:
        for session in _SESSIONS:
            session.created = [p for p in session.created if p != path]


def _is_write_error(exc: BaseException) -> bool:
    return isinstance(exc, OutputWriteError) or (isinstance(exc, OSError) and not isinstance(exc, ValueError))


@contextlib.contextmanager
def command_folder(
    path: str | os.PathLike[str],
    command: str,
    option: str = "--out",
    *,
    own: tuple[str, ...] = (),
) -> Iterator[Path]:
    """The output folder of one run of ``command``: checked (:func:`check_command_folder`),
    created if missing, locked (:func:`output_lock`) and marked as ``command``'s while the
    block runs; yields the folder.

    Every file written with this module's writers inside it is tracked: if the block fails
    with a write error (a full disk), the files this run created are removed (the error names
    the path); files of an earlier run that were being replaced are left as they were. A
    folder this run created is removed again when it is left empty (a refused or failed run).
    """
    folder = check_command_folder(path, command, option, own=own)
    with output_lock(folder, command):
        session = _Session(folder)
        marker = folder / MARKER_NAME
        new_marker = not marker.exists()
        with _HELD_GUARD:
            _SESSIONS.append(session)
        try:
            if new_marker:
                atomic_write_json(marker, {"command": command, "written_by": "drill-env"})
            yield folder
        except BaseException as exc:
            if _is_write_error(exc):
                for p in reversed(session.created):
                    with contextlib.suppress(OSError):
                        p.unlink()
            if new_marker:
                left = [p for p in folder.iterdir() if p.name not in (LOCK_NAME, MARKER_NAME)]
                if not left:
                    with contextlib.suppress(OSError):
                        marker.unlink()
            raise
        finally:
            with _HELD_GUARD:
                _SESSIONS.remove(session)


def _refuse_foreign_folder(
    folder: Path, command: str, option: str, shown: Path, accepts: tuple[str, ...] = ()
) -> None:
    """Refuse a folder that holds a dataset or another command's outputs (its marker names a
    command other than ``command`` and ``accepts``)."""
    if not folder.is_dir():
        return
    where = f"{option} {shown}: " + ("" if folder == shown else f"{folder} ")
    marked = _marker_command(folder)
    if marked is not None and marked != command and marked not in accepts:
        raise OutputFolderError(
            f"{where}holds the outputs of `drill-env {marked}` ({MARKER_NAME}); a folder holds one command's "
            f"outputs, never mixed: choose another folder for `drill-env {command}`"
        )
    if (folder / "dataset.json").exists() or (folder / "dataset.json").is_symlink():
        raise OutputFolderError(
            f"{where}holds a dataset (dataset.json); outputs are never written into a dataset folder: "
            "choose another folder"
        )


def check_command_file(path: str | os.PathLike[str], command: str, option: str = "--out") -> Path:
    """Check, before any work and writing nothing, that ``command`` may write the file ``path``
    (a command whose output is named files, not a folder of its own): :func:`check_output_file`
    (never a link, a folder or a special file; its folder creatable and writable), and its
    folder must not hold a dataset or another command's outputs (a marker naming another command).
    """
    path = check_output_file(path, option)
    _refuse_foreign_folder(path.parent, command, option, path)
    return path


def check_tree_files(
    root: str | os.PathLike[str],
    files: list[Path],
    command: str,
    option: str,
    *,
    accepts: tuple[str, ...] = (),
) -> None:
    """Check, before the first write, the files a command rewrites in place under the folder
    ``root`` (policy cards beside trained policies, upgraded policy files): every file lies in
    ``root`` by its real path (a linked folder that leads elsewhere is refused), no file is a
    symbolic link, and neither ``root`` nor a file's folder holds a dataset or the outputs of a
    command other than ``command`` and ``accepts`` (whose outputs it updates, e.g. ``train``).
    Raises :class:`OutputFolderError` naming ``option``."""
    root = Path(root)
    real_root = os.path.realpath(root)
    _refuse_foreign_folder(root, command, option, root, accepts)
    for path in files:
        real = os.path.realpath(path.parent)
        if real != real_root and not real.startswith(real_root + os.sep):
            raise OutputFolderError(
                f"{option} {root}: {path.parent} leads outside it (to {real}, through a link); files are "
                "written only inside the folder named: remove the link or name that folder itself"
            )
        if path.is_symlink():
            raise OutputFolderError(
                f"{option} {root}: {path} is a symbolic link (to {os.readlink(path)}); output files are "
                "never written through links: remove the link"
            )
        if path.parent != root:
            _refuse_foreign_folder(path.parent, command, option, root, accepts)


@contextlib.contextmanager
def command_files(
    paths: list[str | os.PathLike[str]] | tuple[str | os.PathLike[str], ...],
    command: str,
    option: str = "--out",
) -> Iterator[list[Path]]:
    """The output files of one run of a command that writes named files: each checked
    (:func:`check_command_file`), their folders created if missing; yields the paths.

    Write them with this module's writers inside the block: on a write error (a full disk)
    the files this run created are removed (a file of an earlier run being replaced is left as
    it was; the error names the path), and on any error the folders made here are removed
    again when left empty. Nothing is marked: the folder may hold other files (a config folder).
    """
    checked = [check_command_file(p, command, option) for p in paths]
    made: list[Path] = []
    for path in checked:
        probe = path.parent
        while not probe.exists() and not probe.is_symlink() and probe != probe.parent:
            if probe not in made:
                made.append(probe)
            probe = probe.parent
    made.sort(key=lambda p: len(p.parts), reverse=True)  # innermost first
    sessions = [_Session(folder) for folder in dict.fromkeys(p.parent for p in checked)]
    with _HELD_GUARD:
        _SESSIONS.extend(sessions)
    try:
        for path in checked:
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise OutputFolderError(
                    f"{option} {path}: cannot create {path.parent}: {_reason(exc)}"
                ) from None
        for session in sessions:  # the folders now exist: their real paths
            session.folder = os.path.realpath(session.folder)
        yield checked
    except BaseException as exc:
        if _is_write_error(exc):
            for session in sessions:
                for p in reversed(session.created):
                    with contextlib.suppress(OSError):
                        p.unlink()
        for folder in made:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    finally:
        with _HELD_GUARD:
            for session in sessions:
                _SESSIONS.remove(session)


def fresh_run_folder(parent: str | os.PathLike[str], name: str) -> Path:
    """Create and return a new folder ``parent/name_<YYYYmmdd-HHMMSS>`` (``_2``, ``_3``, ...
    appended if that exists): a run's own output, never a folder that holds anything."""
    base = Path(parent)
    try:
        base.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFolderError(f"{base}: cannot create the run folder ({exc.strerror or exc})") from None
    stem = f"{name}_{time.strftime('%Y%m%d-%H%M%S')}"
    for k in range(1, 1000):
        path = base / (stem if k == 1 else f"{stem}_{k}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        except OSError as exc:
            raise OutputFolderError(f"{path}: cannot create the run folder ({exc.strerror or exc})") from None
        return path
    raise OutputFolderError(f"{base}: no free run folder name for {stem}")
