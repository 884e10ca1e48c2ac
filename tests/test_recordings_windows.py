"""The equation-error windows of a coarse encoder: a window is kept only where its disk turns
one way throughout (friction of one sign), checked against the true speed of the same run."""

from __future__ import annotations

import math

import numpy as np

from drill_env.identify import draw_rig
from drill_env.recordings.equation_error import RunEquations, estimate_angle_noise
from drill_env.recordings.protocols import record_protocol


def _prbs(counts: int):
    rig = draw_rig("no_brake", 43, low=0.35, high=3.0)
    res = record_protocol(
        rig,
        "prbs",
        seed=1,
        duration_s=30.0,
        sample_rate_hz=1000.0,
        encoder_counts_per_rev=counts,
        preset="no_brake",
    )
    return rig, res.runs[0]  # the -3/3 V sequence: the upper disk slows and reverses at its switches


def test_windows_where_a_coarse_encoder_disk_reverses_are_dropped():
    """1024 counts at 1 kHz: at a slow turn the speed is a 0.4 s window's, which averages a short
    reversal away; the readings show it (a count held as long as a stop holds it, or one back).
    Every window kept has the true speed of one sign over its support, and at the truth the
    equation error is at its noise floor (a reversal left in gave a sum of squares 25 times it)."""
    rig, run = _prbs(1024)
    _, fine = _prbs(2**24)  # the same run read by a fine encoder: the true speed
    assert np.array_equal(run.u, fine.u) and np.ptp(run.u) == 6.0
    v = np.gradient(fine.theta_u, fine.dt)
    eq = RunEquations(run, rig, estimate_angle_noise([run], 2.0 * math.pi / 1024))
    w = eq.upper
    reversing = [
        c for c, s in zip(w.centers, w.sign, strict=True) if np.any(s * v[c - eq.L : c + eq.L + 1] <= 0.0)
    ]
    assert len(w) >= 5 and not reversing, (len(w), reversing)
    assert w.z @ w.z / len(w) < 1.6
    # a disk slipping fast throughout loses no window to the check: those the fine encoder keeps
    # with the true speed above 1 rad/s over the support are all kept at 1024 counts
    ref = RunEquations(fine, rig, estimate_angle_noise([fine], 2.0 * math.pi / 2**24)).upper
    fast = {
        int(c)
        for c, s in zip(ref.centers, ref.sign, strict=True)
        if np.all(s * v[c - eq.L : c + eq.L + 1] > 1.0)
    }
    assert len(fast) >= 3 and fast <= set(w.centers.tolist()), (sorted(fast), w.centers)


def test_a_lower_disk_minimum_speed_keeps_only_its_faster_windows():
    """``min_speed_lower_rad_s``: the lower disk's windows are those where it slips at least that
    fast throughout; the upper disk's are untouched (the structure tests of a fit whose lower
    friction is seen only from some slip up compare there only)."""
    from drill_env.recordings.equation_error import EquationErrorConfig

    rig, run = _prbs(4096)
    noise = estimate_angle_noise([run], 2.0 * math.pi / 4096)
    every = RunEquations(run, rig, noise)
    slow = float(np.quantile(np.abs(every.gather(every.speed_l, every.lower.centers)).min(axis=1), 0.5))
    fast = RunEquations(run, rig, noise, EquationErrorConfig(min_speed_lower_rad_s=slow))
    assert np.array_equal(fast.upper.centers, every.upper.centers)
    assert 0 < len(fast.lower) < len(every.lower)
    assert set(fast.lower.centers) <= set(every.lower.centers)
    assert np.all(np.abs(fast.gather(fast.speed_l, fast.lower.centers)) >= slow)
