"""Held-out scoring of the candidate library: per-run sufficient statistics, joint fits of a
candidate with the identified parameters, and the false-discovery step.

All statistics are in noise units: every window's residual and candidate columns are
divided by that window's noise standard deviation, so that the nominal model with the
right noise floor gives a sum of squares ~ chi^2 with one degree of freedom per window.
Per run the sufficient statistics (X'X, X'z, z'z) are kept, so refits on other sets of
runs, and the bootstrap over runs, cost nothing. The rule that turns the scores into a
verdict is in :mod:`~drill_env.discrepancy.verdict`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from scipy import stats

from drill_env.discrepancy.calibrate import (
    CalibrationRule,
    CalibrationStatistics,
    solve_joint,
)
from drill_env.params import RigParams
from drill_env.recordings.effects import CANDIDATES, Candidate
from drill_env.recordings.equation_error import RunEquations

__all__ = [
    "DecisionRule",
    "RunStatistics",
    "run_statistics",
    "CandidateScore",
    "CalibrationSetup",
    "JointFit",
    "benjamini_hochberg",
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


def _lag_blocks(train, held, cal: CalibrationSetup):
    """The calibration blocks of the training and held-out runs, which every time constant of
    a lag candidate shares."""
    f, ata, atz = _cal_block(cal, train)
    _, ath, atzh = _cal_block(cal, held)
    return f, ata, atz, ath, atzh


def _fit_lag_joint(
    train, held, cal: CalibrationSetup, c: Candidate, rule: DecisionRule, i: int, blocks=None
) -> JointFit:
    """Calibration refitted with the lag candidate's column (coefficient 1, physics) at tau_i
    (``blocks``: :func:`_lag_blocks` of these runs, computed once for every tau)."""
    f, ata, atz, ath, atzh = blocks if blocks is not None else _lag_blocks(train, held, cal)
    atx = sum((cal.stats[s.name].cross_lag[c.name][f, i] for s in train), np.zeros(f.size))
    rhs = atz - atx
    theta, cov = solve_joint(ata, rhs, cal.prior[cal.free], rule.ridge)
    q_tr = float(sum(s.ztz - 2.0 * s.lag[c.name][0][i] + s.lag[c.name][1][i] for s in train))
    q_tr += float(-2.0 * theta @ rhs + theta @ ata @ theta)
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
        blocks = _lag_blocks(train, held, cal)
        fits = [_fit_lag_joint(train, held, cal, c, rule, i, blocks) for i in range(c.lags.size)]
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


def benjamini_hochberg(p_values, alpha: float) -> np.ndarray:
    """Which of ``p_values`` the Benjamini-Hochberg step-up rule rejects at false-discovery
    level ``alpha``: those whose BH-adjusted p-value (:func:`scipy.stats.false_discovery_control`)
    is at most ``alpha``. A p-value that is not a number (a candidate whose fit came out
    singular: its gain NaN) is no evidence, p = 1; it is never rejected."""
    p = np.asarray(p_values, dtype=float)
    p = np.where(np.isfinite(p), np.clip(p, 0.0, 1.0), 1.0)
    if p.size == 0:
        return np.zeros(0, dtype=bool)
    return stats.false_discovery_control(p, method="bh") <= alpha


def _significance(scores, candidates, n_h: int, rule: DecisionRule) -> None:
    """Benjamini-Hochberg at level alpha over the admissible candidates, and the BIC penalty."""
    k_of = {c.name: c.n_params for c in candidates}
    pool = [s for s in scores if s.admissible]
    m = max(len(pool), 1)
    rejected = benjamini_hochberg([s.p_value for s in pool], rule.alpha)
    passed = {s.name for s, r in zip(pool, rejected, strict=True) if r}
    for s in scores:
        k = k_of[s.name]
        bic = k * math.log(max(n_h, 2))
        s.threshold = max(float(stats.chi2.isf(rule.alpha / m, k)), bic)
        s.significant = bool(s.name in passed and s.gain > bic and s.admissible)
