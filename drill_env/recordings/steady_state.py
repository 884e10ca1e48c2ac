"""Steady states of constant-voltage runs and the friction curves they give.

A constant-voltage run recorded after its transient sits on one of three steady states
(Sec. 3 of the paper): both disks stuck (below the stick boundary, point A), a slip
equilibrium (constant speed x3, constant twist x1), or a limit cycle.

* At a **slip equilibrium** the lower disk's balance ``k_theta x1 = T_l(x3)`` gives one
  point of the lower friction curve, in units of the string stiffness.
* At an equilibrium *or* on a limit cycle that the upper disk rides without sticking, the
  mean of the upper disk's equation over the recording (the accelerations average out)
  is ``k_m u = T_sup + b_up mean(x2) + k_theta mean(x1)``: one linear equation in
  ``k_m, T_sup, b_up`` per run (mean(x2) is the upper angle turned over the recording
  divided by its length; the lower disk's differs by the change of the twist over an
  unfinished cycle).

Speeds come from the encoder angles alone: the mean speed is the angle turned over the
recording divided by its length (exact up to two counts), the spread of the speed that of
the angle turned over 0.1 s windows.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["SteadyState", "steady_state", "steady_states", "upper_balance", "lower_curve_points"]

SPEED_WINDOW_S = 0.1  # [s] span over which the angle turned gives the speed's min and max
SMOOTH_WINDOW_S = 0.5  # [s] span of the speed used to tell an equilibrium from a cycle


@dataclass(frozen=True)
class SteadyState:
    """The steady state of one constant-voltage run (SI units)."""

    run: str
    voltage: float  # [V]
    mean_speed: float  # mean lower-disk speed x3 [rad/s]
    mean_upper_speed: (
        float  # mean upper-disk speed x2 [rad/s] (differs from x3's by the twist's change / length)
    )
    min_speed: float  # min of the lower speed over 0.1 s windows [rad/s]
    max_speed: float  # max [rad/s]
    mean_twist: float  # mean x1 = theta_u - theta_l [rad]
    upper_min_speed: float  # min of the upper speed over 0.1 s windows [rad/s]
    kind: str  # "stuck", "equilibrium" or "cycle"
    speed_noise: float  # what one encoder count does to the 0.5 s speed [rad/s]

    @property
    def upper_always_slips(self) -> bool:
        """The upper disk never stops (its mean balance is then exact)."""
        return self.kind != "stuck" and abs(self.upper_min_speed) > 3.0 * self.speed_noise

    def as_dict(self) -> dict:
        return asdict(self)


def _window_speed(theta: np.ndarray, dt: float, span_s: float) -> np.ndarray:
    k = max(1, int(round(span_s / dt)))
    if theta.size <= k:
        return np.array([(theta[-1] - theta[0]) / max(dt * (theta.size - 1), dt)])
    return (theta[k:] - theta[:-k]) / (k * dt)


def steady_state(run, encoder_step: float) -> SteadyState:
    """Classify a constant-voltage run and measure its steady state."""
    if not run.is_constant_voltage:
        raise ValueError(f"run {run.name}: not a constant-voltage run")
    dt = run.dt
    T = run.duration
    travel_l = float(run.theta_l[-1] - run.theta_l[0])
    travel_u = float(run.theta_u[-1] - run.theta_u[0])
    mean_speed = travel_l / T
    v_l = _window_speed(run.theta_l, dt, SPEED_WINDOW_S)
    v_u = _window_speed(run.theta_u, dt, SPEED_WINDOW_S)
    smooth = _window_speed(run.theta_l, dt, SMOOTH_WINDOW_S)
    noise = encoder_step / SMOOTH_WINDOW_S
    moved = max(abs(travel_l), abs(travel_u), float(np.ptp(run.theta_l)), float(np.ptp(run.theta_u)))
    if moved <= 4.0 * encoder_step:
        kind = "stuck"
    else:
        # an equilibrium: the 0.5 s speed stays within a few counts (and a percent) of its mean
        spread = float(np.percentile(smooth, 99.5) - np.percentile(smooth, 0.5))
        kind = "cycle" if spread > 4.0 * noise + 0.04 * abs(mean_speed) else "equilibrium"
    sign = 1.0 if mean_speed >= 0 else -1.0
    return SteadyState(
        run=run.name,
        voltage=float(run.voltage),
        mean_speed=mean_speed,
        mean_upper_speed=travel_u / T,
        min_speed=float(v_l.min()),
        max_speed=float(v_l.max()),
        mean_twist=float(np.mean(run.theta_u - run.theta_l)),
        upper_min_speed=float(sign * np.min(sign * v_u)),
        kind=kind,
        speed_noise=noise,
    )


def steady_states(runs, encoder_step: float) -> list[SteadyState]:
    """The steady state of every constant-voltage run, in order of voltage."""
    out = [steady_state(r, encoder_step) for r in runs if r.is_constant_voltage]
    return sorted(out, key=lambda s: (s.voltage, s.run))


@dataclass(frozen=True)
class UpperBalance:
    """``k_m u = T_s + b mean(x2) + k_theta mean(x1)`` fitted over the runs of one direction."""

    direction: int  # +1: positive voltages, -1: negative
    motor_constant: float  # [N m / V]
    string_stiffness: float  # [N m / rad]
    static: float  # T_sup (or T_sun) [N m]
    viscous: float  # b_up (or b_un) [N m s / rad]
    runs: tuple[str, ...]

    def as_dict(self) -> dict:
        return asdict(self)


def upper_balance(
    states: list[SteadyState], scale: tuple[str, float], direction: int = 1
) -> UpperBalance | None:
    """Least squares over the runs whose upper disk never stops, in one direction.

    ``scale`` is the parameter whose value is known, ``("string_stiffness", k)`` or
    ``("motor_constant", k_m)``. None when fewer than three runs with distinct speeds
    (three unknowns) are available."""
    use = [s for s in states if s.upper_always_slips and np.sign(s.mean_upper_speed) == direction]
    if len({round(s.mean_upper_speed, 6) for s in use}) < 3:
        return None
    u = np.array([s.voltage for s in use])
    w = np.array([s.mean_upper_speed for s in use])
    x1 = np.array([s.mean_twist for s in use])
    sgn = float(direction)
    name, value = scale
    if name == "string_stiffness":
        # k_theta x1 = k_m u - sgn T_s - b w
        a = np.column_stack([u, -sgn * np.ones_like(u), -w])
        coef, *_ = np.linalg.lstsq(a, value * x1, rcond=None)
        km, ts, b = coef
        kth = value
    else:
        # k_m u = k_theta x1 + sgn T_s + b w
        a = np.column_stack([x1, sgn * np.ones_like(u), w])
        coef, *_ = np.linalg.lstsq(a, value * u, rcond=None)
        kth, ts, b = coef
        km = value
    return UpperBalance(direction, float(km), float(kth), float(ts), float(b), tuple(s.run for s in use))


def lower_curve_points(states: list[SteadyState], string_stiffness: float) -> tuple[np.ndarray, np.ndarray]:
    """(|x3|, T_l(|x3|)) at every slip equilibrium [rad/s], [N m]: ``T_l = k_theta |x1|``."""
    eq = [s for s in states if s.kind == "equilibrium" and math.isfinite(s.mean_speed)]
    w = np.array([abs(s.mean_speed) for s in eq])
    t = np.array([string_stiffness * abs(s.mean_twist) for s in eq])
    return w, t
