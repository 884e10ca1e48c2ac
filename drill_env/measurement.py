"""The measurement model of a rig: how its encoders read the disks' angles.

The plant (:class:`~drill_env.params.RigParams`) says how the rig moves; a measurement model
says how its angles are read. The one error it holds is an encoder's *eccentricity*: an
encoder disk mounted off-centre (or tilted) on its shaft reads

    reading = theta + a sin(theta + phi)

once per revolution, ``a`` [rad] the amplitude and ``phi`` [rad] the phase, for either disk's
encoder. It exerts no torque: the rig moves as the plant says, only the readings err. The
discrepancy workflow finds it (``encoder_eccentricity_lower`` / ``_upper``) and writes it
as the ``measurement:`` section of ``model.yaml``::

    measurement:
      lower_encoder_eccentricity: 0.008  # a [rad]
      lower_encoder_phase: 1.2           # phi [rad]

Plant files (:mod:`drill_env.plant_file`) hold such a section and ``drill-env synth
--plant`` applies it to the recorded angles (before the encoder's quantisation); the rig
loader :func:`drill_env.params.load_params`, which reads the plant alone, refuses a file
that has one rather than drop it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "MAX_ENCODER_ECCENTRICITY",
    "MeasurementModel",
    "measurement_text",
    "write_model_yaml",
]

# [rad] the largest eccentricity a measurement model holds: beyond it the reading error is no
# small once-per-revolution error of a mounted encoder (0.2 rad is 11 degrees)
MAX_ENCODER_ECCENTRICITY = 0.2
_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class MeasurementModel:
    """Angle reading errors of the rig's encoders; all zero: the readings are the angles."""

    upper_encoder_eccentricity: float = 0.0  # a [rad], upper encoder
    upper_encoder_phase: float = 0.0  # phi [rad], in [0, 2 pi)
    lower_encoder_eccentricity: float = 0.0  # a [rad], lower encoder
    lower_encoder_phase: float = 0.0  # phi [rad], in [0, 2 pi)

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ValueError(f"measurement.{f.name}: expected a number, got {v!r}")
            v = float(v)
            if f.name.endswith("eccentricity"):
                ok, allowed = (
                    math.isfinite(v) and 0.0 <= v < MAX_ENCODER_ECCENTRICITY,
                    (f"[0, {MAX_ENCODER_ECCENTRICITY:g}) rad"),
                )
            else:
                ok, allowed = math.isfinite(v) and 0.0 <= v < _TWO_PI, "[0, 2 pi) rad"
            if not ok:
                raise ValueError(
                    f"measurement.{f.name}: {v!r} is outside the allowed range; allowed: {allowed}"
                )
            object.__setattr__(self, f.name, v)

    @classmethod
    def from_mapping(cls, value: Any, *, source: str = "measurement") -> MeasurementModel:
        """A measurement model from a file's ``measurement:`` mapping; a ValueError naming
        ``source`` and the field for anything else."""
        allowed = sorted(f.name for f in fields(cls))
        if not isinstance(value, Mapping):
            raise ValueError(f"{source}: measurement: expected a mapping of {allowed}, got {value!r}")
        unknown = sorted(str(k) for k in set(value) - set(allowed))
        if unknown:
            raise ValueError(f"{source}: measurement: unknown field(s) {unknown}; allowed: {allowed}")
        try:
            return cls(**dict(value))
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None

    @property
    def active(self) -> tuple[str, ...]:
        """The encoders that err ("upper", "lower")."""
        return tuple(d for d in ("upper", "lower") if getattr(self, f"{d}_encoder_eccentricity") > 0.0)

    def to_dict(self) -> dict[str, float]:
        """The fields of the encoders that err (an empty mapping: exact readings)."""
        return {
            f"{d}_encoder_{k}": getattr(self, f"{d}_encoder_{k}")
            for d in self.active
            for k in ("eccentricity", "phase")
        }

    def reading_error(self, disk: str, theta: np.ndarray) -> np.ndarray:
        """``a sin(theta + phi)`` [rad] of ``disk``'s encoder at the true angles ``theta``."""
        if disk not in ("upper", "lower"):
            raise ValueError(f"disk: {disk!r}; allowed: upper, lower")
        a = getattr(self, f"{disk}_encoder_eccentricity")
        theta = np.asarray(theta, dtype=float)
        if a == 0.0:
            return np.zeros_like(theta)
        return a * np.sin(theta + getattr(self, f"{disk}_encoder_phase"))

    def read(self, theta_u: np.ndarray, theta_l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The readings of the true angles (before the encoder's quantisation)."""
        return (
            np.asarray(theta_u, dtype=float) + self.reading_error("upper", theta_u),
            np.asarray(theta_l, dtype=float) + self.reading_error("lower", theta_l),
        )

    def true_angle(self, disk: str, reading: float) -> float:
        """The angle whose reading is ``reading`` (fixed point; ``a < 1`` makes it a contraction)."""
        theta = float(reading)
        for _ in range(30):
            theta = float(reading) - float(self.reading_error(disk, np.array(theta)))
        return theta

    def reading_slope(self, disk: str, theta: float) -> float:
        """d reading / d theta = 1 + a cos(theta + phi) at the true angle ``theta``."""
        a = getattr(self, f"{disk}_encoder_eccentricity")
        return 1.0 + a * math.cos(theta + getattr(self, f"{disk}_encoder_phase"))


def measurement_text(m: MeasurementModel) -> str:
    """One line: what the measurement model holds."""
    if not m.active:
        return "exact readings"
    return "; ".join(
        f"{d} encoder eccentricity {getattr(m, f'{d}_encoder_eccentricity'):.4g} rad at phase "
        f"{getattr(m, f'{d}_encoder_phase'):.4g} rad"
        for d in m.active
    )


def write_model_yaml(params, path: str | Path, measurement: MeasurementModel | None = None) -> Path:
    """Write a rig YAML (``params``, its ``effects:`` included) with the ``measurement:``
    section of ``measurement`` when it holds a reading error: a plant file
    (:func:`drill_env.plant_file.read_plant_file` reads it back)."""
    import yaml

    data = params.to_dict()
    if measurement is not None and measurement.active:
        data["measurement"] = measurement.to_dict()
    from drill_env.outputs import atomic_write_text

    return atomic_write_text(path, yaml.safe_dump(data, sort_keys=False))
