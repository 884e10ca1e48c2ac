"""Gain tuning on the nominal linearised rig: one documented, reproducible procedure.

Every classical controller here is tuned the same way, never by hand for the test grid:

1. *Design set.* The slip equilibria of the nominal rig at the design voltages
   (default: 12 voltages from just above the start of motion A to the rig's 5 V limit,
   log-spaced in speed) — the whole operating envelope, including the points where the
   friction slope d_l is most negative (the Hopf region and beyond).
2. *Closed loop.* For each design point the controller and the linearisation of
   :mod:`agents.linear_model` form a linear closed loop (integrator and filter states
   included).
3. *Criterion.* Maximise the worst-case decay rate ``alpha = min over design points
   of (-max Re lambda)`` of the closed loop, subject to a gain bound that keeps the
   voltage noise caused by the speed-estimate noise small (``max_gain`` [V s/rad]).
4. *Search.* A coarse log-grid over the gains followed by Nelder–Mead from the best
   grid point; deterministic.

The linear criterion cannot see stick-slip (a nonsmooth, large-amplitude cycle); the
benchmark measures that. It does decide whether the torsional mode is damped at every
operating point, which is what removes the Hopf cycle and, with enough margin, keeps
the orbit away from the stick boundary.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_continuous_are
from scipy.optimize import minimize

from agents.linear_model import OperatingPoint, linearise, operating_point
from drill_env.params import RigParams

__all__ = [
    "TunedGains",
    "design_points",
    "closed_loop",
    "tune",
    "lqi_gain",
    "worst_decay_rate",
]

VOLTAGE_LIMIT = 5.0  # [V] the rig's amplifier range


@dataclass(frozen=True)
class TunedGains:
    kind: str
    gains: dict[str, float]
    worst_decay_rate: float  # [1/s] min over design points of -max Re(lambda)
    design_voltages: tuple[float, ...]


def design_points(params: RigParams, n: int = 12, u_max: float = VOLTAGE_LIMIT) -> list[OperatingPoint]:
    """Slip equilibria spanning the envelope from just above point A to ``u_max``."""
    lo = operating_point(params, voltage=params.uc1 * 1.05 + 1e-3).speed
    hi = operating_point(params, voltage=u_max).speed
    return [operating_point(params, speed=w) for w in np.geomspace(lo, hi, n)]


def closed_loop(kind: str, gains: dict[str, float], params: RigParams, op: OperatingPoint) -> np.ndarray:
    """State matrix of the linear closed loop of controller ``kind`` about ``op``.

    States: (x1, x2, x3) deviations, then the controller's own states.

    * ``pi_upper``: u = u0 + kp (w - x2) + ki z,  z' = w - x2
    * ``pi_lower``: u = u0 + kp (w - x3) + ki z,  z' = w - x3
    * ``torque_feedback``: upper-speed PI tracking w_ref = w - (T - T_slow)/z_imp with the
      string torque T = k_theta x1 measured by the encoders and T_slow its low-pass
      (time constant tau_hp) — the top drive yields to torque fluctuations (SoftTorque).
    """
    A, B = linearise(params, op)
    b = B[:, 0]
    if kind in ("pi_upper", "pi_lower"):
        c = np.array([0.0, 1.0, 0.0]) if kind == "pi_upper" else np.array([0.0, 0.0, 1.0])
        kp, ki = gains["kp"], gains["ki"]
        M = np.zeros((4, 4))
        M[:3, :3] = A - kp * np.outer(b, c)
        M[:3, 3] = ki * b
        M[3, :3] = -c
        return M
    if kind == "torque_feedback":
        kp, ki, z_imp, tau = gains["kp"], gains["ki"], gains["z_imp"], gains["tau_hp"]
        k = params.string_stiffness
        # states: x1, x2, x3, z (PI integrator), s (slow torque estimate)
        # w_ref - w = -(k x1 - s)/z_imp ; e = w_ref - x2
        e_row = np.array([-k / z_imp, -1.0, 0.0, 0.0, 1.0 / z_imp])
        M = np.zeros((5, 5))
        M[:3, :3] = A
        M[:3, :] += np.outer(b, kp * e_row)
        M[:3, 3] += ki * b
        M[3, :] = e_row
        M[4, 0] = k / tau
        M[4, 4] = -1.0 / tau
        return M
    raise ValueError(f"kind: unknown controller {kind!r}; allowed: pi_upper, pi_lower, torque_feedback")


def worst_decay_rate(kind: str, gains: dict[str, float], params: RigParams, points: list[OperatingPoint]) -> float:
    return float(min(-np.max(np.linalg.eigvals(closed_loop(kind, gains, params, op)).real) for op in points))


_SEARCH = {
    # name: (grid, log-bounds) of each tuned gain
    "pi_upper": {"kp": (0.05, 20.0), "ki": (0.01, 20.0)},
    "pi_lower": {"kp": (0.05, 20.0), "ki": (0.01, 20.0)},
    "torque_feedback": {"kp": (0.05, 20.0), "ki": (0.01, 20.0), "z_imp": (0.01, 10.0)},
}


def tune(
    kind: str,
    params: RigParams,
    *,
    max_gain: float = 5.0,
    points: list[OperatingPoint] | None = None,
    fixed: dict[str, float] | None = None,
    grid: int = 7,
) -> TunedGains:
    """Tune ``kind`` by the procedure in the module docstring.

    ``max_gain`` bounds the proportional gain [V s/rad]: with the speed estimates'
    noise (a few 1e-3 rad/s after the 200 rad/s filter) it keeps the noise-induced
    voltage well below 0.1 V.
    """
    if kind not in _SEARCH:
        raise ValueError(f"kind: unknown controller {kind!r}; allowed: {sorted(_SEARCH)}")
    if not np.isfinite(max_gain) or max_gain <= 0:
        raise ValueError(f"max_gain: must be finite and > 0, got {max_gain!r}")
    pts = points or design_points(params)
    fixed = dict(fixed or {})
    if kind == "torque_feedback":
        fixed.setdefault("tau_hp", 10.0)  # [s] well above the torsional period (~4 s)
    names = [n for n in _SEARCH[kind] if n not in fixed]
    bounds = {n: (np.log(lo), np.log(min(hi, max_gain) if n == "kp" else hi)) for n, (lo, hi) in _SEARCH[kind].items()}

    def objective(logg: np.ndarray) -> float:
        g = dict(fixed)
        for n, v in zip(names, logg):
            lo, hi = bounds[n]
            if not lo <= v <= hi:
                return 1e6
            g[n] = float(np.exp(v))
        return -worst_decay_rate(kind, g, params, pts)

    axes = [np.linspace(*bounds[n], grid) for n in names]
    mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(names))
    scores = np.array([objective(x) for x in mesh])
    x0 = mesh[int(np.argmin(scores))]
    res = minimize(objective, x0, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-7, "maxiter": 2000})
    best = res.x if res.fun <= scores.min() else x0
    gains = dict(fixed)
    gains.update({n: float(np.exp(v)) for n, v in zip(names, best)})
    return TunedGains(
        kind=kind,
        gains=gains,
        worst_decay_rate=-float(objective(best)),
        design_voltages=tuple(round(op.voltage, 6) for op in pts),
    )


def lqi_gain(
    params: RigParams,
    op: OperatingPoint,
    *,
    speed_scale: float | None = None,
    voltage_scale: float = 1.0,
    integral_time: float = 4.0,
) -> np.ndarray:
    """LQR gain on (x1, x2, x3, z) with z' = w - x3, by Bryson's rule.

    Weights: a speed deviation of ``speed_scale`` (default 10 % of w, at least
    0.05 rad/s) costs as much as ``voltage_scale`` volts; the twist is weighted
    through its torque k_theta x1 at the same speed scale times the string's
    impedance sqrt(k_theta J_l); the integral through ``integral_time``.
    Returns K with u = u0 - K @ [dx1, dx2, dx3, -z].
    """
    A, B = linearise(params, op)
    w_s = speed_scale if speed_scale is not None else max(0.1 * op.speed, 0.05)
    z_s = np.sqrt(params.string_stiffness * params.lower_inertia)
    x1_s = w_s * z_s / params.string_stiffness
    Aa = np.zeros((4, 4))
    Aa[:3, :3] = A
    Aa[3, 2] = 1.0  # integral of the speed error (sign folded into K)
    Ba = np.vstack([B, [[0.0]]])
    Q = np.diag([1 / x1_s**2, 1 / w_s**2, 1 / w_s**2, 1 / (w_s * integral_time) ** 2])
    R = np.array([[1 / voltage_scale**2]])
    P = solve_continuous_are(Aa, Ba, Q, R)
    return (np.linalg.solve(R, Ba.T @ P)).ravel()


def _closed_loop_lqi(params: RigParams, op: OperatingPoint, K: np.ndarray) -> np.ndarray:
    A, B = linearise(params, op)
    Aa = np.zeros((4, 4))
    Aa[:3, :3] = A
    Aa[3, 2] = 1.0
    Ba = np.vstack([B, [[0.0]]])
    return Aa - Ba @ K[None, :]


def robustness(fn: Callable[[OperatingPoint], np.ndarray], points: list[OperatingPoint]) -> float:
    """Worst decay rate of closed loops produced by ``fn`` over ``points``."""
    return float(min(-np.max(np.linalg.eigvals(fn(op)).real) for op in points))
