"""Rig parameters: a frozen, validated dataclass in SI units, and the presets.

The nominal model is the one of Mihajlovic et al. (2004), eq. (10)/(36) with the
friction laws (12) and (14). :class:`ModelEffects` holds the physical effects the
paper neglected by assumption or found missing (Sec. 2.2 and 4.1); all are off by
default, so a preset is exactly the paper's model.

Presets live in ``configs/rig/<name>.yaml``; a user file has the same keys.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "DISSIPATIVE_CHECK_SPEEDS",
    "ModelEffects",
    "RigParams",
    "ParameterError",
    "available_presets",
    "load_params",
    "resolve_params",
    "load_yaml",
    "MAX_YAML_BYTES",
    "RIG_VOLTAGE_LIMIT",
    "IDENTIFIED_SPEED_RAD_S",
    "PRESETS",
    "validity_warnings",
]


class ParameterError(ValueError):
    """A rig parameter is missing, unknown or outside its allowed range."""


RIG_VOLTAGE_LIMIT = 5.0  # [V] the amplifier input range of the rig, Sec. 2.1
# [rad/s] the lower-disk speed up to which a preset's friction was identified from rig data:
# the brake's measured friction reached about 12.6 rad/s (Sec. 4 of the paper); the no-brake
# friction has no stated limit.
IDENTIFIED_SPEED_RAD_S: dict[str, float] = {"brake": 12.6}
# The presets shipped with the package (``configs/rig/<name>.yaml``): the lower disk with the
# brake, parameters (17), the configuration of the experiments in Sec. 4; and without it, (16).
PRESETS: tuple[str, ...] = ("brake", "no_brake")
# The parameters the paper identified from the rig (eq. 11, 13, 15 and 16/17), RigParams
# field names: what a real rig may have a few percent off (synth's --param-error) and what the
# discrepancy workflow recalibrates.
IDENTIFIED_PARAMETERS: tuple[str, ...] = (
    "motor_constant",
    "upper_inertia",
    "upper_static_pos",
    "upper_static_neg",
    "upper_viscous_pos",
    "upper_viscous_neg",
    "lower_inertia",
    "string_stiffness",
    "lower_static",
    "lower_viscous",
    "lower_hump_1",
    "lower_hump_2",
    "lower_hump_rate_1",
    "lower_hump_rate_2",
)


# [rad/s] where a rig's lower slip friction must be positive (eq. 4, checked by RigParams)
DISSIPATIVE_CHECK_SPEEDS = np.linspace(0.0, 50.0, 2001)
DISSIPATIVE_CHECK_SPEEDS.flags.writeable = False


def validity_warnings(
    preset: str, *, voltages: tuple[float, float] | None = None, max_speed: float | None = None
) -> list[str]:
    """Where an analysis leaves the model's validated range, one sentence each (empty: inside).

    ``voltages`` is the (lowest, highest) voltage analysed [V], ``max_speed`` the largest
    |lower-disk speed| reached [rad/s]; ``preset`` names the friction model (its identified
    speed range, :data:`IDENTIFIED_SPEED_RAD_S`).
    """
    notes: list[str] = []
    if voltages is not None:
        lo, hi = voltages
        if hi > RIG_VOLTAGE_LIMIT or lo < -RIG_VOLTAGE_LIMIT:
            what = f"u = {lo:g} V is" if lo == hi else f"voltages from {lo:g} to {hi:g} V are"
            notes.append(
                f"{what} outside the rig's +-{RIG_VOLTAGE_LIMIT:g} V amplifier range: the model is "
                "unvalidated there"
            )
    limit = IDENTIFIED_SPEED_RAD_S.get(preset)
    if max_speed is not None and limit is not None and max_speed > limit:
        notes.append(
            f"the lower disk reaches {max_speed:.4g} rad/s, beyond the {limit:g} rad/s up to which the "
            f"{preset} friction was identified (Sec. 4 of the paper): results there are extrapolation"
        )
    return notes


# Allowed ranges: (low, high, low_inclusive). high is always exclusive (inf).
_POSITIVE = (0.0, math.inf, False)
_NONNEGATIVE = (0.0, math.inf, True)
_ANY = (-math.inf, math.inf, False)


@dataclass(frozen=True)
class ModelEffects:
    """Effects beyond the paper's model; zero means absent (the paper's model).

    Every field is in SI units. Position-dependent friction multiplies the
    static + Stribeck part of a disk's friction (its band at zero speed too) by
    ``1 + a1 cos(theta + phi1) + a2 cos(2 theta + phi2)``; drift multiplies the
    same part of the lower-disk friction by ``1 + friction_drift * t``; friction heating
    multiplies it by ``1 + friction_heating * Th``, where the thermal state Th [W] is the
    power the lower friction dissipates, lagged by ``thermal_time``:
    ``thermal_time * Th' = |T_fl x3| - Th`` (zero power while the disk sticks), with
    ``Th = 0`` at the start of every simulation (the contact starts at its ambient level).
    """

    string_damping: float = 0.0  # b_theta [N m s / rad], torsional damping of the string
    motor_lag: float = 0.0  # tau_m = L_r / (R_i + R_r) [s], lag of the motor torque
    lower_position_amp_1: float = 0.0  # [-] once-per-revolution friction modulation, lower disk
    lower_position_phase_1: float = 0.0  # [rad]
    lower_position_amp_2: float = 0.0  # [-] twice-per-revolution modulation, lower disk
    lower_position_phase_2: float = 0.0  # [rad]
    upper_position_amp_1: float = 0.0  # [-] once-per-revolution modulation, upper disk
    upper_position_phase_1: float = 0.0  # [rad]
    upper_position_amp_2: float = 0.0  # [-]
    upper_position_phase_2: float = 0.0  # [rad]
    friction_lag: float = 0.0  # tau_f [s], memory of the Stribeck part (frictional lag)
    friction_drift: float = 0.0  # [1/s], relative change of the lower friction level per second
    friction_heating: float = 0.0  # kappa [1/W], relative change of the lower friction level per W
    thermal_time: float = 0.0  # tau_th [s], thermal time constant of the lower friction contact
    disturbance_amp: float = 0.0  # [N m], external torque on the lower disk A sin(w t + phi)
    disturbance_freq: float = 0.0  # w [rad/s]
    disturbance_phase: float = 0.0  # phi [rad]

    def __post_init__(self) -> None:
        ranges = {
            "string_damping": _NONNEGATIVE,
            "motor_lag": _NONNEGATIVE,
            "friction_lag": _NONNEGATIVE,
            "thermal_time": _NONNEGATIVE,
            "disturbance_freq": _NONNEGATIVE,
        }
        for f in fields(self):
            _check_value(f"effects.{f.name}", getattr(self, f.name), ranges.get(f.name, _ANY))
        if (self.friction_heating != 0.0) != (self.thermal_time > 0.0):
            raise ParameterError(
                "effects.friction_heating/thermal_time: friction heating needs both kappa != 0 "
                f"[1/W] and a thermal time > 0 s, got {self.friction_heating!r} and {self.thermal_time!r}"
            )
        for disk in ("lower", "upper"):
            total = abs(getattr(self, f"{disk}_position_amp_1")) + abs(
                getattr(self, f"{disk}_position_amp_2")
            )
            if total >= 1.0:
                raise ParameterError(
                    f"effects.{disk}_position_amp_1/_2: |a1| + |a2| = {total:g} must be < 1 "
                    "(friction would change sign)"
                )

    @property
    def active(self) -> tuple[str, ...]:
        """Names of the effects that are switched on."""
        return tuple(f.name for f in fields(self) if getattr(self, f.name) != 0.0)


@dataclass(frozen=True)
class RigParams:
    """Parameters of the drill-string rig, eq. (10) with friction laws (12), (14).

    Names follow the rig; the paper's symbols are in the comments.
    """

    motor_constant: float  # k_m [N m / V]
    upper_inertia: float  # J_u [kg m^2]
    upper_static_pos: float  # T_sup [N m], static friction band upper edge, upper disk
    upper_static_neg: float  # T_sun [N m], static friction band lower edge (as magnitude)
    upper_viscous_pos: float  # b_up [N m s / rad]
    upper_viscous_neg: float  # b_un [N m s / rad]
    lower_inertia: float  # J_l [kg m^2]
    string_stiffness: float  # k_theta [N m / rad]
    lower_static: float  # T_sl [N m], static friction level, lower disk
    lower_viscous: float  # b_l [N m s / rad]
    lower_hump_1: float  # T_1 [N m]
    lower_hump_2: float  # T_2 [N m]
    lower_hump_rate_1: float  # beta_1 [s / rad]
    lower_hump_rate_2: float  # beta_2 [s / rad]
    effects: ModelEffects = field(default_factory=ModelEffects)
    name: str = "custom"
    description: str = ""

    _RANGES = {
        "motor_constant": _POSITIVE,
        "upper_inertia": _POSITIVE,
        "upper_static_pos": _NONNEGATIVE,
        "upper_static_neg": _NONNEGATIVE,
        "upper_viscous_pos": _NONNEGATIVE,
        "upper_viscous_neg": _NONNEGATIVE,
        "lower_inertia": _POSITIVE,
        "string_stiffness": _POSITIVE,
        "lower_static": _NONNEGATIVE,
        "lower_viscous": _NONNEGATIVE,
        "lower_hump_1": _ANY,
        "lower_hump_2": _ANY,
        "lower_hump_rate_1": _NONNEGATIVE,
        "lower_hump_rate_2": _NONNEGATIVE,
    }

    def __post_init__(self) -> None:
        for name, rng in self._RANGES.items():
            _check_value(name, getattr(self, name), rng)
        if not isinstance(self.effects, ModelEffects):
            raise ParameterError(f"effects: expected ModelEffects, got {type(self.effects).__name__}")
        # Eq. (4): friction is dissipative, T_lp(w) > 0 for all w >= 0.
        w = DISSIPATIVE_CHECK_SPEEDS
        from drill_env.friction import lower_friction_curve  # compiled: imported when used

        slip = lower_friction_curve(self, w)
        if np.any(slip[1:] <= 0.0):
            raise ParameterError(
                "lower_hump_1/lower_hump_2: the lower-disk slip friction becomes <= 0 "
                f"at {w[1:][slip[1:] <= 0][0]:.3g} rad/s; eq. (4) requires it dissipative"
            )

    # -- derived quantities of the paper -------------------------------------------------
    @property
    def uc1(self) -> float:
        """Point A: the largest voltage at which the rig stays stuck, (T_sup + T_sl)/k_m [V]."""
        return (self.upper_static_pos + self.lower_static) / self.motor_constant

    @property
    def uc1_neg(self) -> float:
        """Lower end of the stick range (25): -(T_sun + T_sl)/k_m [V]."""
        return -(self.upper_static_neg + self.lower_static) / self.motor_constant

    @property
    def resonance_rad_s(self) -> float:
        """Natural frequency of the lower disk on the string, sqrt(k_theta/J_l) [rad/s]."""
        return math.sqrt(self.string_stiffness / self.lower_inertia)

    # -- construction ---------------------------------------------------------------------
    def replace(self, **overrides: Any) -> RigParams:
        """A copy with some fields changed; effect fields may be given directly."""
        return _apply_overrides(self, overrides)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["effects"] = {k: v for k, v in d["effects"].items() if v != 0.0}
        if not d["effects"]:
            del d["effects"]
        return d

    def to_yaml(self, path: str | Path) -> None:
        import yaml

        from drill_env.outputs import atomic_write_text

        atomic_write_text(path, yaml.safe_dump(self.to_dict(), sort_keys=False))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, source: str = "parameters") -> RigParams:
        data = dict(data)
        if "measurement" in data:
            # how the angles are read (drill_env.measurement), not how the rig moves: checked, and
            # refused rather than dropped by a reader of the plant alone
            from drill_env.measurement import MeasurementModel

            try:
                m = MeasurementModel.from_mapping(data["measurement"], source=source)
            except ValueError as exc:
                raise ParameterError(str(exc)) from None
            raise ParameterError(
                f"{source}: measurement: the file holds a measurement model ({', '.join(m.active) or 'no'} "
                "encoder eccentricity: how the angles are read, not how the rig moves), which a rig "
                "parameter file has not; allowed: a plant file reader (drill-env synth --plant, "
                "drill_env.plant_file.read_plant_file) applies it to the readings; to use the plant "
                "alone, delete the measurement section"
            )
        if "amplifier" in data:
            raise ParameterError(
                f"{source}: amplifier: the file holds amplifier errors (how the voltage asked for is "
                "applied, not how the rig moves), which a rig parameter file has not; allowed: a plant "
                "file reader (drill-env synth --plant, drill_env.plant_file.read_plant_file) applies "
                "them; to use the plant alone, delete the amplifier section"
            )
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ParameterError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(known)}")
        missing = sorted(n for n in cls._RANGES if n not in data)
        if missing:
            raise ParameterError(f"{source}: missing key(s) {missing}")
        eff = data.pop("effects", None) or {}
        if not isinstance(eff, Mapping):
            raise ParameterError(f"{source}: 'effects' must be a mapping")
        eff_known = {f.name for f in fields(ModelEffects)}
        eff_unknown = sorted(set(eff) - eff_known)
        if eff_unknown:
            raise ParameterError(f"{source}: unknown effect(s) {eff_unknown}; allowed: {sorted(eff_known)}")
        try:
            for key, value in list(data.items()):
                if key in cls._RANGES:
                    data[key] = _as_float(key, value)
            effects = ModelEffects(**{k: _as_float(f"effects.{k}", v) for k, v in eff.items()})
        except ParameterError as exc:  # the file as well as the field
            raise ParameterError(f"{source}: {exc}") from None
        return cls(effects=effects, **data)

    def as_array(self) -> np.ndarray:
        """The flat float64 vector the compiled kernels read (layout in ``_layout``)."""
        from drill_env import _layout as L

        e = self.effects
        p = np.zeros(L.NP)
        p[L.KM] = self.motor_constant
        p[L.JU] = self.upper_inertia
        p[L.TSUP] = self.upper_static_pos
        p[L.TSUN] = self.upper_static_neg
        p[L.BUP] = self.upper_viscous_pos
        p[L.BUN] = self.upper_viscous_neg
        p[L.JL] = self.lower_inertia
        p[L.KTH] = self.string_stiffness
        p[L.TSL] = self.lower_static
        p[L.BL] = self.lower_viscous
        p[L.T1] = self.lower_hump_1
        p[L.T2] = self.lower_hump_2
        p[L.BETA1] = self.lower_hump_rate_1
        p[L.BETA2] = self.lower_hump_rate_2
        p[L.BTH] = e.string_damping
        p[L.TAU_M] = e.motor_lag
        p[L.POSL_A1] = e.lower_position_amp_1
        p[L.POSL_P1] = e.lower_position_phase_1
        p[L.POSL_A2] = e.lower_position_amp_2
        p[L.POSL_P2] = e.lower_position_phase_2
        p[L.POSU_A1] = e.upper_position_amp_1
        p[L.POSU_P1] = e.upper_position_phase_1
        p[L.POSU_A2] = e.upper_position_amp_2
        p[L.POSU_P2] = e.upper_position_phase_2
        p[L.TAU_F] = e.friction_lag
        p[L.DRIFT] = e.friction_drift
        p[L.DIST_A] = e.disturbance_amp
        p[L.DIST_W] = e.disturbance_freq
        p[L.DIST_P] = e.disturbance_phase
        p[L.HEAT] = e.friction_heating
        p[L.TAU_TH] = e.thermal_time
        p[L.ANY_EFFECT] = 1.0 if e.active else 0.0
        p[L.INV_JU] = 1.0 / self.upper_inertia
        p[L.INV_JL] = 1.0 / self.lower_inertia
        return p


def _as_float(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ParameterError(f"{name}: expected a number, got {value!r}")
    return float(value)


def _check_value(name: str, value: Any, rng: tuple[float, float, bool]) -> None:
    value = _as_float(name, value)
    lo, hi, lo_incl = rng
    if not math.isfinite(value):
        raise ParameterError(f"{name}: must be finite, got {value!r}")
    ok_lo = value >= lo if lo_incl else value > lo
    if not ok_lo or value >= hi:
        bracket = "[" if lo_incl else "("
        raise ParameterError(f"{name}: {value!r} is outside the allowed range {bracket}{lo:g}, {hi:g})")


def _apply_overrides(params: RigParams, overrides: Mapping[str, Any]) -> RigParams:
    top = {f.name for f in fields(RigParams)}
    eff_names = {f.name for f in fields(ModelEffects)}
    top_kw: dict[str, Any] = {}
    eff_kw: dict[str, Any] = {}
    for key, value in overrides.items():
        k = key[len("effects.") :] if key.startswith("effects.") else key
        if key in top and key != "effects":
            top_kw[key] = _as_float(key, value) if key in RigParams._RANGES else value
        elif k in eff_names:
            eff_kw[k] = _as_float(f"effects.{k}", value)
        elif key == "effects" and isinstance(value, Mapping):
            for ek, ev in value.items():
                if ek not in eff_names:
                    raise ParameterError(f"unknown effect {ek!r}; allowed: {sorted(eff_names)}")
                eff_kw[ek] = _as_float(f"effects.{ek}", ev)
        else:
            raise ParameterError(
                f"unknown parameter {key!r}; allowed: {sorted((top - {'effects'}) | eff_names)}"
            )
    effects = dataclasses.replace(params.effects, **eff_kw) if eff_kw else params.effects
    return dataclasses.replace(params, effects=effects, **top_kw)


# -- YAML files ------------------------------------------------------------------------------

from drill_env.yamlio import MAX_YAML_BYTES  # noqa: E402 (re-exported)


def load_yaml(path: str | Path, *, what: str = "YAML file", error: type[Exception] = ParameterError) -> Any:
    """Read a small YAML file by the rules of :mod:`drill_env.yamlio` (YAML 1.2 numbers and
    booleans, duplicate keys refused, size, nesting and numbers bounded); every failure is
    ``error`` with a one-line message naming the file."""
    from drill_env.yamlio import load_yaml as _load

    return _load(path, what=what, error=error)


def _preset_dirs() -> list[Path]:
    here = Path(__file__).resolve().parent
    return [here / "_configs" / "rig", here.parent / "configs" / "rig"]


def available_presets() -> list[str]:
    names: set[str] = set()
    for d in _preset_dirs():
        if d.is_dir():
            names.update(p.stem for p in d.glob("*.yaml"))
    return sorted(names)


def load_params(name_or_path: str | Path, **overrides: Any) -> RigParams:
    """Load a preset by name (``brake``, ``no_brake``) or a YAML file by path."""
    path = Path(name_or_path)
    if path.suffix.lower() not in (".yaml", ".yml"):
        for d in _preset_dirs():
            candidate = d / f"{name_or_path}.yaml"
            if candidate.is_file():
                path = candidate
                break
        else:
            raise ParameterError(
                f"preset: unknown preset {str(name_or_path)!r}; available: {available_presets()}"
            )
    if not path.exists():
        raise ParameterError(f"preset: no such file {str(path)!r}")
    data = load_yaml(path, error=ParameterError)
    if not isinstance(data, Mapping):
        raise ParameterError(f"{path.name}: expected a mapping of parameter names to values")
    params = RigParams.from_dict(data, source=path.name)
    return params.replace(**overrides) if overrides else params


def resolve_params(params_or_preset: RigParams | str | Path, **overrides: Any) -> RigParams:
    """Accept a :class:`RigParams`, a preset name or a YAML path."""
    if isinstance(params_or_preset, RigParams):
        return params_or_preset.replace(**overrides) if overrides else params_or_preset
    if isinstance(params_or_preset, (str, Path)):
        return load_params(params_or_preset, **overrides)
    raise ParameterError(
        f"params: expected RigParams, a preset name or a YAML path, got {type(params_or_preset).__name__}"
    )
