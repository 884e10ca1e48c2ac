"""SoftTorque-type control: a top-drive speed loop tuned to the string's torsional mode, with
band-pass torque feedback that makes the top drive absorb the mode instead of reflecting it.

Where it comes from. Halsey, Kyllingstad & Kylling (*Torque Feedback Used to Cure Slip-Stick
Motion*, SPE 18049, 1988) fed the measured string torque back to the top drive, so that it
yields to torque fluctuations; Kyllingstad & Halsey (*A Study of Slip/Stick Motion of the
Bit*, SPE Drilling Engineering 3(4), 1988) explained stick-slip as a torsional wave reflected
by a stiff top drive. Kyllingstad & Nessjoen (*A New Stick-Slip Prevention System*, SPE/IADC
119660, 2009) gave the tuning rule that the industrial systems (SoftTorque, SoftSpeed) use:
the top drive's mechanical impedance seen from the string,

    Z_td(i w) = P + b + i (J w - I / w)       (speed PI: P [N m s/rad], I [N m/rad]),

is made a pure damper at the stick-slip frequency ``w_s`` by the I-term ``I = J w_s^2``
(the inertia's reactance cancelled), and the damping is set against the string's
characteristic impedance ``zeta``, the reflection coefficient at the top being
``r = (zeta - Z_td) / (zeta + Z_td)``. The field-scale simulators DynaString (Kyllingstad,
NOV) and Simulator4nDOF (Aarsnes & Shor, open source) ship it as their stick-slip
mitigation baseline.

Adapted to the rig. The "top drive" is the motor and the upper disk (``J = J_u``), whose own
viscous friction ``b = b_up`` (1.97 N m s/rad) is forty times the lumped string's ``zeta``
(0.050 N m s/rad, :mod:`~drill_env.agents.controllers.impedance`): however it is tuned, a
plain speed PI reflects nearly all of the wave (``r ~ -0.95``). The torque feedback closes
that gap. With the string torque ``T = k_theta twist`` (the encoders' twist) through a
band-pass ``H`` centred on ``w_s`` (unit gain, zero phase there) added to the motor torque
with gain ``g``,

    T_m = km u_nom + P e + I z + g H(T),   e = w* - v_u,   z = integral of e,
    Z_td(i w) = (P + b + i (J w - I / w)) / (1 - g H(i w)),

and at ``w_s`` (``I = J w_s^2``, ``H = 1``) ``Z_td = (P + b) / (1 - g)``: matched to ``zeta``
(``r = 0``) by ``g = 1 - (P + b) / zeta``. Away from ``w_s`` the band-pass fades and the PI
holds the mean speed. The design rules, all on the design model:

* ``w_s = sqrt(k_theta / J_l)`` (the stick-slip period of the rig is close to this mode's);
* ``I = J_u w_s^2`` (Kyllingstad & Nessjoen's I-term);
* ``P = zeta`` (their P-term: a damper of the string's impedance on the drive's own account);
* ``g = 1 - (P + b_up) / zeta`` (matched at ``w_s``; negative: the drive yields to torque);
* ``H(s) = 2 xi w_s s / (s^2 + 2 xi w_s s + w_s^2)``, ``xi = 0.5`` (half-power band one
  ``w_s`` wide), discretised by Tustin's rule prewarped at ``w_s``.

The voltage is ``u = T_m / km`` within the amplifier's +-5 V, the PI with the
back-calculation anti-windup of :mod:`drill_env.agents.controllers.pi`; ``v_u`` is the upper
encoder speed over the last control period. The band-pass starts at rest on the string
torque of the design model's equilibrium (the lower friction at the target speed, eq. 20).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drill_env.agents.controllers.base import Controller, ControllerSpec
from drill_env.agents.controllers.impedance import characteristic_impedance, torsional_mode
from drill_env.agents.controllers.pi import _gain
from drill_env.friction import lower_friction_curve

__all__ = ["SoftTorque", "band_pass_coefficients"]

BAND_PASS_DAMPING = 0.5  # xi of the torque band-pass: its half-power band is w_s wide


def band_pass_coefficients(w0: float, xi: float, dt: float) -> tuple[float, float, float]:
    """(b0, a1, a2) of the Tustin discretisation, prewarped at ``w0`` [rad/s], of
    ``2 xi w0 s / (s^2 + 2 xi w0 s + w0^2)`` at period ``dt`` [s]; ``b1 = 0``, ``b2 = -b0``."""
    k = w0 / math.tan(0.5 * w0 * dt)
    a0 = k * k + 2.0 * xi * w0 * k + w0 * w0
    return (
        2.0 * xi * w0 * k / a0,
        (2.0 * w0 * w0 - 2.0 * k * k) / a0,
        (k * k - 2.0 * xi * w0 * k + w0 * w0) / a0,
    )


class SoftTorque(Controller):
    """SoftTorque-type top-drive control (see the module docstring).

    Args:
        spec: the environment's :class:`~drill_env.agents.controllers.base.ControllerSpec`.
        p_torque: P-term of the speed loop [N m s/rad], >= 0.
        i_torque: I-term of the speed loop [N m/rad], >= 0.
        torque_gain: gain ``g`` of the band-passed string torque on the motor torque [-].
        mode: centre ``w_s`` of the band-pass [rad/s], > 0.
        band_pass_damping: ``xi`` of the band-pass, > 0.

    :meth:`design` builds it with the published rules on the design model.
    """

    name = "soft_torque"
    state_size = 3  # z (speed-error integral [rad]), the band-pass's two states [N m]

    def __init__(
        self,
        spec: ControllerSpec,
        p_torque: float,
        i_torque: float,
        torque_gain: float,
        mode: float,
        band_pass_damping: float = BAND_PASS_DAMPING,
    ):
        super().__init__(spec)
        self.p_torque = _gain("p_torque", p_torque)
        self.i_torque = _gain("i_torque", i_torque)
        if isinstance(torque_gain, bool) or not math.isfinite(float(torque_gain)):
            raise ValueError(f"torque_gain: expected a finite number, got {torque_gain!r}")
        self.torque_gain = float(torque_gain)
        self.mode = _gain("mode", mode, positive=True)
        self.band_pass_damping = _gain("band_pass_damping", band_pass_damping, positive=True)
        dt = spec.control_dt
        if self.mode * dt >= math.pi:
            raise ValueError(
                f"mode: {mode!r} rad/s is beyond the Nyquist frequency of the control period ({math.pi / dt:.4g} rad/s)"
            )
        self._b0, self._a1, self._a2 = band_pass_coefficients(self.mode, self.band_pass_damping, dt)
        km = spec.params.motor_constant
        self._kp, self._ki = self.p_torque / km, self.i_torque / km  # [V s/rad], [V/rad]
        self._kt = self.torque_gain / km  # [V / N m]
        self._k = spec.params.string_stiffness
        self.tracking_time = max(self._kp / self._ki, dt) if self._ki > 0 else dt

    @classmethod
    def design(cls, spec: ControllerSpec) -> SoftTorque:
        """The published tuning on the design model ``spec.params`` (module docstring)."""
        p = spec.params
        w_s = torsional_mode(p)
        zeta = characteristic_impedance(p)
        p_torque = zeta
        return cls(
            spec,
            p_torque=p_torque,
            i_torque=p.upper_inertia * w_s * w_s,
            torque_gain=1.0 - (p_torque + p.upper_viscous_pos) / zeta,
            mode=w_s,
        )

    def initial_state(self, y: np.ndarray) -> np.ndarray:
        s = np.zeros((y.shape[0], self.state_size))
        w = np.maximum(y[:, self._i_target], 0.0)
        t0 = np.asarray(lower_friction_curve(self.spec.params, w), dtype=float)
        s[:, 1] = s[:, 2] = -self._b0 * t0  # the band-pass at rest on a constant torque t0
        return s

    def control(self, y: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dt, vmax = self.spec.control_dt, self.spec.voltage_limit
        z, s1, s2 = state[:, 0], state[:, 1], state[:, 2]
        torque = self._k * y[:, self._i_twist]
        t_bp = self._b0 * torque + s1  # transposed direct form II, b1 = 0, b2 = -b0
        s1_next = -self._a1 * t_bp + s2
        s2_next = -self._b0 * torque - self._a2 * t_bp
        e = y[:, self._i_target] - y[:, self._i_upper_mean]
        u_req = y[:, self._i_unom] + self._kp * e + self._ki * z + self._kt * t_bp
        u = np.clip(u_req, -vmax, vmax)
        z_next = z + dt * e
        if self._ki > 0:
            z_next = z_next + dt / (self._ki * self.tracking_time) * (u - u_req)
        return u, np.stack([z_next, s1_next, s2_next], axis=1)

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "p_torque": self.p_torque,
            "i_torque": self.i_torque,
            "torque_gain": self.torque_gain,
            "mode": self.mode,
            "band_pass_damping": self.band_pass_damping,
        }
