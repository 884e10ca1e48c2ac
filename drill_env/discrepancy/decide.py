"""Decide which effect, if any, explains the equation error: fit, hold out, test, bootstrap.

All statistics are in noise units: every window's residual and candidate columns are
divided by that window's noise standard deviation, so that the nominal model with
the right noise floor gives a sum of squares ~ chi^2 with one degree of freedom per
window. The floor is the encoder's, spectral lines of the quantisation error included
(:mod:`drill_env.discrepancy.equation_error`): a window where a line of an undithered
encoder aliases into its pass band weighs little, one where none does weighs much. Per run the sufficient statistics (X'X, X'z, z'z) are kept, so refits on
other sets of runs, and the bootstrap over runs, cost nothing.

The rule (all numbers in :class:`DecisionRule`):

0. With a :class:`CalibrationSetup` (see :mod:`~drill_env.discrepancy.calibrate`), the
   statistics are those of the recalibrated model and every fit below refits the
   identified parameters jointly: effects are scored as additions to the recalibrated
   model, against recalibration alone.
1. Fit each candidate on the training runs; its *held-out gain* is the drop of the
   held-out sum of squares ``D = Q_ref - Q_c``, divided by ``max(1, Q_c/n)`` so that a
   residual left far above the noise floor cannot make a partial fit look significant.
   Each held-out sum is predictive: whitened by the uncertainty of the parameters refitted
   on the training runs (:func:`_predictive`), so that a refit extrapolated to held-out
   runs that fix a parameter more sharply than the training runs is not read as a gain.
2. A candidate is *significant* when it passes the Benjamini-Hochberg step-up rule at
   false-discovery level alpha over the admissible candidates (p-values of the gain,
   chi^2 with k degrees of freedom) and its gain exceeds the BIC penalty ``k ln n``
   (k fitted parameters, n held-out windows), and its fitted parameters are physical.
3. The *excess* of the recalibrated model is its held-out sum of squares above what
   noise gives (n, with a tolerance for the noise-floor estimate). The best significant
   candidate (largest gain above its threshold) is named when it removes at least
   ``min_explained`` of a significant excess (or when there is no significant excess
   left to explain).
4. Otherwise the answer is ``unexplained`` if the residual has structure,
   ``recalibrated`` if the recalibrated model lowers the held-out sum of squares of the
   nominal one significantly, and ``none`` if neither. Structure is what the quantisation
   error cannot make: a significant excess over the floor; a spectral line at one
   frequency common to the runs, significant without the run that contributes most to it
   and shown by at least ``line_run_fraction`` of them on their own (the lines of the
   quantisation error sit at each run's own count rate); a correlation of neighbouring
   windows that stays significant without the run that contributes most to it (at a
   constant count rate the lines can make the windows of one run depend on each other; a
   torque the model lacks acts in every run).
5. The confidence is the fraction of bootstrap replicates (training and held-out runs
   each resampled with replacement, within each kind of run: constant or varying
   voltage) that reach the same answer. A named effect that wins in fewer than
   ``min_confidence`` of the replicates is not named: the answer falls back to rule 4.
6. The workflow also withdraws a named effect that makes a held-out sensor-space gap
   worse (:func:`sensor_worse`, :func:`demote`).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np
from scipy import stats

from drill_env.discrepancy.calibrate import (
    CALIBRATED,
    CalibrationRule,
    CalibrationStatistics,
    ParameterFit,
    calibrated_params,
    calibration_columns,
    parameter_fits,
    solve_joint,
)
from drill_env.discrepancy.effects import CANDIDATES, Candidate
from drill_env.discrepancy.equation_error import RunEquations
from drill_env.params import IDENTIFIED_PARAMETERS, ParameterError, RigParams

NOT_AN_EFFECT = ("none", "recalibrated", "unexplained")  # verdicts that name no effect

__all__ = [
    "DecisionRule",
    "RunStatistics",
    "run_statistics",
    "CandidateScore",
    "CalibrationSetup",
    "Decision",
    "JointFit",
    "NOT_AN_EFFECT",
    "decide",
    "LineSignature",
    "line_signature",
    "demote",
    "final_parameters",
    "first_calibration",
    "second_effect",
    "sensor_worse",
    "line_scan",
    "LineScan",
    "recalibrated_equations",
    "split_runs",
]


@dataclass(frozen=True)
class DecisionRule:
    alpha: float = 1e-3  # level of the likelihood-ratio test of a candidate
    floor_tolerance: float = 0.15  # relative error allowed on the noise floor
    excess_z: float = 4.0  # sigmas of chi^2 above which the excess is significant
    min_explained: float = 0.5  # fraction of the excess the named effect must remove
    min_confidence: float = 0.5  # a named effect must win in at least this share of the bootstrap
    line_alpha: float = 1e-4  # level of the spectral-line test (Bonferroni over frequencies)
    line_run_fraction: float = 0.5  # share of runs that must show the line on their own (p < 0.01)
    autocorr_z: float = 4.5  # z-score of the neighbour correlation that counts as structure
    bootstrap: int = 200
    ridge: float = 1e-9


@dataclass
class RunStatistics:
    """Sufficient statistics of one run for every candidate (noise units)."""

    name: str
    n: int  # windows (both disks)
    ztz: float  # nominal sum of squares
    linear: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # X'X, X'z
    lag: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # per tau: x'z, x'x
    neighbour: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sum z_i z_i+1, sum z_i^2, sum z_i+1^2
    n_pairs: int = 0


def _weighted(eq: RunEquations, xu: np.ndarray, xl: np.ndarray) -> np.ndarray:
    return np.vstack([xu / eq.upper.sigma[:, None], xl / eq.lower.sigma[:, None]])


def run_statistics(eq: RunEquations, candidates: tuple[Candidate, ...] = CANDIDATES) -> RunStatistics:
    z = np.concatenate([eq.upper.z, eq.lower.z])
    st = RunStatistics(name=eq.run.name, n=int(z.size), ztz=float(z @ z))
    for c in candidates:
        if c.is_lag:
            grid = c.lags
            a = np.empty(grid.size)
            b = np.empty(grid.size)
            for k, tau in enumerate(grid):
                x = _weighted(eq, *c.columns(eq, float(tau)))[:, 0]
                a[k] = x @ z
                b[k] = x @ x
            st.lag[c.name] = (a, b)
        else:
            X = _weighted(eq, *c.columns(eq))
            st.linear[c.name] = (X.T @ X, X.T @ z)
    # correlation of neighbouring windows (adjacent on the window grid)
    i, j = eq.neighbour_pairs()
    za, zb = z[i], z[j]
    s_ab, s_aa, s_bb = float(za @ zb), float(za @ za), float(zb @ zb)
    pairs = int(i.size)
    st.neighbour = (s_ab, s_aa, s_bb)
    st.n_pairs = pairs
    return st


@dataclass
class CandidateScore:
    name: str
    gain: float  # held-out drop of the sum of squares, normalised (see module doc)
    raw_gain: float  # held-out drop of the sum of squares
    threshold: float
    significant: bool
    admissible: bool
    note: str
    parameters: dict[str, float]
    heldout_ss: float  # held-out sum of squares with the candidate
    p_value: float = float("nan")  # of the held-out gain, chi^2 with k degrees of freedom
    fit: Any = field(default=None, repr=False)  # the joint fit (calibration + candidate)

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "fit"}


@dataclass
class CalibrationSetup:
    """What the decision needs to score effects as additions to the recalibrated model.

    ``stats`` are the calibration statistics at the model being scored (the recalibrated
    one), ``free`` the identified parameters refitted jointly with every candidate,
    ``nominal_ztz`` the nominal model's sum of squares per run and ``moved`` the
    parameters that the recalibrated model changes (the recalibration is confirmed when
    it lowers the held-out sum of squares significantly, with ``len(moved)`` degrees of
    freedom)."""

    stats: dict[str, CalibrationStatistics]
    free: list[int]
    prior: np.ndarray  # prior precision of every calibrated parameter (CALIBRATED order)
    nominal_ztz: dict[str, float]
    moved: list[int]
    nominal: RigParams | None  # None: no calibration (_no_calibration)
    base: RigParams | None  # the recalibrated model the statistics were computed at
    rule: CalibrationRule = field(default_factory=CalibrationRule)


def _no_calibration(names) -> CalibrationSetup:
    empty = CalibrationStatistics(name="", ata=np.zeros((0, 0)), atz=np.zeros(0))
    return CalibrationSetup(
        stats={n: empty for n in names},
        free=[],
        prior=np.zeros(0),
        nominal_ztz={},
        moved=[],
        nominal=None,
        base=None,
    )


def _cal_block(cal: CalibrationSetup, group):
    f = np.array(cal.free, dtype=int)
    ata = sum((cal.stats[s.name].ata[np.ix_(f, f)] for s in group), np.zeros((f.size, f.size)))
    atz = sum((cal.stats[s.name].atz[f] for s in group), np.zeros(f.size))
    return f, ata, atz


@dataclass
class JointFit:
    """Parameter changes (and candidate coefficients) fitted on the training runs."""

    theta: np.ndarray  # [parameter changes, candidate coefficients]
    cov: np.ndarray  # unscaled posterior covariance
    train_ss: float
    train_n: int
    heldout_ss: float
    tau: float | None = None  # lag candidates: the time constant

    @property
    def variance_scale(self) -> float:
        dof = max(self.train_n - self.theta.size, 1)
        return max(1.0, self.train_ss / dof)


def _joint(group, cal: CalibrationSetup, name: str | None = None):
    """Gram matrix and right-hand side of [calibration | candidate columns] summed over runs."""
    f, ata, atz = _cal_block(cal, group)
    if name is None:
        return ata, atz
    xx = sum(s.linear[name][0] for s in group)
    xz = sum(s.linear[name][1] for s in group)
    ax = sum((cal.stats[s.name].cross[name][f] for s in group), np.zeros((f.size, xx.shape[0])))
    return np.block([[ata, ax], [ax.T, xx]]), np.concatenate([atz, xz])


def _ss(group, theta, m, b) -> float:
    return float(sum(s.ztz for s in group) - 2.0 * theta @ b + theta @ m @ theta)


def _predictive(q_h: float, grad: np.ndarray, h_held: np.ndarray, p_train: np.ndarray) -> float:
    """Held-out sum of squares whitened by the uncertainty of the refitted parameters.

    The parameters refitted on the training runs carry their posterior covariance
    ``C = p_train^-1`` (the training precision of the parameter block, prior included), so
    the held-out residual ``r`` has covariance ``I + A_h C A_h'``, not ``I``. Its predictive
    sum of squares ``r' (I + A_h C A_h')^-1 r = q_h - g' (p_train + A_h'A_h)^-1 g`` with
    ``g = A_h' r`` (Woodbury) is chi^2 with one degree of freedom per held-out window when
    the model is right, however much more precisely the held-out windows pin a parameter
    than the training windows do. The plain ``q_h`` is not: with the quantisation-aware
    floor a held-out run at a speed the training runs do not cover can see the friction
    curve a hundred times more sharply, the extrapolated refit then leaves thousands in
    ``q_h`` on data without any effect, and any candidate whose columns shift that refit
    "gains" (a false discovery). The same ``p_train`` (the parameter block, conditional on
    the candidate's coefficients) is used for the model with and without a candidate, so
    only the candidate's own prediction is scored."""
    if grad.size == 0:
        return float(q_h)
    return float(q_h - grad @ np.linalg.solve(p_train + h_held, grad))


def _fit_linear_joint(train, held, cal: CalibrationSetup, name: str | None, rule: DecisionRule) -> JointFit:
    m, b = _joint(train, cal, name)
    theta, cov = solve_joint(m, b, cal.prior[cal.free], rule.ridge)
    mh, bh = _joint(held, cal, name)
    nf = len(cal.free)
    q_h = _predictive(
        _ss(held, theta, mh, bh),
        bh[:nf] - mh[:nf] @ theta,
        mh[:nf, :nf],
        m[:nf, :nf] + np.diag(cal.prior[cal.free]),
    )
    return JointFit(theta, cov, _ss(train, theta, m, b), sum(s.n for s in train), q_h)


def _fit_lag_joint(train, held, cal: CalibrationSetup, c: Candidate, rule: DecisionRule, i: int) -> JointFit:
    """Calibration refitted with the lag candidate's column (coefficient 1, physics) at tau_i."""
    f, ata, atz = _cal_block(cal, train)
    atx = sum((cal.stats[s.name].cross_lag[c.name][f, i] for s in train), np.zeros(f.size))
    rhs = atz - atx
    theta, cov = solve_joint(ata, rhs, cal.prior[cal.free], rule.ridge)
    q_tr = float(sum(s.ztz - 2.0 * s.lag[c.name][0][i] + s.lag[c.name][1][i] for s in train))
    q_tr += float(-2.0 * theta @ rhs + theta @ ata @ theta)
    _, ath, atzh = _cal_block(cal, held)
    atxh = sum((cal.stats[s.name].cross_lag[c.name][f, i] for s in held), np.zeros(f.size))
    q_h = float(sum(s.ztz - 2.0 * s.lag[c.name][0][i] + s.lag[c.name][1][i] for s in held))
    q_h += float(-2.0 * theta @ (atzh - atxh) + theta @ ath @ theta)
    q_h = _predictive(q_h, atzh - atxh - ath @ theta, ath, ata + np.diag(cal.prior[cal.free]))
    return JointFit(theta, cov, q_tr, sum(s.n for s in train), q_h, tau=float(c.lags[i]))


# A lag whose best time constant is the shortest one tried is not resolved: for a small lag
# tau, the lagged term is tau times the derivative of the unlagged one, which an inertia
# (or another parameter) change mimics; such a fit is not admissible as an effect.
_EDGE_NOTE = (
    "the time constant is the shortest of the grid: a lag this short is not resolved from a parameter change"
)


def _score(c: Candidate, train, held, rule: DecisionRule, cal: CalibrationSetup, ref: JointFit):
    """Score a candidate as an addition to the recalibrated model ``ref`` (calibration alone)."""
    n_h = sum(s.n for s in held)
    nf = len(cal.free)
    if c.is_lag:
        fits = [_fit_lag_joint(train, held, cal, c, rule, i) for i in range(c.lags.size)]
        gain_train = np.array([ref.train_ss - f.train_ss for f in fits])
        i = int(np.argmax(gain_train))
        tau = float(c.lags[i])
        if 0 < i < c.lags.size - 1:
            # parabola through the best grid point and its neighbours, in log tau
            y0, y1, y2 = gain_train[i - 1], gain_train[i], gain_train[i + 1]
            den = y0 - 2.0 * y1 + y2
            if den < 0.0:
                step = math.log(c.lags[i + 1] / c.lags[i])
                tau = float(c.lags[i] * math.exp(0.5 * (y0 - y2) / den * step))
        fit = fits[i]
        raw = ref.heldout_ss - fit.heldout_ss
        params = c.to_parameters(np.array([1.0]), tau)
        if gain_train[i] <= 0.0:
            raw = 0.0  # no lag improves the training fit: the candidate stays at zero
            params = c.to_parameters(np.array([1.0]), 0.0)
            fit = ref
    else:
        fit = _fit_linear_joint(train, held, cal, c.name, rule)
        raw = ref.heldout_ss - fit.heldout_ss
        params = c.to_parameters(fit.theta[nf:])
    q_c = ref.heldout_ss - raw
    gain = raw / max(1.0, q_c / max(n_h, 1))
    k = c.n_params
    why = c.admissible(params)
    if c.is_lag and why is None and i == 0 and raw > 0.0:
        why = _EDGE_NOTE
    score = CandidateScore(
        name=c.name,
        gain=float(gain),
        raw_gain=float(raw),
        threshold=float("nan"),  # set by the false-discovery step, see _significance
        significant=False,
        admissible=why is None,
        note=why or "",
        parameters={k_: float(v) for k_, v in params.items()},
        heldout_ss=float(q_c),
    )
    score.p_value = float(stats.chi2.sf(max(gain, 0.0), k))
    score.fit = fit
    return score


def _significance(scores, candidates, n_h: int, rule: DecisionRule) -> None:
    """Benjamini-Hochberg at level alpha over the admissible candidates, and the BIC penalty."""
    k_of = {c.name: c.n_params for c in candidates}
    pool = [s for s in scores if s.admissible]
    m = max(len(pool), 1)
    order = sorted(pool, key=lambda s: s.p_value)
    last = 0
    for i, s in enumerate(order, start=1):
        if s.p_value <= rule.alpha * i / m:
            last = i
    passed = {s.name for s in order[:last]}
    for s in scores:
        k = k_of[s.name]
        bic = k * math.log(max(n_h, 2))
        s.threshold = max(float(stats.chi2.isf(rule.alpha / m, k)), bic)
        s.significant = bool(s.name in passed and s.gain > bic and s.admissible)


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

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def summary(self) -> str:
        where = [r for r in self.runs if r["shown"]]
        volts = sorted({r["voltage_v"] for r in where if r["voltage_v"] is not None})
        what = {
            "time": f"locked to time: {self.frequency_hz:.4g} Hz in every run whatever the speed",
            "voltage": "locked to the voltage: it follows the measured voltage",
        }.get(self.locked_to, f"locked to the {self.locked_to} (harmonic {self.harmonic} of its angle)")
        amp = ", ".join(f"{d} disk {a:.3g} N m" for d, a in self.amplitude_nm.items())
        shown = f"shows in {len(where)} of {len(self.runs)} runs"
        if volts:
            shown += " (constant voltages " + ", ".join(f"{v:g}" for v in volts) + " V)"
        if not self.significant:
            return f"no line stands out (the strongest, {what}, does not pass its test); {shown}"
        return f"{what}; torque amplitude {amp}; {shown}"


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
        row = {
            "run": eq.run.name,
            "voltage_v": float(eq.run.u[0]) if eq.run.is_constant_voltage else None,
            "lower_rotation_hz": float(np.mean(np.abs(eq.speed_l))) / (2.0 * math.pi),
            "upper_rotation_hz": float(np.mean(np.abs(eq.speed_u))) / (2.0 * math.pi),
            "amplitude_nm": {d: a for d, (_, a) in res.items()},
            "shown": bool(shown),
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


@dataclass
class Decision:
    effect: str
    confidence: float
    reason: str
    scores: list[CandidateScore]
    winner: CandidateScore | None
    excess: dict[str, float]
    structure: dict[str, Any]
    bootstrap_counts: dict[str, int]
    train_runs: list[str]
    heldout_runs: list[str]
    parameters: list[ParameterFit] = field(default_factory=list)  # the chosen model's calibration
    reference: JointFit | None = field(default=None, repr=False)  # recalibration alone
    reference_parameters: list[ParameterFit] = field(default_factory=list)  # ... and its parameters
    calibration: CalibrationSetup | None = field(default=None, repr=False)

    @property
    def named(self) -> bool:
        return self.effect not in NOT_AN_EFFECT

    @property
    def named_winner(self) -> CandidateScore:
        """The score of the named effect (a named decision has one)."""
        if self.winner is None:
            raise ValueError(f"decision {self.effect!r}: no winning candidate")
        return self.winner

    @property
    def recalibrated(self) -> list[ParameterFit]:
        return [f for f in self.parameters if f.moved]

    def score(self, name: str) -> CandidateScore:
        for s in self.scores:
            if s.name == name:
                return s
        raise KeyError(name)


def _recalibration_gain(held, cal: CalibrationSetup) -> tuple[float, float]:
    """Held-out drop of the sum of squares from the nominal to the recalibrated model, and the
    threshold it must pass (the candidates' rule with one degree of freedom per moved parameter)."""
    k = len(cal.moved)
    if k == 0 or not cal.nominal_ztz:
        return 0.0, float("inf")
    n_h = sum(s.n for s in held)
    gain = sum(cal.nominal_ztz[s.name] for s in held) - sum(s.ztz for s in held)
    thr = max(float(stats.chi2.isf(1e-3, k)), k * math.log(max(n_h, 2)))
    return float(gain), thr


def _parameter_change(cal: CalibrationSetup, fit: JointFit) -> np.ndarray:
    """The change of every calibrated parameter (:data:`CALIBRATED` order) that ``fit`` makes."""
    d = np.zeros(len(CALIBRATED))
    d[cal.free] = fit.theta[: len(cal.free)]
    return d


def _neighbour_after(st: RunStatistics, cal: CalibrationSetup, ref: JointFit) -> tuple[float, float, float]:
    """Neighbour sums of one run's residual after the parameter changes of ``ref``."""
    cs = cal.stats.get(st.name)
    if not cal.free or cs is None or cs.neighbour is None:
        return st.neighbour
    return cs.neighbour_sums(_parameter_change(cal, ref))


def recalibrated_equations(
    eqs: list[RunEquations],
    stats_by_run: dict[str, RunStatistics],
    train: list[str],
    heldout: list[str],
    cal: CalibrationSetup | None,
    rule: DecisionRule | None = None,
) -> list[RunEquations]:
    """The equations with each window's residual after the recalibration alone (the parameter
    changes :func:`decide` fits on the training runs without any candidate): the structure
    a parameter change removes is not scanned for a line. Without a calibration, ``eqs``."""
    if cal is None or not cal.free:
        return eqs
    rule = rule or DecisionRule()
    ref = _fit_linear_joint(
        [stats_by_run[n] for n in train], [stats_by_run[n] for n in heldout], cal, None, rule
    )
    d = _parameter_change(cal, ref)
    out = []
    for eq in eqs:
        xu, xl = calibration_columns(eq)
        e = copy.copy(eq)  # shares everything but the windows' residuals
        e.upper = dataclasses.replace(eq.upper, residual=eq.upper.residual + xu @ d)
        e.lower = dataclasses.replace(eq.lower, residual=eq.lower.residual + xl @ d)
        out.append(e)
    return out


def _verdict(train, held, rule: DecisionRule, line: LineScan | None, candidates, cal: CalibrationSetup):
    n_h = sum(s.n for s in held)
    ref = _fit_linear_joint(train, held, cal, None, rule)  # recalibration alone
    scores = [_score(c, train, held, rule, cal, ref) for c in candidates]
    _significance(scores, candidates, n_h, rule)
    q0_h = ref.heldout_ss
    n_all = n_h + sum(s.n for s in train)
    q0_all = q0_h + ref.train_ss

    def excess_significant(q, n):
        return q > n * (1.0 + rule.floor_tolerance) + rule.excess_z * math.sqrt(2.0 * n)

    # the neighbour correlation of the residual of the recalibrated model (the structure a
    # parameter change removes is not a missing effect)
    neighbour = {s.name: _neighbour_after(s, cal, ref) for s in train + held}
    s_ab = sum(neighbour[s.name][0] for s in train + held)
    s_aa = sum(neighbour[s.name][1] for s in train + held)
    s_bb = sum(neighbour[s.name][2] for s in train + held)
    pairs = sum(s.n_pairs for s in train + held)
    rho = s_ab / math.sqrt(s_aa * s_bb) if s_aa > 0 and s_bb > 0 else 0.0
    rho_z = rho * math.sqrt(max(pairs, 1))
    # At a constant count rate the quantisation error of an encoder is a sum of spectral
    # lines that can make all windows of one run depend on each other; a torque the model
    # lacks acts in every run. So the correlation counts only if it stays significant
    # without whichever run contributes most to it.
    rho_z_robust = rho_z
    if len(train + held) > 1:
        for st in train + held:
            nb = neighbour[st.name]
            a, b, c = s_ab - nb[0], s_aa - nb[1], s_bb - nb[2]
            p = max(pairs - st.n_pairs, 1)
            rho_z_robust = min(rho_z_robust, a / math.sqrt(b * c) * math.sqrt(p) if b > 0 and c > 0 else 0.0)
    excess_h = q0_h - n_h
    cal_gain, cal_thr = _recalibration_gain(held, cal)
    structure = {
        "excess_heldout": bool(excess_significant(q0_h, n_h)),
        "excess_all": bool(excess_significant(q0_all, n_all)),
        "neighbour_correlation": float(rho),
        "neighbour_correlation_z": float(rho_z),
        "neighbour_correlation_z_without_top_run": float(rho_z_robust),
        "correlated": bool(rho_z_robust > rule.autocorr_z),
        "line": bool(line.significant) if line is not None else False,
        "recalibration_gain": cal_gain,
        "recalibration_threshold": cal_thr,
        "recalibration_confirmed": bool(cal_gain > cal_thr),
    }
    has_structure = structure["excess_all"] or structure["correlated"] or structure["line"]
    sig = [s for s in scores if s.significant]
    winner = max(sig, key=lambda s: s.gain - s.threshold) if sig else None
    if winner is not None:
        if structure["excess_heldout"] and excess_h > 0:
            explained = winner.raw_gain / excess_h
        else:
            explained = 1.0
        if explained >= rule.min_explained:
            reason = (
                f"{winner.name} removes {min(explained, 1.0):.0%} of the held-out excess of the "
                f"{'recalibrated' if cal.free else 'nominal'} model "
                f"(gain {winner.gain:.1f} > threshold {winner.threshold:.1f})"
            )
            return winner.name, reason, scores, winner, structure, explained, ref
        reason = (
            f"the best candidate {winner.name} removes only {explained:.0%} of the held-out excess "
            f"(< {rule.min_explained:.0%}): the residual has structure no candidate explains"
        )
        return "unexplained", reason, scores, winner, structure, explained, ref
    if has_structure:
        what = [k for k in ("excess_all", "correlated", "line") if structure[k]]
        return (
            "unexplained",
            f"no candidate is significant but the residual has structure ({', '.join(what)})",
            scores,
            None,
            structure,
            0.0,
            ref,
        )
    if structure["recalibration_confirmed"]:
        return (
            "recalibrated",
            f"new parameter values lower the held-out sum of squares by {cal_gain:.1f} "
            f"(> {cal_thr:.1f}); no candidate is significant on top of them and the residual is "
            "at the noise floor",
            scores,
            None,
            structure,
            0.0,
            ref,
        )
    return (
        "none",
        "no candidate is significant and the residual is at the noise floor",
        scores,
        None,
        structure,
        0.0,
        ref,
    )


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


def _fallback(structure) -> str:
    if structure["excess_all"] or structure["correlated"] or structure["line"]:
        return "unexplained"
    return "recalibrated" if structure["recalibration_confirmed"] else "none"


def jackknife_var(theta_of, runs: list) -> np.ndarray:
    """Leave-one-run-out jackknife variance of the estimates ``theta_of(runs)`` over ``runs``."""
    r = len(runs)
    loo = np.array([theta_of(runs[:i] + runs[i + 1 :]) for i in range(r)])
    return (r - 1) / r * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0)


def final_parameters(
    cal: CalibrationSetup | None,
    fit: JointFit | None,
    refit=None,
    train=None,
    *,
    identified: list[int] | None = None,
    moved_all: bool = False,
    marginal: np.ndarray | tuple[np.ndarray, np.ndarray] | None = None,
) -> list[ParameterFit]:
    """Every calibrated parameter of the model a fit stands for, judged against the nominal.

    With ``marginal`` (standard deviations of every :data:`CALIBRATED` parameter from
    :func:`marginal_sd`), each standard deviation of an interval is at least the marginal
    one: a parameter held at nominal that is in truth off (it is known only to
    within its prior) moves the fitted ones it is correlated with (the two hump terms and the
    viscous friction of the lower disk nearly trade off over the measured speeds), and the
    interval then says so instead of claiming a precision the data do not give. With
    ``marginal`` a pair ``(sd, delta)`` (``marginal_sd(..., with_estimate=True)``), the
    marginal standard deviation also holds the selection's own uncertainty
    (:func:`selection_sd`).

    With ``refit`` (training runs -> JointFit) and the training runs, each standard deviation
    of an interval is at least the jackknife one over the training runs (leave one run out):
    errors common to the windows of a run, which the per-window noise model does not see,
    then widen the intervals instead of hiding in them. Whether a parameter moved is
    judged on the per-window noise alone (the jackknife over a handful of runs is itself
    too noisy for a test)."""
    if cal is None or fit is None or not cal.free or cal.nominal is None or cal.base is None:
        return []  # no calibration (nominal and base are set together)
    nf = len(cal.free)
    cov = fit.cov[:nf, :nf] * fit.variance_scale
    sd_interval = None
    if refit is not None and train is not None and len(train) >= 3:
        var_jk = jackknife_var(lambda runs: refit(runs).theta[:nf], train)
        sd_interval = np.sqrt(np.maximum(var_jk, np.diag(cov)))
    if marginal is not None:
        if isinstance(marginal, tuple):
            sd_m = selection_sd(fit.theta[:nf], cal.free, marginal)
        else:
            sd_m = np.asarray(marginal, dtype=float)[np.array(cal.free, dtype=int)]
        base_sd = sd_interval if sd_interval is not None else np.sqrt(np.maximum(np.diag(cov), 0.0))
        sd_interval = np.maximum(base_sd, sd_m)
    fits = parameter_fits(
        cal.nominal,
        cal.base,
        cal.free,
        fit.theta[:nf],
        cov,
        cal.rule,
        identified=identified,
        sd_interval=sd_interval,
    )
    if moved_all:
        fits = [
            dataclasses.replace(f, moved=True) if CALIBRATED.index(f.name) in cal.free else f for f in fits
        ]
    return fits


def _refit_of(cal: CalibrationSetup, held, rule: DecisionRule, winner: CandidateScore | None, candidates):
    """Training runs -> the same joint fit (calibration alone, or with the winner at its tau)."""
    if winner is None:
        return lambda tr: _fit_linear_joint(tr, held, cal, None, rule)
    cand = next(c for c in candidates if c.name == winner.name)
    if not cand.is_lag:
        return lambda tr: _fit_linear_joint(tr, held, cal, cand.name, rule)
    fit = winner.fit
    i = int(np.argmin(np.abs(np.log(cand.lags / fit.tau)))) if fit.tau else 0
    return lambda tr: _fit_lag_joint(tr, held, cal, cand, rule, i)


# Sensor-space metrics a named effect must not make worse (compare.aggregate keys), with the
# absolute part of the tolerance: "angle" and "speed" stand for the angle noise and the noise of
# the smooth speed; the relative part is SENSOR_RELATIVE_TOLERANCE of the recalibrated model's gap.
SENSOR_CHECKS: dict[str, tuple[str, float]] = {
    "short_horizon_angle_rms_rad": ("angle", 1.0),
    "short_horizon_speed_rms_rad_s": ("speed", 1.0),
    "steady_mean_speed_abs_error": ("speed", 1.0),
    "steady_min_speed_abs_error": ("speed", 3.0),
    "steady_max_speed_abs_error": ("speed", 3.0),
    "steady_stick_fraction_abs_error": ("one", 0.05),
    "steady_period_abs_error_s": ("one", 0.25),
}
SENSOR_RELATIVE_TOLERANCE = 0.25


def sensor_worse(before: dict[str, float], after: dict[str, float], floors: dict[str, float]) -> list[str]:
    """The sensor-space gaps that the model ``after`` makes worse than ``before`` by more than
    their noise: ``after > (1 + SENSOR_RELATIVE_TOLERANCE) before + c floor``."""
    worse = []
    scale = {"angle": floors.get("angle_rad", 0.0), "speed": floors.get("speed_rad_s", 0.0), "one": 1.0}
    for key, (unit, c) in SENSOR_CHECKS.items():
        if key not in before or key not in after:
            continue
        b, a = before[key], after[key]
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        if a > (1.0 + SENSOR_RELATIVE_TOLERANCE) * b + c * scale[unit]:
            worse.append(key)
    return worse


# the identified parameters of the lower friction curve, eq. (14), in their listed order
_LOWER_CURVE = tuple(n for n in IDENTIFIED_PARAMETERS if n.startswith("lower_") and n != "lower_inertia")


def admissible_fits(nominal: RigParams, fits: list[ParameterFit]) -> list[ParameterFit]:
    """``fits`` with every moved parameter whose value would leave the rig's valid range (e.g.
    a negative viscous friction, which a weakly fixed parameter can reach) kept at nominal:
    the corrected model is always a rig the simulator accepts."""
    fits = list(fits)
    for _ in range(len(fits)):
        try:
            calibrated_params(nominal, fits)
            return fits
        except ParameterError as exc:
            names = str(exc).split(":", 1)[0].strip().split("/")  # e.g. lower_hump_1/lower_hump_2
            hit = [i for i, f in enumerate(fits) if f.moved and f.name in names]
            if not hit and "lower_hump_1" in names:
                # the lower friction curve as a whole is not dissipative: free its moved terms
                # from the last one listed back
                hit = [i for i, f in enumerate(fits) if f.moved and f.name in _LOWER_CURVE][::-1]
            if not hit:
                raise
            i = hit[0]
            fits[i] = dataclasses.replace(fits[i], moved=False, value=fits[i].nominal)
    return fits


def _select_parameters(
    tr, ho, cal: CalibrationSetup, rule: DecisionRule, cand: Candidate | None
) -> list[int]:
    """Forward selection of the parameters that moved: add, one at a time, the calibrated
    parameter whose refit lowers the training sum of squares most, while that drop passes
    the candidates' test for one parameter, max(chi2_1(1 - alpha), ln n).

    Every calibrated parameter is a candidate, the identified ones (:attr:`CalibrationSetup.free`)
    and those the data fix only in combination with others (the second hump term, its rate
    and the lower viscous friction trade off over the measured speeds): when such a
    combination is off, one of them must move or the residual keeps a structure that
    reads as a missing effect. Their intervals say that the data fix them only jointly."""
    n_tr = sum(s.n for s in tr)
    pen = max(float(stats.chi2.isf(rule.alpha, 1)), math.log(max(n_tr, 2)))

    def train_ss(free) -> float:
        """The training sum of squares with ``free`` refitted (inf if that leaves the rig's
        valid range, e.g. a negative viscous friction: no such model is admissible)."""
        c = dataclasses.replace(cal, free=sorted(free))
        ref = _fit_linear_joint(tr, ho, c, None, rule)
        fit = _score(cand, tr, ho, rule, c, ref).fit if cand is not None else ref
        if cal.base is not None and c.free:
            changes = {
                CALIBRATED[j]: float(getattr(cal.base, CALIBRATED[j])) + float(fit.theta[i])
                for i, j in enumerate(c.free)
            }
            try:
                cal.base.replace(**changes)
            except ParameterError:
                return math.inf
        return fit.train_ss

    chosen: list[int] = []
    current = train_ss(chosen)
    while True:
        trial = {j: train_ss(chosen + [j]) for j in range(len(CALIBRATED)) if j not in chosen}
        trial = {j: v for j, v in trial.items() if math.isfinite(v)}
        if not trial:
            break
        j = min(trial, key=lambda k: trial[k])
        if current - trial[j] <= pen:
            break
        chosen.append(j)
        current = trial[j]
    return sorted(chosen)


def first_calibration(
    stats_by_run: dict[str, RunStatistics],
    train: list[str],
    heldout: list[str],
    cal: CalibrationSetup,
    *,
    rule: DecisionRule | None = None,
    candidates: tuple[Candidate, ...] = CANDIDATES,
) -> tuple[list[int], str | None]:
    """The parameters that moved, chosen on the nominal model's statistics (training runs):
    the best significant candidate, if any, is fitted jointly with all identified parameters
    (so that an effect is not absorbed into the parameters, nor a parameter error into an
    effect), then the parameters are selected forward alongside it. Returns their indices
    in :data:`CALIBRATED` and the candidate's name."""
    rule = rule or DecisionRule()
    tr = [stats_by_run[n] for n in train]
    ho = [stats_by_run[n] for n in heldout]
    n_h = sum(s.n for s in ho)
    ref = _fit_linear_joint(tr, ho, cal, None, rule)
    scores = [_score(c, tr, ho, rule, cal, ref) for c in candidates]
    _significance(scores, candidates, n_h, rule)
    sig = [s for s in scores if s.significant]
    winner = max(sig, key=lambda s: s.gain - s.threshold) if sig else None
    cand = next(c for c in candidates if c.name == winner.name) if winner is not None else None
    return _select_parameters(tr, ho, cal, rule, cand), winner.name if winner is not None else None


def moved_fit(
    cal: CalibrationSetup, tr, ho, rule: DecisionRule, cand: Candidate | None
) -> tuple[JointFit, Any, CalibrationSetup]:
    """The fit with only the moved parameters free (and the candidate, if any), and its refit."""
    c = dataclasses.replace(cal, free=list(cal.moved))
    ref = _fit_linear_joint(tr, ho, c, None, rule)
    if cand is None:
        return ref, (lambda t: _fit_linear_joint(t, ho, c, None, rule)), c
    sc = _score(cand, tr, ho, rule, c, ref)
    if cand.is_lag and sc.fit.tau and all(st.gram is not None for st in c.stats.values()):
        return _lag_fit_between(tr, ho, c, cand, rule, sc.fit.tau)
    return sc.fit, _refit_of(c, ho, rule, sc, (cand,)), c


def _lag_fit_between(
    tr, ho, cal: CalibrationSetup, cand: Candidate, rule: DecisionRule, tau_grid_best: float
):
    """The parameters refitted with a lag candidate at its time constant, free between the grid
    points either side of the best one.

    For a short lag the lagged term is tau times the derivative of the unlagged one, which an
    inertia change mimics: a time constant held at the nearest grid point (27 % apart) moves
    that inertia by the rest, many times its interval. So the candidate's column is
    interpolated in tau (quadratic over the three nearest grid points; exact where the lag
    is short and the column is linear in tau), and tau is the one that minimises the training sum of
    squares with the parameters refitted."""
    grid = cand.lags
    i = int(np.argmin(np.abs(np.log(grid / tau_grid_best))))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]

    def keys(tau):
        # quadratic (Lagrange) interpolation in tau over the three grid points nearest tau
        j = int(np.clip(np.argmin(np.abs(np.log(grid / tau))), 1, grid.size - 2))
        nodes = grid[j - 1 : j + 2]
        w = [
            float(np.prod([(tau - nodes[m]) / (nodes[k] - nodes[m]) for m in range(3) if m != k]))
            for k in range(3)
        ]
        return [(cand.name, j - 1 + k) for k in range(3)], w

    def fit_at(runs, tau) -> JointFit:
        off, w = keys(tau)
        theta, q_tr, q_h, cov = _gram_fit(runs, cal, [], off, ho, rule, with_cov=True, offset_weights=w)
        return JointFit(theta, cov, q_tr, sum(s.n for s in runs), q_h, tau=float(tau))

    taus = np.geomspace(lo, hi, 41) if hi > lo else np.array([lo])
    fits = [fit_at(tr, t) for t in taus]
    best = min(fits, key=lambda f: f.train_ss)
    return best, (lambda runs: fit_at(runs, best.tau)), cal


def _gram_fit(
    group,
    cal: CalibrationSetup,
    free_keys,
    offset_keys,
    held,
    rule: DecisionRule,
    with_cov=False,
    offset_weights=None,
):
    """Joint fit from the per-run Gram matrices: the identified parameters and the columns of
    ``free_keys`` fitted, the columns of ``offset_keys`` added with coefficient 1 (a lag effect
    at its time constant), or with ``offset_weights`` (a lag between two grid points).
    Returns the coefficients, the training and the held-out sum of squares."""
    idx = cal.stats[group[0].name].index
    free = np.concatenate([idx["A"][np.array(cal.free, dtype=int)]] + [idx[k] for k in free_keys])
    off = np.concatenate([np.zeros(0, dtype=int)] + [idx[k] for k in offset_keys])
    w = np.ones(off.size) if offset_weights is None else np.asarray(offset_weights, dtype=float)
    z = int(idx["z"][0])

    def parts(runs):
        g = sum(cal.stats[s.name].gram for s in runs)
        yy = g[z, z] - 2.0 * g[z, off] @ w + w @ g[np.ix_(off, off)] @ w
        dy = g[free, z] - g[np.ix_(free, off)] @ w
        return g[np.ix_(free, free)], dy, float(yy)

    m, dy, yy = parts(group)
    theta, cov = solve_joint(m, dy, cal.prior[cal.free], rule.ridge)
    q_tr = yy - 2.0 * theta @ dy + theta @ m @ theta
    mh, dyh, yyh = parts(held)
    q_h = yyh - 2.0 * theta @ dyh + theta @ mh @ theta
    nf = len(cal.free)
    q_h = _predictive(
        q_h, dyh[:nf] - mh[:nf] @ theta, mh[:nf, :nf], m[:nf, :nf] + np.diag(cal.prior[cal.free])
    )
    if with_cov:
        return theta, float(q_tr), float(q_h), cov
    return theta, float(q_tr), float(q_h)


def _is_lag(candidates, name: str) -> bool:
    return next(c for c in candidates if c.name == name).is_lag


def marginal_sd(
    cal: CalibrationSetup,
    tr,
    ho,
    rule: DecisionRule,
    effects: list[tuple[Candidate, float | None]],
    *,
    with_estimate: bool = False,
):
    """Posterior standard deviation of every :data:`CALIBRATED` parameter with all of them
    free under their prior, jointly with the ``effects`` (candidate, fitted time constant
    of a lag or None) [parameter units]. With ``with_estimate``, also the changes of every
    parameter from ``cal.base`` in that fit: ``(sd, delta)``.

    A lag effect is fitted on a grid of time constants; here the columns of the two
    neighbouring grid points are free too, so that the time constant is free between them
    and the parameters it trades off with (an inertia against a short lag) carry that
    freedom in their intervals."""
    every = list(range(len(CALIBRATED)))
    cal_all = dataclasses.replace(cal, free=every)
    if not cal.stats or any(s.gram is None for s in cal.stats.values()):
        c = effects[0][0] if effects else None
        fit = moved_fit(dataclasses.replace(cal, moved=every), tr, ho, rule, c)[0]
        sd = np.sqrt(np.maximum(np.diag(fit.cov)[: len(every)] * fit.variance_scale, 0.0))
        return (sd, fit.theta[: len(every)]) if with_estimate else sd
    free_keys: list = []
    off_keys: list = []
    for c, tau in effects:
        if not c.is_lag:
            free_keys.append(c.name)
            continue
        if not tau:
            continue  # a lag fitted at zero time constant is no column at all
        i = int(np.argmin(np.abs(np.log(c.lags / tau))))
        off_keys.append((c.name, i))
        free_keys += [(c.name, j) for j in (i - 1, i + 1) if 0 <= j < c.lags.size]
    theta, q_tr, _, cov = _gram_fit(tr, cal_all, free_keys, off_keys, ho, rule, with_cov=True)
    n_tr = sum(s.n for s in tr)
    scale = max(1.0, q_tr / max(n_tr - len(cov), 1))
    sd = np.sqrt(np.maximum(np.diag(cov)[: len(every)] * scale, 0.0))
    return (sd, theta[: len(every)]) if with_estimate else sd


def selection_sd(delta: np.ndarray, free: list[int], marginal: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Standard deviations of the ``free`` parameters' changes ``delta`` (fitted with only the
    moved parameters free) that hold the uncertainty of the selection too.

    The parameters that the forward selection left at nominal are off by up to what the
    selection could not detect, and the moved ones that trade off with them take up that
    error: with every parameter a few percent off, the lower static friction ends up four of
    its own standard deviations off when the first hump term is held at nominal. So the
    variance is the unconditional one over the two fits (Buckland, Burnham & Augustin,
    Biometrics 1997): the variance with every parameter free plus the squared difference of
    the two estimates, ``sd_all^2 + (delta - delta_all)^2``."""
    sd_all, delta_all = marginal
    j = np.asarray(free, dtype=int)
    return np.sqrt(sd_all[j] ** 2 + (np.asarray(delta, dtype=float) - delta_all[j]) ** 2)


def second_effect(
    decision: Decision,
    stats_by_run: dict[str, RunStatistics],
    cal: CalibrationSetup | None,
    *,
    rule: DecisionRule | None = None,
    candidates: tuple[Candidate, ...] = CANDIDATES,
) -> dict[str, Any]:
    """Greedy forward step: with the named effect in the model, is a second candidate needed?

    Tried only when the held-out residual of the recalibrated model with the first effect
    still shows a significant excess; each other candidate is fitted jointly with the
    identified parameters and the first effect (a lag effect at its fitted time constant)
    and scored on the held-out runs by the same rule as the first (Benjamini-Hochberg over
    the remaining candidates, BIC penalty, physical parameters, at least ``min_explained``
    of the remaining excess)."""
    rule = rule or DecisionRule()
    out: dict[str, Any] = {"tried": False, "named": None}
    if not decision.named or cal is None or not cal.stats:
        return out
    if any(st.gram is None for st in cal.stats.values()):
        return out
    tr = [stats_by_run[n] for n in decision.train_runs]
    ho = [stats_by_run[n] for n in decision.heldout_runs]
    n_h = sum(s.n for s in ho)
    first = next(c for c in candidates if c.name == decision.effect)
    if first.is_lag:
        tau = decision.named_winner.fit.tau
        i_w = int(np.argmin(np.abs(np.log(first.lags / tau)))) if tau else 0
        f_free, f_off = [], [(first.name, i_w)]
    else:
        f_free, f_off = [first.name], []
    _, q_tr0, q_h0 = _gram_fit(tr, cal, f_free, f_off, ho, rule)
    excess = q_h0 - n_h
    out["heldout_ss_per_window_with_first"] = q_h0 / max(n_h, 1)
    if not q_h0 > n_h * (1.0 + rule.floor_tolerance) + rule.excess_z * math.sqrt(2.0 * n_h):
        out["reason"] = f"the held-out residual with {first.name} is at the noise floor"
        return out
    out["tried"] = True
    rest = tuple(c for c in candidates if c.name != first.name)
    scores = []
    for c in rest:
        if c.is_lag:
            fits = [_gram_fit(tr, cal, f_free, f_off + [(c.name, i)], ho, rule) for i in range(c.lags.size)]
            i = int(np.argmin([f[1] for f in fits]))
            raw = q_h0 - fits[i][2] if fits[i][1] < q_tr0 else 0.0
            edge = i == 0 and raw > 0.0
            params = c.to_parameters(np.array([1.0]), float(c.lags[i]) if fits[i][1] < q_tr0 else 0.0)
        else:
            theta, _, q_h = _gram_fit(tr, cal, f_free + [c.name], f_off, ho, rule)
            raw = q_h0 - q_h
            params = c.to_parameters(theta[-c.n_params :])
        q_c = q_h0 - raw
        gain = raw / max(1.0, q_c / max(n_h, 1))
        why = c.admissible(params)
        if c.is_lag and why is None and edge:
            why = _EDGE_NOTE
        sc = CandidateScore(
            name=c.name,
            gain=float(gain),
            raw_gain=float(raw),
            threshold=float("nan"),
            significant=False,
            admissible=why is None,
            note=why or "",
            parameters={k: float(v) for k, v in params.items()},
            heldout_ss=float(q_c),
        )
        sc.p_value = float(stats.chi2.sf(max(gain, 0.0), c.n_params))
        scores.append(sc)
    _significance(scores, rest, n_h, rule)
    out["candidates"] = [s.as_dict() for s in scores]
    sig = [s for s in scores if s.significant]
    if not sig:
        out["reason"] = "no second candidate is significant"
        return out
    best = max(sig, key=lambda s: s.gain - s.threshold)
    keys: dict[str, list] = {}
    for c in rest:
        if c.name == best.name:
            if c.is_lag:
                tau = best.parameters[next(iter(best.parameters))]
                i = int(np.argmin(np.abs(np.log(c.lags / tau)))) if tau else 0
                keys = {"free": f_free, "off": f_off + [(c.name, i)]}
            else:
                keys = {"free": f_free + [c.name], "off": f_off}
    explained = best.raw_gain / excess if excess > 0 else 1.0
    out["explained_fraction"] = float(explained)
    if explained < rule.min_explained:
        out["reason"] = f"{best.name} removes only {explained:.0%} of the excess left by {first.name}"
        return out
    # One model holds both effects: the moved parameters and the coefficients of both effects
    # fitted together. The first effect's coefficients from its fit alone carry the second
    # effect's share (string damping against the position friction of the upper disk, a drift
    # against the lower friction level), and a model that mixes them with the second effect's
    # fitted on top simulates worse than either.
    second_c = next(c for c in rest if c.name == best.name)
    cal_m = dataclasses.replace(cal, free=list(cal.moved))
    theta, q_tr, _, cov = _gram_fit(tr, cal_m, keys["free"], keys["off"], ho, rule, with_cov=True)
    nf = len(cal_m.free)
    coef = theta[nf:]
    if first.is_lag:
        first_params = dict(decision.named_winner.parameters)
    else:
        first_params = first.to_parameters(coef[: first.n_params])
        coef = coef[first.n_params :]
    second_params = best.parameters if second_c.is_lag else second_c.to_parameters(coef[: second_c.n_params])
    why = first.admissible(first_params) or second_c.admissible(second_params)
    if why is not None:
        out["reason"] = (
            f"{best.name} is significant but the joint fit with {first.name} is not physical ({why})"
        )
        return out
    out["named"] = best.name
    out["parameters"] = {k: float(v) for k, v in second_params.items()}
    out["first_parameters"] = {k: float(v) for k, v in first_params.items()}
    out["heldout_ss"] = best.heldout_ss
    # the moved parameters refitted with both effects; those no longer significant stay nominal
    if cal.moved and cal.nominal is not None and cal.base is not None:  # set together
        n_tr = sum(s_.n for s_ in tr)
        scale = max(1.0, q_tr / max(n_tr - theta.size, 1))
        # intervals at least as wide as with every calibrated parameter free under its prior
        # (see final_parameters): those held at nominal are known only to within it
        second_tau = best.parameters[next(iter(best.parameters))] if _is_lag(rest, best.name) else None
        first_tau = decision.named_winner.fit.tau if first.is_lag else None
        both = [(first, first_tau), (second_c, second_tau)]
        marginal = marginal_sd(cal, tr, ho, rule, both, with_estimate=True)
        sd_own = np.sqrt(np.maximum(np.diag(cov[:nf, :nf]) * scale, 0.0))
        sd_interval = np.maximum(sd_own, selection_sd(theta[:nf], cal_m.free, marginal))
        if len(tr) >= 3:  # and at least the jackknife over the training runs, as for one effect
            var_jk = jackknife_var(
                lambda runs: _gram_fit(runs, cal_m, keys["free"], keys["off"], ho, rule)[0][:nf], tr
            )
            sd_interval = np.maximum(sd_interval, np.sqrt(var_jk))
        fits = parameter_fits(
            cal.nominal,
            cal.base,
            cal_m.free,
            theta[:nf],
            cov[:nf, :nf] * scale,
            cal.rule,
            identified=cal.free,
            sd_interval=sd_interval,
        )
        # every moved parameter keeps its joint value, as with one effect (final_parameters,
        # moved_all): the effects' coefficients were fitted with these values, and one set back
        # to nominal because its change is within the test's threshold no longer matches them
        free_names = {CALIBRATED[j] for j in cal_m.free}
        fits = [dataclasses.replace(f, moved=True) if f.name in free_names else f for f in fits]
        out["parameter_fits"] = admissible_fits(cal.nominal, fits)
    out["reason"] = (
        f"{best.name} removes {min(explained, 1.0):.0%} of the held-out excess left by {first.name} "
        f"(gain {best.gain:.1f} > threshold {best.threshold:.1f})"
    )
    return out


def demote(decision: Decision, reason: str) -> None:
    """Withdraw the named effect (e.g. it makes the model worse in sensor space)."""
    decision.effect = _fallback(decision.structure)
    decision.reason = f"{reason}; answer {decision.effect}"
    decision.confidence = decision.bootstrap_counts.get(decision.effect, 0) / max(
        sum(decision.bootstrap_counts.values()), 1
    )
    decision.winner = None
    decision.parameters = decision.reference_parameters
    if decision.effect == "recalibrated" and not any(f.moved for f in decision.parameters):
        decision.effect = "none"


def decide(
    stats_by_run: dict[str, RunStatistics],
    train: list[str],
    heldout: list[str],
    *,
    line: LineScan | None = None,
    rule: DecisionRule | None = None,
    candidates: tuple[Candidate, ...] = CANDIDATES,
    seed: int = 0,
    kinds: dict[str, str] | None = None,
    calibration: CalibrationSetup | None = None,
    progress=None,
) -> Decision:
    """The verdict on the held-out runs, with effects scored as additions to the recalibrated
    model when ``calibration`` is given (else to the model the statistics were computed at)."""
    rule = rule or DecisionRule()
    cal = calibration if calibration is not None else _no_calibration(stats_by_run)
    tr = [stats_by_run[n] for n in train]
    ho = [stats_by_run[n] for n in heldout]
    effect, reason, scores, winner, structure, explained, ref = _verdict(tr, ho, rule, line, candidates, cal)
    rng = np.random.default_rng(seed)
    counts: dict[str, int] = {}
    kinds = kinds or {}

    def resample(group):
        # stratified by kind of run, so that every replicate keeps the kinds of the original sets
        out = []
        for kind in sorted({kinds.get(s.name, "") for s in group}):
            members = [s for s in group if kinds.get(s.name, "") == kind]
            out += [members[i] for i in rng.integers(0, len(members), len(members))]
        return out

    for b in range(rule.bootstrap):
        tr_b = resample(tr)
        ho_b = resample(ho)
        e_b = _verdict(tr_b, ho_b, rule, line, candidates, cal)[0]
        counts[e_b] = counts.get(e_b, 0) + 1
        if progress is not None:
            progress(b + 1, rule.bootstrap)
    confidence = counts.get(effect, 0) / max(rule.bootstrap, 1)
    if effect not in NOT_AN_EFFECT and rule.bootstrap > 0 and confidence < rule.min_confidence:
        # significant on these runs but not stable over resampled runs: do not force a name
        fallback = _fallback(structure)
        reason = (
            f"{effect} was significant but wins in only {confidence:.0%} of the bootstrap replicates "
            f"(< {rule.min_confidence:.0%}); answer {fallback}"
        )
        effect = fallback
        confidence = counts.get(effect, 0) / max(rule.bootstrap, 1)
        winner = None
    named = winner is not None and effect == winner.name
    ref_params: list[ParameterFit] = []
    params: list[ParameterFit] = []
    if calibration is not None and calibration.nominal is not None:
        fit_m, refit_m, cal_m = moved_fit(calibration, tr, ho, rule, None)
        marginal = marginal_sd(calibration, tr, ho, rule, [], with_estimate=True)
        ref_params = admissible_fits(
            calibration.nominal,
            final_parameters(
                cal_m, fit_m, refit_m, tr, marginal=marginal, identified=calibration.free, moved_all=True
            ),
        )
        params = ref_params
        if named:
            cand = next(c for c in candidates if c.name == winner.name)
            fit_m, refit_m, cal_m = moved_fit(calibration, tr, ho, rule, cand)
            if cand.is_lag and fit_m.tau:
                # the model's time constant is the one its parameters were refitted at
                winner = dataclasses.replace(
                    winner, parameters=cand.to_parameters(np.array([1.0]), fit_m.tau)
                )
            marginal = marginal_sd(calibration, tr, ho, rule, [(cand, fit_m.tau)], with_estimate=True)
            params = admissible_fits(
                calibration.nominal,
                final_parameters(
                    cal_m, fit_m, refit_m, tr, marginal=marginal, identified=calibration.free, moved_all=True
                ),
            )
    if effect == "recalibrated" and not any(f.moved for f in params):
        effect, reason = (
            "none",
            "the recalibration is confirmed but no parameter differs from nominal beyond its interval",
        )
    n_h = sum(s.n for s in ho)
    q0_h = sum(cal.nominal_ztz[s.name] for s in ho) if cal.nominal_ztz else sum(s.ztz for s in ho)
    excess = {
        "heldout_windows": int(n_h),
        "heldout_ss_nominal": float(q0_h),
        "heldout_ss_per_window_nominal": float(q0_h / max(n_h, 1)),
        "heldout_ss_per_window_recalibrated": float(ref.heldout_ss / max(n_h, 1)),
        "heldout_ss_per_window_chosen": float(winner.heldout_ss / max(n_h, 1)) if winner else float("nan"),
        "explained_fraction": float(explained),
    }
    return Decision(
        effect=effect,
        confidence=float(confidence),
        reason=reason,
        scores=scores,
        winner=winner,
        excess=excess,
        structure=structure,
        bootstrap_counts=counts,
        train_runs=list(train),
        heldout_runs=list(heldout),
        parameters=params,
        reference=ref,
        reference_parameters=ref_params,
        calibration=calibration,
    )
