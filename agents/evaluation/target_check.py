"""The learned controllers' target, checked cheaply: suppression and tracking on a small grid.

A controller *meets the target* on a rig when, over the check grid of that rig
(:data:`CHECK_VOLTAGES`: at least three voltages in every regime of the design model, 5 V
included, each run from every seed of :data:`CHECK_SEEDS`):

* its mean suppression is at least :data:`SUPPRESSION_TARGET` (0.99) in each regime with a
  cycle (Hopf limit cycle, stick-slip), as the benchmark scores it;
* its mean RMS speed error is within the benchmark's tracking limit in every regime:
  :data:`TRACKING_FACTOR` (2) times the tuned LQI's mean RMS error on the same runs plus
  :data:`TRACKING_MARGIN` (0.01 rad/s), the limit the committed benchmark's learned rows are
  held to;
* no run stalls.

Every run is :func:`drill_env.agents.evaluation.episodes.evaluate` (the benchmark's episode and
metrics) with the benchmark's episode settings, on seeds the benchmark does not use (1000,
1001): the check can pick a policy without looking at the benchmark's runs. The grid is 22 to
24 runs of about 0.05 s each: about a second per check.

:attr:`TargetResult.margin` ranks policies: the smallest slack over the criteria, each as a
fraction of its own scale ((suppression - 0.99) / 0.01 per cycle regime, (limit - RMS) / limit
per regime, -1 for a stalled run); >= 0 exactly when the target is met.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env

__all__ = [
    "CHECK_VOLTAGES",
    "CHECK_SEEDS",
    "CYCLE_REGIMES",
    "SUPPRESSION_TARGET",
    "TRACKING_FACTOR",
    "TRACKING_MARGIN",
    "TargetResult",
    "TargetCheck",
    "tracking_limits",
]

# [V] per preset and design-model regime (the labels of the benchmark's full grid); 5 V is in
# the braked rig's stick-slip regime and the unbraked rig's upper equilibrium branch
CHECK_VOLTAGES: dict[str, dict[str, tuple[float, ...]]] = {
    "brake": {
        "equilibrium": (0.2, 0.3, 0.5),
        "limit_cycle": (0.7, 1.0, 1.25, 1.75),
        "stick_slip": (2.0, 3.0, 4.0, 5.0),
    },
    "no_brake": {
        "equilibrium": (0.3, 1.8, 3.5, 5.0),
        "limit_cycle": (0.55, 1.35, 1.5, 1.6),
        "stick_slip": (0.7, 0.85, 1.0, 1.15),
    },
}
CHECK_SEEDS = (1000, 1001)
CYCLE_REGIMES = ("limit_cycle", "stick_slip")
SUPPRESSION_TARGET = 0.99
TRACKING_FACTOR = 2.0
TRACKING_MARGIN = 0.01  # [rad/s]

_LIMITS: dict[tuple[str, tuple[int, ...]], dict[str, float]] = {}


@dataclass(frozen=True)
class TargetResult:
    """One check: per regime the mean suppression (cycle regimes), mean RMS speed error and
    its limit [rad/s]; whether the target is met, the margin and the wall time of the check."""

    preset: str
    suppression: dict[str, float]
    rms_error: dict[str, float]
    rms_limit: dict[str, float]
    stalled: int
    met: bool
    margin: float
    wall_s: float
    runs: list[dict[str, Any]] = field(default_factory=list, repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {
            "preset": self.preset,
            "met": self.met,
            "margin": self.margin,
            "suppression": dict(self.suppression),
            "rms_error": dict(self.rms_error),
            "rms_limit": dict(self.rms_limit),
            "stalled": self.stalled,
            "wall_s": self.wall_s,
        }


def _runs(controller: Any, preset: str, version: int, seeds: tuple[int, ...]) -> list[dict[str, Any]]:
    settings = EpisodeSettings()
    env = make_env(preset, settings, version)
    try:
        rows = []
        for regime, volts in CHECK_VOLTAGES[preset].items():
            for v in volts:
                for s in seeds:
                    m = evaluate(controller, preset, v, s, settings, env=env)
                    if m.regime != regime:  # the grid is labelled by the design model's analysis
                        raise RuntimeError(f"check grid: {v} V on {preset} is {m.regime}, listed as {regime}")
                    rows.append(m.as_dict())
        return rows
    finally:
        env.close()


def tracking_limits(preset: str, seeds: tuple[int, ...] = CHECK_SEEDS) -> dict[str, float]:
    """The tracking limit per regime [rad/s]: 2 x the tuned LQI's mean RMS error on the check
    grid + 0.01 (computed once per process and preset)."""
    key = (preset, tuple(seeds))
    if key not in _LIMITS:
        from drill_env.agents.controllers.base import ControllerSpec
        from drill_env.agents.controllers.gains import classical_controller
        from drill_env.envs.config import OBSERVATION_VERSIONS

        # the env the benchmark runs a classical controller on (registry.observation_version),
        # read here without the registry, which imports the learners that import this module
        version = max(OBSERVATION_VERSIONS)
        env = make_env(preset, EpisodeSettings(), version)
        lqi = classical_controller("lqi", ControllerSpec.from_env(env), preset)
        env.close()
        rows = _runs(lqi, preset, version, tuple(seeds))
        _LIMITS[key] = {
            r: TRACKING_FACTOR * _mean([x["rms_error"] for x in rows if x["regime"] == r]) + TRACKING_MARGIN
            for r in CHECK_VOLTAGES[preset]
        }
    return dict(_LIMITS[key])


def _mean(values: list[float]) -> float:
    return float(sum(values) / len(values)) if values else math.nan


class TargetCheck:
    """The target check of one rig for controllers observing env version ``version``."""

    def __init__(self, preset: str, version: int, seeds: tuple[int, ...] = CHECK_SEEDS):
        if preset not in CHECK_VOLTAGES:
            raise ValueError(f"preset: {preset!r} is not one of {sorted(CHECK_VOLTAGES)}")
        if len(seeds) < 1:
            raise ValueError("seeds: expected at least one seed")
        self.preset, self.version, self.seeds = preset, int(version), tuple(int(s) for s in seeds)
        self.limits = tracking_limits(preset, self.seeds)

    def __call__(self, controller: Any) -> TargetResult:
        t0 = time.perf_counter()
        rows = _runs(controller, self.preset, self.version, self.seeds)
        supp, rms = {}, {}
        slack = []
        for regime in CHECK_VOLTAGES[self.preset]:
            runs = [r for r in rows if r["regime"] == regime]
            rms[regime] = _mean([r["rms_error"] for r in runs])
            limit = self.limits[regime]
            slack.append((limit - rms[regime]) / limit if math.isfinite(rms[regime]) else -math.inf)
            if regime in CYCLE_REGIMES:
                values = [r["suppression"] for r in runs if math.isfinite(r["suppression"])]
                supp[regime] = _mean(values)
                s = supp[regime]
                slack.append(
                    (s - SUPPRESSION_TARGET) / (1.0 - SUPPRESSION_TARGET) if math.isfinite(s) else -math.inf
                )
        stalled = sum(bool(r["stalled"]) for r in rows)
        if stalled:
            slack.append(-1.0)
        margin = float(min(slack))
        return TargetResult(
            preset=self.preset,
            suppression=supp,
            rms_error=rms,
            rms_limit=dict(self.limits),
            stalled=stalled,
            met=bool(margin >= 0.0),
            margin=margin,
            wall_s=time.perf_counter() - t0,
            runs=rows,
        )
