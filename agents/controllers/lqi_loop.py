"""The closed loop of the sampled rig and an LQI, as the feedforward designs need it: its
matrices and its frequency response from a voltage added to the LQI's output to the measured
lower speed (:mod:`drill_env.agents.controllers.angle_feedforward`,
:mod:`drill_env.agents.controllers.effect_feedforward`)."""

from __future__ import annotations

import cmath
from typing import Any

import numpy as np

from drill_env.agents.controllers.linear_model import SampledRig, design_point

_LOWER_MEAN = 3  # row of the lower_speed_mean entry in SampledRig.H


def _loop(rig: SampledRig, lqi: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A, b, c, Bn): ``rig`` closed by the LQI, the input of a voltage added to the LQI's
    output, the output lower_speed_mean and the input of the measurement noise, in deviations
    from the equilibrium. The LQI is affine in the observation with gains scheduled on w*:
    its linear part, probed at the equilibrium of its own (nominal) model at the rig's speed,
    holds on any rig turning at that speed."""
    from drill_env.agents.controllers.tuning import closed_loop, controller_matrices

    own = design_point(lqi.spec.params, speed=rig.speed)
    A, Bn, _, _ = closed_loop(rig, controller_matrices(lqi, own))
    nc = A.shape[0] - rig.n
    b = np.concatenate([rig.G, np.zeros(nc)])
    c = np.concatenate([rig.H[_LOWER_MEAN], np.zeros(nc)])
    return A, b, c, Bn


def _response(A: np.ndarray, b: np.ndarray, c: np.ndarray, omega: float, dt: float) -> complex:
    z = cmath.exp(1j * omega * dt)
    return complex(c @ np.linalg.solve(z * np.eye(A.shape[0]) - A, b.astype(complex)))
