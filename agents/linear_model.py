"""What the controllers believe: the nominal rig, its slip equilibria and their linearisation.

Controllers are designed on the nominal model (the preset's parameters), never on the
plant the env simulates (which may be randomised or carry extra effects).

Linearisation of eq. (36) about the slip equilibrium (20) at lower-disk speed w > 0,
states (x1, x2, x3), input u::

    x1' = x2 - x3
    Ju x2' = km u - k_theta x1 - b_up x2
    Jl x3' = k_theta x1 - d_l(w) x3

with d_l the friction slope of eq. (24).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from drill_env.friction import lower_friction_curve, lower_friction_slope
from drill_env.params import RigParams

__all__ = ["OperatingPoint", "operating_point", "nominal_voltage", "equilibrium_speed", "linearise"]


def nominal_voltage(params: RigParams, speed: float) -> float:
    """Voltage whose slip equilibrium (20) turns the lower disk at ``speed`` > 0 [V]."""
    if not np.isfinite(speed) or speed <= 0.0:
        raise ValueError(f"speed: the equilibrium speed must be finite and > 0, got {speed!r}")
    w = float(speed)
    torque = params.upper_static_pos + params.upper_viscous_pos * w + float(lower_friction_curve(params, w))
    return torque / params.motor_constant


def equilibrium_speed(params: RigParams, voltage: float) -> float:
    """Lower-disk speed x3_eq of the slip equilibrium (20) at ``voltage``; 0 in the stick set."""
    if not np.isfinite(voltage):
        raise ValueError(f"voltage: must be finite, got {voltage!r}")
    if voltage <= params.uc1:
        return 0.0

    def g(w: float) -> float:
        return nominal_voltage(params, w) - voltage

    hi = 1.0
    while g(hi) < 0.0:
        hi *= 2.0
        if hi > 1e4:
            raise ValueError(f"voltage: no slip equilibrium found below 1e4 rad/s at {voltage} V")
    # Condition (21) makes g increasing, so the root is unique.
    return float(brentq(g, 1e-14, hi, xtol=1e-14, rtol=1e-14))


@dataclass(frozen=True)
class OperatingPoint:
    """A slip equilibrium of the nominal rig."""

    voltage: float  # u [V]
    speed: float  # x2 = x3 [rad/s]
    twist: float  # x1 = T_l(w)/k_theta [rad]
    friction_slope: float  # d_l(w) [N m s / rad]


def operating_point(params: RigParams, *, speed: float | None = None, voltage: float | None = None) -> OperatingPoint:
    """The slip equilibrium given either its lower-disk speed or its voltage."""
    if (speed is None) == (voltage is None):
        raise ValueError("operating_point: give exactly one of speed, voltage")
    if speed is None:
        speed = equilibrium_speed(params, float(voltage))
        if speed == 0.0:
            raise ValueError(f"voltage: {voltage} V is in the stick set (<= uc1 = {params.uc1:.4f} V)")
    u = nominal_voltage(params, speed)
    return OperatingPoint(
        voltage=u,
        speed=float(speed),
        twist=float(lower_friction_curve(params, speed)) / params.string_stiffness,
        friction_slope=float(lower_friction_slope(params, speed)),
    )


def linearise(params: RigParams, op: OperatingPoint) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the linearisation about ``op`` in the states (x1, x2, x3)."""
    ju, jl, k = params.upper_inertia, params.lower_inertia, params.string_stiffness
    A = np.array(
        [
            [0.0, 1.0, -1.0],
            [-k / ju, -params.upper_viscous_pos / ju, 0.0],
            [k / jl, 0.0, -op.friction_slope / jl],
        ]
    )
    B = np.array([[0.0], [params.motor_constant / ju], [0.0]])
    return A, B
