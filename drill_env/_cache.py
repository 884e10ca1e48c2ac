"""Where numba keeps the compiled kernels, keyed by the package's own source.

numba's disk cache checks only the source file of the function it compiled, not the
files of the functions that function calls, so a change to ``dynamics.py`` would leave a
stale ``run`` (from ``kernel.py``) in the cache. Keying the cache directory on a hash of
every source file of the package makes any change start a fresh cache, and lets every
compiled function be cached safely.

The directory is ``$DRILL_ENV_CACHE_DIR`` or ``$NUMBA_CACHE_DIR`` or the user's cache
(``$XDG_CACHE_HOME`` or ``~/.cache``) under ``drill-env/numba/<hash>``. Must run before
any compiled function of the package is defined.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba


def source_hash() -> str:
    root = Path(__file__).resolve().parent
    h = hashlib.sha256(numba.__version__.encode())
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def configure() -> Path:
    base = os.environ.get("DRILL_ENV_CACHE_DIR") or os.environ.get("NUMBA_CACHE_DIR")
    if base:
        root = Path(base)
    else:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "drill-env" / "numba"
    path = root / source_hash()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return Path(numba.config.CACHE_DIR or "")  # not writable: numba's own default
    numba.config.CACHE_DIR = str(path)
    return path
