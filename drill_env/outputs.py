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
    "clear_folder",
    "refuse_links",
    "open_append",
]

LOCK_NAME = ".drill-env.lock"


class OutputFolderError(ValueError):
    """An output folder cannot be used (not creatable, or in use by another run)."""


class OutputFolderBusy(OutputFolderError):
    """Another run is writing into the output folder."""


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
    entries = sorted(p for p in path.iterdir() if p.name != LOCK_NAME)
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


def open_append(path: str | os.PathLike[str], **open_kwargs: Any) -> IO[Any]:
    """Open ``path`` for appending text, never through a symbolic link (``O_NOFOLLOW``)."""
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(path, flags, 0o666)
    except OSError:
        if Path(path).is_symlink():
            raise OutputFolderError(
                f"{path}: is a symbolic link; output files are never written through links"
            ) from None
        raise
    open_kwargs.setdefault("encoding", "utf-8")
    return os.fdopen(fd, "a", **open_kwargs)


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


def _acquire(folder: Path, what: str, folder_key: str) -> tuple[Path, str]:
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
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            holder, ident = _read_holder(path)
            if holder is None:
                continue  # released in the meantime: try again
            if _is_stale(holder, folder_key):
                warnings.warn(
                    f"{folder}: taking over the lock left by a run that is gone ({_describe(holder)}); "
                    "its results in this folder may be incomplete",
                    RuntimeWarning,
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
        try:
            os.write(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        return path, token
    raise OutputFolderBusy(f"{folder} is in use by another drill-env run (its lock {path} keeps changing)")


def _release(path: Path, token: str) -> None:
    try:
        holder = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    if isinstance(holder, dict) and holder.get("token") == token:  # still ours
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


@contextlib.contextmanager
def output_lock(folder: str | os.PathLike[str], what: str = "drill-env") -> Iterator[Path]:
    """Hold ``folder`` (created if missing) for one writer while the block runs; yields the folder.

    ``what`` names the run in the lock file and in the message another run gets. Raises
    :class:`OutputFolderBusy` if another run holds the folder, :class:`OutputFolderError` if
    it cannot be created.
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFolderError(f"cannot create the output folder {folder}: {exc.strerror or exc}") from None
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
    path, token = _acquire(folder, what, key)
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
        _release(path, token)


# -- files replaced whole --------------------------------------------------------------------------

_UMASK = os.umask(0o022)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike[str], mode: str = "w", **open_kwargs: Any) -> Iterator[IO[Any]]:
    """Open a unique temporary file beside ``path``; on success it replaces ``path`` in one step.

    On an error the temporary file is removed and ``path`` is left as it was. ``mode`` is
    ``"w"`` or ``"wb"``; ``open_kwargs`` go to :func:`open` (``encoding``, ``newline``).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode: expected 'w' or 'wb', got {mode!r}")
    path = Path(path)
    try:
        perms = path.stat().st_mode & 0o7777
    except OSError:
        perms = 0o666 & ~_UMASK
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        if mode == "w":
            open_kwargs.setdefault("encoding", "utf-8")
        os.close(fd)
        with open(tmp, mode, **open_kwargs) as f:  # f.name: the temporary file
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, perms)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


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
