"""What produced a benchmark's rows: ``provenance.json`` beside ``benchmark.csv``.

Each call of :func:`~drill_env.agents.evaluation.benchmark.run_benchmark` on a folder adds one
*session* to the file: the code version (``git describe`` of the checkout, else the package
version) and a digest of the package's source files, the platform and the versions of the
libraries a run depends on, the seeds, the solver tolerances and the episode settings, and how
many rows it ran (the runs it found done are those of the sessions before; rows made before
this file existed are counted as such). A row's session is found by its place: the rows of
session i are the ``rows_run`` new keys it appended, listed in ``keys_digest`` order-free.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

__all__ = ["code_identity", "code_version", "session_record", "source_digest", "write_provenance"]

PROVENANCE_FILE = "provenance.json"
# the libraries a run's numbers depend on (simulation, policies, statistics)
_LIBRARIES = ("numpy", "scipy", "numba", "torch", "stable_baselines3", "gymnasium", "pandas")


def source_digest() -> str:
    """SHA-256 over the package's Python sources (path and content, in sorted order): equal
    digests, equal code, whether or not it runs from a git checkout."""
    from drill_env.agents._locations import PACKAGE_DIR

    h = hashlib.sha256()
    roots = [PACKAGE_DIR, (PACKAGE_DIR / "agents").resolve()]
    seen: set[Path] = set()
    for root in roots:
        for path in sorted(root.rglob("*.py")):
            real = path.resolve()
            if real in seen or "__pycache__" in path.parts:
                continue
            seen.add(real)
            h.update(path.relative_to(root).as_posix().encode())
            h.update(b"\0")
            h.update(real.read_bytes())
    return h.hexdigest()


def code_version() -> str:
    """``git describe --always --dirty`` of the checkout the package runs from, else
    ``drill-env <version>`` (an installed wheel)."""
    from drill_env.agents._locations import ROOT

    if (ROOT / ".git").exists() and (ROOT / "pyproject.toml").is_file():
        try:
            out = subprocess.run(
                ["git", "-C", str(ROOT), "describe", "--always", "--dirty", "--tags"],
                capture_output=True,
                text=True,
                timeout=10,
                check=True,
            )
            return f"git {out.stdout.strip()}"
        except (OSError, subprocess.SubprocessError):
            pass
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"drill-env {version('drill-env')}"
    except PackageNotFoundError:
        return "unknown"


def _library_versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in _LIBRARIES:
        try:
            out[name] = version(name.replace("_", "-"))
        except PackageNotFoundError:
            out[name] = "not installed"
    return out


def code_identity() -> dict[str, str]:
    """The code version and the source digest of the package as it is now."""
    return {"code_version": code_version(), "source_sha256": source_digest()}


def session_record(
    cfg: Any, *, rows_run: int, rows_before: int, backend: str, code: dict[str, str] | None = None
) -> dict[str, Any]:
    """One session's record (see the module docstring); ``code``: :func:`code_identity` taken
    when the session started (default: now)."""
    from drill_env.envs.config import EnvSettings

    env_kwargs = dict(cfg.episode.env_kwargs)
    defaults = EnvSettings()
    return {
        "finished": datetime.now(UTC).isoformat(timespec="seconds"),
        **(code or code_identity()),
        "rows_run": int(rows_run),
        "rows_found_done": int(rows_before),
        "backend": backend,
        "seeds": list(cfg.seeds),
        "solver": {
            "method": "event-driven DOP853 between friction events (drill_env.integrator)",
            "rtol": float(env_kwargs.get("rtol", defaults.rtol)),
            "atol": float(env_kwargs.get("atol", defaults.atol)),
            "control_dt": float(env_kwargs.get("control_dt", defaults.control_dt)),
        },
        "episode": cfg.episode.to_dict(),
        "custom_controllers": dict(cfg.custom),
        "platform": {
            "python": sys.version.split()[0],
            "implementation": platform.python_implementation(),
            "system": platform.platform(),
            "machine": platform.machine(),
            "cpus": os.cpu_count(),
            "libraries": _library_versions(),
        },
    }


def write_provenance(out: Path, session: dict[str, Any]) -> Path:
    """Append ``session`` to ``out/provenance.json`` (rows already in the CSV when the file
    did not exist yet are recorded as made before it)."""
    from drill_env.outputs import atomic_write_text

    path = out / PROVENANCE_FILE
    record: dict[str, Any] = {"sessions": []}
    if path.is_file():
        try:
            record = json.loads(path.read_text(encoding="utf-8"))
        except ValueError:
            record = {"sessions": [], "note": f"an unreadable {PROVENANCE_FILE} was replaced"}
    elif session["rows_found_done"]:
        record["sessions"].append(
            {
                "rows_run": session["rows_found_done"],
                "code_version": "unknown: made before provenance.json was recorded",
            }
        )
    record["sessions"].append(session)
    atomic_write_text(path, json.dumps(record, indent=2, default=str) + "\n")
    return path
