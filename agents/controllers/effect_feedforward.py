"""Feedforward of an identified position-dependent friction: what a design on a corrected
model does with the effect the discrepancy workflow named.

The problem
-----------
A friction that varies with where a disk is in its revolution
(:class:`~drill_env.params.ModelEffects` ``lower_position_amp_1`` ... ``upper_position_phase_2``)
is no parameter of a linear model: retuning the LQI on a model that has it changes nothing (the
linearisation drops it). But once the workflow has identified it, its torque is a known
function of the measured angle. On the lower disk, turning forward at w*::

    dT_l(theta_l) = (T_sl + S(w*)) sum_h a_h cos(h theta_l + phi_h)        h = 1, 2

(S the Stribeck hump; the static and Stribeck part is what the effect modulates), and on the
upper disk ``dT_u(theta_u) = T_sup sum_h a_h cos(h theta_u + phi_h)``.

The design
----------
The controller adds to its voltage a feedforward in harmonics of the *measured* angles (the
encoder counts, ``lower_angle_sin``/``cos`` and ``upper_angle_sin``/``cos`` of observation
version 1; absolute within the revolution, as the workflow's phases are)::

    u_ff = sum_h Re(C_h^l exp(j h theta_l)) + sum_h Re(C_h^u exp(j h theta_u))
    C_h = - H_h D_h / G_h

with ``D_h = -level a_h exp(j phi_h)`` the phasor of the friction's modulation as a torque in
the direction of motion, ``G_h`` the closed-loop (rig + the controller's feedback) response
from a voltage added to the feedback's output to the measured lower speed, and ``H_h`` the
response from the (continuous, not held) torque on that disk to the same output, both at
``h w*`` on the design model linearised at the slip equilibrium of w* and sampled with its
zero-order hold and encoder chain (:func:`drill_env.agents.controllers.linear_model.sampled_rig`,
:func:`~drill_env.agents.controllers.linear_model.sampled_sinusoid_input`). In steady rotation
the lower speed's harmonic is ``G_h C_h + H_h D_h = 0``: the feedforward pushes through the
string, with the string's phase at the rotation frequency, the torque that cancels the
friction's at the speed the controller regulates. Nothing is adapted: the design is the
identified effect's, and it is as good as the identification (the worked example: amplitude
and phase within 0.1 % and 0.002 rad of the truth).

Stability
---------
The feedforward is a bounded function of the measured angle, ``|u_ff| <= sum |C_h|``, added
after the feedback: it is not part of the feedback's linear loop, whose poles stay the LQI's
(:mod:`drill_env.agents.controllers.tuning`). What couples it back is the angle: theta_l is the
integral of x3, so a speed deviation shifts the feedforward's phase (a gain
``d u_ff / d theta`` on the angle's deviation), and the friction itself varies with the angle
and, through its Stribeck part, with the speed, periodically over the revolution. The
linearisation about the cancelled rotation (x at the equilibrium of w*, theta = w* t) is
therefore a *periodic* linear system: the sampled loop of the design model and the LQI, with
the angle's deviation as one more state, the feedforward's ``d u_ff / d theta`` and the
friction's ``d dT / d theta`` and ``dT / d x3`` at each control period's phase. Its stability
is that of its monodromy matrix, the product of the per-period transitions over one
revolution (Floquet): :func:`orbit_decay_rate` returns ``-ln(rho) / T`` with rho its spectral
radius and T the revolution's time, > 0 iff the rotation is locally stable. One multiplier is
always 1 and is left out: the system is autonomous (nothing depends on time), so a shift of
the rotation's phase, the angle and the LQI's integral of the speed error moving together, is
neither corrected nor amplified.
On the worked example's corrected model (lower position friction a1 = 0.12, a2 = 0.016) it is
0.04-0.17 1/s at 0.3-3 V, within 0.01 1/s of the LQI's on the model without the effect
(``tests/test_effect_feedforward.py``, which also simulates the LQI with the feedforward on the
corrected model itself from the open-loop cycle: it settles and stays).
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from drill_env.agents.controllers.base import ControllerSpec
from drill_env.agents.controllers.linear_model import design_point, sampled_rig, sampled_sinusoid_input
from drill_env.agents.controllers.lqi import LQI
from drill_env.params import ModelEffects, RigParams

__all__ = [
    "EffectFeedforward",
    "EffectFeedforwardDesign",
    "LQIEffectFeedforward",
    "design",
    "has_position_effect",
    "orbit_decay_rate",
    "position_torque",
]

HARMONICS = (1, 2)
DISKS = ("lower", "upper")


def has_position_effect(effects: ModelEffects | None) -> bool:
    """Whether ``effects`` name a position-dependent friction on either disk."""
    if effects is None:
        return False
    return any(getattr(effects, f"{d}_position_amp_{h}") != 0.0 for d in DISKS for h in HARMONICS)


def position_torque(params: RigParams, effects: ModelEffects, speed: float, disk: str) -> np.ndarray:
    """D_h [N m] per harmonic: the phasor (against exp(j h theta) of the disk's angle) of the
    friction modulation of ``effects`` on ``disk`` as a torque in the direction of motion, at
    steady forward rotation at ``speed`` [rad/s] of ``params``."""
    from drill_env.friction import hump_law

    if disk == "lower":
        level = params.lower_static + float(
            hump_law(
                params.lower_hump_1,
                params.lower_hump_rate_1,
                params.lower_hump_2,
                params.lower_hump_rate_2,
                speed,
            )
        )
    elif disk == "upper":
        level = params.upper_static_pos
    else:
        raise ValueError(f"disk: {disk!r} is not one of {list(DISKS)}")
    return np.array(
        [
            -level
            * getattr(effects, f"{disk}_position_amp_{h}")
            * cmath.exp(1j * getattr(effects, f"{disk}_position_phase_{h}"))
            for h in HARMONICS
        ]
    )


@dataclass(frozen=True)
class EffectFeedforwardDesign:
    """The feedforward at one target speed (see :func:`design`)."""

    speed: float  # [rad/s]
    lower: np.ndarray  # C_h [V] (complex) per harmonic of the lower angle
    upper: np.ndarray  # C_h [V] (complex) per harmonic of the upper angle
    response: np.ndarray  # G_h [rad/s per V] per harmonic

    @property
    def amplitude(self) -> float:
        """The largest |u_ff| [V]: sum of |C_h|."""
        return float(np.sum(np.abs(self.lower)) + np.sum(np.abs(self.upper)))


def design(params: RigParams, effects: ModelEffects, speed: float, feedback) -> EffectFeedforwardDesign:
    """C_h of both disks at target ``speed`` [rad/s] on the design model ``params`` (its linear
    part) with ``effects`` (module docstring); ``feedback`` the LQI that closes the loop."""
    from drill_env.agents.controllers.lqi_loop import _loop, _response

    dt = feedback.spec.control_dt
    rig = sampled_rig(params, design_point(params, speed=speed), dt, feedback.spec.sensors)
    A, b, c, _ = _loop(rig, feedback)
    nc = A.shape[0] - rig.n
    out: dict[str, np.ndarray] = {}
    G = np.array([_response(A, b, c, h * rig.speed, dt) for h in HARMONICS])
    for disk in DISKS:
        D = position_torque(params, effects, rig.speed, disk)
        C = np.zeros(len(HARMONICS), dtype=complex)
        for i, h in enumerate(HARMONICS):
            if D[i] == 0:
                continue
            omega = h * rig.speed
            bd = np.concatenate(
                [sampled_sinusoid_input(params, rig.eq, dt, feedback.spec.sensors, disk, omega), np.zeros(nc)]
            )
            z = cmath.exp(1j * omega * dt)
            H = complex(c @ np.linalg.solve(z * np.eye(A.shape[0]) - A, bd))
            C[i] = -H * D[i] / G[i]
        out[disk] = C
    return EffectFeedforwardDesign(speed=float(rig.speed), lower=out["lower"], upper=out["upper"], response=G)


def _level(params: RigParams, speed: float, disk: str) -> tuple[float, float]:
    """(the friction level the effect modulates [N m], its slope in the disk's speed [N m s/rad])."""
    from drill_env.friction import hump_law, hump_slope_law

    if disk == "upper":
        return params.upper_static_pos, 0.0
    args = (
        params.lower_hump_1,
        params.lower_hump_rate_1,
        params.lower_hump_2,
        params.lower_hump_rate_2,
        speed,
    )
    return params.lower_static + float(hump_law(*args)), float(hump_slope_law(*args))


def orbit_decay_rate(
    params: RigParams,
    effects: ModelEffects,
    speed: float,
    feedback,
    feedforward: EffectFeedforwardDesign | None,
) -> float:
    """The decay rate [1/s] of the rotation at ``speed`` [rad/s] on the design model ``params``
    with ``effects``, closed by ``feedback`` (an LQI) plus ``feedforward`` (None: without):
    ``-ln(rho) / T`` of the monodromy matrix of the periodic linearisation over one revolution
    (module docstring). > 0: locally stable."""
    from drill_env.agents.controllers.lqi_loop import _loop

    dt = feedback.spec.control_dt
    sensors = feedback.spec.sensors
    rig = sampled_rig(params, design_point(params, speed=speed), dt, sensors)
    A, b, c, _ = _loop(rig, feedback)
    n = A.shape[0]
    w = rig.speed
    cols = {
        d: np.concatenate(
            [sampled_sinusoid_input(params, rig.eq, dt, sensors, d, 0.0).real, np.zeros(n - rig.n)]
        )
        for d in DISKS
    }
    steps = max(1, int(round(2.0 * math.pi / (w * dt))))
    h = np.asarray(HARMONICS)
    mono = np.eye(n + 1)
    for k in range(steps):
        theta = w * k * dt
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = A
        # the angle's deviation (last state) and the twist's (state 0) shift each disk's phase
        for disk in DISKS:
            amp = np.array([getattr(effects, f"{disk}_position_amp_{q}") for q in HARMONICS])
            phi = np.array([getattr(effects, f"{disk}_position_phase_{q}") for q in HARMONICS])
            if not amp.any():
                continue
            level, slope = _level(params, w, disk)
            # dT/dtheta of the friction, as a torque in the direction of motion: -d(level s)/dtheta
            d_theta = level * float(np.sum(h * amp * np.sin(h * theta + phi)))
            gain_theta = d_theta * cols[disk]
            if feedforward is not None:
                C = feedforward.lower if disk == "lower" else feedforward.upper
                # d u_ff / d theta = -sum h Im(C_h exp(j h theta))
                du = -float(np.sum(h * (C * np.exp(1j * h * theta)).imag))
                gain_theta = gain_theta + du * b
            M[:n, n] += gain_theta
            if disk == "upper":
                M[:n, 0] += gain_theta  # theta_u = theta_l + twist
            else:
                # the modulated Stribeck part's slope: -s(theta) dS/dw on the lower speed
                mod = float(np.sum(amp * np.cos(h * theta + phi)))
                M[:n, 2] += -mod * slope * cols[disk]
        # theta_{k+1} = theta_k + dt (the lower speed's mean over the period, at k+1)
        M[n, :] = dt * np.concatenate([c, [0.0]]) @ M
        M[n, n] += 1.0
        mono = M @ mono
    # the rotation's phase is free (the system is autonomous: the LQI's integral and the angle
    # move together by a constant), one multiplier is 1; the others decide
    eig = np.linalg.eigvals(mono)
    eig = np.delete(eig, int(np.argmin(np.abs(eig - 1.0))))
    rho = float(np.max(np.abs(eig)))
    return -math.log(max(rho, 1e-300)) / (steps * dt)


def angles(spec, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(theta_l, theta_u) [rad] (n,) from observations ``y`` (SI) of observation version 1."""
    il, cl = spec.index("lower_angle_sin"), spec.index("lower_angle_cos")
    iu, cu = spec.index("upper_angle_sin"), spec.index("upper_angle_cos")
    return np.arctan2(y[:, il], y[:, cl]), np.arctan2(y[:, iu], y[:, cu])


def voltage(d: EffectFeedforwardDesign, theta_l: np.ndarray, theta_u: np.ndarray) -> np.ndarray:
    """u_ff [V] at the measured angles."""
    h = np.asarray(HARMONICS)
    return np.sum((d.lower[None, :] * np.exp(1j * np.outer(theta_l, h))).real, axis=1) + np.sum(
        (d.upper[None, :] * np.exp(1j * np.outer(theta_u, h))).real, axis=1
    )


ANGLES = ("lower_angle_sin", "lower_angle_cos", "upper_angle_sin", "upper_angle_cos")


class EffectFeedforward:
    """The feedforward of the position friction that ``spec.effects`` (the design model's) names,
    for ``feedback`` (the LQI it is added to): designed per target speed (cached),
    :meth:`voltage` at the measured angles."""

    def __init__(self, spec: ControllerSpec, feedback: LQI):
        if not has_position_effect(spec.effects):
            raise ValueError("spec: the design model names no position-dependent friction to feed forward")
        if not set(ANGLES) <= set(spec.observation_names):
            raise ValueError(
                "spec: the design model names a position-dependent friction, whose feedforward needs the "
                f"encoder angles (observation version 1); got observation entries {list(spec.observation_names)}"
            )
        self.spec, self.feedback = spec, feedback
        self._designs: dict[float, EffectFeedforwardDesign] = {}
        self._i_target = spec.index("target_speed")

    def design(self, speed: float) -> EffectFeedforwardDesign:
        w = float(speed)
        if w not in self._designs:
            self.feedback.gain(w)  # validates the speed
            self._designs[w] = design(self.spec.params, self.spec.effects, w, self.feedback)
        return self._designs[w]

    def voltage(self, y: np.ndarray) -> np.ndarray:
        """u_ff [V] (n,) at observations ``y`` (SI)."""
        theta_l, theta_u = angles(self.spec, y)
        out = np.zeros(y.shape[0])
        w = y[:, self._i_target]
        for target in np.unique(w):
            rows = w == target
            out[rows] = voltage(self.design(target), theta_l[rows], theta_u[rows])
        return out

    def decay_rate(self, speed: float) -> float:
        """:func:`orbit_decay_rate` of the design at target ``speed`` [rad/s]."""
        return orbit_decay_rate(
            self.spec.params, self.spec.effects, float(speed), self.feedback, self.design(speed)
        )


class LQIEffectFeedforward(LQI):
    """The tuned LQI plus the feedforward of the position friction its design model names
    (module docstring): what ``lqi`` is when designed on a model with such an effect
    (:func:`drill_env.agents.controllers.gains.classical_controller`)."""

    name = "lqi"

    def __init__(self, spec: ControllerSpec, **lqi_gains):
        super().__init__(spec, **lqi_gains)
        self.effect = EffectFeedforward(spec, LQI(spec, **lqi_gains))

    def control(self, y: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u, out, _ = self._step(y, state, self.effect.voltage(y))
        return u, out

    def describe(self) -> dict:
        return {**super().describe(), "effect_feedforward": list(self.spec.effects.active)}
