"""The safety supervisor between a controller and the rig: always on.

Every voltage a controller asks for passes :meth:`Supervisor.apply` before it reaches the
rig: clamped to +-``voltage_limit`` (at most the amplifier's 5 V), then slew-limited to
``slew_limit`` V/s (a step of at most ``slew_limit * control_dt`` per control period). Each
reading passes :meth:`Supervisor.check_speed`: a lower-disk speed estimate beyond
``speed_limit`` trips it. The loop trips it too when no reading came for
``watchdog_periods`` control periods, when as many commands in a row reached the rig only
after its next reading (the loop fell behind), or when a controller call overran its period. A trip is
final: the loop writes 0 V, stops the rig and exits non-zero with the trip's one line.

Defaults: 5 V; 100 V/s (the whole range in 50 ms: no benchmark controller's step is
clipped); the speed up to which the brake's friction was identified (12.6 rad/s, Sec. 4
of the paper: beyond it the model vouches for nothing); 3 periods.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from drill_env.params import IDENTIFIED_SPEED_RAD_S, RIG_VOLTAGE_LIMIT

__all__ = [
    "DEFAULT_SLEW_LIMIT",
    "DEFAULT_SPEED_LIMIT",
    "MAX_SLEW_LIMIT",
    "MAX_SPEED_LIMIT",
    "MAX_WATCHDOG_PERIODS",
    "SupervisorLimits",
    "Supervisor",
    "Trip",
]

DEFAULT_SLEW_LIMIT = 100.0  # [V/s]
MAX_SLEW_LIMIT = 1e4  # [V/s] (a step of 5 V within 0.5 ms: no limit a rig can tell apart)
DEFAULT_SPEED_LIMIT = IDENTIFIED_SPEED_RAD_S["brake"]  # [rad/s]
MAX_SPEED_LIMIT = 100.0  # [rad/s] the measured-data loader's bound of a believable speed
MAX_WATCHDOG_PERIODS = 100


class Trip(RuntimeError):
    """The supervisor stopped the run (its one line is the message)."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


def _bounded(name: str, value: float, lo: float, hi: float, unit: str, *, lo_open: bool = True) -> float:
    v = float(value)
    ok = math.isfinite(v) and (v > lo if lo_open else v >= lo) and v <= hi
    if not ok:
        raise ValueError(
            f"{name}: {value!r} is outside the allowed range {'(' if lo_open else '['}{lo:g}, {hi:g}] {unit}"
        )
    return v


@dataclass(frozen=True)
class SupervisorLimits:
    """The supervisor's limits; a value outside its range is a ValueError naming it."""

    voltage_limit: float = RIG_VOLTAGE_LIMIT  # [V]
    slew_limit: float = DEFAULT_SLEW_LIMIT  # [V/s]
    speed_limit: float = DEFAULT_SPEED_LIMIT  # [rad/s] |lower-disk speed estimate|
    watchdog_periods: int = 3  # control periods without a reading

    def __post_init__(self) -> None:
        _bounded("--voltage-limit", self.voltage_limit, 0.0, RIG_VOLTAGE_LIMIT, "V")
        _bounded("--slew-limit", self.slew_limit, 0.0, MAX_SLEW_LIMIT, "V/s")
        _bounded("--speed-limit", self.speed_limit, 0.0, MAX_SPEED_LIMIT, "rad/s")
        w = self.watchdog_periods
        if isinstance(w, bool) or not isinstance(w, int) or not 1 <= w <= MAX_WATCHDOG_PERIODS:
            raise ValueError(
                f"--watchdog-periods: {w!r} is outside the allowed range [1, {MAX_WATCHDOG_PERIODS}]"
            )

    def as_dict(self) -> dict[str, float]:
        return {
            "voltage_limit_V": self.voltage_limit,
            "slew_limit_V_per_s": self.slew_limit,
            "speed_limit_rad_s": self.speed_limit,
            "watchdog_periods": self.watchdog_periods,
        }


@dataclass
class Supervisor:
    """Clamp, slew limit, speed limit; :attr:`events` lists what it did (time [s], kind, text)."""

    limits: SupervisorLimits
    control_dt: float  # [s]
    applied: float = 0.0  # [V] the last voltage let through
    events: list[tuple[float, str, str]] = field(default_factory=list)
    clamped: int = 0  # periods whose request was clamped
    slewed: int = 0  # periods whose step was slew-limited

    def apply(self, requested: float, t: float) -> float:
        """The voltage to write for the request ``requested`` [V] at time ``t`` [s]."""
        if not math.isfinite(requested):
            raise Trip("controller", f"controller: asked for a voltage of {requested!r} at t = {t:.3f} s")
        lim = self.limits.voltage_limit
        u = min(max(requested, -lim), lim)
        if u != requested:
            self.clamped += 1
        step = self.limits.slew_limit * self.control_dt
        v = min(max(u, self.applied - step), self.applied + step)
        if v != u:
            self.slewed += 1
        self.applied = v
        return v

    def check_speed(self, lower_speed: float, t: float) -> None:
        """Trip when the lower-disk speed estimate [rad/s] is beyond the speed limit."""
        if not abs(lower_speed) <= self.limits.speed_limit:
            raise Trip(
                "speed_limit",
                f"supervisor: lower-disk speed {lower_speed:.3f} rad/s at t = {t:.3f} s is beyond "
                f"--speed-limit {self.limits.speed_limit:g} rad/s",
            )

    def zero(self) -> float:
        """0 V, whatever the slew limit (a stop is never slew-limited)."""
        self.applied = 0.0
        return 0.0
