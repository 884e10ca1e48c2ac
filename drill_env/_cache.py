"""Where numba keeps the compiled kernels, keyed by the package's own source.

numba's disk cache checks only the source file of the function it compiled, not the
files of the functions that function calls, so a change to ``dynamics.py`` would leave a
stale ``run`` (from ``kernel.py``) in the cache. Keying the cache directory on a hash of
every source file of the package makes any change start a fresh cache, and lets every
compiled function be cached safely.

The directory is ``$DRILL_ENV_CACHE_DIR`` or ``$NUMBA_CACHE_DIR`` or the user's cache
(``$XDG_CACHE_HOME`` or ``~/.cache``) under ``drill-env/numba/<hash>``. Must run before
any compiled function of the package is defined: numba reads ``numba.config.CACHE_DIR``
when a ``cache=True`` function is decorated.

If that directory cannot be created or written, the kernels are compiled into a private
temporary directory (removed at exit) with a warning -- never into numba's default
locations (``__pycache__`` beside the source), which are not keyed by the hash and would
hand back a stale kernel after a source change. Unless ``$NUMBA_CACHE_LOCATOR_CLASSES``
says otherwise, numba is also told to use that directory only, so that a failure there
is an error rather than a silent fall-back to those locations.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import numba

ENV_VAR = "DRILL_ENV_CACHE_DIR"


def source_hash(root: Path | None = None) -> str:
    """The cache key of the package in ``root`` (default: this one)."""
    root = Path(__file__).resolve().parent if root is None else root
    h = hashlib.sha256(numba.__version__.encode())
    for path in sorted(root.rglob("*.py")):
        if path.relative_to(root).parts[0] == "agents":
            # the controllers (drill_env.agents) define no compiled function, and none may
            # be added there; left out, the key is the same in a checkout (drill_env/agents
            # links to agents/) and in the wheel (a copy), and editing them keeps the cache
            continue
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _usable(path: Path) -> None:
    """Create ``path`` and check that a file can be written in it; OSError if not."""
    path.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryFile(dir=path):
        pass


def _private_cache(reason: str) -> Path:
    try:
        tmp = Path(tempfile.mkdtemp(prefix="drill-env-numba-"))
    except OSError as exc:
        raise OSError(
            f"drill-env: {reason}, and no temporary directory is writable either ({exc}); "
            f"set {ENV_VAR} to a writable directory"
        ) from None
    atexit.register(shutil.rmtree, tmp, ignore_errors=True)
    warnings.warn(
        f"drill-env: {reason}; compiling the kernels into a private temporary cache {tmp} "
        f"(removed at exit, so every run compiles afresh); set {ENV_VAR} to a writable directory "
        "to keep them",
        RuntimeWarning,
        stacklevel=3,
    )
    # worker processes (spawned, they import the package anew) share it instead of
    # warning and compiling each on its own; they end before this process removes it
    os.environ[ENV_VAR] = str(tmp)
    return tmp / source_hash()


def configure() -> Path:
    base = os.environ.get(ENV_VAR) or os.environ.get("NUMBA_CACHE_DIR")
    if base:
        root = Path(base)
    else:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "drill-env" / "numba"
    path = root / source_hash()
    try:
        _usable(path)
    except OSError as exc:
        path = _private_cache(f"cannot use the numba cache directory {path} ({exc.strerror or exc})")
        _usable(path)
    numba.config.CACHE_DIR = str(path)  # type: ignore[attr-defined]  # set at runtime; numba's stubs omit it
    from numba.core import caching

    if (
        not os.environ.get("NUMBA_CACHE_LOCATOR_CLASSES")
        and hasattr(numba.config, "CACHE_LOCATOR_CLASSES")  # recent numba only
        and hasattr(caching, "UserProvidedCacheLocator")
    ):
        # only the directory above: never numba's default locations, not keyed by the hash
        numba.config.CACHE_LOCATOR_CLASSES = "UserProvidedCacheLocator"
    return path


def cache_dir() -> Path:
    """The directory the compiled kernels of this process go to."""
    return Path(numba.config.CACHE_DIR)  # type: ignore[attr-defined]  # numba's stubs omit it
