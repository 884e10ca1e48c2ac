"""The task of the env: each episode's operating point.

An operating point is a nominal (constant) input voltage ``u`` and the lower-disk speed
it gives at the slip equilibrium of eq. (20),

    km u = T_sup + b_up w + T_l(w),   x2 = x3 = w,   x1 = T_l(w) / k_theta,

which is unique for every ``u > uc1`` by condition (21) (:mod:`.equilibrium`, from the
analysis), and the regime the nominal model is in at ``u`` (:mod:`.regimes`): an episode
draws a regime and then a voltage in it (:class:`TaskConfig`, :class:`OperatingPointSampler`).

The regimes belong to the *nominal* model (the paper's eq. (36), effects of
:class:`~drill_env.params.ModelEffects` ignored): it is what a controller designer knows.
Everything the env used to import from here still is: the equilibrium and the regimes are
re-exported.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drill_env.envs.equilibrium import (
    critical_friction_slope,
    equilibrium_speed,
    equilibrium_state,
    hopf_voltages,
    nominal_params,
    nominal_voltage,
)
from drill_env.envs.regimes import REGIMES, OperatingRegimes, operating_regimes
from drill_env.params import RIG_VOLTAGE_LIMIT, RigParams

__all__ = [
    "REGIMES",
    "VOLTAGE_LIMIT",
    "OperatingPoint",
    "OperatingPointSampler",
    "OperatingRegimes",
    "RegimeAbsentWarning",
    "TaskConfig",
    "critical_friction_slope",
    "equilibrium_speed",
    "equilibrium_state",
    "hopf_voltages",
    "nominal_params",
    "nominal_voltage",
    "operating_regimes",
]

VOLTAGE_LIMIT = RIG_VOLTAGE_LIMIT  # [V] the amplifier input range of the rig is [-5, 5] V (Sec. 2.1)


class RegimeAbsentWarning(UserWarning):
    """A regime the task asks for does not occur on the design model (e.g. an identified rig
    whose equilibrium is unstable at every voltage): its episodes are drawn from the others."""

    one_line = True  # the command line shows it as one line (drill_env.cli)


@dataclass(frozen=True)
class OperatingPoint:
    """An episode's operating point."""

    regime: str
    nominal_voltage: float  # [V]
    target_speed: float  # [rad/s] slip-equilibrium speed of the nominal model at nominal_voltage


@dataclass(frozen=True)
class TaskConfig:
    """How each episode draws its operating point.

    By default a regime is drawn uniformly from ``regimes`` and then the nominal voltage
    uniformly over that regime's voltage intervals, above the voltage of
    ``min_target_speed``. ``voltage_range`` (nominal voltage uniform in [lo, hi] V) or
    ``target_speed_range`` (target speed uniform in [lo, hi] rad/s) replace the regime draw.
    """

    regimes: tuple[str, ...] = REGIMES
    voltage_range: tuple[float, float] | None = None  # [V]
    target_speed_range: tuple[float, float] | None = None  # [rad/s]
    min_target_speed: float = 0.1  # [rad/s] floor of regime draws (the paper's lowest: 0.0911 rad/s)

    def __post_init__(self) -> None:
        regimes = self.regimes
        if isinstance(regimes, str):
            regimes = (regimes,)
        if not isinstance(regimes, Sequence) or len(regimes) == 0:
            raise ValueError(f"regimes: expected a non-empty sequence of {REGIMES}, got {self.regimes!r}")
        for r in regimes:
            if r not in REGIMES:
                raise ValueError(f"regimes: {r!r} is not one of {REGIMES}")
        if len(set(regimes)) != len(regimes):
            raise ValueError(f"regimes: duplicate entries in {tuple(regimes)!r}")
        object.__setattr__(self, "regimes", tuple(regimes))
        if self.voltage_range is not None and self.target_speed_range is not None:
            raise ValueError("voltage_range, target_speed_range: give at most one of them")
        for name in ("voltage_range", "target_speed_range"):
            rng = getattr(self, name)
            if rng is None:
                continue
            try:
                lo, hi = (float(v) for v in rng)
            except (TypeError, ValueError):
                raise ValueError(f"{name}: expected (low, high), got {rng!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo <= hi):
                raise ValueError(f"{name}: expected finite 0 < low <= high, got {rng!r}")
            object.__setattr__(self, name, (lo, hi))
        m = self.min_target_speed
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not (math.isfinite(m) and m >= 0.0):
            raise ValueError(f"min_target_speed: expected a finite number >= 0 rad/s, got {m!r}")

    @classmethod
    def from_any(cls, value: TaskConfig | Mapping[str, Any] | None) -> TaskConfig:
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, Mapping):
            allowed = {f.name for f in dataclasses.fields(cls)}
            unknown = sorted(set(value) - allowed)
            if unknown:
                raise ValueError(f"task: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
            return cls(**value)
        raise ValueError(f"task: expected TaskConfig, a dict or None, got {type(value).__name__}")


class OperatingPointSampler:
    """Draws operating points for one nominal model (validated against it once)."""

    def __init__(self, params: RigParams, config: TaskConfig):
        self.params = nominal_params(params)
        self.config = config
        self.u_max = VOLTAGE_LIMIT
        self.speed_max = equilibrium_speed(self.params, self.u_max)
        self.uc1 = self.params.uc1
        self._regimes: OperatingRegimes | None = None
        self._pools: dict[str, list[tuple[float, float]]] = {}
        if config.voltage_range is not None:
            lo, hi = config.voltage_range
            if not (self.uc1 < lo and hi <= self.u_max):
                raise ValueError(
                    f"voltage_range: ({lo:g}, {hi:g}) must lie in ({self.uc1:.6g}, {self.u_max:g}] V "
                    "(the rig turns above uc1; the amplifier stops at 5 V)"
                )
        elif config.target_speed_range is not None:
            lo, hi = config.target_speed_range
            if hi > self.speed_max:
                raise ValueError(
                    f"target_speed_range: ({lo:g}, {hi:g}) must lie in (0, {self.speed_max:.6g}] rad/s "
                    "(the equilibrium speed at 5 V)"
                )
        else:
            u_floor = (
                nominal_voltage(self.params, config.min_target_speed)
                if config.min_target_speed > 0
                else self.uc1
            )
            regimes = self.regimes
            missing = []
            for name in config.regimes:
                pool = [(max(lo, u_floor), hi) for lo, hi in regimes.intervals_of(name) if hi > u_floor]
                if pool:
                    self._pools[name] = pool
                else:
                    missing.append(name)
            if not self._pools:
                raise ValueError(
                    f"regimes: {', '.join(map(repr, missing))} "
                    f"{'does' if len(missing) == 1 else 'do'} not occur between {u_floor:.4g} V and "
                    f"{self.u_max:g} V for these parameters; regimes found: "
                    + "; ".join(f"{n} {lo:.4g}-{hi:.4g} V" for n, lo, hi in regimes.intervals)
                )
            if missing:
                # a rig without one of the regimes (e.g. no stable equilibrium anywhere): the
                # episodes draw from the regimes it has, and the user is told which are absent
                warnings.warn(
                    f"regimes: {', '.join(missing)} {'does' if len(missing) == 1 else 'do'} not occur between "
                    f"{u_floor:.4g} V and {self.u_max:g} V on this rig ({self.params.name}); episodes draw "
                    f"from {', '.join(self._pools)}",
                    RegimeAbsentWarning,
                    stacklevel=2,
                )
        self.available_regimes: tuple[str, ...] = tuple(self._pools)

    @property
    def regimes(self) -> OperatingRegimes:
        if self._regimes is None:
            self._regimes = operating_regimes(self.params, self.u_max)
        return self._regimes

    def point_from_voltage(self, voltage: float) -> OperatingPoint:
        u = float(voltage)
        if not (math.isfinite(u) and self.uc1 < u <= self.u_max):
            raise ValueError(
                f"nominal_voltage: {voltage!r} is outside the allowed range ({self.uc1:.6g}, {self.u_max:g}] V"
            )
        return OperatingPoint(self.regimes.regime_of(u), u, equilibrium_speed(self.params, u))

    def point_from_speed(self, speed: float) -> OperatingPoint:
        w = float(speed)
        if not (math.isfinite(w) and 0.0 < w <= self.speed_max):
            raise ValueError(
                f"target_speed: {speed!r} is outside the allowed range (0, {self.speed_max:.6g}] rad/s"
            )
        # A speed so small that its voltage rounds to uc1 gets the next voltage above uc1.
        u = min(max(nominal_voltage(self.params, w), math.nextafter(self.uc1, math.inf)), self.u_max)
        return OperatingPoint(self.regimes.regime_of(u), u, w)

    def _pool(self, regime: str) -> list[tuple[float, float]]:
        """The voltage intervals of ``regime`` above the task's speed floor (maybe none)."""
        pool = self._pools.get(regime)
        if pool is None:
            u_floor = (
                nominal_voltage(self.params, self.config.min_target_speed)
                if self.config.min_target_speed > 0
                else self.uc1
            )
            pool = [(max(lo, u_floor), hi) for lo, hi in self.regimes.intervals_of(regime) if hi > u_floor]
            if pool:
                self._pools[regime] = pool
        return pool

    def regimes_present(self) -> tuple[str, ...]:
        """The regimes of :data:`REGIMES` that occur on this model above the speed floor (an
        identified rig may lack one: no stable equilibrium anywhere, or no cycle)."""
        return tuple(r for r in REGIMES if self._pool(r))

    def point_in_regime(self, regime: str, rng: np.random.Generator) -> OperatingPoint:
        if regime not in REGIMES:
            raise ValueError(f"regime: {regime!r} is not one of {REGIMES}")
        pool = self._pool(regime)
        if not pool:
            raise ValueError(
                f"regime: {regime!r} does not occur for these parameters; regimes found: "
                + ", ".join(self.regimes_present())
            )
        total = sum(hi - lo for lo, hi in pool)
        x = float(rng.uniform(0.0, total))
        for lo, hi in pool:
            if x <= hi - lo:
                u = lo + x
                break
            x -= hi - lo
        else:
            u = pool[-1][1]
        return OperatingPoint(regime, u, equilibrium_speed(self.params, u))

    def sample(self, rng: np.random.Generator) -> OperatingPoint:
        cfg = self.config
        if cfg.voltage_range is not None:
            return self.point_from_voltage(rng.uniform(*cfg.voltage_range))
        if cfg.target_speed_range is not None:
            return self.point_from_speed(rng.uniform(*cfg.target_speed_range))
        names = self.available_regimes
        regime = names[int(rng.integers(len(names)))]
        return self.point_in_regime(regime, rng)
