"""What the oscillations tell before any fit: the period of the torsional cycles.

On a cycle the lower disk swings on the string at close to the string's resonance,
``sqrt(k_theta / J_l)`` (the paper, Sec. 4: "the period of the vibrations stays close to
that of the linear resonance"), so the dominant frequency of the lower disk's speed in the
constant-voltage runs that cycle gives a first ``J_l = k_theta / (2 pi f)^2``. It only
weights the first pass of the joint fit (:mod:`.joint`), where the inertias come from the
random-level runs and the cycles together.
"""

from __future__ import annotations

import numpy as np

__all__ = ["oscillation_frequency"]


def oscillation_frequency(runs, states) -> float:
    """Median dominant frequency of the lower-disk speed over the cycling runs [Hz] (nan: none)."""
    cycling = {s.run for s in states if s.kind == "cycle"}
    found = []
    for r in runs:
        if r.name not in cycling:
            continue
        k = max(1, int(round(0.05 / r.dt)))
        speed = (r.theta_l[k:] - r.theta_l[:-k]) / (k * r.dt)
        speed = speed[:: max(1, k // 2)]
        dt = r.dt * max(1, k // 2)
        x = speed - speed.mean()
        if x.size < 64:
            continue
        spec = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
        f = np.fft.rfftfreq(x.size, dt)
        band = (f > 0.02) & (f < 5.0)
        if band.any():
            found.append(float(f[band][np.argmax(spec[band])]))
    return float(np.median(found)) if found else float("nan")
