"""The regimes of the nominal model along the voltage axis (Fig. 8 of the paper).

* ``equilibrium``: the slip equilibrium is stable and reached open loop from rest;
* ``limit_cycle``: torsional limit cycle without stick-slip (beyond the Hopf point B,
  and for the no-brake rig also between E and F where a stable cycle coexists with
  the stable equilibrium beyond the subcritical Hopf point C);
* ``stick_slip``: the limit cycle has stick phases of the lower disk (beyond D).

How the boundaries are found (:func:`operating_regimes`):

* A = uc1 = (T_sup + T_sl)/km, where the rig starts to move (closed form);
* Hopf points: from :mod:`drill_env.analysis.equilibria` (Routh-Hurwitz on the
  linearisation of eq. (23); the equilibrium is stable iff ``dT_l/dx3`` exceeds a
  critical slope, -0.00114 N m s/rad for the paper's parameters);
* stick-slip and coexistence boundaries (D, E, F) are not local bifurcations of the
  equilibrium, so they come from simulation: the exact simulator runs from rest at a
  grid of voltages between the Hopf points, each run is classified over a late window
  (a lower-disk stick event means stick-slip; a sustained oscillation on the stable
  side means a coexisting cycle), and each change of class is refined by repeated
  subdivision to about a tenth of a millivolt.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np

from drill_env import _layout as L
from drill_env._numba import JIT_ALLOC
from drill_env.envs.equilibrium import (
    critical_friction_slope,
    equilibrium_speed,
    hopf_voltages,
    nominal_params,
    stable_at_speed,
)
from drill_env.kernel import N_STATS, ST_EVENTS, ST_LOGGED, STATUS_MESSAGES, run
from drill_env.params import RIG_VOLTAGE_LIMIT, RigParams

__all__ = ["REGIMES", "OperatingRegimes", "operating_regimes"]

REGIMES = ("equilibrium", "limit_cycle", "stick_slip")

_JIT = JIT_ALLOC


@nb.njit(**_JIT)
def _classify_runs(P, volts, t_settle, t_window, n_window, rtol, atol, max_steps, res):
    """From rest at each voltage: settle, then watch a window. res[i] = (lower stick events,
    x3 range first half, x3 range second half, mean x3, status)."""
    cap = 8192
    ev_t = np.empty(cap)
    ev_disk = np.empty(cap, dtype=np.int64)
    ev_from = np.empty(cap, dtype=np.int64)
    ev_to = np.empty(cap, dtype=np.int64)
    ev_y = np.empty((cap, L.NY))
    stats = np.zeros(N_STATS)
    modes = np.zeros(2, dtype=np.int64)
    seg_t = np.empty(2)
    seg_u = np.empty(1)
    t1 = np.empty(1)
    Y1 = np.empty((1, L.NY))
    M1 = np.empty((1, 2), dtype=np.int64)
    U1 = np.empty(1)
    t_out = np.empty(n_window)
    Y = np.empty((n_window, L.NY))
    M = np.empty((n_window, 2), dtype=np.int64)
    U = np.empty(n_window)
    for k in range(n_window):
        t_out[k] = t_settle + (k + 1) * (t_window / n_window)
    for i in range(volts.shape[0]):
        y = np.zeros(L.NY)
        y[L.TM] = P[i, L.KM] * volts[i]
        modes[:] = 0
        seg_u[0] = volts[i]
        seg_t[0] = 0.0
        seg_t[1] = t_settle
        t1[0] = t_settle
        status = run(
            P[i],
            y,
            modes,
            seg_t,
            seg_u,
            None,
            False,
            np.inf,
            t1,
            rtol,
            atol,
            0.0,
            max_steps,
            Y1,
            M1,
            U1,
            ev_t,
            ev_disk,
            ev_from,
            ev_to,
            ev_y,
            stats,
        )
        h = stats[5]
        if status == 0:
            seg_t[0] = t_settle
            seg_t[1] = t_settle + t_window
            status = run(
                P[i],
                y,
                modes,
                seg_t,
                seg_u,
                None,
                False,
                np.inf,
                t_out,
                rtol,
                atol,
                h,
                max_steps,
                Y,
                M,
                U,
                ev_t,
                ev_disk,
                ev_from,
                ev_to,
                ev_y,
                stats,
            )
        sticks = 0.0
        logged = int(stats[ST_LOGGED])
        for e in range(logged):
            if ev_disk[e] == 1 and ev_to[e] == 0:
                sticks += 1.0
        if stats[ST_EVENTS] > logged:
            sticks += stats[ST_EVENTS] - logged  # overflow: count the rest as possible sticks
        half = n_window // 2
        lo1 = np.inf
        hi1 = -np.inf
        lo2 = np.inf
        hi2 = -np.inf
        mean = 0.0
        for k in range(n_window):
            x3 = Y[k, L.X3]
            mean += x3
            if M[k, 1] == 0:
                sticks = max(sticks, 1.0)
            if k < half:
                lo1 = min(lo1, x3)
                hi1 = max(hi1, x3)
            else:
                lo2 = min(lo2, x3)
                hi2 = max(hi2, x3)
        res[i, 0] = sticks
        res[i, 1] = hi1 - lo1
        res[i, 2] = hi2 - lo2
        res[i, 3] = mean / n_window
        res[i, 4] = status


_SETTLE = 150.0  # [s] open-loop run from rest before the classification window
_WINDOW = 50.0  # [s] about a dozen periods of the torsional cycle
_N_WINDOW = 5000
_MAX_STEPS = 10_000_000  # passed as an argument: a literal would compile the kernel a second time
_SUSTAINED_REL = 0.05  # a cycle on the stable side: range > 5 % of the mean speed ...
_SUSTAINED_RATIO = 0.9  # ... and not decaying between the halves of the window


def _classify(params: RigParams, volts: np.ndarray) -> list[str]:
    volts = np.asarray(volts, dtype=float)
    p = params.as_array()
    res = np.zeros((volts.size, 5))
    _classify_runs(
        np.tile(p, (volts.size, 1)), volts, _SETTLE, _WINDOW, _N_WINDOW, 1e-9, 1e-11, _MAX_STEPS, res
    )
    # A run that the kernel could not finish is repeated at a voltage a few parts per
    # million off (its trajectory then avoids the failing instant).
    for attempt in range(1, 4):
        bad = np.flatnonzero(res[:, 4] != 0)
        if bad.size == 0:
            break
        sub = np.zeros((bad.size, 5))
        _classify_runs(
            np.tile(p, (bad.size, 1)),
            volts[bad] * (1.0 + 3e-6 * attempt),
            _SETTLE,
            _WINDOW,
            _N_WINDOW,
            1e-9,
            1e-11,
            _MAX_STEPS,
            sub,
        )
        res[bad] = sub
    bad = np.flatnonzero(res[:, 4] != 0)
    if bad.size:
        raise RuntimeError(
            f"operating_regimes: the simulation at {volts[bad[0]]:g} V failed: "
            f"{STATUS_MESSAGES[int(res[bad[0], 4])]}"
        )
    out = []
    for u, (sticks, amp1, amp2, mean, _) in zip(volts, res, strict=True):
        if sticks > 0:
            out.append("stick_slip")
            continue
        w = equilibrium_speed(params, u)
        if not stable_at_speed(params, w):
            out.append("limit_cycle")
        elif amp2 > _SUSTAINED_REL * max(abs(mean), 1e-3) and amp2 >= _SUSTAINED_RATIO * amp1:
            out.append("limit_cycle")  # a stable cycle coexists and attracts the start from rest
        else:
            out.append("equilibrium")
    return out


@dataclass(frozen=True)
class OperatingRegimes:
    """The voltage axis (uc1, u_max] of the nominal model split into regimes.

    ``intervals`` are (regime, low, high) voltage intervals [V] in increasing order;
    ``hopf`` the Hopf voltages (closed form), ``transitions`` the boundaries found by
    simulation.
    """

    uc1: float  # [V] point A
    u_max: float  # [V]
    critical_slope: float  # [N m s / rad] Routh-Hurwitz threshold on dT_l/dx3
    hopf: tuple[float, ...]  # [V]
    transitions: tuple[float, ...]  # [V]
    intervals: tuple[tuple[str, float, float], ...]

    def regime_of(self, voltage: float) -> str:
        """Regime at a nominal voltage in (uc1, u_max]."""
        u = float(voltage)
        if not self.uc1 < u <= self.u_max:
            raise ValueError(f"voltage: {u!r} is outside ({self.uc1:.6g}, {self.u_max:g}] V")
        for name, lo, hi in self.intervals:
            if lo < u <= hi:
                return name
        return self.intervals[-1][0]

    def intervals_of(self, regime: str) -> list[tuple[float, float]]:
        if regime not in REGIMES:
            raise ValueError(f"regime: {regime!r} is not one of {REGIMES}")
        return [(lo, hi) for name, lo, hi in self.intervals if name == regime]

    def describe(self) -> str:
        return "\n".join(f"{name:12s} {lo:8.4f} .. {hi:8.4f} V" for name, lo, hi in self.intervals)


@functools.lru_cache(maxsize=16)
def _operating_regimes(params: RigParams, u_max: float, spacing: float) -> OperatingRegimes:
    a = params.uc1
    if not u_max > a:
        raise ValueError(f"u_max: {u_max:g} V must exceed uc1 = {a:.6g} V")
    d_crit = critical_friction_slope(params)
    hopf = hopf_voltages(params, u_max)
    edges = [a, *hopf, u_max]
    # Grid points inside each stretch of constant linear stability, kept away from its
    # ends (a decaying oscillation near a Hopf point decays arbitrarily slowly).
    stretches = []
    points: list[float] = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        margin = min(0.02, 0.25 * (hi - lo))
        n = max(2, int(math.ceil((hi - lo - 2 * margin) / spacing)) + 1)
        pts = np.linspace(lo + margin, hi - margin, n)
        stretches.append((lo, hi, len(points), len(points) + n))
        points.extend(pts.tolist())
    grid = np.array(points)
    cls = _classify(params, grid)
    # Brackets of class changes within a stretch, refined by subdivision.
    brackets = []
    for _, _, i0, i1 in stretches:
        for i in range(i0, i1 - 1):
            if cls[i] != cls[i + 1]:
                brackets.append([grid[i], grid[i + 1], cls[i], cls[i + 1]])
    for _ in range(4):
        if not brackets:
            break
        inner = [np.linspace(b[0], b[1], 9)[1:-1] for b in brackets]
        flat = _classify(params, np.concatenate(inner))
        for j, b in enumerate(brackets):
            c = flat[7 * j : 7 * j + 7]
            us = [b[0], *inner[j], b[1]]
            cs = [b[2], *c, b[3]]
            k = next(k for k in range(8) if cs[k] != cs[k + 1])
            brackets[j] = [us[k], us[k + 1], cs[k], cs[k + 1]]
    transitions = sorted(0.5 * (b[0] + b[1]) for b in brackets)
    # Assemble: within a stretch the class is constant between consecutive transitions.
    pieces: list[list[Any]] = []
    for lo, hi, i0, i1 in stretches:
        cuts = [lo, *[t for t in transitions if lo < t < hi], hi]
        for j in range(len(cuts) - 1):
            members = [cls[i] for i in range(i0, i1) if cuts[j] <= grid[i] <= cuts[j + 1]]
            # Every piece holds a grid point except the margins at the stretch ends, which
            # take the class of the nearest grid point.
            name = members[0] if members else (cls[i0] if j == 0 else cls[i1 - 1])
            if pieces and pieces[-1][0] == name:
                pieces[-1][2] = cuts[j + 1]
            else:
                pieces.append([name, cuts[j], cuts[j + 1]])
    return OperatingRegimes(
        uc1=a,
        u_max=float(u_max),
        critical_slope=d_crit,
        hopf=tuple(float(h) for h in hopf),
        transitions=tuple(float(t) for t in transitions),
        intervals=tuple((n, float(lo), float(hi)) for n, lo, hi in pieces),
    )


def operating_regimes(
    params: RigParams, u_max: float = RIG_VOLTAGE_LIMIT, spacing: float = 0.1
) -> OperatingRegimes:
    """Regimes of the nominal model along the voltage axis (uc1, u_max], computed once per
    parameter set (cached): Hopf points in closed form, the rest by simulation from rest.

    Takes about half a second for the paper's presets.
    """
    u_max = float(u_max)
    spacing = float(spacing)
    if not (math.isfinite(u_max) and u_max > 0):
        raise ValueError(f"u_max: must be finite and > 0, got {u_max!r}")
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing: must be finite and > 0, got {spacing!r}")
    return _operating_regimes(nominal_params(params), u_max, spacing)
