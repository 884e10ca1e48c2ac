"""The string's torsional mode and characteristic impedance on the design model: what the
industry's stick-slip controllers (:mod:`~drill_env.agents.controllers.soft_torque`,
:mod:`~drill_env.agents.controllers.z_torque`) are tuned to.

A field drill string is a torsional transmission line: a wave travels down the pipe and is
reflected at the bit and at the top drive. The pipe's characteristic impedance
``zeta = I_p sqrt(G rho)`` [N m s/rad] is the torque per unit speed that a wave carries; a top
drive whose impedance equals it absorbs the wave coming up the string instead of reflecting
it (Kyllingstad & Halsey, *A Study of Slip/Stick Motion of the Bit*, SPE Drilling Engineering
3(4), 1988; Dwars, SPE-173037-MS, 2015). The stick-slip period of a long string is close to
that of its fundamental mode with the top drive held, ``4 L / c``.

On the rig the string is one lumped spring ``k_theta`` carrying the lower disk ``J_l``: the
mode with the upper disk held is ``omega_s = sqrt(k_theta / J_l)`` (1.547 rad/s, a 4.06 s
period; the paper's measured cycles are at 0.21-0.25 Hz, close to it) and the lumped
equivalent of the characteristic impedance is ``zeta = sqrt(k_theta J_l) = J_l omega_s``
(0.0504 N m s/rad): in that mode the string torque ``k_theta x1`` and the lower-disk speed
swing with the ratio ``k_theta / omega_s = zeta``, the torque per unit speed of the wave.
"""

from __future__ import annotations

import math

from drill_env.params import RigParams

__all__ = ["characteristic_impedance", "torsional_mode"]


def torsional_mode(params: RigParams) -> float:
    """``sqrt(k_theta / J_l)`` [rad/s]: the string's torsional mode with the upper disk held."""
    return math.sqrt(params.string_stiffness / params.lower_inertia)


def characteristic_impedance(params: RigParams) -> float:
    """``sqrt(k_theta J_l)`` [N m s/rad]: the lumped string's characteristic impedance."""
    return math.sqrt(params.string_stiffness * params.lower_inertia)
