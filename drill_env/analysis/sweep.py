"""Independent check of a bifurcation diagram by brute-force simulation.

The event-driven simulator (:func:`drill_env.simulate_batch`, a different integrator
from the continuation's) runs the rig at a grid of constant voltages:

* from a *small* perturbation of the equilibrium and from a *large* one (the lower disk
  held at rest while the upper disk turns at the equilibrium speed, then released),
  each for ``settle`` seconds;
* in two quasi-static *sweeps*, one rig stepping u up the grid and one stepping it
  down, ``dwell`` seconds per step, each step starting where the last one ended.

Every end state is then run for ``measure`` seconds more and the steady extremes of the
lower-disk speed x3 measured. Each run must land on an attractor of the diagram: a
stable equilibrium with the same x3, or a stable periodic orbit whose max/min of x3
agree within ``tol`` (relative to the orbit's largest |x3|). Every stable branch must be
reached at every grid voltage inside its range, and between the subcritical Hopf point
C and the fold F both the stable equilibrium and the stable cycle must be found.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from drill_env.analysis.diagram import BifurcationDiagram, EquilibriumBranch, PeriodicSegment
from drill_env.analysis.equilibria import equilibria
from drill_env.analysis.shooting import LimitCycle

__all__ = ["SweepRun", "BruteForceCheck", "brute_force_check"]

RUN_KINDS = ("small", "large", "forward", "backward")


@dataclass
class SweepRun:
    """The steady state one simulation reached at voltage u."""

    u: float
    kind: str  # small, large, forward, backward
    x3_min: float
    x3_max: float
    x3_mean: float
    period: float  # mean time between upward crossings of the mean [s]; nan at rest
    stick_fraction: float
    attractor: str = ""  # "equilibrium" or "cycle"
    branch: str = ""  # name of the diagram branch it matched, "" if none
    error: float = math.nan  # relative error of max/min x3 against that branch
    ok: bool = False


@dataclass
class BruteForceCheck:
    preset: str
    u_grid: np.ndarray
    runs: list[SweepRun]
    tol: float
    settle: float
    dwell: float
    measure: float
    branches_confirmed: dict[str, list[float]] = field(default_factory=dict)  # name -> grid u not reached
    coexistence: list[dict] = field(default_factory=list)
    jumps: dict[str, list[dict]] = field(default_factory=dict)  # attractor changes along each sweep
    seconds: float = 0.0

    @property
    def max_error(self) -> float:
        errs = [r.error for r in self.runs if math.isfinite(r.error)]
        return max(errs) if errs else math.nan

    @property
    def unmatched(self) -> list[SweepRun]:
        return [r for r in self.runs if not r.ok]

    @property
    def passed(self) -> bool:
        return (
            not self.unmatched
            and all(not missing for missing in self.branches_confirmed.values())
            and all(c["equilibrium"] and c["cycle"] for c in self.coexistence)
        )

    def summary(self) -> str:
        lines = [
            f"brute-force check ({self.preset}): {len(self.runs)} runs at {self.u_grid.size} voltages, "
            f"{'PASSED' if self.passed else 'FAILED'}",
            f"  largest relative error of max/min x3 against the continuation: {self.max_error:.2e} (tol {self.tol:g})",
        ]
        for name, missing in self.branches_confirmed.items():
            lines.append(
                f"  stable branch {name}: "
                + ("confirmed" if not missing else f"NOT reached at u = {missing}")
            )
        if self.coexistence:
            both = sum(c["equilibrium"] and c["cycle"] for c in self.coexistence)
            lines.append(
                f"  coexistence C-F: stable equilibrium and stable cycle at {both}/{len(self.coexistence)} voltages"
            )
        for k, v in self.jumps.items():
            steps = ", ".join(f"{j['from']} -> {j['to']} near {j['u']:.3f} V" for j in v)
            lines.append(f"  {k} sweep: {steps or 'no change of attractor'}")
        for r in self.unmatched:
            lines.append(
                f"  unmatched: {r.kind} run at u = {r.u:.4f} V, x3 in [{r.x3_min:.5f}, {r.x3_max:.5f}]"
            )
        return "\n".join(lines)

    def to_dict(self) -> dict:
        def clean(d):
            return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}

        return {
            "preset": self.preset,
            "passed": self.passed,
            "tolerance": self.tol,
            "max_relative_error": None if math.isnan(self.max_error) else self.max_error,
            "settle_s": self.settle,
            "dwell_s": self.dwell,
            "measure_s": self.measure,
            "u_grid": self.u_grid.tolist(),
            "branches_confirmed": {
                k: {"confirmed": not v, "not_reached_at": v} for k, v in self.branches_confirmed.items()
            },
            "coexistence_C_F": self.coexistence,
            "sweep_jumps": self.jumps,
            "runs": [clean(asdict(r)) for r in self.runs],
        }

    def save_json(self, path: str | Path) -> None:
        from drill_env.outputs import atomic_write_text

        atomic_write_text(path, json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n")

    def plot(self, diagram: BifurcationDiagram, ax=None):
        """The diagram's Fig. 8 with the steady max/min of x3 of every run as open markers."""
        return diagram.plot("fig8", ax=ax, check=self)


def _stretches(diagram: BifurcationDiagram) -> list[EquilibriumBranch | PeriodicSegment]:
    """The diagram's equilibrium branches and periodic segments, each with ``u`` and ``stable``."""
    return [*diagram.equilibrium_branches, *diagram.periodic_segments]


def _default_grid(diagram: BifurcationDiagram, n: int, settle: float) -> np.ndarray:
    lo, hi = diagram.u_min, diagram.u_max
    step = (hi - lo) / n
    grid = list(lo + step * (np.arange(n) + 0.5))
    # At least two voltages inside every stable stretch of a branch.
    for seg in _stretches(diagram):
        stable = np.asarray(seg.stable)
        if stable.size and stable.mean() > 0.5:
            a, b = float(np.min(seg.u)), float(np.max(seg.u))
            inside = [g for g in grid if a < g < b]
            if len(inside) < 2 and b - a > 1e-3:
                grid += [a + (b - a) / 3, a + 2 * (b - a) / 3]
    # Keep clear of the Hopf points and folds, where transients decay (or grow) slowly:
    # next to a Hopf point the rate is |d Re(lambda)/du| |u - u_H|, and ``settle`` must
    # cover some twenty time constants of it.
    gap = 0.01 * max(1.0, (hi - lo) / 2.5)
    specials = []
    for pt in diagram.points.values():
        if pt.type.startswith("hopf"):
            specials.append((pt.u, max(gap, 20.0 / (settle * abs(pt.detail["crossing_speed"])))))
        elif pt.type.startswith("fold"):
            specials.append((pt.u, gap))
    out = []
    for g in sorted(grid):
        for s, width in specials:
            if abs(g - s) < width:
                g = s + math.copysign(width, g - s if g != s else 1.0)
        if lo < g < hi:
            out.append(g)
    return np.unique(np.round(out, 10))


def _measure(t: np.ndarray, x3: np.ndarray, stuck: np.ndarray) -> tuple[float, float, float, float, float]:
    lo, hi, mean = float(x3.min()), float(x3.max()), float(x3.mean())
    period = math.nan
    if hi - lo > 1e-6 * max(1.0, abs(mean)):
        s = x3 - mean
        idx = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))
        if idx.size >= 2:
            tc = t[idx] - s[idx] * (t[idx + 1] - t[idx]) / (s[idx + 1] - s[idx])
            period = float((tc[-1] - tc[0]) / (idx.size - 1))
    return lo, hi, mean, period, float(np.mean(stuck))


def _segment_of(diagram: BifurcationDiagram, u: float, cycle: LimitCycle) -> str:
    for seg in diagram.periodic_segments:
        us = seg.u
        if us.min() - 1e-9 <= u <= us.max() + 1e-9 and seg.stick_slip == cycle.stick_slip:
            if bool(np.mean(seg.stable) > 0.5) == cycle.stable:
                return seg.name
    return ""


def _equilibrium_branch_of(diagram: BifurcationDiagram, u: float) -> tuple[str, bool]:
    for b in diagram.equilibrium_branches:
        if b.u.min() - 1e-12 <= u <= b.u.max() + 1e-12:
            return b.name, bool(np.mean(b.stable) > 0.5)
    return "", False


def brute_force_check(
    diagram: BifurcationDiagram,
    u_grid: np.ndarray | None = None,
    *,
    n_grid: int = 50,
    settle: float = 4000.0,
    dwell: float = 1000.0,
    measure: float = 30.0,
    tol: float = 0.01,
    progress: Callable[[str, float], None] | None = None,
) -> BruteForceCheck:
    """Confirm the attractors of ``diagram`` by long simulations (see the module docstring)."""
    from drill_env.simulator import simulate_batch

    t_start = time.perf_counter()
    params = diagram.params
    grid = _default_grid(diagram, n_grid, settle) if u_grid is None else np.asarray(u_grid, dtype=float)
    report = progress or (lambda stage, frac: None)
    eqs = [equilibria(params, u)[0] for u in grid]
    small = []
    large = []
    for e in eqs:
        x1, x3 = e.x1, e.x3
        small.append([x1 + 1e-3 * max(1.0, abs(x1)), x3, x3 + 1e-3 * max(1.0, abs(x3))])
        large.append([x1, x3, 0.0] if x3 != 0.0 else [x1, 0.0, 0.0])
    n = grid.size
    report("independent runs", 0.0)
    ind = simulate_batch(params, np.concatenate([grid, grid]), settle, x0=np.array(small + large), dt=settle)
    report("independent runs", 1.0)
    # Quasi-static sweeps: one rig up the grid, one down.
    report("sweeps", 0.0)
    stairs = np.vstack([grid, grid[::-1]])
    start = np.array([small[0], small[-1]])
    sw = simulate_batch(params, stairs, n * dwell, x0=start, dt=dwell, control_dt=dwell)
    report("sweeps", 1.0)
    # End states: independent runs, then each sweep level's end.
    ends = [ind.final_state[i, :3] for i in range(2 * n)]
    us = list(grid) + list(grid)
    kinds = ["small"] * n + ["large"] * n
    for j, kind in ((0, "forward"), (1, "backward")):
        for k in range(n):
            ends.append(np.array([sw.x1[j, k + 1], sw.x2[j, k + 1], sw.x3[j, k + 1]]))
            us.append(stairs[j, k])
            kinds.append(kind)
    report("measurement", 0.0)
    meas = simulate_batch(params, np.array(us), measure, x0=np.array(ends, dtype=float), dt=0.01)
    report("measurement", 1.0)
    runs = []
    for i, (u, kind) in enumerate(zip(us, kinds, strict=True)):
        lo, hi, mean, period, stick = _measure(meas.t, meas.x3[i], meas.stick_l[i])
        runs.append(
            SweepRun(
                u=float(u), kind=kind, x3_min=lo, x3_max=hi, x3_mean=mean, period=period, stick_fraction=stick
            )
        )
    # Match every run with the nearest stable attractor of the diagram.
    cycles_cache: dict[float, list[LimitCycle]] = {}
    for k, r in enumerate(runs):
        report("matching", k / len(runs))
        if r.u not in cycles_cache:
            cycles_cache[r.u] = diagram.stable_cycles_at(r.u)
        candidates: list[tuple[float, str, str]] = []  # (error, attractor, branch)
        eq = equilibria(params, r.u)[0]
        name, stable = _equilibrium_branch_of(diagram, r.u)
        if stable:
            scale = max(1.0, abs(eq.x3))
            err = max(abs(r.x3_max - eq.x3), abs(r.x3_min - eq.x3)) / scale
            candidates.append((err, "equilibrium", name))
        for c in cycles_cache[r.u]:
            ref = max(abs(c.x3_max), abs(c.x3_min))
            err = max(abs(r.x3_max - c.x3_max), abs(r.x3_min - c.x3_min)) / ref
            candidates.append((err, "cycle", _segment_of(diagram, r.u, c)))
        if candidates:
            r.error, r.attractor, r.branch = min(candidates)
            r.ok = r.error <= tol
            if not r.ok:
                r.branch = ""
        else:
            r.attractor = (
                "cycle" if r.x3_max - r.x3_min > 2 * tol * max(1.0, abs(r.x3_mean)) else "equilibrium"
            )
    report("matching", 1.0)
    # Every stable branch reached at every grid voltage inside its range.
    confirmed: dict[str, list[float]] = {}
    for seg in _stretches(diagram):
        if not np.mean(np.asarray(seg.stable)) > 0.5:
            continue
        a, b = float(np.min(seg.u)), float(np.max(seg.u))
        inside = [u for u in grid if a < u < b]
        missing = [
            float(u) for u in inside if not any(r.ok and r.branch == seg.name and r.u == u for r in runs)
        ]
        if inside:
            confirmed[seg.name] = missing
    # Coexistence between C and F.
    coexist = []
    if "C" in diagram.points and "F" in diagram.points:
        uc, uf = diagram.points["C"].u, diagram.points["F"].u
        for u in grid:
            if min(uc, uf) < u < max(uc, uf):
                at_u = [r for r in runs if r.u == u and r.ok]
                coexist.append(
                    {
                        "u": float(u),
                        "equilibrium": any(r.attractor == "equilibrium" for r in at_u),
                        "cycle": any(r.attractor == "cycle" for r in at_u),
                    }
                )
    # Where the sweeps change attractor (B; and the hysteresis between C and F).
    jumps: dict[str, list[dict]] = {}
    for kind in ("forward", "backward"):
        seq = [r for r in runs if r.kind == kind]
        jumps[kind] = [
            {"u": 0.5 * (a.u + b.u), "from": a.attractor, "to": b.attractor}
            for a, b in zip(seq[:-1], seq[1:], strict=True)
            if a.attractor != b.attractor
        ]
    return BruteForceCheck(
        preset=diagram.preset,
        u_grid=grid,
        runs=runs,
        tol=tol,
        settle=settle,
        dwell=dwell,
        measure=measure,
        branches_confirmed=confirmed,
        coexistence=coexist,
        jumps=jumps,
        seconds=time.perf_counter() - t_start,
    )
