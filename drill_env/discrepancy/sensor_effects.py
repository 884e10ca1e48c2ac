"""Sensor explanations of a residual line locked to a disk's rotation.

A line that keeps a disk's angle can be physical (a friction that changes with the
position, :mod:`~drill_env.recordings.effects`) or an error of the measurement: an
eccentric encoder disk reads ``theta + a sin(theta + phi)``, once per revolution. The
second is no torque at all, but the equation error computed from the readings holds the
model's response to the reading error,

    r(theta + e) - r(theta) = [J B*D2 e + k_theta K[e] + b K[e']] / h^2 + sgn K[S'(w) e'] / h^2

on the disk whose encoder errs (inertia, string, viscous and Stribeck terms of its own
equation) and ``-k_theta K[e] / h^2`` on the other disk (the twist). With ``e = c cos
theta + s sin theta`` that is two columns, linear in ``(c, s)``, fitted like a candidate's
(coefficients common to the runs: the encoder is the same in every run). The columns
(:func:`~drill_env.recordings.effects.eccentricity_columns`) make the library's measurement
candidates ``encoder_eccentricity_<disk>``, judged by the held-out rules like every other;
here, for a line that stays ``unexplained``, both explanations are scored on the same
residual and listed side by side in the report, so that a lab user looks at the encoder as
well as at the brake.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drill_env.recordings.effects import CANDIDATES, eccentricity_columns
from drill_env.recordings.equation_error import RunEquations

__all__ = ["eccentricity_columns", "rotation_explanations"]


def _drop(eqs: list[RunEquations], columns) -> tuple[float, np.ndarray]:
    """Drop of the sum of squares (noise units) with coefficients common to the runs, and them."""
    xs, zs = [], []
    for eq in eqs:
        xu, xl = columns(eq)
        for x, w in ((xu, eq.upper), (xl, eq.lower)):
            if len(w):
                xs.append(x / w.sigma[:, None])
                zs.append(w.z)
    if not xs:
        return 0.0, np.zeros(0)
    x = np.vstack(xs)
    z = np.concatenate(zs)
    coef, *_ = np.linalg.lstsq(x, z, rcond=None)
    r = z - x @ coef
    return float(z @ z - r @ r), coef


def rotation_explanations(eqs: list[RunEquations], disk: str) -> list[dict[str, Any]]:
    """The physical and the sensor explanation of a line locked to ``disk``'s rotation, each
    with its drop of the sum of squares (noise units, coefficients common to the runs), its
    parameters and its BIC score (drop minus ``k ln n``), best first."""
    n = sum(len(eq.upper) + len(eq.lower) for eq in eqs)
    log_n = math.log(max(n, 2))
    friction = next(c for c in CANDIDATES if c.name == f"position_friction_{disk}")
    drop_f, coef_f = _drop(eqs, friction.columns)
    drop_e, coef_e = _drop(eqs, lambda eq: eccentricity_columns(eq, disk))
    rows = [
        {
            "explanation": f"position_friction_{disk}",
            "kind": "physical",
            "what": f"a friction of the {disk} disk that changes with its angle (brake contact, runout "
            "of the disk)",
            "drop": drop_f,
            "k": friction.n_params,
            "score": drop_f - friction.n_params * log_n,
            "parameters": friction.to_parameters(coef_f) if coef_f.size else {},
        },
        {
            "explanation": f"encoder_eccentricity_{disk}",
            "kind": "sensor",
            "what": f"a once-per-revolution reading error a sin(theta + phi) of the {disk} encoder (an "
            "eccentric or tilted encoder disk): no torque, the angle is read wrong",
            "drop": drop_e,
            "k": 2,
            "score": drop_e - 2 * log_n,
            "parameters": (
                {
                    f"{disk}_encoder_eccentricity_rad": float(math.hypot(*coef_e)),
                    f"{disk}_encoder_phase_rad": float(math.atan2(coef_e[0], coef_e[1]) % (2 * math.pi)),
                }
                if coef_e.size
                else {}
            ),
        },
    ]
    return sorted(rows, key=lambda r: -r["score"])
