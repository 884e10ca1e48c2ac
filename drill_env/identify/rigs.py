"""Rigs other than the paper's, for tests, benchmarks and examples: every parameter of a
preset scaled by its own random factor."""

from __future__ import annotations

import math

import numpy as np

from drill_env.params import IDENTIFIED_PARAMETERS, ParameterError, RigParams, load_params

__all__ = ["draw_rig"]


def draw_rig(
    structure: str, seed: int, *, low: float = 0.5, high: float = 2.0, max_tries: int = 1000
) -> RigParams:
    """A rig of ``structure`` (a preset) with every identified parameter times a factor drawn
    log-uniformly from [low, high] (redrawn until the lower friction stays dissipative); the hump
    terms in the paper's order, the faster rate first."""
    if not (0.0 < low <= high and math.isfinite(high)):
        raise ValueError(f"low/high: need 0 < low <= high, got {low!r}, {high!r}")
    base = load_params(structure)
    rng = np.random.default_rng([seed, 33])
    for _ in range(max_tries):
        f = np.exp(rng.uniform(math.log(low), math.log(high), len(IDENTIFIED_PARAMETERS)))
        values = {
            n: float(getattr(base, n)) * float(k) for n, k in zip(IDENTIFIED_PARAMETERS, f, strict=True)
        }
        if values["lower_hump_rate_1"] < values["lower_hump_rate_2"]:
            # the same friction curve with its terms in the paper's order (beta_1 >= beta_2), the
            # order identify reports them in
            for a, b in (("lower_hump_1", "lower_hump_2"), ("lower_hump_rate_1", "lower_hump_rate_2")):
                values[a], values[b] = values[b], values[a]
        try:
            return base.replace(
                **values,
                name=f"{structure}-drawn-{seed}",
                description=f"{structure} rig with every parameter x{low:g}-x{high:g} (seed {seed})",
            )
        except ParameterError:
            continue
    raise ValueError(f"no dissipative rig drawn in {max_tries} tries (structure {structure!r}, seed {seed})")
