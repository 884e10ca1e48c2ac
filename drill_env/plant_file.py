"""Plant files: a rig YAML in the preset format (parameters and ``effects:``) that may also
hold the measurement chain of that rig: ``actuator_delay`` [s] and a ``sensors:`` mapping of
:class:`~drill_env.sensors.SensorConfig` fields (``angle_noise_std`` [rad],
``speed_noise_std`` [rad/s], ``counts_per_rev``, ``cutoff_rad_s`` [rad/s], ``filter_order``,
``sample_rate_hz`` [Hz]) and a ``measurement:`` mapping of its encoders' reading errors
(:class:`~drill_env.measurement.MeasurementModel`: ``lower_encoder_eccentricity`` [rad],
``lower_encoder_phase`` [rad], the same for the upper encoder; the discrepancy workflow writes
it when it finds an eccentric encoder) and an ``amplifier:`` mapping of its amplifier's errors
(``gain`` [1], ``offset_v`` [V]: it applies ``gain u + offset_v`` when ``u`` is asked for, and
the recording holds ``u``). Everything a rig of the standard plant family varies fits in one.

``actuator_delay`` becomes the sensors' ``delay_samples`` (a whole number of sensor samples):
the environment delays the measurements, which in a loop with constant set points is the
same as delaying the voltage. :func:`read_plant_file` validates like a preset: a
:class:`~drill_env.params.ParameterError` naming the field and its allowed range.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from drill_env.measurement import MeasurementModel
from drill_env.params import ParameterError, RigParams, load_yaml

__all__ = [
    "AMPLIFIER_RANGES",
    "MAX_ACTUATOR_DELAY",
    "PLANT_FILE_KEYS",
    "PlantFile",
    "read_plant_file",
    "without_measurement",
]

PLANT_FILE_KEYS = ("actuator_delay", "sensors", "measurement", "amplifier")  # beside the rig's parameters
MAX_ACTUATOR_DELAY = 1.0  # [s]
AMPLIFIER_RANGES = {"gain": (0.5, 2.0), "offset_v": (-1.0, 1.0)}  # [1], [V]


@dataclass(frozen=True)
class PlantFile:
    """What a plant file holds."""

    params: RigParams  # the rig, effects included
    sensors: dict[str, Any] = field(default_factory=dict)  # SensorConfig fields, delay_samples included
    source: str = ""
    measurement: MeasurementModel = field(default_factory=MeasurementModel)  # the encoders' reading errors
    amplifier_gain: float = 1.0  # [1] applied voltage per asked-for volt
    amplifier_offset_v: float = 0.0  # [V] applied at 0 V asked for

    @property
    def amplifier_exact(self) -> bool:
        return self.amplifier_gain == 1.0 and self.amplifier_offset_v == 0.0

    @property
    def actuator_delay(self) -> float:
        """[s]"""
        from drill_env.sensors import SensorConfig

        n = int(self.sensors.get("delay_samples", 0))
        return n / float(self.sensors.get("sample_rate_hz", SensorConfig().sample_rate_hz))


def _sensor_fields() -> list[str]:
    from drill_env.sensors import SensorConfig

    return sorted(f.name for f in fields(SensorConfig) if f.name != "delay_samples")


def _sensors(data: dict[str, Any], where: str) -> dict[str, Any]:
    from drill_env.sensors import SensorConfig

    allowed = _sensor_fields()
    sensors = data.pop("sensors", None) or {}
    if not isinstance(sensors, Mapping):
        raise ParameterError(f"{where}: sensors: expected a mapping of {allowed}, got {sensors!r}")
    sensors = dict(sensors)
    unknown = sorted(set(sensors) - set(allowed))
    if unknown:
        hint = " (give the delay as actuator_delay [s])" if "delay_samples" in unknown else ""
        raise ParameterError(f"{where}: sensors: unknown field(s) {unknown}{hint}; allowed: {allowed}")
    try:
        cfg = SensorConfig(**sensors)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{where}: sensors.{exc}") from None
    if "actuator_delay" in data:
        d = data.pop("actuator_delay")
        ok = not isinstance(d, bool) and isinstance(d, (int, float)) and math.isfinite(d)
        if not (ok and 0 <= d <= MAX_ACTUATOR_DELAY):
            raise ParameterError(
                f"{where}: actuator_delay: {d!r} is outside the allowed range [0, {MAX_ACTUATOR_DELAY:g}] s"
            )
        n = round(float(d) * cfg.sample_rate_hz)
        if abs(n - float(d) * cfg.sample_rate_hz) > 1e-6:
            raise ParameterError(
                f"{where}: actuator_delay: {d!r} s is not a whole number of sensor samples "
                f"(1 / sample_rate_hz = {1 / cfg.sample_rate_hz:g} s)"
            )
        if n:
            sensors["delay_samples"] = int(n)
    return sensors


def _amplifier(data: dict[str, Any], where: str) -> tuple[float, float]:
    amp = data.pop("amplifier", None) or {}
    allowed = sorted(AMPLIFIER_RANGES)
    if not isinstance(amp, Mapping):
        raise ParameterError(f"{where}: amplifier: expected a mapping of {allowed}, got {amp!r}")
    unknown = sorted(set(amp) - set(allowed))
    if unknown:
        raise ParameterError(f"{where}: amplifier: unknown field(s) {unknown}; allowed: {allowed}")
    out = {"gain": 1.0, "offset_v": 0.0}
    for key, value in amp.items():
        lo, hi = AMPLIFIER_RANGES[key]
        ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
        if not (ok and lo <= value <= hi):
            unit = " V" if key == "offset_v" else ""
            raise ParameterError(
                f"{where}: amplifier.{key}: {value!r} is outside the allowed range [{lo:g}, {hi:g}]{unit}"
            )
        out[key] = float(value)
    return out["gain"], out["offset_v"]


def read_plant_file(path: str | Path) -> PlantFile:
    """Read and validate a plant file (module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise ParameterError(f"plant: {path} is not a file (a rig YAML in the preset format)")
    if p.suffix.lower() not in (".yaml", ".yml"):
        raise ParameterError(f"plant: {path} is not a YAML file (.yaml or .yml)")
    data = load_yaml(p, error=ParameterError)
    if not isinstance(data, Mapping):
        raise ParameterError(f"{p.name}: expected a mapping of parameter names to values")
    data = dict(data)
    sensors = _sensors(data, p.name)
    gain, offset = _amplifier(data, p.name)
    measurement = MeasurementModel()
    if "measurement" in data:
        try:
            measurement = MeasurementModel.from_mapping(data.pop("measurement"), source=p.name)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
    return PlantFile(
        params=RigParams.from_dict(data, source=p.name),
        sensors=sensors,
        source=str(p),
        measurement=measurement,
        amplifier_gain=gain,
        amplifier_offset_v=offset,
    )


def without_measurement(plant: PlantFile, reader: str) -> PlantFile:
    """``plant`` when it has no measurement model and an exact amplifier; else a ParameterError:
    ``reader`` (a command whose sensor model has no encoder eccentricity and whose voltage is
    the one applied) would drop them."""
    if not plant.amplifier_exact:
        name = Path(plant.source).name or "plant"
        raise ParameterError(
            f"{name}: amplifier: {reader} applies the voltage asked for and cannot apply this file's "
            f"amplifier errors (gain {plant.amplifier_gain:g}, offset {plant.amplifier_offset_v:g} V); "
            "allowed: a plant file without an amplifier section (drill-env synth --plant records through it)"
        )
    if plant.measurement.active:
        from drill_env.measurement import measurement_text

        name = Path(plant.source).name or "plant"
        raise ParameterError(
            f"{name}: measurement: {reader} simulates the rig's encoders without eccentricity and cannot "
            f"apply this file's ({measurement_text(plant.measurement)}); allowed: a plant file without a "
            "measurement section (delete it to use the plant alone; drill-env synth --plant records "
            "through it)"
        )
    return plant
