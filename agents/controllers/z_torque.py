"""Z-Torque-type control: a stiff top-drive speed loop whose set point yields to the string
torque so that the top drive's impedance matches the string's characteristic impedance.

Where it comes from. Dwars (*Recent Advances in Soft Torque Rotary Systems*, SPE/IADC-173037-MS,
2015; Shell's Z-Torque) treats the string as a torsional transmission line (Kyllingstad &
Halsey, SPE Drilling Engineering 3(4), 1988): a wave coming up the string is absorbed
without reflection when the top end is terminated by the pipe's characteristic impedance
``zeta``. Z-Torque therefore keeps the top drive's own (stiff) speed controller and lowers its
set point by the high-pass filtered string torque divided by ``zeta``,

    w_ref = w* - (T - T_slow) / zeta,

so that at the frequencies where the speed loop follows its set point the top drive behaves
as a damper of exactly ``zeta`` (``delta T = -zeta delta w``): impedance matching over a broad
band, not only at one frequency as the tuned speed loop of
:mod:`~drill_env.agents.controllers.soft_torque` does. The mean torque (``T_slow``, the bit's
mean friction) is not fed back, so the mean speed stays at the operator's set point. It is one
of the mitigation baselines of the open field-scale simulator Simulator4nDOF (Aarsnes & Shor)
and of DynaString-type studies.

Adapted to the rig, with the design rules, all on the design model:

* ``zeta = sqrt(k_theta J_l)`` (:mod:`~drill_env.agents.controllers.impedance`; 0.050 N m s/rad);
* the string torque ``T = k_theta twist`` (the encoders' twist), ``T_slow`` its first-order
  low-pass with time constant two torsional periods, ``tau = 4 pi / w_s`` (8.1 s): the
  high-pass keeps the mode (gain 0.99 at ``w_s``) and drops the mean;
* a stiff speed PI on the upper disk ("the drive's speed loop much faster than the string"):
  closed-loop poles of the upper disk (``J_u s^2 + (b_up + P) s + I``) critically damped at
  ``w_c = min(4 w_s, pi / (10 dt))`` -- four times the mode, and no faster than a tenth of the
  control clock's Nyquist frequency -- so ``I = J_u w_c^2`` and ``P = max(2 J_u w_c - b_up, 0)``
  [N m s/rad], in volts divided by ``km``.

``u = u_nom + (P e + I z) / km``, ``e = w_ref - v_u`` (``v_u``: the upper encoder speed over
the last control period), within +-5 V with the back-calculation anti-windup of
:mod:`drill_env.agents.controllers.pi`. ``T_slow`` starts at the design model's equilibrium
torque (the lower friction at the target speed, eq. 20). The structure is that of
:mod:`~drill_env.agents.controllers.torque_feedback`, whose gains are instead tuned by the
benchmark's decay-rate criterion.
"""

from __future__ import annotations

import math
from typing import Any

from drill_env.agents.controllers.base import ControllerSpec
from drill_env.agents.controllers.impedance import characteristic_impedance, torsional_mode
from drill_env.agents.controllers.pi import _gain
from drill_env.agents.controllers.torque_feedback import TorqueFeedback

__all__ = ["ZTorque"]

SPEED_LOOP_FACTOR = 4.0  # w_c / w_s: the stiff speed loop
NYQUIST_FRACTION = 0.1  # w_c at most this fraction of pi / dt
HIGH_PASS_PERIODS = 2.0  # tau of the torque low-pass in torsional periods


class ZTorque(TorqueFeedback):
    """Z-Torque-type impedance matching (see the module docstring): the control law of
    :class:`~drill_env.agents.controllers.torque_feedback.TorqueFeedback` (with its anti-windup
    and tracking time), its gains given as the speed loop's torques and designed by :meth:`design`.

    Args:
        spec: the environment's :class:`~drill_env.agents.controllers.base.ControllerSpec`.
        p_torque: P-term of the speed loop [N m s/rad], >= 0.
        i_torque: I-term of the speed loop [N m/rad], >= 0.
        impedance: the impedance ``zeta`` the top drive presents [N m s/rad], > 0.
        tau_hp: time constant of the torque low-pass [s], > 0.

    :meth:`design` builds it with the published rules on the design model.
    """

    name = "z_torque"

    def __init__(
        self,
        spec: ControllerSpec,
        p_torque: float,
        i_torque: float,
        impedance: float,
        tau_hp: float,
    ):
        self.p_torque = _gain("p_torque", p_torque)
        self.i_torque = _gain("i_torque", i_torque)
        self.impedance = _gain("impedance", impedance, positive=True)
        km = spec.params.motor_constant
        # the speed loop's torques in volts: kp [V s/rad], ki [V/rad]
        super().__init__(
            spec, kp=self.p_torque / km, ki=self.i_torque / km, z_imp=self.impedance, tau_hp=tau_hp
        )

    @classmethod
    def design(cls, spec: ControllerSpec) -> ZTorque:
        """The published tuning on the design model ``spec.params`` (module docstring)."""
        p = spec.params
        w_s = torsional_mode(p)
        w_c = min(SPEED_LOOP_FACTOR * w_s, NYQUIST_FRACTION * math.pi / spec.control_dt)
        return cls(
            spec,
            p_torque=max(2.0 * p.upper_inertia * w_c - p.upper_viscous_pos, 0.0),
            i_torque=p.upper_inertia * w_c * w_c,
            impedance=characteristic_impedance(p),
            tau_hp=HIGH_PASS_PERIODS * 2.0 * math.pi / w_s,
        )

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "p_torque": self.p_torque,
            "i_torque": self.i_torque,
            "impedance": self.impedance,
            "tau_hp": self.tau_hp,
        }
