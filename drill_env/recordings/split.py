"""Which runs of a dataset are held out: the runs a fit never sees, for validation."""

from __future__ import annotations

__all__ = ["split_runs"]


def split_runs(runs) -> tuple[list[str], list[str]]:
    """Held-out runs: every third run, in order of voltage, separately for constant-voltage
    and varying-voltage runs (at least one of each kind held out when it has two or more)."""
    const = sorted([r for r in runs if r.is_constant_voltage], key=lambda r: (r.voltage, r.name))
    vary = sorted([r for r in runs if not r.is_constant_voltage], key=lambda r: r.name)
    held: list[str] = []
    for group in (const, vary):
        if len(group) >= 2:
            held += [r.name for i, r in enumerate(group) if i % 3 == 1]
    if not held:
        raise ValueError("the dataset needs at least two runs of one kind to hold one out")
    train = [r.name for r in runs if r.name not in held]
    return train, held
