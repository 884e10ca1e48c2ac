"""The options every compiled function of the package is built with.

All are cached on disk (in the directory :mod:`drill_env._cache` keys on the package's
source, so a change anywhere cannot leave a stale kernel), release the GIL, keep IEEE
semantics (no fastmath: the event location relies on exact comparisons) and follow
NumPy's rules for floating-point errors (1/0 is inf, not an exception).

* :data:`JIT_ALLOC` for functions that allocate arrays;
* :data:`JIT` for those that allocate nothing: they run without numba's reference
  counting (``_nrt=False``), which would otherwise cost atomic increments and decrements
  on every call that passes arrays -- as much as the arithmetic of a step;
* :data:`INLINE` for small helpers of the innermost loops, inlined into their callers.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from drill_env import _cache

# every compiled module imports this one before defining a function: the cache directory is
# set here, once, and ``import drill_env`` alone (or ``drill-env --help``) loads no numba
_cache.configure()

__all__ = ["JIT_ALLOC", "JIT", "INLINE"]

# keyword arguments of numba.njit, of several types each (``_nrt`` is one numba's own
# signature does not name: it takes it through its **options)
JIT_ALLOC: Mapping[str, Any] = MappingProxyType(
    dict(cache=True, nogil=True, fastmath=False, error_model="numpy")
)
JIT: Mapping[str, Any] = MappingProxyType(dict(JIT_ALLOC, _nrt=False))
INLINE: Mapping[str, Any] = MappingProxyType(dict(JIT, inline="always"))
