"""One section of a training config read from its mapping."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def config_section(cls: type, value: Any, name: str) -> Any:
    """``cls(**value)`` for the config section ``name`` (``cls`` a dataclass).

    ``None`` and instances of ``cls`` pass through. Anything but a mapping, or a key that is
    not a field of ``cls``, is a ``ValueError`` naming the section and the allowed keys."""
    if value is None or isinstance(value, cls):
        return value
    if not isinstance(value, Mapping):
        raise ValueError(f"{name}: expected a mapping or null, got {value!r}")
    allowed = sorted(cls.__dataclass_fields__)
    unknown = sorted(set(value) - set(allowed))
    if unknown:
        raise ValueError(f"{name}: unknown key(s) {unknown}; allowed: {allowed}")
    return cls(**value)
