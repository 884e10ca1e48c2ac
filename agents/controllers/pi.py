"""PI control of the upper- or the lower-disk speed with feed-forward and anti-windup.

``u = u_nom + kp e + ki z``, ``e = w* - v``, with ``v`` the encoder speed of the chosen disk
averaged over the last control period (observation ``*_speed_mean``: the count difference
over the period, far less noisy than the filtered 1 kHz estimate), ``w*`` the target
lower-disk speed (at the slip equilibrium both disks turn at w*) and ``u_nom`` the
nominal voltage of the operating point, the feed-forward that holds the nominal rig at
its equilibrium with zero error. ``z`` is the integral of the error [rad].

Anti-windup by back-calculation (Astrom & Hagglund, *Advanced PID Control*, 2006,
Sec. 3.5): when the requested voltage leaves the amplifier's +-5 V range, the integrator
is driven back towards the value at which the request sits at the limit,

    z(k+1) = z(k) + dt e(k) + dt / (ki Tt) (u_sat(k) - u_req(k)),

with the tracking time constant ``Tt`` (default ``max(Ti, dt)``, ``Ti = kp/ki``, their rule
for PI). So the output leaves the limit as soon as the error changes sign instead of
after the wound-up integral has been unwound.

* :class:`UpperSpeedPI`: what a real top drive does (the upper disk is the top drive);
* :class:`LowerSpeedPI`: possible on this rig, whose lower disk (the bit) is instrumented.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drill_env.agents.controllers.base import Controller, ControllerSpec

__all__ = ["SpeedPI", "UpperSpeedPI", "LowerSpeedPI"]


def _gain(name: str, value: Any, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (positive and v == 0):
        rng = "(0, inf)" if positive else "[0, inf)"
        raise ValueError(f"{name}: {value!r} is outside the allowed range {rng}")
    return v


class SpeedPI(Controller):
    """PI control of one disk's speed (see the module docstring).

    Args:
        spec: the environment's :class:`~drill_env.agents.controllers.base.ControllerSpec`.
        kp: proportional gain [V s/rad], >= 0.
        ki: integral gain [V/rad], >= 0.
        disk: ``"upper"`` or ``"lower"``.
        anti_windup: back-calculation on (default) or off (the integrator winds up).
        tracking_time: Tt [s] of the back-calculation, > 0 (default max(kp/ki, dt)).
    """

    state_size = 1  # z, the integral of the speed error [rad]

    def __init__(
        self,
        spec: ControllerSpec,
        kp: float,
        ki: float,
        *,
        disk: str = "upper",
        anti_windup: bool = True,
        tracking_time: float | None = None,
    ):
        super().__init__(spec)
        if disk not in ("upper", "lower"):
            raise ValueError(f"disk: {disk!r} is not one of ['upper', 'lower']")
        self.disk = disk
        self.kp = _gain("kp", kp)
        self.ki = _gain("ki", ki)
        self.anti_windup = bool(anti_windup)
        dt = spec.control_dt
        if tracking_time is None:
            tracking_time = max(self.kp / self.ki, dt) if self.ki > 0 else dt
        self.tracking_time = _gain("tracking_time", tracking_time, positive=True)
        self._i_meas = self._i_upper_mean if disk == "upper" else self._i_lower_mean

    def control(self, y: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dt, vmax = self.spec.control_dt, self.spec.voltage_limit
        z = state[:, 0]
        e = y[:, self._i_target] - y[:, self._i_meas]
        u_req = y[:, self._i_unom] + self.kp * e + self.ki * z
        u = np.clip(u_req, -vmax, vmax)
        z_next = z + dt * e
        if self.anti_windup and self.ki > 0:
            z_next = z_next + dt / (self.ki * self.tracking_time) * (u - u_req)
        return u, z_next[:, None]

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "disk": self.disk,
            "kp": self.kp,
            "ki": self.ki,
            "anti_windup": self.anti_windup,
            "tracking_time": self.tracking_time,
        }


class UpperSpeedPI(SpeedPI):
    """PI control of the upper-disk (top-drive) speed: what a real top drive does."""

    name = "pi_upper"

    def __init__(self, spec: ControllerSpec, kp: float, ki: float, **kwargs: Any):
        super().__init__(spec, kp, ki, disk="upper", **kwargs)


class LowerSpeedPI(SpeedPI):
    """PI control of the lower-disk (bit) speed, measured by the lower encoder."""

    name = "pi_lower"

    def __init__(self, spec: ControllerSpec, kp: float, ki: float, **kwargs: Any):
        super().__init__(spec, kp, ki, disk="lower", **kwargs)
