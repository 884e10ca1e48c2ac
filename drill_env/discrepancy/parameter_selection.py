"""Calibration selection: which calibrated parameters moved (forward selection alongside
the best candidate), their joint refits and the intervals they are reported with (jackknife
over runs, marginal over the parameters held at nominal, the selection's own uncertainty)."""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import Any

import numpy as np
from scipy import stats

from drill_env.discrepancy.calibrate import (
    ParameterFit,
    calibrated_params,
    parameter_fits,
    solve_joint,
)
from drill_env.discrepancy.scoring import (
    CalibrationSetup,
    CandidateScore,
    DecisionRule,
    JointFit,
    RunStatistics,
    _fit_lag_joint,
    _fit_linear_joint,
    _predictive,
    _score,
    _significance,
)
from drill_env.params import IDENTIFIED_PARAMETERS, ParameterError, RigParams
from drill_env.recordings.effects import CANDIDATES, Candidate
from drill_env.recordings.equation_error import RunEquations
from drill_env.recordings.regression import CALIBRATED, calibration_columns

__all__ = [
    "recalibrated_equations",
    "jackknife_var",
    "final_parameters",
    "admissible_fits",
    "first_calibration",
    "moved_fit",
    "marginal_sd",
    "selection_sd",
]


# the least share of a parameter's training information that is not the reading error of its
# columns, for the forward selection to move it (see _select_parameters)
MIN_SIGNAL_SHARE = 0.5


def _parameter_change(cal: CalibrationSetup, fit: JointFit) -> np.ndarray:
    """The change of every calibrated parameter (:data:`CALIBRATED` order) that ``fit`` makes."""
    d = np.zeros(len(CALIBRATED))
    d[cal.free] = fit.theta[: len(cal.free)]
    return d


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

    # a parameter whose training columns are mostly the encoders' reading error (an inertia on
    # runs at constant speeds) is not determined by those runs: moved, it wanders within its
    # prior (a recalibration from the true rig put both inertias at four times their value and
    # every held-out run off by millions of noise variances, an "unexplained" on a clean rig)
    signal = np.zeros(len(CALIBRATED))
    raw = np.zeros(len(CALIBRATED))
    for s in tr:
        st = cal.stats.get(s.name)
        if st is None:
            continue
        d = np.diag(st.ata)
        signal += d
        raw += d + (np.diag(st.reading) if st.reading is not None else 0.0)
    determined = signal >= MIN_SIGNAL_SHARE * np.maximum(raw, 1e-300)
    chosen: list[int] = []
    current = train_ss(chosen)
    while True:
        trial = {
            j: train_ss(chosen + [j]) for j in range(len(CALIBRATED)) if j not in chosen and determined[j]
        }
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
