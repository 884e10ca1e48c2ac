"""Spectral lines of the residual: a sinusoid common to the runs (:func:`line_scan`) and
what it is locked to -- time, a disk's rotation or the voltage (:func:`line_signature`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from drill_env.discrepancy.scoring import DecisionRule
from drill_env.recordings.equation_error import RunEquations

__all__ = [
    "LineScan",
    "line_scan",
    "LineSignature",
    "line_signature",
    "LOCK_HARMONICS",
]


@dataclass(frozen=True)
class LineScan:
    """Best common spectral line of the nominal residual (per-run amplitude and phase)."""

    frequency_hz: float
    reduction: float  # drop of the sum of squares (noise units), without the run contributing most
    threshold: float
    significant: bool
    dof: int
    rotation_ratio: list[float]  # line frequency / lower-disk rotation rate, per run
    related_to_rotation: bool
    amplitude_nm: dict[str, float]  # per run, fitted amplitude [N m] (lower disk)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def line_scan(eqs: list[RunEquations], rule: DecisionRule, n_freq: int = 240) -> LineScan:
    """Scan for a sinusoid at one frequency common to the runs in the nominal residual.

    Each run and disk gets its own amplitude and phase; the line is significant when the
    drop of the sum of squares, leaving out the run that contributes most to it, passes a
    Bonferroni-corrected chi^2 test and at least ``line_run_fraction`` of the runs show
    it on their own."""
    groups = []
    for eq in eqs:
        for w in (eq.upper, eq.lower):
            if len(w) >= 8:
                groups.append((eq, w))
    if not groups:
        return LineScan(float("nan"), 0.0, float("inf"), False, 0, [], False, {})
    stride_t = min(eq.stride * eq.dt for eq, _ in groups)
    t_max = max(eq.run.duration for eq, _ in groups)
    f_lo = 3.0 / t_max
    f_hi = 0.45 / stride_t
    freqs = np.geomspace(f_lo, f_hi, n_freq)
    red_g = np.zeros((len(groups), freqs.size))
    for g, (_, w) in enumerate(groups):
        z = w.z
        s = 1.0 / w.sigma
        for i, f in enumerate(freqs):
            ph = 2.0 * math.pi * f * w.t
            X = np.column_stack([np.cos(ph) * s, np.sin(ph) * s])
            A = X.T @ X
            b = X.T @ z
            try:
                red_g[g, i] = float(b @ np.linalg.solve(A, b))
            except np.linalg.LinAlgError:
                pass
    red = red_g.sum(axis=0)
    dof = 2 * len(groups)
    # A line of the quantisation error sits at one run's count rate, and on the grid of
    # windows it can alias anywhere; a torque the model lacks acts in every run. So the
    # line is scored without the run that contributes most to it at its frequency.
    run_of = [eq.run.name for eq, _ in groups]
    names = sorted(set(run_of))
    if len(names) > 1:
        member = np.array([[n == name for n in run_of] for name in names])  # runs x groups
        per_run = member.astype(float) @ red_g
        top = np.argmax(per_run, axis=0)
        robust = red - per_run[top, np.arange(freqs.size)]
        i = int(np.argmax(robust))
        dof_robust = dof - 2 * int(member[top[i]].sum())
    else:
        robust = red
        i = int(np.argmax(red))
        dof_robust = dof
    thr = float(stats.chi2.isf(rule.line_alpha / freqs.size, max(dof_robust, 1)))
    f = float(freqs[i])
    # a line common to the runs shows in most of them on its own, not in one or two
    # (an undithered encoder at constant speed can alias into a line of a single run)
    single = float(stats.chi2.isf(0.01, 2))
    shown: dict[str, bool] = {}
    for g, (eq, _) in enumerate(groups):
        shown[eq.run.name] = shown.get(eq.run.name, False) or bool(red_g[g, i] > single)
    common = sum(shown.values()) >= rule.line_run_fraction * len(shown)
    ratios = []
    amps = {}
    for eq in eqs:
        mean_speed = float(np.mean(np.abs(eq.speed_l)))
        rot = mean_speed / (2.0 * math.pi)
        ratios.append(f / rot if rot > 1e-3 else float("inf"))
        w = eq.lower
        if len(w) >= 8:
            ph = 2.0 * math.pi * f * w.t
            X = np.column_stack([np.cos(ph), np.sin(ph)]) / w.sigma[:, None]
            coef, *_ = np.linalg.lstsq(X, w.z, rcond=None)
            amps[eq.run.name] = float(math.hypot(*coef))
    near = [min(abs(r - 1.0), abs(r - 2.0)) < 0.1 for r in ratios if math.isfinite(r)]
    related = bool(near) and sum(near) >= 0.5 * len(near)
    return LineScan(
        frequency_hz=f,
        reduction=float(robust[i]),
        threshold=thr,
        significant=bool(robust[i] > thr and common),
        dof=dof,
        rotation_ratio=ratios,
        related_to_rotation=related,
        amplitude_nm=amps,
    )


# -- what an unexplained line is locked to ------------------------------------------------------

LOCK_HARMONICS = (1, 2, 3)  # harmonics of a disk's rotation tried as the origin of a line


@dataclass(frozen=True)
class LineSignature:
    """What a residual line is locked to, its torque on each disk and the runs that show it.

    Each hypothesis is a sinusoidal torque on both disks with its own amplitude and phase per
    run and disk, pushed through the same window kernel as the equation error: at a fixed
    frequency in time (``time``), at a harmonic of a disk's angle (``lower_rotation_k``,
    ``upper_rotation_k``: the line moves with that disk's speed from run to run), or following
    the measured voltage's deviation from its run mean (``voltage``). The hypothesis with the
    largest drop of the sum of squares (noise units) names the locking."""

    locked_to: str  # "time", "lower disk rotation", "upper disk rotation" or "voltage"
    hypothesis: str  # e.g. "lower_rotation_1", "time"
    frequency_hz: float  # for "time": the common frequency; else nan (it moves with the run)
    harmonic: int  # of the rotation (0 for time/voltage)
    drops: dict[str, float]  # per hypothesis, drop of the sum of squares (noise units)
    amplitude_nm: dict[str, float]  # per disk: median over the runs that show it [N m]
    runs: list[dict[str, Any]]  # per run: name, voltage, rotation rates, amplitudes, shown
    threshold: float = float("nan")  # chi^2 level the winning drop must pass (Bonferroni)
    significant: bool = True
    # a line locked to a disk's rotation: the physical and the sensor explanation, best first
    # (see drill_env.discrepancy.sensor_effects.rotation_explanations)
    explanations: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def largest_residual_run(self) -> str | None:
        """The run whose residual exceeds the noise floor the most (sum of squares minus the
        number of windows, both disks), or None when no run's does."""
        rows = [r for r in self.runs if r.get("excess_ss", 0.0) > 0.0]
        return max(rows, key=lambda r: r["excess_ss"])["run"] if rows else None

    def summary(self) -> str:
        where = [r for r in self.runs if r["shown"]]
        volts = sorted({r["voltage_v"] for r in where if r["voltage_v"] is not None})
        what = {
            "time": f"locked to time: {self.frequency_hz:.4g} Hz in every run whatever the speed",
            "voltage": "locked to the voltage: it follows the measured voltage",
        }.get(self.locked_to, f"locked to the {self.locked_to} (harmonic {self.harmonic} of its angle)")
        amp = ", ".join(f"{d} disk {a:.3g} N m" for d, a in self.amplitude_nm.items())
        shown = f"shows in {len(where)} of {len(self.runs)} runs"
        if where:
            # by name, the run with the largest residual first: where to look on the recordings
            ranked = sorted(where, key=lambda r: -r.get("excess_ss", r.get("drop", 0.0)))
            shown += " (" + ", ".join(r["run"] for r in ranked)
            if volts:
                shown += "; constant voltages " + ", ".join(f"{v:g}" for v in volts) + " V"
            shown += ")"
        top = self.largest_residual_run()
        if top is not None:
            shown += f"; largest residual: {top}"
        if not self.significant:
            return f"no line stands out (the strongest, {what}, does not pass its test); {shown}"
        out = f"{what}; torque amplitude {amp}; {shown}"
        if self.explanations:
            out += "; explained as " + " or ".join(
                f"{e['explanation']} ({e['kind']}, score {e['score']:.4g})" for e in self.explanations
            )
        return out


def _disk_regressors(eq: RunEquations, hyp: str, freq: float) -> dict[str, np.ndarray]:
    if hyp == "time":
        ph = 2.0 * math.pi * freq * eq.t_rel
        sig = [np.cos(ph), np.sin(ph)]
    elif hyp == "voltage":
        sig = [eq.u - float(np.mean(eq.u))]
    else:
        disk, _, k = hyp.split("_")
        theta = eq.theta_l if disk == "lower" else eq.theta_u
        sig = [np.cos(int(k) * theta), np.sin(int(k) * theta)]
    out = {}
    for disk in ("upper", "lower"):
        w = eq.upper if disk == "upper" else eq.lower
        if len(w) < 8:
            continue
        out[disk] = np.column_stack([eq.kernel(x, disk) for x in sig]) / w.sigma[:, None]
    return out


def _fit_hypothesis(eqs: list[RunEquations], hyp: str, freq: float):
    """Per run and disk: (drop in noise units, torque amplitude [N m])."""
    per_run = []
    for eq in eqs:
        res = {}
        for disk, X in _disk_regressors(eq, hyp, freq).items():
            z = (eq.upper if disk == "upper" else eq.lower).z
            if not np.any(X):
                continue
            coef, *_ = np.linalg.lstsq(X, z, rcond=None)
            fit = X @ coef
            drop = float(z @ z - (z - fit) @ (z - fit))
            if hyp == "voltage":
                amp = abs(float(coef[0])) * float(np.std(eq.u))
            else:
                amp = float(math.hypot(coef[0], coef[1]))
            res[disk] = (drop, amp)
        per_run.append(res)
    return per_run


def _refine_time_frequency(eqs: list[RunEquations], f0: float) -> float:
    """The common frequency near the scan's ``f0`` that removes the most (grid finer than 1/T)."""
    t_max = max(eq.run.duration for eq in eqs)
    best, best_drop = f0, -1.0
    for f in f0 + np.linspace(-2.0, 2.0, 81) / t_max:
        if f <= 0.0:
            continue
        drop = 0.0
        for eq in eqs:
            for w in (eq.upper, eq.lower):
                if len(w) < 8:
                    continue
                ph = 2.0 * math.pi * f * w.t
                X = np.column_stack([np.cos(ph), np.sin(ph)]) / w.sigma[:, None]
                coef, *_ = np.linalg.lstsq(X, w.z, rcond=None)
                r = w.z - X @ coef
                drop += float(w.z @ w.z - r @ r)
        if drop > best_drop:
            best, best_drop = float(f), drop
    return best


def line_signature(eqs: list[RunEquations], frequency_hz: float, alpha: float = 1e-4) -> LineSignature:
    """Which clock a residual line keeps (time, a disk's rotation, the voltage), with its torque.

    ``frequency_hz`` is the common line found by :func:`line_scan`; a line locked to a disk's
    rotation shows there only where runs happen to share a speed, so every hypothesis is
    fitted on its own and the largest drop of the sum of squares decides. A run shows the
    line when the drop on one of its disks passes chi^2_2 at 1 % (chi^2_1 for the voltage). The
    winning drop is significant when it passes chi^2 at ``alpha`` / (number of hypotheses) with
    its degrees of freedom (2 per run and disk; 1 for the voltage)."""
    freq = _refine_time_frequency(eqs, frequency_hz) if math.isfinite(frequency_hz) else float("nan")
    hyps = ["time"] if math.isfinite(freq) else []
    hyps += [f"{d}_rotation_{k}" for d in ("lower", "upper") for k in LOCK_HARMONICS]
    if any(not eq.run.is_constant_voltage for eq in eqs):
        hyps.append("voltage")
    fits = {h: _fit_hypothesis(eqs, h, freq) for h in hyps}
    drops = {h: float(sum(d for run in f for d, _ in run.values())) for h, f in fits.items()}
    best = max(drops, key=lambda h: drops[h])
    per = 1 if best == "voltage" else 2
    single = float(stats.chi2.isf(0.01, per))
    dof = per * sum(len(run) for run in fits[best])
    threshold = float(stats.chi2.isf(alpha / len(hyps), max(dof, 1)))
    runs = []
    amps: dict[str, list[float]] = {"upper": [], "lower": []}
    for eq, res in zip(eqs, fits[best], strict=True):
        shown = any(d > single for d, _ in res.values())
        # where the residual concentrates: its excess over the noise floor, both disks
        excess = float(sum(float(w.z @ w.z) - len(w) for w in (eq.upper, eq.lower)))
        row = {
            "run": eq.run.name,
            "voltage_v": eq.run.voltage if eq.run.is_constant_voltage else None,
            "lower_rotation_hz": float(np.mean(np.abs(eq.speed_l))) / (2.0 * math.pi),
            "upper_rotation_hz": float(np.mean(np.abs(eq.speed_u))) / (2.0 * math.pi),
            "amplitude_nm": {d: a for d, (_, a) in res.items()},
            "shown": bool(shown),
            "drop": float(sum(d for d, _ in res.values())),
            "excess_ss": excess,
        }
        runs.append(row)
        if shown:
            for d, (_, a) in res.items():
                amps[d].append(a)
    if best == "time":
        locked, harmonic = "time", 0
    elif best == "voltage":
        locked, harmonic = "voltage", 0
    else:
        disk, _, k = best.split("_")
        locked, harmonic = f"{disk} disk rotation", int(k)
    return LineSignature(
        locked_to=locked,
        hypothesis=best,
        frequency_hz=freq if best == "time" else float("nan"),
        harmonic=harmonic,
        drops=drops,
        amplitude_nm={d: float(np.median(v)) for d, v in amps.items() if v},
        runs=runs,
        threshold=threshold,
        significant=bool(drops[best] > threshold),
    )
