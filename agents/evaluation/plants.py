"""Plants: the rig a controller runs on, which need not be the model it was designed on.

Every controller is designed on the nominal model of its preset (gains tuned, policies
trained). A :class:`Plant` is what it then drives:

* ``nominal``: the preset's own model (the paper's);
* a *plant file* (:meth:`Plant.from_path`): a rig YAML in the preset format, effects
  included (e.g. a discrepancy ``model.yaml``), and optionally the measurement chain that
  rig has: ``actuator_delay`` [s] and a ``sensors:`` mapping (``angle_noise_std`` [rad],
  ``speed_noise_std`` [rad/s], ``counts_per_rev``, ``cutoff_rad_s`` [rad/s],
  ``filter_order``, ``sample_rate_hz`` [Hz]); that whole rig, whatever the preset;
* a *variant* of the preset's model: some identified parameters scaled, some effects of the
  library switched on, or another measurement chain (:func:`standard_family`).

The standard family (``drill-env benchmark --plants family``) is what a rig built to the
paper's drawings may plausibly be: each identified parameter off by what its identification
allows, each effect of the library at a magnitude the paper or the rig's hardware suggests,
a slower loop and a noisier encoder. Magnitudes (relative to the preset's model):

==========================  ==========================================================
``Jl_x0.90``/``Jl_x1.10``    lower-disk inertia J_l -10 % / +10 %
``ktheta_x0.90``/``_x1.10``  string stiffness k_theta -10 % / +10 %
``Tsl_x0.80``/``_x1.20``     lower static friction T_sl -20 % / +20 %
``hump_x0.80``/``_x1.20``    the hump of the lower friction, T_1 and T_2 together,
                             -20 % / +20 % (each alone would make the no-brake friction,
                             where T_1 and T_2 nearly cancel, negative at low speed)
``km_x0.95``/``_x1.05``      motor constant k_m -5 % / +5 %
``position_friction_lower``  once-per-revolution lower friction modulation a1 = 0.12
                             (the paper's Sec. 4.1 observation on the rig)
``position_friction_upper``  the same at the upper disk, a1 = 0.12
``string_damping``           torsional damping b_theta = 2e-3 N m s/rad (about 2 % of
                             critical for the torsional mode)
``motor_lag``                motor torque lag L/R = 20 ms
``friction_memory``          frictional lag of the Stribeck part, tau_f = 0.1 s
``delay_10ms``               10 ms transport delay of the measurements (in a loop with
                             constant set points equivalent to a 10 ms actuator delay;
                             ``actuator_delay: 0.01`` in a plant file)
``angle_noise_3mrad``        3 mrad Gaussian noise on both encoder angles (about one count)
==========================  ==========================================================

Every member of the family is also a plant file (:meth:`Plant.to_file`, :func:`write_family`):
``drill-env benchmark --plants FOLDER`` runs on a folder of them as ``--plants family`` does.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from drill_env.plant_file import PLANT_FILE_KEYS  # re-exported: a plant file's keys beside the rig's

__all__ = ["NOMINAL", "FAMILY", "PLANT_FILE_KEYS", "Plant", "standard_family", "plants_in", "write_family"]

NOMINAL = "nominal"  # the plant that is the preset's own model (the paper's)
FAMILY = "family"  # the keyword of the standard family


def _sensor_fields() -> set[str]:
    from drill_env.sensors import SensorConfig

    return {f.name for f in fields(SensorConfig)}


@dataclass(frozen=True, eq=False)
class Plant:
    """One plant (see the module docstring). ``params`` is a whole rig read from a file;
    otherwise the plant is the preset's model with ``scale`` (relative factors on its
    parameters), ``effects`` (effect values) and ``sensors`` (fields of the measurement
    chain) applied; all empty: the nominal model."""

    name: str = NOMINAL
    params: Any = None  # RigParams from a file: the whole rig, for any preset
    source: str = ""  # where it was read from
    scale: Mapping[str, float] = field(default_factory=dict)
    effects: Mapping[str, float] = field(default_factory=dict)
    sensors: Mapping[str, Any] = field(default_factory=dict)
    description: str = ""

    def __post_init__(self) -> None:
        from drill_env.params import ModelEffects, RigParams

        if not isinstance(self.name, str) or not self.name or any(c in self.name for c in '/\\:*?"<>| '):
            raise ValueError(f"plant: name {self.name!r} must be a non-empty file-name-safe string")
        top = {f.name for f in fields(RigParams)} - {"effects", "name", "description"}
        for k, v in self.scale.items():
            if k not in top:
                raise ValueError(f"plant {self.name}: scale: unknown parameter {k!r}; allowed: {sorted(top)}")
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 10:
                raise ValueError(f"plant {self.name}: scale.{k}: {v!r} is outside the allowed range (0, 10)")
        eff = {f.name for f in fields(ModelEffects)}
        for k in self.effects:
            if k not in eff:
                raise ValueError(f"plant {self.name}: effects: unknown effect {k!r}; allowed: {sorted(eff)}")
        for k in self.sensors:
            if k not in _sensor_fields():
                raise ValueError(
                    f"plant {self.name}: sensors: unknown field {k!r}; allowed: {sorted(_sensor_fields())}"
                )
        if self.sensors:
            from drill_env.sensors import SensorConfig

            try:
                SensorConfig(**dict(self.sensors))
            except (TypeError, ValueError) as exc:
                raise ValueError(f"plant {self.name}: sensors.{exc}") from None
        if self.params is not None and (self.scale or self.effects):
            raise ValueError(f"plant {self.name}: a rig read from a file takes no scale or effects")
        if self.name == NOMINAL and not self.is_nominal:
            raise ValueError(f"plant: the name {NOMINAL!r} is the preset's own model")
        for name in ("scale", "effects", "sensors"):
            object.__setattr__(self, name, dict(getattr(self, name)))

    @classmethod
    def from_path(cls, path: str | Path) -> Plant:
        """A plant from a plant file (module docstring); its name is the file's stem. Raises
        ``ParameterError`` (a ValueError) naming the field for a bad file."""
        from drill_env.plant_file import read_plant_file, without_measurement

        p = Path(path)
        f = without_measurement(read_plant_file(p), "the benchmark")
        params, sensors = f.params, f.sensors
        if p.stem in (NOMINAL, FAMILY):
            raise ValueError(f"plant: {path}: the name {p.stem!r} is reserved; rename the file")
        return cls(name=p.stem, params=params, source=str(p), sensors=sensors, description=params.description)

    def to_file(self, path: str | Path, preset: str) -> Path:
        """Write the plant as a plant file (its rig under ``preset``, effects, actuator delay and
        sensors): :meth:`from_path` reads it back as the same plant."""
        import yaml

        from drill_env.params import load_params
        from drill_env.sensors import SensorConfig

        rig = self.rig(preset) or load_params(preset)
        data = rig.to_dict()
        data["name"] = self.name
        if self.description:
            data["description"] = self.description
        sensors = dict(self.sensors)
        n = sensors.pop("delay_samples", 0)
        if n:
            rate = float(sensors.get("sample_rate_hz", SensorConfig().sample_rate_hz))
            data["actuator_delay"] = n / rate
        if sensors:
            data["sensors"] = sensors
        from drill_env.outputs import atomic_write_text

        return atomic_write_text(path, yaml.safe_dump(data, sort_keys=False))

    @property
    def is_nominal(self) -> bool:
        return self.params is None and not self.scale and not self.effects and not self.sensors

    def rig(self, preset: str):
        """The plant's ``RigParams`` when it runs under ``preset`` (None: the preset's own)."""
        if self.params is not None:
            return self.params
        if not self.scale and not self.effects:
            return None
        from drill_env.params import load_params

        base = load_params(preset)
        over: dict[str, Any] = {k: getattr(base, k) * f for k, f in self.scale.items()}
        over.update(self.effects)
        return base.replace(**over)

    def env_overrides(self, base: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Environment arguments of the plant's measurement chain, merged into ``base``."""
        out = dict(base or {})
        if self.sensors:
            sensors = out.get("sensors") or {}
            if not isinstance(sensors, Mapping):
                sensors = asdict(sensors)
            out["sensors"] = {**sensors, **self.sensors}
        return out

    def record(self) -> dict[str, Any]:
        """What identifies the plant's rig (for resuming a benchmark safely)."""
        rec: dict[str, Any] = {"name": self.name}
        if self.params is not None:
            rec.update(source=self.source, params=asdict(self.params))
        for name in ("scale", "effects", "sensors"):
            if getattr(self, name):
                rec[name] = dict(getattr(self, name))
        return rec

    def effects_on(self, preset: str) -> list[str]:
        rig = self.rig(preset)
        return [] if rig is None else list(rig.effects.active)

    def friction_family(self) -> str | None:
        """For a rig read from a file: the preset whose lower-disk friction its own is
        closest to (None otherwise)."""
        if self.params is None:
            return None
        from drill_env.params import PRESETS, load_params

        names = ("lower_static", "lower_viscous", "lower_hump_1", "lower_hump_2")

        def dist(preset: str) -> float:
            ref = load_params(preset)
            return sum(
                abs(getattr(self.params, f) - getattr(ref, f)) / max(abs(getattr(ref, f)), 1e-12)
                for f in names
            )

        return min(PRESETS, key=dist)


def _scaled(symbol: str, parameters: str | tuple[str, ...], factor: float, what: str) -> Plant:
    pct = f"{100 * (factor - 1):+.0f} %"
    names = (parameters,) if isinstance(parameters, str) else parameters
    return Plant(
        name=f"{symbol}_x{factor:.2f}", scale={p: factor for p in names}, description=f"{what} {pct}"
    )


def standard_family() -> tuple[Plant, ...]:
    """The standard family of plants (module docstring), the nominal model first."""
    scaled = [
        ("Jl", "lower_inertia", 0.10, "lower-disk inertia J_l"),
        ("ktheta", "string_stiffness", 0.10, "string stiffness k_theta"),
        ("Tsl", "lower_static", 0.20, "lower static friction T_sl"),
        ("hump", ("lower_hump_1", "lower_hump_2"), 0.20, "hump of the lower friction (T_1 and T_2)"),
        ("km", "motor_constant", 0.05, "motor constant k_m"),
    ]
    plants = [Plant()]
    for symbol, parameter, rel, what in scaled:
        plants += [_scaled(symbol, parameter, 1 - rel, what), _scaled(symbol, parameter, 1 + rel, what)]
    plants += [
        Plant(
            "position_friction_lower",
            effects={"lower_position_amp_1": 0.12},
            description="lower friction modulated once per revolution, a1 = 0.12 (paper Sec. 4.1)",
        ),
        Plant(
            "position_friction_upper",
            effects={"upper_position_amp_1": 0.12},
            description="upper friction modulated once per revolution, a1 = 0.12",
        ),
        Plant(
            "string_damping",
            effects={"string_damping": 2e-3},
            description="string damping b_theta = 2e-3 N m s/rad",
        ),
        Plant("motor_lag", effects={"motor_lag": 0.02}, description="motor torque lag 20 ms"),
        Plant(
            "friction_memory",
            effects={"friction_lag": 0.1},
            description="frictional lag of the lower Stribeck friction 0.1 s",
        ),
        Plant(
            "delay_10ms",
            sensors={"delay_samples": 10},
            description="10 ms measurement delay (1 kHz sensor clock)",
        ),
        Plant(
            "angle_noise_3mrad",
            sensors={"angle_noise_std": 3e-3},
            description="3 mrad Gaussian noise on the encoder angles",
        ),
    ]
    return tuple(plants)


def write_family(folder: str | Path, preset: str) -> list[Path]:
    """The standard family of ``preset`` as plant files in ``folder`` (the nominal model left
    out: it is ``--plant nominal``), one per plant, named by it."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    return [q.to_file(out / f"{q.name}.yaml", preset) for q in standard_family() if not q.is_nominal]


def plants_in(folder: str | Path) -> list[Plant]:
    """Every plant file (``*.yaml``, ``*.yml``) of ``folder``, by name."""
    d = Path(folder)
    if not d.is_dir():
        raise ValueError(f"plants: {folder} is not a folder of plant files")
    files = sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in (".yaml", ".yml"))
    if not files:
        raise ValueError(f"plants: {folder} holds no plant file (*.yaml)")
    return [Plant.from_path(p) for p in files]
