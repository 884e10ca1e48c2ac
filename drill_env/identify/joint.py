"""The joint fit: every parameter of the rig model from the filtered equation error of all runs.

The equation error of :mod:`drill_env.recordings.equation_error` is, per window and disk,
the mean unexplained torque. It is *linear* in every parameter of the model but the two
Stribeck rates (:func:`drill_env.recordings.regression.calibration_columns` gives the
columns; the string stiffness adds ``+K[x1]`` to the upper and ``-K[x1]`` to the lower
disk's rows):

    r = X_lin p_lin + T_1 H(beta_1) + T_2 H(beta_2),     H(beta) = sgn K[tanh(beta |x3| / 2)] / h^2

so for given rates everything else is a weighted linear least-squares problem (weights:
each window's noise standard deviation). The rates are found globally on a grid (the
profile of the linear fit over beta_1 > beta_2), then every parameter is refined together
(bounded Gauss-Newton, scipy's ``least_squares``). The data fix ratios only (scaling every
torque and inertia together leaves r / sigma unchanged): the parameter given by the user
(or the assumed string stiffness) is held at its value.

How many hump terms the lower friction needs is chosen on the data: none (Coulomb plus
viscous), one or two; a term is kept when it lowers the weighted sum of squares by more
than ``chi2_{2}(1 - alpha)`` residual variances (alpha = 1e-4, a rate found on a grid is a
search). A friction curve without a hump thus gets no hump terms, and says so.

Intervals: the Gauss-Newton covariance scaled by the residual variance when the fit
leaves more than the noise floor, at least as wide as the one-step jackknife over the runs
(errors common to a run's windows are not in the per-window noise model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats

from drill_env.friction import hump_law
from drill_env.params import DISSIPATIVE_CHECK_SPEEDS, IDENTIFIED_PARAMETERS, ModelEffects, RigParams
from drill_env.recordings.equation_error import RunEquations
from drill_env.recordings.regression import CALIBRATED, calibration_columns, reading_error_gram

__all__ = ["RunRows", "JointFit", "run_rows", "joint_fit", "HUMP_AMPLITUDES", "HUMP_RATES", "LINEAR"]

HUMP_AMPLITUDES = ("lower_hump_1", "lower_hump_2")
HUMP_RATES = ("lower_hump_rate_1", "lower_hump_rate_2")
# the parameters the equation error is linear in, in IDENTIFIED_PARAMETERS order
LINEAR: tuple[str, ...] = tuple(p for p in IDENTIFIED_PARAMETERS if p not in HUMP_AMPLITUDES + HUMP_RATES)
_LINEAR_IDX = [IDENTIFIED_PARAMETERS.index(p) for p in LINEAR]
BETA_GRID = np.geomspace(0.02, 60.0, 26)  # [s/rad] Stribeck rates tried before refining
BETA_BOUNDS = (1e-3, 500.0)  # [s/rad]
# a hump term this close to saturation (tanh(beta w/2)) at the slowest slip of the data is
# the static level over every window: its rate is bounded so that it is not (see _Problem)
SATURATED = 0.99
OBSERVED_QUANTILE = 0.02  # of the lower windows' mean slip: the slowest slip the curve is seen at
HUMP_ALPHA = 1e-4  # level at which a hump term is kept
SANDWICH_BLOCK = 10  # neighbouring windows per block of the sandwich covariance
MERGED_RATES = 0.02  # two rates this close in log are one (see _merged)
SEPARATED_RATES = 0.05  # the least log distance of the rates of a fit held apart (see joint_fit)
GRID_STARTS = 3  # best grid points refined (of those with linear parameters >= 0, and of all)
NEGATIVE_MIN_WINDOWS = 10
# the share of the reading-error correction (_reading_error_correction) taken as its uncertainty
READING_CORRECTION_UNCERTAINTY = 0.25  # upper-disk windows turning backwards needed for T_sun, b_un


@dataclass
class RunRows:
    """The equation-error rows of one run: linear columns, hump material and noise."""

    name: str
    constant: bool  # a constant-voltage run
    x_lin: np.ndarray  # (windows, len(LINEAR)) columns [N m per unit]
    sigma: np.ndarray  # (windows,) noise standard deviation [N m]
    lower: np.ndarray  # (lower windows,) row indices of the lower disk's windows
    sign_l: np.ndarray  # (lower windows,) direction of slip
    speed_l: np.ndarray  # (lower windows, support) |x3| on each window's support [rad/s]
    kernel: np.ndarray  # (support,) the triangle kernel / h^2 [1]
    negative_upper: int  # upper windows in which the upper disk turns backwards
    # columns of the effects fitted with the base parameters: d r / d c for each coefficient c
    # (the residual of the model with the effects is x_lin p + humps + x_eff c); none: base only
    x_eff: np.ndarray | None = None  # (windows, len(effect_names))
    effect_names: tuple[str, ...] = ()
    backward_upper: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))  # their row indices
    # (lower windows, support) variance of the reading error of |x3| [rad^2/s^2] (None: taken as
    # exact): how far it may bend the hump columns (see :meth:`hump_correction`)
    speed_var_l: np.ndarray | None = None
    # (lower windows, support) a known factor on the lower static + Stribeck friction per sample
    # (a position modulation at its current estimate, :func:`drill_env.identify.effect_fit.effect_rows`;
    # None: 1): the hump columns carry it, as the static level's column does
    scale_l: np.ndarray | None = None
    # (windows,) a known part of the residual (None: none): the Gauss-Newton step's offset
    offset: np.ndarray | None = None
    # (LINEAR, LINEAR) what the encoders' reading error in the angle columns adds to the expected
    # sum of squares, p' G p (recordings.regression.reading_error_gram; None: taken as exact),
    # over every window: the backward upper windows that _Problem may leave out hold almost none
    reading_gram: np.ndarray | None = None

    def _scaled(self, per_sample: np.ndarray) -> np.ndarray:
        return per_sample if self.scale_l is None else per_sample * self.scale_l

    def hump(self, beta: float) -> np.ndarray:
        """H(beta) on every row (zero on the upper disk's) [N m per N m of T]."""
        out = np.zeros(self.sigma.size)
        out[self.lower] = self.sign_l * (self._scaled(np.tanh(0.5 * beta * self.speed_l)) @ self.kernel)
        return out

    def hump_rate(self, beta: float) -> np.ndarray:
        """dH/dbeta on every row [N m per (N m s/rad)]."""
        e = np.exp(-beta * self.speed_l)  # sech^2(b w / 2) = 4 e / (1 + e)^2, without overflow
        out = np.zeros(self.sigma.size)
        out[self.lower] = self.sign_l * (self._scaled(2.0 * self.speed_l * e / (1.0 + e) ** 2) @ self.kernel)
        return out

    def hump_correction(self, beta: float) -> np.ndarray:
        """What a white reading error of the speed adds to H(beta) on every row, to second order.

        The speed is measured, ``w + e``, and tanh bends: the mean of ``tanh(beta (w + e) / 2)`` is
        ``tanh(a) + (beta / 2)^2 v tanh''(a) / 2`` (a = beta w / 2, v the variance of e), a bias
        common to every window at that speed that the kernel's average does not remove. Returns
        ``-(beta^2 / 4) v tanh(a) sech^2(a)`` through the kernel (the measured column less the
        true one). How large v really is lies between zero (an encoder's quantisation error
        that barely changes over the derivative's window, slow motion) and the white model's (a
        dithered encoder, or many counts per sample); the fit takes the columns as measured and
        widens its intervals by the shift this bias would give (:func:`joint_fit`)."""
        out = np.zeros(self.sigma.size)
        if self.speed_var_l is None:
            return out
        t = np.tanh(0.5 * beta * self.speed_l)
        out[self.lower] = -self.sign_l * (
            self._scaled(0.25 * beta * beta * self.speed_var_l * t * (1.0 - t * t)) @ self.kernel
        )
        return out


def run_rows(eq: RunEquations) -> RunRows:
    """The rows of one run's equation error, built on the calibration columns."""
    with np.errstate(over="ignore"):  # cosh of a steep Stribeck rate: its columns are not used here
        xu, xl = calibration_columns(eq)
    h2 = eq.h**2
    cal = {n: i for i, n in enumerate(CALIBRATED)}
    nu, nl = len(eq.upper), len(eq.lower)
    x = np.zeros((nu + nl, len(LINEAR)))
    for j, name in enumerate(LINEAR):
        if name == "string_stiffness":
            if nu:
                x[:nu, j] = (eq.gather(eq.twist, eq.upper.centers) @ eq.w_tri) / h2
            if nl:
                x[nu:, j] = -(eq.gather(eq.twist, eq.lower.centers) @ eq.w_tri) / h2
        else:
            x[:nu, j] = xu[:, cal[name]]
            x[nu:, j] = xl[:, cal[name]]
    speed = np.abs(eq.gather(eq.speed_l, eq.lower.centers)) if nl else np.zeros((0, eq.w_tri.size))
    # the correction is second order in the relative error: held to a reading error of half the
    # speed at most (a slow window on the longest derivative, where the expansion would not hold)
    speed_var = np.minimum(speed_reading_variance(eq), 0.25 * speed**2) if nl else np.zeros_like(speed)
    return RunRows(
        name=eq.run.name,
        constant=bool(eq.run.is_constant_voltage),
        x_lin=x,
        sigma=np.concatenate([eq.upper.sigma, eq.lower.sigma]),
        lower=np.arange(nu, nu + nl),
        sign_l=eq.lower.sign.astype(float),
        speed_l=speed,
        kernel=eq.w_tri / h2,
        negative_upper=int(np.sum(eq.upper.sign < 0)),
        backward_upper=np.flatnonzero(eq.upper.sign < 0),
        speed_var_l=speed_var,
        reading_gram=reading_error_gram(eq)[np.ix_(_LINEAR_IDX, _LINEAR_IDX)],
    )


def speed_reading_variance(eq: RunEquations) -> np.ndarray:
    """(lower windows, support) variance of the lower disk's speed reading error [rad^2/s^2]: the
    angle noise (quantisation and dither, :class:`~drill_env.recordings.equation_error.AngleNoise`)
    through the Savitzky-Golay derivative each sample's speed is taken with."""
    norms = np.array([float(c @ c) for c in eq.sg])
    choice = eq.gather(eq.choice_l, eq.lower.centers)
    return eq.noise.lower**2 * norms[choice]


@dataclass
class JointFit:
    """The joint fit's values, covariance and diagnostics (RigParams field names)."""

    values: dict[str, float]
    free: list[str]  # the parameters fitted (in the order of ``cov``)
    cov: np.ndarray  # covariance of the free parameters (interval scale)
    sd_model: np.ndarray  # standard deviations from the window noise alone
    sd_jackknife: np.ndarray  # one-step jackknife over the runs
    sd_sandwich: np.ndarray  # block sandwich: SANDWICH_BLOCK neighbouring windows of a run per block
    sd_information: np.ndarray  # from the window noise alone, unscaled by the misfit: what the data excite
    hump_terms: int  # 0, 1 or 2
    hump_tests: dict[str, float]  # chi2 of each added hump term, and the threshold
    ss: float  # weighted sum of squares at the optimum
    n_windows: int
    dof: int
    scale: tuple[str, float]
    negative_side: bool  # the upper disk turned backwards in enough windows
    info_constant: dict[str, float] = field(
        default_factory=dict
    )  # share of information from constant-voltage runs
    relative_sd: dict[str, float] = field(default_factory=dict)
    # range of each base parameter over the friction curves that fit as well (see
    # _alternative_ranges): what the data cannot tell apart
    alternatives: dict[str, tuple[float, float]] = field(default_factory=dict)
    # the slowest lower-disk slip the fit sees [rad/s]: the OBSERVED_QUANTILE of the windows'
    # mean slip (a few windows alone do not fix the curve); below it the curve is extrapolated
    slowest_slip: float = math.nan
    # the shift the speed's reading error may give (its bias on the hump columns, white model)
    sd_speed_reading: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # the correction made for the encoders' reading error in the angle columns (the bias-compensated
    # values less the least-squares ones; see _reading_error_correction), per free parameter, and
    # whether it was made (False: the data could not carry it; the shift then widens the intervals)
    reading_correction: dict[str, float] = field(default_factory=dict)
    reading_corrected: bool = False

    @property
    def residual_variance(self) -> float:
        return self.ss / max(self.dof, 1)

    def sd_excited(self, name: str) -> float:
        """Standard deviation from the window noise alone: how well the runs excite ``name``
        (a model the data contradict widens the interval, not this)."""
        if name not in self.free:
            return math.inf
        return float(self.sd_information[self.free.index(name)])

    def sd(self, name: str) -> float:
        if name not in self.free:
            return 0.0
        i = self.free.index(name)
        return float(math.sqrt(max(self.cov[i, i], 0.0)))


def _effect_names(rows: list[RunRows]) -> tuple[str, ...]:
    names = {r.effect_names for r in rows}
    if len(names) > 1:
        raise ValueError(f"rows: the runs carry different effect columns {sorted(names)}")
    return names.pop() if names else ()


def _free_linear(scale: str, negative: bool) -> list[str]:
    out = [p for p in LINEAR if p != scale]
    if not negative:
        out = [p for p in out if p not in ("upper_static_neg", "upper_viscous_neg")]
    return out


class _Problem:
    """The stacked weighted rows of a set of runs, for one choice of free linear parameters."""

    def __init__(self, rows: list[RunRows], scale: tuple[str, float], free_lin: list[str]):
        self.rows = rows
        self.scale = scale
        self.free_lin = free_lin
        # too few backward windows to fit the negative side of the upper friction: the windows
        # that do turn backwards are left out (the negative side is reported as the positive
        # side's, an assumption); fitted with the negative side held at zero they would pull
        # every other parameter off
        keep = []
        for r in rows:
            k_ = np.ones(r.sigma.size, dtype=bool)
            if "upper_static_neg" not in free_lin:
                k_[r.backward_upper] = False
            keep.append(k_)
        self.keep = keep
        x = np.vstack([(r.x_lin / r.sigma[:, None])[k_] for r, k_ in zip(rows, keep, strict=True)])
        idx = [LINEAR.index(p) for p in free_lin]
        self.k_lin = len(idx)  # the base parameters (>= 0); the effects' coefficients follow (free)
        self.effect_names = _effect_names(rows)
        self.a = x[:, idx]
        if self.effect_names:
            x_eff = np.vstack([(r.x_eff / r.sigma[:, None])[k_] for r, k_ in zip(rows, keep, strict=True)])
            self.a = np.column_stack([self.a, x_eff])
        self.y = -x[:, LINEAR.index(scale[0])] * scale[1]
        if any(r.offset is not None for r in rows):
            self.y = self.y - np.concatenate(
                [
                    ((r.offset if r.offset is not None else np.zeros(r.sigma.size)) / r.sigma)[k_]
                    for r, k_ in zip(rows, keep, strict=True)
                ]
            )
        self.inv_sigma = np.concatenate([1.0 / r.sigma[k_] for r, k_ in zip(rows, keep, strict=True)])
        self.run_of_row = np.concatenate([np.full(int(k_.sum()), i) for i, k_ in enumerate(keep)])
        self._h: dict[float, np.ndarray] = {}
        # the fastest hump the data can see: one that has saturated below the slowest lower-disk
        # slip of the windows is T_sl over every window, and T_sl - T and a hump of amplitude T
        # trade exactly (T_sl 720 N m against a hump of -720 N m at 90 s/rad on one rig)
        slowest = [float(r.speed_l.min()) for r in rows if r.speed_l.size]
        w_min = max(min(slowest), 1e-6) if slowest else 1e-6
        self.beta_max = float(min(BETA_BOUNDS[1], 2.0 * math.atanh(SATURATED) / w_min))
        means = [r.speed_l.mean(axis=1) for r in rows if r.speed_l.size]
        self.slowest_slip = (
            float(np.quantile(np.concatenate(means), OBSERVED_QUANTILE)) if means else math.nan
        )
        self.beta_grid = BETA_GRID[BETA_GRID <= self.beta_max]
        if self.beta_grid.size < 2:
            self.beta_grid = BETA_GRID[:2]

    @property
    def n(self) -> int:
        return self.y.size

    def hump(self, beta: float) -> np.ndarray:
        key = float(beta)
        if key not in self._h:
            self._h[key] = self._stacked([r.hump(beta) for r in self.rows])
            if len(self._h) > 200:
                self._h.pop(next(iter(self._h)))
        return self._h[key]

    def hump_rate(self, beta: float) -> np.ndarray:
        return self._stacked([r.hump_rate(beta) for r in self.rows])

    def hump_correction(self, beta: float) -> np.ndarray:
        return self._stacked([r.hump_correction(beta) for r in self.rows])

    def _stacked(self, cols: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([c[k_] for c, k_ in zip(cols, self.keep, strict=True)]) * self.inv_sigma

    def lstsq(self, extra: list[np.ndarray]) -> tuple[np.ndarray, float]:
        a = np.column_stack([self.a, *extra]) if extra else self.a
        coef, *_ = np.linalg.lstsq(a, self.y, rcond=None)
        res = self.y - a @ coef
        return coef, float(res @ res)


def _grid_search(prob: _Problem, terms: int) -> tuple[tuple[float, ...], float]:
    """Best rates on the grid for a friction with ``terms`` hump terms, and the sum of squares."""
    return _grid_starts(prob, terms, 1)[0]


def _grid_starts(prob: _Problem, terms: int, top: int) -> list[tuple[tuple[float, ...], float]]:
    """The ``top`` best rates on the grid whose linear parameters are all >= 0, then the ``top``
    best of all (best first, without repeats): the starts of the refinement. On a grid of ratio
    1.38 the best pair can lie in another basin than the optimum (two rates that merge, their
    amplitudes +-10^4), so more than one start is refined."""
    if terms == 0:
        return [((), prob.lstsq([])[1])]
    # normal equations, with the hump columns precomputed on the grid
    a, y = prob.a, prob.y
    grid = prob.beta_grid
    h = np.column_stack([prob.hump(b) for b in grid])
    g_aa, g_ay = a.T @ a, a.T @ y
    g_ah, g_hh, g_hy = a.T @ h, h.T @ h, h.T @ y
    yy = float(y @ y)
    # the best pairs whose linear parameters are all >= 0 (a negative viscous slope can mimic a slow
    # Stribeck term on the grid, and would be clipped away afterwards), then the best of all
    feasible: list[tuple[tuple[float, ...], float]] = []
    every: list[tuple[tuple[float, ...], float]] = []
    k = a.shape[1]
    pairs = (
        [(i,) for i in range(grid.size)]
        if terms == 1
        else [(i, j) for i in range(grid.size) for j in range(i)]
    )
    for sel in pairs:
        s = list(sel)
        m = np.zeros((k + len(s), k + len(s)))
        m[:k, :k] = g_aa
        m[:k, k:] = g_ah[:, s]
        m[k:, :k] = g_ah[:, s].T
        m[k:, k:] = g_hh[np.ix_(s, s)]
        b = np.concatenate([g_ay, g_hy[s]])
        try:
            coef = np.linalg.solve(m + 1e-12 * np.diag(np.diag(m)), b)
        except np.linalg.LinAlgError:
            continue
        ss = yy - float(coef @ b)
        here = (tuple(float(grid[i]) for i in sel), ss)
        every.append(here)
        if not np.any(coef[: prob.k_lin] < 0.0):
            feasible.append(here)
    out: list[tuple[tuple[float, ...], float]] = []
    for pool in (feasible, every):
        for here in sorted(pool, key=lambda x: x[1])[:top]:
            if here not in out:
                out.append(here)
    return out or [(tuple(float(b) for b in grid[:terms]), math.inf)]


def _residual(prob: _Problem, theta: np.ndarray, terms: int) -> np.ndarray:
    k = prob.a.shape[1]
    r = prob.a @ theta[:k] - prob.y
    for t in range(terms):
        r = r + theta[k + t] * prob.hump(theta[k + terms + t])
    return r


def _jacobian(prob: _Problem, theta: np.ndarray, terms: int) -> np.ndarray:
    k = prob.a.shape[1]
    cols = [prob.a]
    cols += [prob.hump(theta[k + terms + t])[:, None] for t in range(terms)]
    cols += [(theta[k + t] * prob.hump_rate(theta[k + terms + t]))[:, None] for t in range(terms)]
    return np.hstack(cols)


def _refine(
    prob: _Problem,
    betas: tuple[float, ...],
    start: np.ndarray | None = None,
    min_separation: float | None = None,
) -> tuple[np.ndarray, float]:
    """Every free parameter together from the grid's best rates, or from ``start``'s.

    Variable projection: at given rates the fit is a bounded linear least-squares problem,
    solved exactly (:func:`_bounded_linear`); the rates alone (in log units) are refined by
    bounded Gauss-Newton on the projected residual (Kaufman's Jacobian: the hump columns'
    rate derivatives projected off the span of the columns not at a bound). A few dozen
    evaluations of the hump columns instead of hundreds for the full problem.

    ``min_separation`` (two terms): the rates are held at least this far apart in log, beta_2 <=
    beta_1 exp(-min_separation) (a fit whose rates would merge otherwise, see :func:`_merged`)."""
    terms = len(betas)
    k = prob.a.shape[1]
    b0 = np.asarray(betas if start is None else np.asarray(start)[k + terms :], dtype=float)
    b0 = np.clip(b0, BETA_BOUNDS[0], prob.beta_max)
    lo_lin = np.concatenate([_linear_lower(prob), np.full(terms, -np.inf)])
    memo: dict[tuple[float, ...], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def inner(log_b: np.ndarray):
        key = tuple(float(x) for x in log_b)
        if key not in memo:
            b = np.exp(log_b)
            extra = [prob.hump(x) for x in b]
            a = np.column_stack([prob.a, *extra])
            coef = optimize.lsq_linear(a, prob.y, bounds=(lo_lin, np.inf), method="bvls").x
            memo.clear()
            memo[key] = (coef, a @ coef - prob.y, a)
        return memo[key]

    def jac(log_b: np.ndarray) -> np.ndarray:
        coef, _, a = inner(log_b)
        b = np.exp(log_b)
        d = np.column_stack([coef[k + t] * b[t] * prob.hump_rate(b[t]) for t in range(terms)])
        active = (coef <= lo_lin) & np.isfinite(lo_lin)
        q, _ = np.linalg.qr(a[:, ~active])
        return d - q @ (q.T @ d)

    x0 = np.log(b0)
    lo_b, hi_b = np.log(BETA_BOUNDS[0]), np.log(prob.beta_max)
    # the rates in log, or for rates held apart (log beta_1, separation): log_b = tmat y
    tmat, y0, lo_y, hi_y = np.eye(terms), x0, np.full(terms, lo_b), np.full(terms, hi_b)
    if min_separation is not None and terms == 2 and hi_b - lo_b > min_separation:
        tmat = np.array([[1.0, 0.0], [1.0, -1.0]])
        sep = float(np.clip(x0.max() - x0.min(), min_separation, hi_b - lo_b))
        y0 = np.array([float(np.clip(x0.max(), lo_b + sep, hi_b)), sep])
        lo_y, hi_y = np.array([lo_b + min_separation, min_separation]), np.array([hi_b, hi_b - lo_b])
        x0 = tmat @ y0
    sol = optimize.least_squares(
        lambda y: inner(tmat @ y)[1],
        y0,
        jac=lambda y: jac(tmat @ y) @ tmat,
        bounds=(lo_y, hi_y),
        method="trf",
        x_scale=1.0,
        max_nfev=100,
    )
    best_x = tmat @ sol.x
    coef, r, _ = inner(best_x)
    c0, r0, _ = inner(x0)
    if float(r0 @ r0) < float(r @ r):  # never worse than where it started
        coef, r, best_x = c0, r0, x0
    return np.concatenate([coef, np.exp(best_x)]), float(r @ r)


def _merged(theta: np.ndarray, k: int, terms: int) -> bool:
    """Two hump terms whose rates merged (within :data:`MERGED_RATES` in log): their amplitudes
    run off to +-A with A (b1 - b2) fixed."""
    if terms < 2:
        return False
    b1, b2 = float(theta[k + terms]), float(theta[k + terms + 1])
    return abs(math.log(b1 / b2)) < MERGED_RATES


def _linear_lower(prob: _Problem) -> np.ndarray:
    """Lower bounds of the columns of ``prob.a``: 0 for the base parameters, none for the
    effects' coefficients."""
    k = prob.a.shape[1]
    return np.concatenate([np.zeros(prob.k_lin), np.full(k - prob.k_lin, -np.inf)])


def _bounded_linear(prob: _Problem, extra: list[np.ndarray], k: int) -> np.ndarray:
    """The linear parameters (>= 0) and hump amplitudes (free) at fixed rates."""
    a = np.column_stack([prob.a, *extra]) if extra else prob.a
    lo = np.concatenate([_linear_lower(prob), np.full(len(extra), -np.inf)])
    return optimize.lsq_linear(a, prob.y, bounds=(lo, np.inf), method="bvls").x


def joint_fit(
    rows: list[RunRows],
    scale: tuple[str, float],
    *,
    hump_terms: int | None = None,
    warm_rates: tuple[float, ...] | None = None,
) -> JointFit:
    """Fit every parameter on the rows of ``rows`` with ``scale = (name, value)`` held.

    ``hump_terms`` forces the number of hump terms (default: chosen on the data);
    ``warm_rates`` (with ``hump_terms`` = their number, > 0) refines from these rates alone, no
    grid: a fit next to one already made (a lag's profile, one time constant to the next)."""
    if warm_rates is not None and (hump_terms is None or len(warm_rates) != hump_terms or not hump_terms):
        raise ValueError(f"warm_rates: {warm_rates!r} needs hump_terms = its length (> 0)")
    negative = sum(r.negative_upper for r in rows) >= NEGATIVE_MIN_WINDOWS
    free_lin = _free_linear(scale[0], negative)
    prob = _Problem(rows, scale, free_lin)
    k = prob.a.shape[1]
    fits: dict[int, tuple[np.ndarray, float]] = {}
    candidates: list[tuple[np.ndarray, float, int]] = []  # every friction curve fitted (not merged)
    for terms in (0, 1, 2) if hump_terms is None else (hump_terms,):
        if terms == 0:
            coef = _bounded_linear(prob, [], k)
            fits[0] = (coef, float(np.sum(_residual(prob, coef, 0) ** 2)))
            candidates.append((fits[0][0], fits[0][1], 0))
        else:
            starts = (
                [tuple(float(b) for b in warm_rates)]
                if warm_rates is not None
                else [b for b, _ in _grid_starts(prob, terms, GRID_STARTS)]
            )
            refined = [_refine(prob, betas) for betas in starts]
            candidates += [(f[0], f[1], terms) for f in refined if not _merged(f[0], k, terms)]
            fits[terms] = min(refined, key=lambda f: (_merged(f[0], k, terms), f[1]))
            if terms == 2 and 1 in fits:
                # also grow the one-term fit by a second term (so that two terms never fit worse than
                # one): its rate the best on the grid with the first term held
                one = fits[1][0]
                b1 = float(one[k + 1])
                best = min(prob.beta_grid, key=lambda b2: prob.lstsq([prob.hump(b1), prob.hump(b2)])[1])
                start = np.concatenate([one[:k], [one[k], 0.0], [b1, best]])
                grown = _refine(prob, (b1, float(best)), start=start)
                if not _merged(grown[0], k, 2):
                    candidates.append((grown[0], grown[1], 2))
                if (_merged(grown[0], k, 2), grown[1]) < (_merged(fits[2][0], k, 2), fits[2][1]):
                    fits[2] = grown
            if terms == 2 and _merged(fits[2][0], k, 2) and warm_rates is None:
                # every two-term fit ran its rates together: the data want two close rates of
                # opposite amplitudes (a curve of eq. 14 all the same: 0.30 and -0.25 N m at 0.81 and
                # 0.72 s/rad on one rig, whose one-term fit left 60 times the noise floor); the best
                # with the rates held apart is the two-term fit
                apart = _refine(
                    prob, tuple(float(b) for b in fits[2][0][k + 2 :]), min_separation=SEPARATED_RATES
                )
                if not _merged(apart[0], k, 2) and _dissipative(apart[0], k, 2, free_lin):
                    candidates.append((apart[0], apart[1], 2))
                    fits[2] = apart
    tests: dict[str, float] = {}
    if hump_terms is None:
        n_top = k + 4
        s2 = max(1.0, fits[2][1] / max(prob.n - n_top, 1))
        thr = float(stats.chi2.isf(HUMP_ALPHA, 2))
        d10 = (fits[0][1] - fits[1][1]) / s2
        d21 = (fits[1][1] - fits[2][1]) / s2
        d20 = (fits[0][1] - fits[2][1]) / s2
        if _merged(fits[2][0], k, 2):
            # two terms only as one rate with amplitudes +-A (a derivative of one term, not a
            # friction curve of eq. 14): not a second term
            d21 = d20 = -math.inf
        tests = {"one_term_vs_none": d10, "two_terms_vs_one": d21, "two_terms_vs_none": d20, "threshold": thr}
        if d21 > thr:
            chosen = 2
        elif d10 > thr:
            chosen = 1
        elif d20 > thr:
            chosen = 2
        else:
            chosen = 0
    else:
        chosen = hump_terms
    theta, ss = fits[chosen]
    # order the terms: beta_1 >= beta_2, as the paper's
    if chosen == 2 and theta[k + 2] < theta[k + 3]:
        theta = theta.copy()
        theta[[k, k + 1]] = theta[[k + 1, k]]
        theta[[k + 2, k + 3]] = theta[[k + 3, k + 2]]
    fastest = max((float(r.speed_l.max()) for r in rows if r.speed_l.size), default=math.inf)
    if (
        chosen
        and not _dissipative(theta, k, chosen, free_lin)
        and _dissipative(theta, k, chosen, free_lin, up_to=fastest)
    ):
        # the curve is positive over the data's slips but turns non-dissipative beyond them (eq. 4
        # asks for a positive friction at every speed a rig file is checked at): the best fit that
        # keeps it positive there (within the data's slips a curve that is not stays refused)
        held = _dissipative_fit(prob, theta, k, chosen, free_lin, beyond=fastest)
        if held is not None:
            theta, ss = held
    names = (
        list(free_lin) + list(prob.effect_names) + list(HUMP_AMPLITUDES[:chosen]) + list(HUMP_RATES[:chosen])
    )
    jac = _jacobian(prob, theta, chosen)
    # the reading error of the angle columns draws the fit off (errors in the variables): the
    # bias-compensated parameters where the data allow it (see _reading_error_correction)
    norms0 = np.sqrt(np.maximum(np.sum(jac**2, axis=0), 1e-300))
    eiv, corrected = _reading_error_correction(
        prob, theta, jac.T @ jac / np.outer(norms0, norms0), norms0, ss / max(prob.n - jac.shape[1], 1)
    )
    if corrected:
        moved = theta + eiv
        if (
            np.all(moved[: prob.k_lin] >= 0.0)
            and (not chosen or np.all(moved[k + chosen :] > 0.0))
            # nor a dissipative curve (as fitted) turned into one that is not
            and (
                not chosen
                or _dissipative(moved, k, chosen, free_lin)
                or not _dissipative(theta, k, chosen, free_lin)
            )
        ):
            theta = moved
            jac = _jacobian(prob, theta, chosen)
        else:  # a base parameter (or a Stribeck rate) would leave its range: not made
            corrected = False
    res = _residual(prob, theta, chosen)
    p = jac.shape[1]
    dof = prob.n - p
    s2 = max(1.0, ss / max(dof, 1))
    jtj = jac.T @ jac
    norms = np.sqrt(np.maximum(np.diag(jtj), 1e-300))
    jn = jtj / np.outer(norms, norms)
    cov_n = np.linalg.inv(jn + 1e-10 * np.eye(p))
    cov_info = cov_n / np.outer(norms, norms)
    cov_model = cov_info * s2
    # one-step jackknife over the runs
    runs = np.unique(prob.run_of_row)
    g = jac.T @ res
    loo = []
    if runs.size >= 3:
        for i in runs:
            sel = prob.run_of_row == i
            ji, ri = jac[sel], res[sel]
            m = (jtj - ji.T @ ji) / np.outer(norms, norms) + 1e-10 * np.eye(p)
            step = -np.linalg.solve(m, (g - ji.T @ ri) / norms) / norms
            loo.append(step)
        loo_a = np.array(loo)
        var_jk = (runs.size - 1) / runs.size * np.sum((loo_a - loo_a.mean(axis=0)) ** 2, axis=0)
    else:
        var_jk = np.zeros(p)
    # block sandwich (cluster-robust) covariance: the score summed over blocks of SANDWICH_BLOCK
    # neighbouring windows of a run, so that errors correlated from window to window and a
    # misfit that differs along the run (not in the per-window noise model) widen the interval
    score = jac * res[:, None]
    blocks = []
    for i in runs:
        idx = np.flatnonzero(prob.run_of_row == i)
        for a in range(0, idx.size, SANDWICH_BLOCK):
            blocks.append(score[idx[a : a + SANDWICH_BLOCK]].sum(axis=0))
    if len(blocks) > p:
        sb = np.array(blocks)
        meat = sb.T @ sb * (len(blocks) / (len(blocks) - p))
        var_sw = np.diag(cov_info @ meat @ cov_info)
    else:
        var_sw = np.zeros(p)
    sd_model = np.sqrt(np.maximum(np.diag(cov_model), 0.0))
    sd_jk = np.sqrt(var_jk)
    sd_sw = np.sqrt(np.maximum(var_sw, 0.0))
    # the speed's reading error bends the hump columns (RunRows.hump_correction) by an amount
    # between none and the white model's, which the data cannot tell apart: the shift of every
    # parameter that the white model's bias would give (one Gauss-Newton step) is added to the
    # interval (at 250 Hz and 4096 counts the hump terms were 3-5 standard deviations off)
    bias = np.zeros(p)
    if chosen:
        bend = sum(theta[k + t] * prob.hump_correction(theta[k + chosen + t]) for t in range(chosen))
        bias = np.linalg.solve(jn + 1e-10 * np.eye(p), -(jac.T @ bend) / norms) / norms
    sd_speed = np.abs(bias)
    # what the reading error's correction leaves uncertain (the noise model's own error), or the
    # shift it causes where it could not be made
    sd_reading = np.abs(eiv) * (READING_CORRECTION_UNCERTAINTY if corrected else 1.0)
    sd = np.sqrt(np.maximum(np.maximum(sd_model, sd_jk), sd_sw) ** 2 + sd_speed**2 + sd_reading**2)
    corr = cov_model / np.outer(np.maximum(sd_model, 1e-300), np.maximum(sd_model, 1e-300))
    cov = corr * np.outer(sd, sd)
    # how much of each parameter's information comes from constant-voltage runs
    const_rows = np.concatenate(
        [np.full(int(k_.sum()), r.constant) for r, k_ in zip(rows, prob.keep, strict=True)]
    )
    info_all = np.sum(jac**2, axis=0)
    info_const = np.sum(jac[const_rows] ** 2, axis=0)
    values: dict[str, float] = {scale[0]: float(scale[1])}
    for name, v in zip(names, theta, strict=True):
        values[name] = float(v)
    for t in range(chosen, 2):
        values[HUMP_AMPLITUDES[t]] = 0.0
        values[HUMP_RATES[t]] = 0.0
    if not negative:
        values["upper_static_neg"] = values["upper_static_pos"]
        values["upper_viscous_neg"] = values["upper_viscous_pos"]
    rel = {n: float(sd[i] / abs(values[n])) if values[n] != 0.0 else math.inf for i, n in enumerate(names)}
    alternatives = _alternative_ranges(prob, candidates, ss, s2, chosen, k, tests.get("threshold"), free_lin)
    return JointFit(
        values=values,
        free=names,
        cov=cov,
        sd_model=sd_model,
        sd_jackknife=sd_jk,
        sd_sandwich=sd_sw,
        sd_information=np.sqrt(np.maximum(np.diag(cov_info), 0.0)),
        sd_speed_reading=sd_speed,
        reading_correction={n: float(eiv[i]) if corrected else 0.0 for i, n in enumerate(names)},
        reading_corrected=corrected,
        hump_terms=chosen,
        hump_tests=tests,
        ss=ss,
        n_windows=prob.n,
        dof=dof,
        scale=scale,
        negative_side=negative,
        info_constant={
            n: float(info_const[i] / info_all[i]) if info_all[i] > 0 else 0.0 for i, n in enumerate(names)
        },
        relative_sd=rel,
        alternatives=alternatives,
        slowest_slip=prob.slowest_slip,
    )


def _reading_error_correction(
    prob: _Problem, theta: np.ndarray, jn: np.ndarray, norms: np.ndarray, floor_ratio: float
) -> tuple[np.ndarray, bool]:
    """The correction of the fitted parameters for the encoders' reading error in the angle
    columns (errors in the variables), and whether it was made.

    The fit minimises the measured equation error, whose expectation adds ``sum_i p' Q_i p /
    sigma_i^2`` (``Q_i`` the covariance of the reading error in window i's columns,
    :meth:`RunEquations.column_noise`; ``p`` every linear parameter, the held scale included): it
    is drawn towards inertias, viscous frictions and a stiffness for which that error weighs
    least. Where the motor and the friction nearly balance (the string's torque a few per cent
    of either), the data fix the upper disk's scale only through that few per cent, and the pull
    moved k_m, J_u, T_su and b_u together by -20 % to -35 % at 4096 counts and 1 kHz. The
    bias-compensated fit minimises the measured sum less that expectation; from the fit this is
    one Newton step, ``(J'J - Q)^-1 sum_i Q_i p / sigma_i^2`` (exact for the linear parameters).
    Where ``J'J - Q`` is not positive definite the reading error dominates some direction of the
    data: no correction, and the returned shift is the first-order one, ``-(J'J)^-1 ...``, the
    bias the fit carries (made part of its intervals). Where the fit's residual lies below the
    noise model's floor (``floor_ratio``, its mean square in noise units, below 1: the model puts
    the reading error too high, e.g. a dither estimated where there is none) the covariance is
    scaled down by it: the correction never assumes more reading error than the residual shows."""
    p = jn.shape[0]
    values = np.zeros(len(LINEAR))
    values[LINEAR.index(prob.scale[0])] = prob.scale[1]
    free = [LINEAR.index(n) for n in prob.free_lin]
    values[free] = theta[: len(free)]
    share = min(1.0, max(floor_ratio, 0.0))
    hess = share * sum(
        (r.reading_gram for r in prob.rows if r.reading_gram is not None), np.zeros((len(LINEAR),) * 2)
    )
    grad = hess @ values
    g = np.zeros(p)
    g[: len(free)] = grad[free]
    qn = np.zeros((p, p))
    qn[: len(free), : len(free)] = hess[np.ix_(free, free)]
    qn /= np.outer(norms, norms)
    reg = 1e-10 * np.eye(p)
    try:
        np.linalg.cholesky(jn - qn + reg)
    except np.linalg.LinAlgError:
        return np.linalg.solve(jn + reg, -g / norms) / norms, False
    return np.linalg.solve(jn - qn + reg, g / norms) / norms, True


def _dissipative(theta: np.ndarray, k: int, terms: int, free_lin: list[str], up_to: float = math.inf) -> bool:
    """Whether the fitted lower slip friction stays > 0 over the speeds a rig file is checked at
    up to ``up_to`` (eq. 4; :data:`~drill_env.params.DISSIPATIVE_CHECK_SPEEDS`): a pair of hump
    terms held apart can cancel within the data and part beyond them."""
    v = _curve_values(theta, terms, k, free_lin)
    w = DISSIPATIVE_CHECK_SPEEDS[1:]
    w = w[w <= up_to]
    hump = hump_law.py_func(
        v["lower_hump_1"], v["lower_hump_rate_1"], v["lower_hump_2"], v["lower_hump_rate_2"], w
    )
    return bool(np.all(v.get("lower_static", 0.0) + v.get("lower_viscous", 0.0) * w + hump > 0.0))


def _dissipative_fit(
    prob: _Problem, theta: np.ndarray, k: int, terms: int, free_lin: list[str], beyond: float
) -> tuple[np.ndarray, float] | None:
    """The least-squares fit at ``theta``'s Stribeck rates with the lower slip friction held
    positive at the speeds above ``beyond`` (the data's fastest slip) that a rig file is checked
    at (a linear inequality on the static level, the viscous slope and the hump amplitudes); None
    where it fails."""
    if "lower_static" not in free_lin or "lower_viscous" not in free_lin:
        return None
    rates = [float(b) for b in theta[k + terms :]]
    a = np.column_stack([prob.a, *[prob.hump(b) for b in rates]])
    w = DISSIPATIVE_CHECK_SPEEDS[1:]
    w = w[w >= beyond]
    if not w.size:
        return None
    g = np.zeros((w.size, a.shape[1]))
    g[:, free_lin.index("lower_static")] = 1.0
    g[:, free_lin.index("lower_viscous")] = w
    for t, b in enumerate(rates):
        g[:, k + t] = hump_law.py_func(1.0, b, 0.0, 0.0, w)  # the term per N m of its amplitude
    scale = np.sqrt(np.maximum(np.sum(a * a, axis=0), 1e-300))
    an, gn = a / scale, g / scale
    lo = _linear_lower(prob)
    bounds = [(lo[i] * scale[i] if np.isfinite(lo[i]) else None, None) for i in range(k)] + [
        (None, None)
    ] * terms
    floor = 1e-4 * float(np.max(np.abs(g @ theta[: k + terms])))
    res = optimize.minimize(
        lambda x: float(np.sum((an @ x - prob.y) ** 2)),
        theta[: k + terms] * scale,
        jac=lambda x: 2.0 * an.T @ (an @ x - prob.y),
        method="SLSQP",
        bounds=bounds,
        constraints=[{"type": "ineq", "fun": lambda x: gn @ x - floor, "jac": lambda x: gn}],
        options={"maxiter": 200, "ftol": 1e-12},
    )
    out = np.concatenate([res.x / scale, rates])
    if not _dissipative(out, k, terms, free_lin):
        return None
    r = a @ (res.x / scale) - prob.y
    return out, float(r @ r)


def _curve_values(theta: np.ndarray, terms: int, k: int, free_lin: list[str]) -> dict[str, float]:
    """The base parameters of one fitted curve, its hump terms in the paper's order."""
    out = {n: float(theta[i]) for i, n in enumerate(free_lin)}
    amps = [float(theta[k + t]) for t in range(terms)]
    rates = [float(theta[k + terms + t]) for t in range(terms)]
    order = sorted(range(terms), key=lambda t: -rates[t])  # beta_1 >= beta_2
    for slot in range(2):
        t = order[slot] if slot < terms else None
        out[HUMP_AMPLITUDES[slot]] = amps[t] if t is not None else 0.0
        out[HUMP_RATES[slot]] = rates[t] if t is not None else 0.0
    return out


def _alternative_ranges(
    prob: _Problem,
    candidates: list[tuple[np.ndarray, float, int]],
    ss: float,
    s2: float,
    chosen: int,
    k: int,
    threshold: float | None,
    free_lin: list[str],
) -> dict[str, tuple[float, float]]:
    """The range of each base parameter over the friction curves that fit the data as
    well as the chosen one: a curve with another number of hump terms that the term test does
    not tell from it (its sum of squares within the test's threshold), or another basin of the
    rates within the 95 % level of one parameter (chi^2_1 = 3.84, in units of the misfit). The
    local covariance of the chosen curve cannot show these: two humps that nearly cancel, a slow
    hump the viscous slope mimics over the speeds seen, a sharp one the static level absorbs."""
    if not candidates:
        return {}
    same = float(stats.chi2.isf(0.05, 1)) * s2
    other = (threshold if threshold is not None else same) * s2
    vals: dict[str, list[float]] = {}
    for theta, ss_c, terms in candidates:
        if not math.isfinite(ss_c):
            continue
        limit = same if terms == chosen else other
        if ss_c > ss + limit:
            continue
        if terms > chosen and ss_c > ss:  # a further term that lowers nothing is no alternative
            continue
        for n, v in _curve_values(theta, terms, k, free_lin).items():
            vals.setdefault(n, []).append(v)
    return {n: (min(v), max(v)) for n, v in vals.items() if len(v) > 1}


def fitted_params(fit: JointFit, *, name: str, description: str) -> RigParams:
    """The fit as a validated :class:`RigParams`."""
    values = {n: fit.values[n] for n in IDENTIFIED_PARAMETERS}  # the numeric fields; the rest by name
    return RigParams(**values, effects=ModelEffects(), name=name, description=description)


def residual_ss(rows: list[RunRows], fit: JointFit) -> tuple[float, int]:
    """The weighted sum of squares of ``rows`` at ``fit``'s values (rows the fit may not have
    used, e.g. held-out runs' with the same effect columns), and the number of windows."""
    p = np.array([fit.values[n] for n in LINEAR])
    ss, n = 0.0, 0
    for r in rows:
        res = r.x_lin @ p
        if r.offset is not None:
            res = res + r.offset
        if r.x_eff is not None and r.effect_names:
            res = res + r.x_eff @ np.array([fit.values.get(n_, 0.0) for n_ in r.effect_names])
        for amp, rate in zip(HUMP_AMPLITUDES, HUMP_RATES, strict=True):
            if fit.values.get(amp, 0.0) != 0.0:
                res = res + fit.values[amp] * r.hump(fit.values[rate])
        z = res / r.sigma
        ss += float(z @ z)
        n += z.size
    return ss, n
