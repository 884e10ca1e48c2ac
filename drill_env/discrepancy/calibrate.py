"""Recalibration of the rig's identified parameters from the equation error.

The paper identified its parameters on the rig (eq. 11, 13, 15, 17); on another rig, or
the same rig another day, they are off by a few percent, and a model with slightly
wrong parameters leaves a residual that a missing effect can mimic (a lower static
friction a few percent off looks like a drift of the friction level, a lower inertia a
few percent off like a frictional lag). So the parameters are refitted first, and an
effect is only ever scored as an *addition to the recalibrated model*.

The equation error of :mod:`~drill_env.recordings.equation_error` is linear in every
identified parameter but the two Stribeck rates:

    r_u = [J_u B*D2 theta_u - k_m K[u] + k_theta K[x1] + b_u K[theta_u']] / h^2 + sgn T_su
    r_l = [J_l B*D2 theta_l - k_theta K[x1] + sgn K[S(w)] + b_l K[theta_l']] / h^2 + sgn T_sl

with ``S(w) = T_1 tanh(beta_1 w / 2) + T_2 tanh(beta_2 w / 2)``. So ``r(p + d) = r(p) + C d``
with ``C = dr/dp`` exact for the linear parameters and the Gauss-Newton linearisation
for ``beta_1, beta_2``. In noise units (each window divided by its noise standard
deviation) the fit is a weighted linear least-squares problem whose sufficient
statistics are kept per run, like the candidates'.

Choices the data leave open, documented here and in the README:

* **The scale.** Multiplying every parameter of both disk equations by one constant
  leaves both residuals zero: the data fix ratios, not the scale. The string's
  stiffness ``k_theta`` (from the string's geometry and material) is kept at its
  nominal value and sets the scale; every other parameter is fitted relative to it.
* **A weak prior.** Each parameter carries a Gaussian prior at its nominal value with
  a standard deviation of ``prior_rel`` (25 %) of it: the paper's values are known to
  that accuracy. It keeps nearly collinear directions (``T_2``, ``beta_2`` and ``b_l``
  at speeds where ``tanh`` is still linear) and unexcited ones (the negative side of
  the upper friction when the voltage never reverses) at their nominal values instead
  of letting them wander, and changes well-determined parameters by a negligible
  fraction of their interval.
* **Identified or not.** A parameter is *identified* when the data shrink its prior
  standard deviation at least ``identified_ratio`` (3) times; the others stay nominal
  and are reported as not identified.
* **Moved.** Which identified parameters moved is chosen by forward selection on the
  training runs (:func:`drill_env.discrepancy.parameter_selection.first_calibration`): add the one
  whose refit lowers the sum of squares most while the drop passes the candidates' test
  for one parameter, jointly with the best significant candidate if there is one, so
  that neither absorbs the other. Only moved parameters are changed in the
  recalibrated model; they are refitted with the others at nominal.

Intervals are posterior 95 % intervals, scaled up by ``sqrt(Q/(n - p))`` when the fit
leaves more than the noise floor, and at least as wide as the jackknife over the
training runs (errors common to a run's windows are not in the per-window noise model).
"""

from __future__ import annotations

import functools
import math
import operator
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from drill_env.params import IDENTIFIED_PARAMETERS, RigParams
from drill_env.recordings.equation_error import RunEquations
from drill_env.recordings.regression import CALIBRATED, calibration_columns, reading_error_gram

__all__ = [
    "CalibrationRule",
    "CalibrationStatistics",
    "ParameterFit",
    "ALTERNATIVE_EXPLANATIONS",
    "calibration_statistics",
    "solve_joint",
    "parameter_fits",
]


@dataclass(frozen=True)
class CalibrationRule:
    prior_rel: float = 0.25  # prior standard deviation, relative to the nominal value [-]
    identified_ratio: float = 3.0  # prior sd / posterior sd above which a parameter is identified
    alpha: float = 1e-3  # family-wise level of the "moved" test over the identified parameters


@dataclass
class CalibrationStatistics:
    """Per-run sufficient statistics of the calibration columns, in noise units.

    ``A = -C / sigma``, so that the residual after a parameter change d is ``z - A d``."""

    name: str
    ata: np.ndarray  # A'A
    atz: np.ndarray  # A'z
    # what the reading error of the angle columns adds to A'A (subtracted from ``ata``: the
    # bias-compensated statistics, see _reading_compensation); None: none
    reading: np.ndarray | None = None
    cross: dict[str, np.ndarray] = field(default_factory=dict)  # linear candidate: A'X
    cross_lag: dict[str, np.ndarray] = field(default_factory=dict)  # lag candidate: A'x per tau (p x n_tau)
    # Gram matrix of every column [z, A, each linear candidate's columns, each lag candidate's
    # column per tau] and where each sits in it (keys "z", "A", name, (name, tau index)):
    # any joint fit of several candidates is a choice of its blocks
    gram: np.ndarray | None = None
    index: dict[Any, np.ndarray] = field(default_factory=dict)
    # [z, A] at the first and second window of each pair of neighbouring windows (D1, D2):
    # D1'D2, D1'D1 and D2'D2 stacked, so that the neighbour correlation of the residual after
    # any parameter change d is that of v = [1, -d]
    neighbour: np.ndarray | None = None

    def neighbour_sums(self, d: np.ndarray) -> tuple[float, float, float]:
        """Sums over neighbouring windows of r_i r_j, r_i^2 and r_j^2 for the residual
        ``r = z - A d`` after the parameter change ``d`` (every calibrated parameter)."""
        v = np.concatenate([[1.0], -np.asarray(d, dtype=float)])
        assert self.neighbour is not None  # set by calibration_statistics
        ab, aa, bb = (float(v @ m @ v) for m in self.neighbour)
        return ab, aa, bb


def calibration_statistics(eq: RunEquations, candidates=()) -> CalibrationStatistics:
    xu, xl = calibration_columns(eq)
    a = -np.vstack([xu / eq.upper.sigma[:, None], xl / eq.lower.sigma[:, None]])
    z = np.concatenate([eq.upper.z, eq.lower.z])
    # bias-compensated (recordings.regression.reading_error_gram): the sum of squares after a change
    # d less what the encoders' reading error in the angle columns adds to it, so that no change is
    # preferred for lowering that error's weight (an inertia set to zero as a motor lag takes its
    # part: a false discovery on a closed-loop run at 1 kHz and 4096 counts)
    ata, atz = a.T @ a, a.T @ z
    q, qp = _reading_compensation(eq, ata, float(z @ z) / max(z.size, 1))
    ata, atz = ata - q, atz + qp
    st = CalibrationStatistics(name=eq.run.name, ata=ata, atz=atz, reading=q)
    i, j = eq.neighbour_pairs()
    za = np.column_stack([z, a])
    d1, d2 = za[i], za[j]
    st.neighbour = np.stack([d1.T @ d2, d1.T @ d1, d2.T @ d2])
    blocks = [z[:, None], a]
    index: dict[Any, np.ndarray] = {"z": np.array([0]), "A": np.arange(1, 1 + a.shape[1])}
    pos = 1 + a.shape[1]
    for c in candidates:
        if c.is_lag:
            cols = np.empty((a.shape[1], c.tau_grid.size))
            for k, tau in enumerate(c.tau_grid):
                cu, cl = c.columns(eq, float(tau))
                x = np.concatenate([cu[:, 0] / eq.upper.sigma, cl[:, 0] / eq.lower.sigma])
                cols[:, k] = a.T @ x
                blocks.append(x[:, None])
                index[(c.name, k)] = np.array([pos])
                pos += 1
            st.cross_lag[c.name] = cols
        else:
            cu, cl = c.columns(eq)
            x = np.vstack([cu / eq.upper.sigma[:, None], cl / eq.lower.sigma[:, None]])
            st.cross[c.name] = a.T @ x
            blocks.append(x)
            index[c.name] = np.arange(pos, pos + x.shape[1])
            pos += x.shape[1]
    d = np.hstack(blocks)
    st.gram = d.T @ d
    ia = index["A"]
    st.gram[np.ix_(ia, ia)] = ata
    st.gram[0, ia] = st.gram[ia, 0] = atz
    st.index = index
    return st


# the compensation takes at most this share of the measured sum of squares along any direction
# of the parameters (a direction the reading error alone would account for is left to the prior)
MAX_COMPENSATED_SHARE = 0.9


def _reading_compensation(
    eq: RunEquations, ata: np.ndarray, floor_ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(Q, Q p)`` on :data:`CALIBRATED`: what the reading error of the angle columns adds to the
    run's noise-unit sum of squares after a change d is ``2 d' Q p + d' Q d`` (p the run's
    parameters, the string stiffness included; :func:`reading_error_gram`). The noise model can
    put the floor too high (an estimated dither where there is none): ``Q`` is scaled by the
    run's own residual, ``floor_ratio`` (its mean square in noise units) where that is below 1
    (over-compensated, a recalibration had moved J_u by +26 % on a closed-loop run whose residual
    sat at 0.05-0.3 of the floor, every held-out run off), and held below
    :data:`MAX_COMPENSATED_SHARE` of ``A'A`` in every direction, so the compensated sum stays a
    sum of squares."""
    g = reading_error_gram(eq) * min(1.0, max(floor_ratio, 0.0))
    pos = [IDENTIFIED_PARAMETERS.index(n) for n in CALIBRATED]
    p_full = np.array([float(getattr(eq.params, n)) for n in IDENTIFIED_PARAMETERS])
    q = g[np.ix_(pos, pos)]
    qp = (g @ p_full)[pos]
    if not np.any(q):
        return q, qp
    scale = np.sqrt(np.maximum(np.diag(ata), 1e-300))
    an = ata / np.outer(scale, scale) + 1e-12 * np.eye(ata.shape[0])
    chol = np.linalg.cholesky(an)
    m = np.linalg.solve(chol, np.linalg.solve(chol, q / np.outer(scale, scale)).T)
    lam, v = np.linalg.eigh(0.5 * (m + m.T))
    if lam.max() > MAX_COMPENSATED_SHARE:
        m = (v * np.minimum(lam, MAX_COMPENSATED_SHARE)) @ v.T
        q = (chol @ m @ chol.T) * np.outer(scale, scale)
    return q, qp


def _total(arrays: Iterable[np.ndarray]) -> np.ndarray:
    """The sum of ``arrays``, added in order (as the built-in ``sum``, typed as an array)."""
    return functools.reduce(operator.add, arrays)


def prior_precision(params: RigParams, rule: CalibrationRule) -> np.ndarray:
    """Diagonal prior precision of the parameter changes [1/unit^2]."""
    nominal = np.array([abs(getattr(params, n)) for n in CALIBRATED])
    sd = rule.prior_rel * np.maximum(nominal, 1e-12)
    return 1.0 / sd**2


def solve_joint(
    m: np.ndarray, b: np.ndarray, prior: np.ndarray, ridge: float = 1e-9
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior mean and (unscaled) covariance of ``z ~ [A X] theta`` with a prior on the first
    ``prior.size`` coefficients (the parameter changes) and a negligible ridge on the rest."""
    k = m.shape[0]
    reg = np.zeros(k)
    reg[: prior.size] = prior
    rest = k - prior.size
    if rest:
        scale = max(float(np.trace(m[prior.size :, prior.size :])) / rest, 1e-300)
        reg[prior.size :] = ridge * scale
    mat = m + np.diag(reg)
    cov = np.linalg.inv(mat)
    return cov @ b, cov


# What else produces the same data as a recalibration far outside a parameter's prior: the
# equation error sees a torque, and these are other torques (or inputs) of the same shape.
ALTERNATIVE_EXPLANATIONS: dict[str, str] = {
    "motor_constant": "an amplifier gain error or a voltage measured before a drop (the motor "
    "torque is k_m u: any error on the gain from the recorded u to the torque reads as k_m)",
    "upper_inertia": "a mass added to or removed from the upper disk, or a lag between the "
    "recorded voltage and the motor torque",
    "upper_static_pos": "a voltage offset at the amplifier or the DAQ (with u >= 0 a constant "
    "offset u0 gives the torque k_m u0, identical to a change of the upper static friction), "
    "or a constant external torque on the upper disk",
    "upper_static_neg": "a voltage offset at the amplifier or the DAQ (with u <= 0 a constant "
    "offset gives a constant torque, identical to a change of this friction), or a constant "
    "external torque on the upper disk",
    "upper_viscous_pos": "a voltage-dependent amplifier gain, or a speed-dependent drag on the "
    "upper disk (a fan, a seal)",
    "upper_viscous_neg": "a voltage-dependent amplifier gain, or a speed-dependent drag on the "
    "upper disk (a fan, a seal)",
    "lower_inertia": "a mass added to or removed from the lower disk, or a lag of the lower "
    "friction behind the speed",
    "lower_static": "a changed brake force, or a constant external torque on the lower disk",
    "lower_viscous": "a speed-dependent drag on the lower disk, or a brake force that changes with speed",
    "lower_hump_1": "a changed brake contact (wear, temperature) or a drift of the friction level",
    "lower_hump_2": "a changed brake contact (wear, temperature) or a drift of the friction level",
    "lower_hump_rate_1": "a changed brake contact (the Stribeck speed of the friction)",
    "lower_hump_rate_2": "a changed brake contact (the Stribeck speed of the friction)",
}


@dataclass(frozen=True)
class ParameterFit:
    """One identified parameter: nominal, value, posterior interval, verdict.

    Every calibrated parameter has the sign physics gives it (all are positive but the second
    hump term of the lower friction, which is negative), so its 95 % interval is the posterior
    one in ``log |p|`` (delta method: ``value * exp(+-1.96 s / |value|)``): it keeps that sign
    however weakly the data fix the parameter, and for a precisely fixed one it is the
    symmetric interval ``value +- 1.96 s`` to first order."""

    name: str
    nominal: float
    value: float
    sd: float  # posterior standard deviation from the window noise (the "moved" test)
    identified: bool
    moved: bool
    sd_interval: float = float("nan")  # the one of the interval, at least sd (see final_parameters)
    prior_sd: float = float("nan")  # of the prior at the nominal value [parameter units]

    @property
    def interval_sd(self) -> float:
        return self.sd if not math.isfinite(self.sd_interval) else max(self.sd, self.sd_interval)

    @property
    def ci95(self) -> tuple[float, float]:
        s = self.interval_sd
        if self.value * self.nominal > 0.0 and math.isfinite(s):
            rel = 1.96 * s / abs(self.value)
            a, b = self.value * math.exp(-rel), self.value * math.exp(rel)
            return (min(a, b), max(a, b))
        return (self.value - 1.96 * s, self.value + 1.96 * s)

    @property
    def excludes_nominal(self) -> bool:
        """The 95 % interval does not hold the nominal value: a change the data resolve."""
        lo, hi = self.ci95
        return bool(self.nominal < lo or self.nominal > hi)

    @property
    def out_of_prior(self) -> bool:
        """The value is further from the nominal than the prior's width (one prior standard
        deviation): the recalibration is larger than the paper's values are thought to be off,
        and something other than this parameter may be what changed."""
        return bool(
            self.moved and math.isfinite(self.prior_sd) and abs(self.value - self.nominal) > self.prior_sd
        )

    def as_dict(self) -> dict[str, Any]:
        lo, hi = self.ci95
        out: dict[str, Any] = {
            "nominal": self.nominal,
            "value": self.value,
            "ci95": [lo, hi],
            "interval_excludes_nominal": self.excludes_nominal,
            "out_of_prior": self.out_of_prior,
        }
        if self.out_of_prior:
            out["alternative_explanation"] = ALTERNATIVE_EXPLANATIONS.get(self.name, "")
        return out


def moved_z(n_identified: int, rule: CalibrationRule) -> float:
    return float(stats.norm.isf(rule.alpha / (2.0 * max(n_identified, 1))))


def parameter_fits(
    nominal: RigParams,
    base: RigParams,
    free: list[int],
    delta: np.ndarray,
    cov: np.ndarray,
    rule: CalibrationRule,
    identified: list[int] | None = None,
    sd_interval: np.ndarray | None = None,
) -> list[ParameterFit]:
    """Fits of every :data:`CALIBRATED` parameter: ``base`` plus ``delta`` on the ``free`` ones,
    judged against ``nominal``. ``identified`` (default: ``free``) is where the data decide."""
    identified = free if identified is None else identified
    z = moved_z(len(identified), rule)
    out = []
    pos = {j: i for i, j in enumerate(free)}
    for j, name in enumerate(CALIBRATED):
        nom = float(getattr(nominal, name))
        prior_sd = rule.prior_rel * abs(nom)
        if j in pos:
            i = pos[j]
            value = float(getattr(base, name)) + float(delta[i])
            sd = float(math.sqrt(max(cov[i, i], 0.0)))
            moved = j in identified and abs(value - nom) > z * sd
            si = float(sd_interval[i]) if sd_interval is not None else float("nan")
            out.append(ParameterFit(name, nom, value, sd, j in identified, bool(moved), si, prior_sd))
        else:
            out.append(
                ParameterFit(
                    name,
                    nom,
                    float(getattr(base, name)),
                    float("nan"),
                    j in identified,
                    False,
                    prior_sd=prior_sd,
                )
            )
    return out


def calibrated_params(nominal: RigParams, fits: list[ParameterFit]) -> RigParams:
    """The nominal parameters with the moved ones replaced (effects kept)."""
    changes = {f.name: f.value for f in fits if f.moved}
    return nominal.replace(**changes) if changes else nominal


def identify(
    train: list[CalibrationStatistics], nominal: RigParams, rule: CalibrationRule
) -> tuple[list[int], np.ndarray, np.ndarray]:
    """Fit every parameter on the training statistics: the identified ones, their changes and
    unscaled posterior covariance (refitted with the unidentified ones fixed at nominal)."""
    prior = prior_precision(nominal, rule)
    ata = _total(s.ata for s in train)
    atz = _total(s.atz for s in train)
    _, cov = solve_joint(ata, atz, prior)
    prior_sd = 1.0 / np.sqrt(prior)
    post_sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    free = [j for j in range(len(CALIBRATED)) if post_sd[j] * rule.identified_ratio <= prior_sd[j]]
    idx = np.array(free, dtype=int)
    delta, cov = solve_joint(ata[np.ix_(idx, idx)], atz[idx], prior[idx])
    return free, delta, cov
