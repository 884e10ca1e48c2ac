"""The experiments that identify a new rig: what to record, and the least that will do.

Each kind of run identifies a part of the model (Sec. 2.3 of the paper did the same on
its rig):

* **constant-voltage runs**, recorded after the transient has died out: the stuck runs
  bracket the stick boundary (point A, ``(T_sup + T_sl)/k_m``); the slip equilibria give
  points of the lower friction curve and, with the cycles, the upper disk's mean balance
  (``k_m``, ``T_sup``, ``b_up`` relative to the string); the cycles sweep the lower disk
  through the hump of its friction and show the string's resonance (``k_theta / J_l``);
* **random-level runs** (levels held 0.5-2 s, both signs): the accelerations after each
  step give the inertias and the motor constant, and the reversals the negative side of
  the upper friction (``T_sun``, ``b_un``).

The voltages of the sweep do not depend on the rig: from a little above zero to the
amplifier's 5 V, closer together at low voltage where the stick boundary and the first
Hopf point of a rig with parameters from x0.3 to x3 of the paper's lie.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from drill_env.recordings.synth import SynthConfig

__all__ = ["ExperimentPlan", "PLANS", "plan_text", "RUN_THAT_IDENTIFIES"]


@dataclass(frozen=True)
class ExperimentPlan:
    """A set of runs for identification (SI units)."""

    name: str
    voltages: tuple[float, ...]  # constant-voltage runs [V]
    random_runs: int  # random-level runs
    random_level_v: tuple[float, float]  # range of the random levels [V]
    hold_s: tuple[float, float]  # how long each random level is held [s]
    duration_s: float  # recorded length of every run [s]
    settle_s: float  # wait at the voltage before recording a constant-voltage run [s]
    sample_rate_hz: tuple[float, float]  # sample rates that do [Hz]

    @property
    def runs(self) -> int:
        return len(self.voltages) + self.random_runs

    def as_dict(self) -> dict:
        return asdict(self)


PLANS: dict[str, ExperimentPlan] = {
    "full": ExperimentPlan(
        name="full",
        voltages=(0.1, 0.25, 0.5, 0.8, 1.5, 3.0, 5.0),
        random_runs=3,
        random_level_v=(-5.0, 5.0),
        hold_s=(0.5, 2.0),
        duration_s=150.0,
        settle_s=60.0,
        sample_rate_hz=(250.0, 1000.0),
    ),
    "minimum": ExperimentPlan(
        name="minimum",
        voltages=(0.25, 1.0, 3.0),
        random_runs=1,
        random_level_v=(-5.0, 5.0),
        hold_s=(0.5, 2.0),
        duration_s=120.0,
        settle_s=60.0,
        sample_rate_hz=(250.0, 1000.0),
    ),
}

# For a parameter the data do not fix: the run that would.
RUN_THAT_IDENTIFIES: dict[str, str] = {
    "motor_constant": "random-level runs (the steps accelerate the upper disk) with the string stiffness "
    "known, and constant-voltage runs at three or more voltages above the stick boundary",
    "string_stiffness": "random-level runs with the motor constant known",
    "upper_inertia": "random-level runs (levels held 0.5-2 s)",
    "upper_static_pos": "constant-voltage runs at three or more positive voltages above the stick boundary",
    "upper_viscous_pos": "constant-voltage runs at three or more positive voltages above the stick boundary",
    "upper_static_neg": "runs at negative voltage (random levels in [-5, 5] V, or constant voltages below "
    "0 V)",
    "upper_viscous_neg": "runs at negative voltage (random levels in [-5, 5] V, or constant voltages below "
    "0 V)",
    "lower_inertia": "random-level runs, or constant-voltage runs in the torsional cycles",
    "lower_static": "constant-voltage runs just above the stick boundary (slip equilibria)",
    "lower_viscous": "constant-voltage runs up to 5 V (the lower disk fast)",
    "lower_hump_1": "constant-voltage runs across the cycles (the sweep of `drill-env identify --plan`)",
    "lower_hump_2": "constant-voltage runs across the cycles (the sweep of `drill-env identify --plan`)",
    "lower_hump_rate_1": "constant-voltage runs across the cycles (the sweep of `drill-env identify --plan`)",
    "lower_hump_rate_2": "constant-voltage runs across the cycles (the sweep of `drill-env identify --plan`)",
}


def _plan_lines(p: ExperimentPlan) -> list[str]:
    v = ", ".join(f"{x:g}" for x in p.voltages)
    lo, hi = p.random_level_v
    return [
        f"  {len(p.voltages)} constant-voltage runs at {v} V: hold each voltage {p.settle_s:g} s, then "
        f"record {p.duration_s:g} s",
        f"  {p.random_runs} random-level run(s): levels uniform in [{lo:g}, {hi:g}] V, each held "
        f"{p.hold_s[0]:g}-{p.hold_s[1]:g} s, record {p.duration_s:g} s",
    ]


def plan_text() -> str:
    """The protocol ``drill-env identify --plan`` prints."""
    full, least = PLANS["full"], PLANS["minimum"]
    lines = [
        "Experiments that identify every parameter of the rig model (eq. 10, 12, 14):",
        "",
        f"full plan ({full.runs} runs, about {full.runs * (full.duration_s + full.settle_s) / 60:.0f} min on the rig):",
        *_plan_lines(full),
        "",
        f"the minimum that will do ({least.runs} runs; wider intervals):",
        *_plan_lines(least),
        "",
        "What each run gives:",
        "  - stuck runs (nothing turns) and the first moving one bracket the stick boundary "
        "(T_sup + T_sl)/k_m; if even the lowest voltage turns the rig, add lower ones (0.05 V);",
        "  - slip equilibria (constant speed): points of the lower friction curve, k_theta x1 = T_l(x3);",
        "  - every run the upper disk rides without stopping: k_m u = T_sup + b_up x2 + k_theta x1 on average;",
        "  - torsional cycles: the hump of the lower friction and k_theta/J_l (the period);",
        "  - random levels: the inertias and the motor constant; negative levels: T_sun, b_un.",
        "",
        "Recording: t, u, theta_u, theta_l in one CSV per run (unwrapped encoder angles sharing the "
        f"untwisted zero), {full.sample_rate_hz[0]:g}-{full.sample_rate_hz[1]:g} Hz, plus dataset.json "
        "with 'preset' (the structure: brake or no_brake) and 'encoder_counts_per_rev'.",
        "One value the data cannot give (scaling every torque and inertia leaves the motion unchanged): "
        "the string stiffness k = G pi d^4 / (32 L) from the string's shear modulus G, diameter d and "
        "length L, or the motor constant; pass it as --known string_stiffness=VALUE.",
        "Synthetic data on a plan for any rig file: drill-env synth --plan full --params RIG.yaml ...",
    ]
    return "\n".join(lines)


def synth_config(plan: ExperimentPlan | str, rig: str, **overrides: Any) -> SynthConfig:
    """The :class:`~drill_env.recordings.synth.SynthConfig` that records ``rig`` (a preset or a
    rig YAML) on ``plan``; ``overrides`` set other fields (sample rate, encoder, ...)."""
    from drill_env.recordings.synth import SynthConfig

    p = PLANS[plan] if isinstance(plan, str) else plan
    fields: dict[str, Any] = {  # SynthConfig's fields by name
        "preset": str(rig),
        "voltages": p.voltages,
        "random_runs": p.random_runs,
        "duration_s": p.duration_s,
        "pre_roll_s": p.settle_s,
        "level_min_v": p.random_level_v[0],
        "level_max_v": p.random_level_v[1],
        "hold_min_s": p.hold_s[0],
        "hold_max_s": p.hold_s[1],
    }
    fields.update(overrides)
    return SynthConfig(**fields)
