"""Torque feedback: a top drive that yields to the string torque (SoftTorque / Z-Torque style).

A stiff top-drive speed loop reflects the torsional wave that comes up the string back
down to the bit, and the negative friction slope at the bit feeds it: stick-slip. Torque
feedback makes the top drive give way to torque fluctuations, so that it absorbs the
wave instead (Halsey, Kyllingstad & Kylling, *Torque Feedback Used to Cure Slip-Stick
Motion*, SPE 18049, 1988). SoftTorque (Kyllingstad & Nessjoen, *A New Stick-Slip
Prevention System*, SPE/IADC 119660, 2009) lowers the speed set point of the top drive's
own PI speed controller by the high-pass filtered string torque; Z-Torque (Dwars,
*Recent Advances in Soft Torque Rotary Systems*, SPE/IADC-173037-MS, 2015) tunes that
feedback so that the top drive's mechanical impedance matches the string's
characteristic impedance and the wave is not reflected.

On this rig the string torque is measured by the two encoders as ``k_theta (theta_u -
theta_l)`` (observation ``twist``), so the controller is::

    T      = k_theta * twist                       string torque [N m]
    T_slow = low-pass of T, time constant tau_hp    (T - T_slow is the high-pass part)
    w_ref  = w* - (T - T_slow) / z_imp             speed set point of the top drive
    u      = u_nom + kp e + ki z,  e = w_ref - v_u  (v_u: upper encoder speed over the period)

with ``z_imp`` [N m s/rad] the impedance the top drive presents to the string (Z-Torque's
tuning target; for this lumped string sqrt(k_theta J_l) = 0.050 N m s/rad), and the PI's
back-calculation anti-windup of :mod:`drill_env.agents.controllers.pi`. ``T_slow`` starts at the string torque
of the nominal equilibrium, which equals the lower-disk friction at the target speed
(eq. 20). The gains are tuned by :mod:`drill_env.agents.controllers.tuning`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drill_env.agents.controllers.base import Controller, ControllerSpec
from drill_env.agents.controllers.pi import _gain
from drill_env.friction import lower_friction_curve

__all__ = ["TorqueFeedback"]


class TorqueFeedback(Controller):
    """SoftTorque / Z-Torque-style torque feedback around an upper-speed PI.

    Args:
        spec: the environment's :class:`~drill_env.agents.controllers.base.ControllerSpec`.
        kp: proportional gain of the top-drive speed PI [V s/rad], >= 0.
        ki: integral gain of the speed PI [V/rad], >= 0.
        z_imp: impedance of the top drive seen by the string [N m s/rad], > 0.
        tau_hp: time constant of the torque low-pass whose complement is the high-pass [s], > 0.
        anti_windup, tracking_time: as for :class:`~drill_env.agents.controllers.pi.SpeedPI`.
    """

    name = "torque_feedback"
    state_size = 2  # z (speed-error integral [rad]), T_slow (low-passed string torque [N m])

    def __init__(
        self,
        spec: ControllerSpec,
        kp: float,
        ki: float,
        z_imp: float,
        tau_hp: float = 10.0,
        *,
        anti_windup: bool = True,
        tracking_time: float | None = None,
    ):
        super().__init__(spec)
        self.kp = _gain("kp", kp)
        self.ki = _gain("ki", ki)
        self.z_imp = _gain("z_imp", z_imp, positive=True)
        self.tau_hp = _gain("tau_hp", tau_hp, positive=True)
        self.anti_windup = bool(anti_windup)
        dt = spec.control_dt
        if tracking_time is None:
            tracking_time = max(self.kp / self.ki, dt) if self.ki > 0 else dt
        self.tracking_time = _gain("tracking_time", tracking_time, positive=True)
        self._a = 1.0 - math.exp(-dt / self.tau_hp)  # exact discrete first-order low-pass
        self._k = spec.params.string_stiffness

    def initial_state(self, y: np.ndarray) -> np.ndarray:
        s = np.zeros((y.shape[0], self.state_size))
        w = np.maximum(y[:, self._i_target], 0.0)
        s[:, 1] = np.asarray(lower_friction_curve(self.spec.params, w), dtype=float)
        return s

    def control(self, y: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dt, vmax = self.spec.control_dt, self.spec.voltage_limit
        z, t_slow = state[:, 0], state[:, 1]
        torque = self._k * y[:, self._i_twist]
        w_ref = y[:, self._i_target] - (torque - t_slow) / self.z_imp
        e = w_ref - y[:, self._i_upper_mean]
        u_req = y[:, self._i_unom] + self.kp * e + self.ki * z
        u = np.clip(u_req, -vmax, vmax)
        z_next = z + dt * e
        if self.anti_windup and self.ki > 0:
            z_next = z_next + dt / (self.ki * self.tracking_time) * (u - u_req)
        t_next = t_slow + self._a * (torque - t_slow)
        return u, np.stack([z_next, t_next], axis=1)

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kp": self.kp,
            "ki": self.ki,
            "z_imp": self.z_imp,
            "tau_hp": self.tau_hp,
            "anti_windup": self.anti_windup,
            "tracking_time": self.tracking_time,
        }
