"""The scenario suite: registered option sets of the environments, each a hard case of the rig.

A scenario is what ``gymnasium.make("DrillString-v3", scenario="start_up")`` (or
``DrillStringNoBrake-v3``) runs: how the episode starts, the measurement chain, and what
changes while the controller runs -- the set point (target speed and its nominal voltage)
and the lower disk's friction (the brake's normal force, the lab's analogue of a change of
weight on bit). The controller is told the new set point when it changes (the observation's
``target_speed`` and ``nominal_voltage``, as an operator's new command), never the friction.

=================  ===========================================================================
name               what it models
=================  ===========================================================================
start_up           both disks at rest (stuck); the controller brings the bit to a stick-slip set
                   point through the stick band
set_point_steps    three set points, 30 s each: below the Hopf band, deep in stick-slip, then
                   back into the Hopf band (brake: 0.5 -> 2.5 -> 1.0 V; no brake:
                   0.4 -> 1.0 -> 1.5 V)
friction_step      a step of the lower friction curve to x1.4 at 20 s, in the Hopf band
friction_drift     the lower friction curve drifts from x0.7 to x1.4 over 80 s
sensing_delay      40 ms delay on both encoders (the top end of 10-40 ms of a field link), at
                   a stick-slip set point
sensing_noise      encoder angle noise (2 mrad) and speed noise (0.2 rad/s) at 1 kHz, in the
                   Hopf band
effort             a constant stick-slip set point; scored on tracking per energy used
=================  ===========================================================================

The voltages are the preset's (:data:`VOLTAGES`): the design model's regimes place them, so
the ``no_brake`` rig gets the "equivalent" points of its own (lower, narrower) Hopf band and
stick-slip range. The schedule's times are seconds since the controller's switch-on (the end of the
open-loop warm-up, or the rest start). A change takes effect at the end of the control period
in which its time falls: the observation returned there already shows the new set point, and
the next period is integrated with the new friction (a drift is therefore a staircase of one
step per control period, 50 ms by default, far faster than the 4 s torsional period).

The friction factor scales the whole lower-disk curve of eq. (14): ``T_sl``, ``b_l``, ``T_1``
and ``T_2`` (not the rates ``beta``), so the static band, the hump and the viscous part grow
together, as a higher normal force on the brake does. It scales the episode's plant (also a
randomised one), never the design model.

The runner that scores controllers on the suite is
:mod:`drill_env.agents.evaluation.scenarios`.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from drill_env import _layout as L

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "FRICTION_SCALED",
    "SCENARIOS",
    "SCENARIO_NAMES",
    "FrictionSchedule",
    "Scenario",
    "ScenarioSchedule",
    "get_scenario",
    "resolve_scenarios",
]

# the entries of the parameter vector the friction factor scales: eq. (14)'s levels and slope
FRICTION_SCALED = (L.TSL, L.BL, L.T1, L.T2)
MAX_FRICTION_FACTOR = 5.0  # beyond this the brake curve is no longer the identified one's shape


@dataclass(frozen=True)
class FrictionSchedule:
    """The factor on the lower-disk friction curve over time: piecewise linear through
    ``points`` ``((time [s], factor [-]), ...)``, constant before the first and after the last
    (a step is two points at the same time)."""

    points: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        pts = tuple((float(t), float(f)) for t, f in self.points)
        if not pts:
            raise ValueError("friction: expected at least one (time, factor) point")
        for t, f in pts:
            if not (math.isfinite(t) and t >= 0):
                raise ValueError(f"friction: time {t!r} is outside the allowed range [0, inf) s")
            if not (math.isfinite(f) and 0 < f <= MAX_FRICTION_FACTOR):
                raise ValueError(
                    f"friction: factor {f!r} is outside the allowed range (0, {MAX_FRICTION_FACTOR:g}]"
                )
        if any(b[0] < a[0] for a, b in zip(pts, pts[1:], strict=False)):
            raise ValueError("friction: the times must not decrease")
        object.__setattr__(self, "points", pts)

    def factor(self, t: float) -> float:
        """The factor at time ``t`` [s] (after a step where ``t`` is its time)."""
        pts = self.points
        if t < pts[0][0]:
            return pts[0][1]
        for (t0, f0), (t1, f1) in zip(pts, pts[1:], strict=False):
            if t < t1:
                return f0 + (f1 - f0) * (t - t0) / (t1 - t0) if t1 > t0 else f1
        return pts[-1][1]


@dataclass(frozen=True)
class Scenario:
    """One scenario of the suite (see the module docstring).

    ``voltages[preset]`` are the nominal voltages of the set points [V]: the first from the
    switch-on, each next one from the matching entry of ``change_times`` [s].
    """

    name: str
    summary: str
    voltages: Mapping[str, tuple[float, ...]]
    change_times: tuple[float, ...] = ()
    friction: FrictionSchedule | None = None
    start: str = "open_loop"
    sensors: Mapping[str, Any] = field(default_factory=dict)
    duration: float = 40.0  # [s] closed-loop time of the suite's episodes
    warmup_time: float = 30.0  # [s] open-loop warm-up before switch-on (unused from rest)
    score: str = "tracking"  # "tracking" or "tracking_per_energy" (the runner's scores)

    def __post_init__(self) -> None:
        for preset, vs in self.voltages.items():
            if len(vs) != len(self.change_times) + 1:
                raise ValueError(
                    f"scenario {self.name}: {preset} has {len(vs)} set points for "
                    f"{len(self.change_times)} changes"
                )
        if list(self.change_times) != sorted(self.change_times):
            raise ValueError(f"scenario {self.name}: change_times must increase")
        object.__setattr__(
            self, "voltages", {k: tuple(float(v) for v in vs) for k, vs in self.voltages.items()}
        )
        object.__setattr__(self, "sensors", dict(self.sensors))

    @property
    def time_varying(self) -> bool:
        """Whether something changes during the episode (set point or friction)."""
        return bool(self.change_times) or self.friction is not None

    def set_point_voltages(self, preset: str) -> tuple[float, ...]:
        """The nominal voltages [V] of the set points on ``preset``'s design model."""
        try:
            return self.voltages[preset]
        except KeyError:
            raise ValueError(
                f"scenario: {self.name!r} defines set points for the design models "
                f"{sorted(self.voltages)}, not {preset!r}"
            ) from None

    def phase_bounds(self) -> list[tuple[float, float]]:
        """(start, end) [s] of each set point's phase within the closed-loop episode."""
        edges = [0.0, *self.change_times, self.duration]
        return list(zip(edges[:-1], edges[1:], strict=True))

    def friction_factor(self, t: float) -> float:
        """The friction factor at time ``t`` [s] (1 without a friction schedule)."""
        return 1.0 if self.friction is None else self.friction.factor(t)


_BOTH = ("brake", "no_brake")

# [V] per preset, placed by the design model's regimes (drill_env.envs.task.operating_regimes).
# Brake: uc1 0.116 V, equilibrium to the Hopf point 0.583 V, limit cycle to 1.781 V, stick-slip
# to 5 V. No brake: equilibrium to 0.489 V, limit cycle to 0.600 V, stick-slip to 1.294 V, limit
# cycle to 1.671 V, equilibrium to 5 V: its "equivalent" points are those of its own regimes.
VOLTAGES: dict[str, dict[str, tuple[float, ...]]] = {
    "start_up": {"brake": (2.5,), "no_brake": (1.0,)},  # stick-slip
    "set_point_steps": {"brake": (0.5, 2.5, 1.0), "no_brake": (0.4, 1.0, 1.5)},  # eq., s-s, l.c.
    "friction_step": {"brake": (1.5,), "no_brake": (1.5,)},  # limit cycle
    "friction_drift": {"brake": (1.5,), "no_brake": (1.5,)},  # limit cycle
    "sensing_delay": {"brake": (2.0,), "no_brake": (0.8,)},  # stick-slip
    "sensing_noise": {"brake": (1.0,), "no_brake": (0.55,)},  # limit cycle
    "effort": {"brake": (3.0,), "no_brake": (1.2,)},  # stick-slip
}

SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            "start_up",
            "from rest (both disks stuck) to a stick-slip set point, through the stick band",
            VOLTAGES["start_up"],
            start="rest",
            duration=40.0,
        ),
        Scenario(
            "set_point_steps",
            "set point below the Hopf band, deep in stick-slip, then in the Hopf band (30 s each)",
            VOLTAGES["set_point_steps"],
            change_times=(30.0, 60.0),
            duration=90.0,
        ),
        Scenario(
            "friction_step",
            "lower friction curve steps to x1.4 at 20 s (the brake pressed harder)",
            VOLTAGES["friction_step"],
            friction=FrictionSchedule(((20.0, 1.0), (20.0, 1.4))),
            duration=60.0,
        ),
        Scenario(
            "friction_drift",
            "lower friction curve drifts from x0.7 to x1.4 over 80 s",
            VOLTAGES["friction_drift"],
            friction=FrictionSchedule(((0.0, 0.7), (80.0, 1.4))),
            duration=90.0,
        ),
        Scenario(
            "sensing_delay",
            "both encoders delayed by 40 ms, at a stick-slip set point",
            VOLTAGES["sensing_delay"],
            sensors={"delay_samples": 40},
            duration=40.0,
        ),
        Scenario(
            "sensing_noise",
            "encoder angle noise 2 mrad and speed noise 0.2 rad/s (1 kHz), in the Hopf band",
            VOLTAGES["sensing_noise"],
            sensors={"angle_noise_std": 2e-3, "speed_noise_std": 0.2},
            duration=40.0,
        ),
        Scenario(
            "effort",
            "a constant stick-slip set point, scored on tracking per energy used",
            VOLTAGES["effort"],
            duration=40.0,
            score="tracking_per_energy",
        ),
    )
}
SCENARIO_NAMES = tuple(SCENARIOS)
assert set(SCENARIO_NAMES) == set(VOLTAGES)


def get_scenario(scenario: str | Scenario) -> Scenario:
    """A scenario by name (or the scenario itself)."""
    if isinstance(scenario, Scenario):
        return scenario
    if not isinstance(scenario, str) or scenario not in SCENARIOS:
        raise ValueError(f"scenario: {scenario!r} is not one of {list(SCENARIO_NAMES)}")
    return SCENARIOS[scenario]


def resolve_scenarios(text: str) -> tuple[str, ...]:
    """``"all"`` or a comma-separated list of scenario names -> the names, in suite order."""
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"scenarios: expected 'all' or names from {list(SCENARIO_NAMES)}, got {text!r}")
    if text.strip() == "all":
        return SCENARIO_NAMES
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in SCENARIOS]
    if unknown:
        raise ValueError(f"scenarios: {unknown} not among {list(SCENARIO_NAMES)} (or 'all')")
    return tuple(n for n in SCENARIO_NAMES if n in names)


class ScenarioSchedule:
    """A scenario's changes bound to one environment: the set points as operating points of
    the design model, applied to a rig's kernel vectors by :meth:`apply` (single and vector
    environment alike)."""

    def __init__(self, scenario: Scenario, points: list[Any], target_scale: float, unom_scale: float):
        self.scenario = scenario
        self.points = points  # OperatingPoint per set point
        self.change_times = tuple(float(t) for t in scenario.change_times)
        self._target_scale = float(target_scale)
        self._unom_scale = float(unom_scale)

    def phase(self, t: float) -> int:
        """The set point in force at time ``t`` [s] (index into :attr:`points`)."""
        return bisect.bisect_right(self.change_times, t + 1e-9)

    def episode_points(self, first: Any) -> list[Any]:
        """The set points of an episode whose first one is ``first`` (reset options may choose
        it; the later ones are the scenario's)."""
        return [first, *self.points[1:]]

    def scale_friction(self, t: float, base_params: np.ndarray, p: np.ndarray) -> None:
        """Scale the lower friction of ``p`` to the factor of time ``t`` [s] from ``base_params``."""
        if self.scenario.friction is not None:
            f = self.scenario.friction.factor(t)
            for j in FRICTION_SCALED:
                p[j] = base_params[j] * f

    def apply(
        self,
        t: float,
        points: list[Any],
        base_params: np.ndarray,
        p: np.ndarray,
        ep: np.ndarray,
        obs: np.ndarray,
        i_target: int,
        i_unom: int,
        ep_target: int,
        ep_unom: int,
    ) -> None:
        """Put the set point (of the episode's ``points``) and the friction of time ``t`` [s]
        into the rig's parameter vector ``p`` (from the episode's plant ``base_params``), its
        episode scalars ``ep`` and the observation ``obs`` (entries ``i_target``, ``i_unom``)."""
        pt = points[self.phase(t)]
        if ep[ep_target] != pt.target_speed or ep[ep_unom] != pt.nominal_voltage:
            ep[ep_target] = pt.target_speed
            ep[ep_unom] = pt.nominal_voltage
            obs[i_target] = pt.target_speed / self._target_scale
            obs[i_unom] = pt.nominal_voltage / self._unom_scale
        self.scale_friction(t, base_params, p)
