"""Rigs far from the paper's, written as ``drill-env identify`` writes its ``rig.yaml``: each is
a preset with some parameters scaled by 0.35-3x, chosen for what its own bifurcation analysis
gives (regimes of :func:`drill_env.envs.regimes.operating_regimes`, checked in the tests):

* ``brake_sticky``: sticks up to 0.537 V (the braked quick grid starts at 0.4 V); equilibrium
  to 1.68 V, limit cycle to 4.41 V, stick-slip to 5 V;
* ``no_brake_sticky``: sticks up to 0.555 V; equilibrium, limit cycle, stick-slip, limit
  cycle and equilibrium again;
* ``brake_all_stick_slip``: no stable equilibrium anywhere (no Hopf point), stick-slip over
  the whole range (uc1 = 0.169 V to 5 V): no equilibrium and no limit-cycle regime.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from drill_env.params import RigParams, load_params

FACTORS: dict[str, tuple[str, dict[str, float]]] = {
    "brake_sticky": (
        "brake",
        {
            "motor_constant": 0.4,
            "upper_static_pos": 1.8,
            "lower_static": 2.0,
            "upper_inertia": 2.0,
            "string_stiffness": 0.6,
        },
    ),
    "no_brake_sticky": (
        "no_brake",
        {"motor_constant": 0.35, "upper_static_pos": 2.0, "lower_static": 3.0, "lower_inertia": 1.8},
    ),
    "brake_all_stick_slip": (
        "brake",
        {
            "lower_hump_1": 0.35,
            "lower_hump_rate_1": 0.35,
            "lower_hump_2": 1.5,
            "lower_hump_rate_2": 3.0,
            "lower_viscous": 3.0,
            "lower_static": 3.0,
        },
    ),
}


def identified_rig(name: str) -> RigParams:
    """The rig ``name`` of :data:`FACTORS`."""
    preset, factors = FACTORS[name]
    base = load_params(preset)
    return base.replace(
        **{k: float(getattr(base, k)) * f for k, f in factors.items()},
        name=name,
        description=f"{preset} rig identified from recordings ({name})",
    )


def write_rig(name: str, folder: Path) -> Path:
    """``folder/<name>.yaml`` in the format of ``drill-env identify``'s rig.yaml."""
    params = identified_rig(name)
    path = Path(folder) / f"{name}.yaml"
    header = (
        f"# {params.description}\n"
        "# written by `drill-env identify`; intervals and methods in identification.json\n"
    )
    path.write_text(header + yaml.safe_dump(params.to_dict(), sort_keys=False))
    return path
