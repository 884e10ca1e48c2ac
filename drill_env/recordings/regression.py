"""Regression columns of the rig model's identified parameters on a recorded run.

The filtered equation error (:mod:`~drill_env.recordings.equation_error`) is linear in every
identified parameter but the two Stribeck rates, so ``r(p + d) = r(p) + C d`` with
``C = dr/dp`` exact for the linear parameters and the Gauss-Newton linearisation for
``beta_1, beta_2``. :func:`calibration_columns` gives ``C`` per window of each disk; the
discrepancy workflow's recalibration (:mod:`drill_env.discrepancy.calibrate`), its
voltage-timing scan and the identification's joint fit (:mod:`drill_env.identify.joint`)
all build on them.
"""

from __future__ import annotations

import numpy as np

from drill_env.params import IDENTIFIED_PARAMETERS, RigParams
from drill_env.recordings.equation_error import RunEquations

__all__ = ["CALIBRATED", "FIXED_SCALE", "calibration_columns", "reading_error_columns", "reading_error_gram"]

# The identified parameters that are refitted (RigParams field names, in column order).
FIXED_SCALE = "string_stiffness"  # fixes the one scale the data cannot
CALIBRATED: tuple[str, ...] = tuple(p for p in IDENTIFIED_PARAMETERS if p != FIXED_SCALE)


def _tanh_cols(p: RigParams, w: np.ndarray):
    a1 = 0.5 * p.lower_hump_rate_1 * w
    a2 = 0.5 * p.lower_hump_rate_2 * w
    t1, t2 = np.tanh(a1), np.tanh(a2)
    d1 = p.lower_hump_1 * 0.5 * w / np.cosh(a1) ** 2
    d2 = p.lower_hump_2 * 0.5 * w / np.cosh(a2) ** 2
    return t1, t2, d1, d2


def calibration_columns(eq: RunEquations) -> tuple[np.ndarray, np.ndarray]:
    """``dr/dp`` at the run's parameters, one column per :data:`CALIBRATED` entry [N m per unit].

    Returns the upper-disk and the lower-disk windows' rows."""
    h2 = eq.h**2
    k = len(CALIBRATED)
    col = {n: i for i, n in enumerate(CALIBRATED)}
    up, lo = eq.upper, eq.lower
    xu = np.zeros((len(up), k))
    if len(up):
        s = up.sign
        th = eq.gather(eq.theta_u, up.centers)
        rate = th @ eq.w_rate / h2
        xu[:, col["upper_inertia"]] = th @ eq.w_d2 / h2
        xu[:, col["motor_constant"]] = -(eq.gather(eq.u, up.centers) @ eq.w_zoh) / h2
        xu[:, col["upper_static_pos"]] = (s > 0).astype(float)
        xu[:, col["upper_static_neg"]] = -(s < 0).astype(float)
        xu[:, col["upper_viscous_pos"]] = np.where(s > 0, rate, 0.0)
        xu[:, col["upper_viscous_neg"]] = np.where(s < 0, rate, 0.0)
    xl = np.zeros((len(lo), k))
    if len(lo):
        s = lo.sign
        th = eq.gather(eq.theta_l, lo.centers)
        w = np.abs(eq.gather(eq.speed_l, lo.centers))
        t1, t2, d1, d2 = _tanh_cols(eq.params, w)
        xl[:, col["lower_inertia"]] = th @ eq.w_d2 / h2
        xl[:, col["lower_static"]] = s
        xl[:, col["lower_viscous"]] = th @ eq.w_rate / h2
        xl[:, col["lower_hump_1"]] = s * (t1 @ eq.w_tri) / h2
        xl[:, col["lower_hump_2"]] = s * (t2 @ eq.w_tri) / h2
        xl[:, col["lower_hump_rate_1"]] = s * (d1 @ eq.w_tri) / h2
        xl[:, col["lower_hump_rate_2"]] = s * (d2 @ eq.w_tri) / h2
    return xu, xl


def reading_error_columns(eq: RunEquations) -> tuple[np.ndarray, np.ndarray]:
    """The covariance of the encoders' reading error in each window's angle columns and where
    those columns sit: ``(q, index)``, ``q`` (windows, 3, 3) [N m^2 per unit^2] for the
    columns of the window's disk's inertia, the string stiffness and its viscous friction
    (:meth:`RunEquations.column_noise`), ``index`` (windows, 3) their positions in
    :data:`~drill_env.params.IDENTIFIED_PARAMETERS`; upper windows first, as the rows of
    :func:`calibration_columns`."""
    pos = {n: i for i, n in enumerate(IDENTIFIED_PARAMETERS)}
    nu, nl = len(eq.upper), len(eq.lower)
    index = np.zeros((nu + nl, 3), dtype=int)
    index[:nu] = [pos["upper_inertia"], pos["string_stiffness"], pos["upper_viscous_pos"]]
    index[:nu][eq.upper.sign < 0, 2] = pos["upper_viscous_neg"]
    index[nu:] = [pos["lower_inertia"], pos["string_stiffness"], pos["lower_viscous"]]
    return np.concatenate([eq.column_noise("upper"), eq.column_noise("lower")]), index


def reading_error_gram(eq: RunEquations, keep: np.ndarray | None = None) -> np.ndarray:
    """``sum_i Q_i / sigma_i^2`` over the windows (``keep``: a mask of them) of the run, on
    :data:`~drill_env.params.IDENTIFIED_PARAMETERS` x itself [1/unit^2]: what the reading error of
    the angle columns adds to the expected noise-unit sum of squares of the equation error is
    ``p' G p`` for the parameters ``p``, so a fit that minimises the measured sum is drawn
    towards parameters for which it is small (errors in the variables). Subtracting ``p' G p``
    from the measured sum (bias compensation) removes that pull."""
    q, index = reading_error_columns(eq)
    sigma = np.concatenate([eq.upper.sigma, eq.lower.sigma])
    if keep is not None:
        q, index, sigma = q[keep], index[keep], sigma[keep]
    g = np.zeros((len(IDENTIFIED_PARAMETERS), len(IDENTIFIED_PARAMETERS)))
    if sigma.size:
        np.add.at(g, (index[:, :, None], index[:, None, :]), q / (sigma**2)[:, None, None])
    return g
