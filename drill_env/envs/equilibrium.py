"""The slip equilibrium of the nominal model at an operating point, from the analysis.

The env draws an operating point as a nominal voltage ``u`` and the lower-disk speed of
the slip equilibrium at ``u`` (eq. 20), and the regimes along ``u`` (:mod:`.regimes`)
start from the Routh-Hurwitz threshold and the Hopf points: all of these are those of
:mod:`drill_env.analysis.equilibria`, which this module only adapts to the env's needs
(speed 0 at rest below uc1, the kernel's state vector, voltages of the forward branch).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drill_env import _layout as L
from drill_env.analysis.equilibria import (
    _speed_at,
    _voltage_of_speed,
    hopf_points,
    routh_hurwitz,
)
from drill_env.analysis.equilibria import critical_friction_slope as _critical_friction_slope
from drill_env.friction import lower_friction_curve
from drill_env.params import RIG_VOLTAGE_LIMIT, ModelEffects, RigParams

__all__ = [
    "critical_friction_slope",
    "equilibrium_speed",
    "equilibrium_state",
    "hopf_voltages",
    "nominal_params",
    "nominal_voltage",
    "stable_at_speed",
]


def nominal_params(params: RigParams) -> RigParams:
    """The paper's model of ``params``: the same coefficients, no extra effects."""
    if params.effects.active:
        return dataclasses.replace(params, effects=ModelEffects())
    return params


def nominal_voltage(params: RigParams, speed: float) -> float:
    """Voltage whose slip equilibrium turns the lower disk at ``speed`` > 0 [rad/s] -> [V]."""
    return float(_voltage_of_speed(params, float(speed)))


def equilibrium_speed(params: RigParams, voltage: float) -> float:
    """Lower-disk speed of the slip equilibrium at ``voltage`` [V] -> [rad/s]; 0 if u <= uc1.

    The torque balance is increasing in the speed by condition (21), so the root is unique.
    """
    u = float(voltage)
    if u <= params.uc1:
        return 0.0
    try:
        return float(_speed_at(params, u))
    except ValueError:
        raise ValueError(f"voltage: no equilibrium speed found for {u:g} V") from None


def equilibrium_state(params: RigParams, voltage: float) -> np.ndarray:
    """Kernel state on the slip equilibrium at ``voltage`` (at rest for u <= uc1)."""
    w = equilibrium_speed(params, voltage)
    y = np.zeros(L.NY)
    if w > 0.0:
        y[L.X1] = float(lower_friction_curve(params, w)) / params.string_stiffness
        y[L.X2] = w
        y[L.X3] = w
        y[L.WL] = w
    y[L.TM] = params.motor_constant * float(voltage)
    return y


def critical_friction_slope(params: RigParams) -> float:
    """Routh-Hurwitz threshold on d_l = dT_l/dx3 of the forward slip equilibria
    [N m s/rad]: stable iff ``d_l > critical_friction_slope``
    (:func:`drill_env.analysis.equilibria.critical_friction_slope` with ``direction=1``)."""
    return float(_critical_friction_slope(params, 1))


def stable_at_speed(params: RigParams, speed: float) -> bool:
    """Whether the forward slip equilibrium turning at ``speed`` > 0 [rad/s] is linearly
    stable (Routh-Hurwitz, :func:`drill_env.analysis.equilibria.routh_hurwitz`)."""
    return bool(routh_hurwitz(params, float(speed))[0])


def hopf_voltages(params: RigParams, u_max: float = RIG_VOLTAGE_LIMIT) -> tuple[float, ...]:
    """Voltages in (uc1, u_max) where the forward slip equilibrium changes stability: the
    Hopf points of :func:`drill_env.analysis.equilibria.hopf_points`."""
    params = nominal_params(params)
    w_max = equilibrium_speed(params, u_max)
    if w_max <= 0.0:
        return ()
    points = hopf_points(params, u_min=params.uc1, u_max=float(u_max), max_speed=max(200.0, 2.0 * w_max))
    return tuple(h.u for h in points if h.x_eq[2] > 0.0 and params.uc1 < h.u < u_max)
