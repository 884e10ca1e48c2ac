"""The model against the measurements on the rig quoted in the paper (Sec. 4 and 4.1).

The experiments were made with the brake applied (preset ``brake``). The paper quotes:
no torsional vibration at 0.5 V; a limit cycle at 0.7 V with its dominant frequency at
0.21-0.22 Hz; 0.25 Hz at 1.0 V; mean lower-disk speeds 0.0911, 0.6411 and 1.0077 rad/s
at 0.2, 0.5 and 0.7 V. The model's steady state at each voltage is the stable
equilibrium or the stable limit cycle; its mean lower-disk speed over a cycle is the
lower-disk angle turned in one period divided by the period.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from drill_env.analysis.equilibria import equilibria, hopf_points, nominal_vector
from drill_env.analysis.shooting import LimitCycle, limit_cycle
from drill_env.params import RigParams

__all__ = ["RIG_MEASUREMENTS", "ComparisonRow", "RigComparison", "rig_comparison"]

# (quantity, voltage [V], value, unit); a frequency band is (low, high).
RIG_MEASUREMENTS = (
    ("torsional vibration", 0.5, "none", ""),
    ("torsional vibration", 0.7, "limit cycle", ""),
    ("dominant frequency", 0.7, (0.21, 0.22), "Hz"),
    ("dominant frequency", 1.0, 0.25, "Hz"),
    ("mean lower-disk speed", 0.2, 0.0911, "rad/s"),
    ("mean lower-disk speed", 0.5, 0.6411, "rad/s"),
    ("mean lower-disk speed", 0.7, 1.0077, "rad/s"),
)


# The paper's parameter equations of each preset: motor and upper disk (11), upper friction
# (13), lower disk (15), and the lower friction with the brake (17) or without it (16).
PRESET_EQUATIONS = {"brake": "11, 13, 15, 17", "no_brake": "11, 13, 15, 16"}


@dataclass(frozen=True)
class ComparisonRow:
    quantity: str
    u: float  # [V]
    rig: str
    model: str
    relative_error: float | None  # (model - rig) / rig; to the middle of a band
    agrees: bool | None  # for qualitative rows, and for bands (model inside the band)
    note: str = ""


@dataclass
class RigComparison:
    preset: str
    rows: list[ComparisonRow]
    hopf_u: float | None
    cycles: dict[float, LimitCycle | None] = field(repr=False, default_factory=dict)

    def to_markdown(self) -> str:
        eqs = PRESET_EQUATIONS.get(self.preset)
        source = f"the paper's model, eq. {eqs}" if eqs else "parameters not from the paper"
        lines = [
            "# The model against the rig",
            "",
            f"Preset `{self.preset}` ({source}) against the measurements "
            "quoted in Mihajlovic et al. (2004), Sec. 4 and 4.1. The model's value is that of its "
            "stable steady state at the voltage: the equilibrium, or the limit cycle (frequency "
            "1/period; mean speed = lower-disk angle per period / period). Relative error = "
            "(model - rig) / rig, to the middle of a band.",
            "",
            "| quantity | u [V] | rig (paper) | model | relative error | agrees |",
            "|---|---|---|---|---|---|",
        ]
        for r in self.rows:
            err = "" if r.relative_error is None else f"{100 * r.relative_error:+.1f} %"
            ok = "" if r.agrees is None else ("yes" if r.agrees else "no")
            lines.append(f"| {r.quantity} | {r.u:g} | {r.rig} | {r.model} | {err} | {ok} |")
        lines.append("")
        if self.hopf_u is not None:
            lines.append(
                f"The model's supercritical Hopf point B is at u = {self.hopf_u:.4f} V, between the rig's "
                "0.5 V (no vibration) and 0.7 V (limit cycle)."
                if 0.5 < self.hopf_u < 0.7
                else f"The model's supercritical Hopf point B is at u = {self.hopf_u:.4f} V, "
                "outside the rig's bracket 0.5-0.7 V."
            )
        notes = [r for r in self.rows if r.note]
        if notes:
            lines.append("")
            for r in notes:
                lines.append(f"- {r.quantity} at {r.u:g} V: {r.note}")
        lines.append("")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {
            "preset": self.preset,
            "hopf_B_u": self.hopf_u,
            "rows": [r.__dict__ for r in self.rows],
        }

    def save(self, path: str | Path) -> None:
        path = Path(path)
        path.write_text(self.to_markdown())
        path.with_suffix(".json").write_text(json.dumps(self.to_dict(), indent=1) + "\n")


def _mean_speed(cycle: LimitCycle) -> float:
    orb = cycle.orbit(n=2000)
    return float((orb.theta_l[-1] - orb.theta_l[0]) / (orb.t[-1] - orb.t[0]))


def rig_comparison(params: RigParams | str = "brake") -> RigComparison:
    """Compare the model's steady states with the rig measurements of the paper."""
    preset = params if isinstance(params, str) else params.name
    params, _ = nominal_vector(params)
    cycles: dict[float, LimitCycle | None] = {}

    def cycle_at(u: float) -> LimitCycle | None:
        if u not in cycles:
            cycles[u] = limit_cycle(params, u)
        return cycles[u]

    rows: list[ComparisonRow] = []
    for quantity, u, rig, unit in RIG_MEASUREMENTS:
        c = cycle_at(u)
        eq = equilibria(params, u)[0]
        if quantity == "torsional vibration":
            if c is not None:
                desc = "limit cycle" + (" with stick-slip" if c.stick_slip else " (no stick-slip)")
                desc += f", x3 in [{c.x3_min:.3f}, {c.x3_max:.3f}] rad/s"
            else:
                desc = "none (stable equilibrium)" if eq.stable else "none found"
            agrees = (c is None) == (rig == "none")
            rows.append(ComparisonRow(quantity, u, rig, desc, None, agrees))
        elif quantity == "dominant frequency":
            if c is None:
                rows.append(ComparisonRow(quantity, u, _fmt(rig, unit), "no oscillation", None, False))
                continue
            f = c.frequency
            if isinstance(rig, tuple):
                mid = 0.5 * (rig[0] + rig[1])
                agrees = rig[0] <= f <= rig[1]
                rig_s = f"{rig[0]:g}-{rig[1]:g} {unit}"
                note = (
                    ""
                    if agrees
                    else (
                        f"the model is {100 * (f - rig[1]) / rig[1]:+.1f} % off the nearest edge of the band"
                        if f > rig[1]
                        else f"the model is {100 * (f - rig[0]) / rig[0]:+.1f} % off the nearest edge of the band"
                    )
                )
            else:
                mid = rig
                agrees = None
                rig_s = _fmt(rig, unit)
                note = ""
            rows.append(
                ComparisonRow(
                    quantity,
                    u,
                    rig_s,
                    f"{f:.4f} {unit} (period {c.period:.3f} s)",
                    (f - mid) / mid,
                    agrees,
                    note,
                )
            )
        else:
            if c is not None:
                mean = _mean_speed(c)
                desc = f"{mean:.4f} {unit} (limit-cycle mean)"
            else:
                mean = eq.x3
                desc = f"{mean:.4f} {unit} (equilibrium)"
            note = ""
            if u < 0.6:
                note = "the paper attributes the measured speed's slow oscillation here to position-dependent friction, which the model lacks"
            rows.append(ComparisonRow(quantity, u, _fmt(rig, unit), desc, (mean - rig) / rig, None, note))
    hopf = [h for h in hopf_points(params, 0.0, math.inf) if h.supercritical and h.x_eq[2] > 0]
    return RigComparison(preset=str(preset), rows=rows, hopf_u=hopf[0].u if hopf else None, cycles=cycles)


def _fmt(value, unit: str) -> str:
    return f"{value:g} {unit}".strip()
