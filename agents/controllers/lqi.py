"""Gain-scheduled LQI: linear-quadratic state feedback with integral action on the measured
twist and speeds.

The rig's full state (x1, x2, x3) is measured: the twist by the two encoders, the speeds
by the filtered encoder differences (observations ``twist``, ``upper_speed``,
``lower_speed``). At each episode's target speed w* the nominal model is linearised about
its slip equilibrium (:mod:`drill_env.agents.controllers.linear_model`), sampled with a zero-order hold at the
control period, and extended by the integral of the lower-disk speed error
``zeta(k+1) = zeta(k) + dt (v_l - w*)`` (``v_l``: the lower encoder speed over the period,
so zeta is exactly the lag of the lower disk's angle behind w* t). The discrete LQR gain
(Riccati equation) of that model gives

    u = u_nom - K [x1 - x1*, x2 - w*, x3 - w*, zeta],

scheduled on w* (recomputed per operating point, cached): the negative friction slope
that destabilises the equilibrium is in the design model at every point. This is the
discrete LQ regulator with integral action (e.g. Franklin, Powell & Workman, *Digital
Control of Dynamic Systems*, 3rd ed., 1998), the observer-free case of the state feedback
designs for stick-slip in the literature, since this rig measures its whole state.

Weights by Bryson's rule (Bryson & Ho, *Applied Optimal Control*, 1975): each term is
divided by the square of its largest acceptable value,

* speeds: ``w_s = max(speed_rel * w*, speed_min)``;
* twist: ``w_s / omega_l`` with ``omega_l = sqrt(k_theta / J_l)``, the twist a lower-disk
  speed swing of w_s makes at the torsional frequency;
* integral: ``w_s * integral_time``;
* voltage: ``voltage_scale`` [V], the one weight tuned by :mod:`drill_env.agents.controllers.tuning`.

Anti-windup: back-calculation on zeta with tracking time ``Tt = max(K_x3 / K_zeta, dt)``,
as in :mod:`drill_env.agents.controllers.pi`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from drill_env.agents.controllers.base import Controller, ControllerSpec
from drill_env.agents.controllers.linear_model import design_point, linearise
from drill_env.agents.controllers.pi import _gain
from drill_env.params import RigParams

__all__ = ["LQI", "lqi_gain"]


def lqi_gain(
    params: RigParams,
    speed: float,
    dt: float,
    *,
    voltage_scale: float = 1.0,
    speed_rel: float = 0.1,
    speed_min: float = 0.05,
    integral_time: float = 4.0,
) -> tuple[np.ndarray, float]:
    """(K, x1*) of the discrete LQI at the slip equilibrium turning at ``speed`` [rad/s].

    K acts on (x1 - x1*, x2 - w, x3 - w, zeta) [V/rad, V s/rad, V s/rad, V/rad].
    """
    eq = design_point(params, speed=speed)
    A, B = linearise(params, eq)
    M = np.zeros((4, 4))
    M[:3, :3] = A
    M[:3, 3] = B[:, 0]
    E = expm(M * dt)
    Ad = np.zeros((4, 4))
    Ad[:3, :3] = E[:3, :3]
    Ad[3, 2] = dt
    Ad[3, 3] = 1.0
    Bd = np.zeros((4, 1))
    Bd[:3, 0] = E[:3, 3]
    w_s = max(speed_rel * eq.x3, speed_min)
    omega_l = math.sqrt(params.string_stiffness / params.lower_inertia)
    scales = np.array([w_s / omega_l, w_s, w_s, w_s * integral_time])
    Q = np.diag(1.0 / scales**2)
    R = np.array([[1.0 / voltage_scale**2]])
    P = solve_discrete_are(Ad, Bd, Q, R)
    K = np.linalg.solve(R + Bd.T @ P @ Bd, Bd.T @ P @ Ad).ravel()
    return K, float(eq.x1)


class LQI(Controller):
    """Gain-scheduled discrete LQI (see the module docstring).

    Args:
        spec: the environment's :class:`~drill_env.agents.controllers.base.ControllerSpec`.
        voltage_scale: Bryson scale of the voltage [V], > 0 (larger: more aggressive).
        speed_rel, speed_min: Bryson scale of the speeds, ``max(speed_rel w*, speed_min)``.
        integral_time: Bryson scale of the integral, in seconds of the speed scale, > 0.
        anti_windup: back-calculation on (default) or off.
    """

    name = "lqi"
    state_size = 6  # zeta [rad], then the scheduled x1* [rad] and K (4), constant per episode
    n_dynamic_states = 1

    def __init__(
        self,
        spec: ControllerSpec,
        voltage_scale: float = 1.0,
        speed_rel: float = 0.1,
        speed_min: float = 0.05,
        integral_time: float = 4.0,
        *,
        anti_windup: bool = True,
    ):
        super().__init__(spec)
        self.voltage_scale = _gain("voltage_scale", voltage_scale, positive=True)
        self.speed_rel = _gain("speed_rel", speed_rel, positive=True)
        self.speed_min = _gain("speed_min", speed_min, positive=True)
        self.integral_time = _gain("integral_time", integral_time, positive=True)
        self.anti_windup = bool(anti_windup)
        self._cache: dict[float, tuple[np.ndarray, float]] = {}

    def gain(self, speed: float) -> tuple[np.ndarray, float]:
        """(K, x1*) at a target speed [rad/s] (cached)."""
        w = float(speed)
        if not (math.isfinite(w) and w > 0):
            raise ValueError(
                f"target_speed: the LQI needs a slip equilibrium, speed > 0 rad/s; got {speed!r}"
            )
        if w not in self._cache:
            self._cache[w] = lqi_gain(
                self.spec.params,
                w,
                self.spec.control_dt,
                voltage_scale=self.voltage_scale,
                speed_rel=self.speed_rel,
                speed_min=self.speed_min,
                integral_time=self.integral_time,
            )
        return self._cache[w]

    def initial_state(self, y: np.ndarray) -> np.ndarray:
        s = np.zeros((y.shape[0], self.state_size))
        for i, w in enumerate(y[:, self._i_target]):
            K, x1 = self.gain(w)
            s[i, 1] = x1
            s[i, 2:6] = K
        return s

    def control(self, y: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u, out, _ = self._step(y, state, 0.0)
        return u, out

    def _step(
        self, y: np.ndarray, state: np.ndarray, u_add: np.ndarray | float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, next state, requested u) with ``u_add`` [V] added to the LQI's request before the
        voltage limit (the anti-windup sees the sum). ``state`` holds the LQI's entries first."""
        dt, vmax = self.spec.control_dt, self.spec.voltage_limit
        zeta, x1s, K = state[:, 0], state[:, 1], state[:, 2:6]
        w = y[:, self._i_target]
        dx = np.stack(
            [y[:, self._i_twist] - x1s, y[:, self._i_upper] - w, y[:, self._i_lower] - w, zeta], axis=1
        )
        u_req = y[:, self._i_unom] - np.einsum("ij,ij->i", K, dx) + u_add
        u = np.clip(u_req, -vmax, vmax)
        zeta_next = zeta + dt * (y[:, self._i_lower_mean] - w)
        if self.anti_windup:
            kz = K[:, 3]
            tt = np.maximum(np.abs(K[:, 2]) / np.maximum(kz, 1e-12), dt)
            zeta_next = zeta_next + np.where(kz > 0, dt / (np.maximum(kz, 1e-12) * tt), 0.0) * (u_req - u)
        out = state.copy()
        out[:, 0] = zeta_next
        return u, out, u_req

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "voltage_scale": self.voltage_scale,
            "speed_rel": self.speed_rel,
            "speed_min": self.speed_min,
            "integral_time": self.integral_time,
            "anti_windup": self.anti_windup,
        }
