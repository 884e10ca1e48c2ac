"""The benchmark's grid: presets, voltages, seeds, controllers and plants of a benchmark
(:class:`BenchmarkConfig`) and its runs (:class:`Job`)."""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drill_env.agents.evaluation.episodes import EpisodeSettings
from drill_env.agents.evaluation.plants import NOMINAL, Plant
from drill_env.agents.registry import CONTROLLERS
from drill_env.params import PRESETS

# Voltages [V] of the grid per preset. Brake: 0.2-5 V across the three regimes (A = 0.116,
# Hopf B = 0.583, stick-slip from D = 1.781 V). No brake: every regime of Fig. 8(a)
# (B = 0.489, D = 0.600, E = 1.294, C = 1.430, F = 1.661 V).
FULL_GRID: dict[str, tuple[float, ...]] = {
    "brake": (0.2, 0.3, 0.4, 0.5, 0.7, 0.85, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0),
    "no_brake": (0.2, 0.3, 0.4, 0.55, 0.7, 0.85, 1.0, 1.15, 1.35, 1.5, 1.6, 1.8, 2.5, 3.5, 5.0),
}
QUICK_GRID: dict[str, tuple[float, ...]] = {
    "brake": (0.4, 1.0, 2.0, 4.0),
    "no_brake": (0.3, 0.55, 1.0, 1.5),
}
FULL_SEEDS = (0, 1, 2, 3, 4)
QUICK_SEEDS = (0,)


@dataclass(frozen=True)
class Job:
    controller: str
    preset: str
    voltage: float
    seed: int
    plant: str = NOMINAL

    @property
    def key(self) -> tuple[str, str, str, float, int]:
        return (self.controller, self.preset, self.plant, round(self.voltage, 9), self.seed)


@dataclass(frozen=True)
class BenchmarkConfig:
    """The grid and the episode settings of a benchmark."""

    presets: tuple[str, ...] = PRESETS
    controllers: tuple[str, ...] = CONTROLLERS
    voltages: Mapping[str, tuple[float, ...]] = field(default_factory=lambda: dict(FULL_GRID))
    seeds: tuple[int, ...] = FULL_SEEDS
    episode: EpisodeSettings = field(default_factory=EpisodeSettings)
    agents_dir: str | None = None  # where the trained policies are (default: results/agents)
    gains_file: str | None = None  # tuned gains (default: configs/agents/controllers.yaml)
    plants: tuple[Plant, ...] = (Plant(),)  # the rigs every controller runs on
    # the design model (a rig YAML): what every controller is built on and what the task knows
    # (target speed, regime); None: the preset's own model
    design_params: str | None = None
    # controllers of the user's own (label, spec): ``drill-env benchmark --controller``
    # (:mod:`drill_env.agents.evaluation.controller_spec`); their labels are in ``controllers``
    custom: tuple[tuple[str, str], ...] = ()
    # the user vouched for the policies from outside results/agents/ (those of ``agents_dir``
    # and of ``custom``; ``benchmark --trust-policies`` or a yes on a terminal): they load
    # (their files are code)
    trust_policies: bool = False

    def __post_init__(self) -> None:
        from drill_env.envs.task import VOLTAGE_LIMIT
        from drill_env.params import load_params

        if not self.presets:
            raise ValueError(f"presets: expected at least one of {list(PRESETS)}")
        for p in self.presets:
            if p not in PRESETS:
                raise ValueError(f"presets: {p!r} is not one of {list(PRESETS)}")
        if not self.controllers:
            raise ValueError(f"controllers: expected at least one of {list(CONTROLLERS)}")
        custom = tuple((str(label), str(spec)) for label, spec in self.custom)
        labels = [label for label, _ in custom]
        for label, spec in custom:
            from drill_env.agents.evaluation.controller_spec import check_spec

            if label in CONTROLLERS:
                raise ValueError(
                    f"--controller {spec!r}: the label {label!r} is a shipped controller's; give another as LABEL=SPEC"
                )
            if labels.count(label) > 1:
                raise ValueError(
                    f"--controller {spec!r}: the label {label!r} is given twice; give each its own as LABEL=SPEC"
                )
            check_spec(spec, trust_policies=self.trust_policies)
        object.__setattr__(self, "custom", custom)
        controllers = tuple(self.controllers) + tuple(lb for lb in labels if lb not in self.controllers)
        object.__setattr__(self, "controllers", controllers)
        for c in self.controllers:
            if c not in CONTROLLERS and c not in labels:
                raise ValueError(f"controllers: {c!r} is not one of {list(CONTROLLERS)}")
        if not self.seeds:
            raise ValueError("seeds: expected at least one seed")
        for s in self.seeds:
            if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
                raise ValueError(f"seeds: {s!r} is not an integer >= 0")
        volts = {}
        for p in self.presets:
            vs = tuple(float(v) for v in self.voltages.get(p, ()))
            if not vs:
                raise ValueError(f"voltages: no voltages for preset {p!r}")
            # with a design model, a voltage where it does not turn is a run that cannot be
            # made (named in the results, the others go on: runs.RunNotMade)
            uc1 = 0.0 if self.design_params is not None else load_params(p).uc1
            for v in vs:
                if not (math.isfinite(v) and uc1 < v <= VOLTAGE_LIMIT):
                    raise ValueError(
                        f"voltages: {v!r} V for {p!r} is outside the allowed range ({uc1:.4g}, {VOLTAGE_LIMIT:g}] V"
                    )
            volts[p] = vs
        if not self.plants or not all(isinstance(p, Plant) for p in self.plants):
            raise ValueError("plants: expected one or more Plant (default: the nominal model)")
        names = [p.name for p in self.plants]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"plants: the name(s) {dup} appear twice (a plant is named by its file's stem)")
        if self.design_params is not None:
            if len(self.presets) != 1:
                raise ValueError(
                    f"design_params: a design model is one rig; give one preset, got {list(self.presets)}"
                )
            object.__setattr__(self, "design_params", str(self.design_params))
            self.design_model()  # a bad file is named before anything runs
        object.__setattr__(self, "plants", tuple(self.plants))
        object.__setattr__(self, "voltages", volts)
        object.__setattr__(self, "presets", tuple(self.presets))
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))

    @classmethod
    def preset_grid(
        cls, presets: Sequence[str] = PRESETS, *, quick: bool = False, **kwargs: Any
    ) -> BenchmarkConfig:
        """The preset's grid (:data:`QUICK_GRID`, :data:`FULL_GRID`); with ``design_params`` as
        many voltages chosen from that model's own regimes (:func:`design_grid`)."""
        grid = QUICK_GRID if quick else FULL_GRID
        kwargs.setdefault("seeds", QUICK_SEEDS if quick else FULL_SEEDS)
        voltages = {p: grid[p] for p in presets}
        design = kwargs.get("design_params")
        if design is not None and len(tuple(presets)) == 1:
            p = tuple(presets)[0]
            voltages = {p: design_grid(_load_design(str(design)), len(grid[p]))}
        return cls(presets=tuple(presets), voltages=voltages, **kwargs)

    def spec_of(self, controller: str) -> str | None:
        """The spec of a controller of the user's own (None for a shipped one)."""
        return dict(self.custom).get(controller)

    def design_model(self):
        """The design model's ``RigParams`` (effects included), or None for the preset's own."""
        if self.design_params is None:
            return None
        return _load_design(self.design_params)

    def is_design_plant(self, plant: Plant) -> bool:
        """Whether ``plant`` is the design model itself (its open loop is then the analysis')."""
        return plant.is_nominal and self.design_params is None

    def plant(self, name: str) -> Plant:
        for p in self.plants:
            if p.name == name:
                return p
        raise ValueError(f"plant: {name!r} is not one of {[p.name for p in self.plants]}")

    def jobs(self) -> list[Job]:
        return [
            Job(c, p, v, s, plant.name)
            for p in self.presets
            for plant in self.plants
            for v in self.voltages[p]
            for s in self.seeds
            for c in self.controllers
        ]

    def settings_record(self) -> dict[str, Any]:
        """What must match for a resumed benchmark (the grid may grow)."""
        rec: dict[str, Any] = {"episode": self.episode.to_dict()}
        if self.custom:
            rec["custom_controllers"] = dict(self.custom)
        if any(not p.is_nominal for p in self.plants):
            rec["plants"] = [p.record() for p in self.plants if not p.is_nominal]
        if self.design_params is not None:
            from dataclasses import asdict

            rec["design_model"] = {"source": self.design_params, "params": asdict(self.design_model())}
        return rec


@functools.lru_cache(maxsize=8)
def _load_design(path: str):
    """The design model read from ``path`` (cached per process); ValueError naming the file."""
    from pathlib import Path

    from drill_env.params import load_params

    if not Path(path).is_file():
        raise ValueError(f"design_params: {path} is not a file (a rig YAML in the preset format)")
    try:
        return load_params(path)
    except ValueError as exc:
        raise ValueError(f"design_params: {path}: {exc}") from None


MIN_TARGET_SPEED = 0.1  # [rad/s] the env's floor of regime draws (TaskConfig.min_target_speed)


def design_regimes(params: Any) -> tuple[tuple[str, float, float], ...]:
    """The regimes of the design model ``params`` along (uc1, 5] V above the speed floor of the
    env's task: (regime, low, high) voltage intervals [V] from its own bifurcation analysis
    (:func:`drill_env.envs.regimes.operating_regimes`: Hopf points, stick-slip boundary)."""
    from drill_env.envs.equilibrium import nominal_params, nominal_voltage
    from drill_env.envs.regimes import operating_regimes
    from drill_env.envs.task import VOLTAGE_LIMIT

    model = nominal_params(params)
    if not model.uc1 < VOLTAGE_LIMIT:
        raise ValueError(
            f"design_params: the design model sticks up to {model.uc1:.4g} V, beyond the rig's "
            f"{VOLTAGE_LIMIT:g} V: it has no operating point"
        )
    floor = max(model.uc1, nominal_voltage(model, MIN_TARGET_SPEED))
    return tuple(
        (name, max(lo, floor), hi)
        for name, lo, hi in operating_regimes(model, VOLTAGE_LIMIT).intervals
        if hi > floor
    )


def describe_regimes(intervals: Sequence[tuple[str, float, float]]) -> str:
    """One line: each regime's voltages, and the regimes the model does not have."""
    from drill_env.envs.task import REGIMES

    text = ", ".join(f"{name} {lo:.3f}-{hi:.3f} V" for name, lo, hi in intervals)
    absent = [r for r in REGIMES if r not in {name for name, _, _ in intervals}]
    return text + (f"; no {' and no '.join(absent)} regime on this model" if absent else "")


def design_grid(params: Any, n: int, regimes: Sequence[str] | None = None) -> tuple[float, ...]:
    """``n`` voltages [V] spread over the regimes of the design model ``params``
    (:func:`design_regimes`): every regime it has gets at least one, the rest go by each
    regime's share of the voltage axis, evenly spaced inside its intervals (away from the
    boundaries). A rig that sticks above the preset grid's lowest voltage, or that has no
    equilibrium regime, thus gets operating points where it turns, in the regimes it has.
    ``regimes``: only these (all of them when the model has none of these)."""
    intervals = design_regimes(params)
    if regimes is not None and any(name in regimes for name, _, _ in intervals):
        intervals = tuple(iv for iv in intervals if iv[0] in regimes)
    names = list(dict.fromkeys(name for name, _, _ in intervals))
    if not names:
        raise ValueError("design_params: the design model has no operating point below 5 V")
    n = max(int(n), len(names))
    length = {r: sum(hi - lo for name, lo, hi in intervals if name == r) for r in names}
    total = sum(length.values())
    extra = n - len(names)
    share = {r: extra * length[r] / total for r in names}
    count = {r: 1 + int(math.floor(share[r])) for r in names}
    for r in sorted(names, key=lambda r: share[r] - math.floor(share[r]), reverse=True)[
        : n - sum(count.values())
    ]:
        count[r] += 1
    volts: list[float] = []
    for r in names:
        pieces = [(lo, hi) for name, lo, hi in intervals if name == r]
        for i in range(count[r]):
            x = (i + 0.5) / count[r] * length[r]
            for lo, hi in pieces:
                if x <= hi - lo:
                    volts.append(round(lo + x, 4))
                    break
                x -= hi - lo
    return tuple(sorted(set(volts)))
