"""Measured-like data from a truth model with one hidden effect.

The truth model is a preset plus one effect (or none). Each run starts from rest at a
random angle, is simulated exactly through a pre-roll that is not recorded (long
enough for the steady state of a constant-voltage run), and is then recorded:
the angles go through the rig's measurement chain (:func:`drill_env.sensors.measure`:
Gaussian angle noise, then floor quantisation to encoder counts), the voltage is
recorded as the zero-order hold it is. Two kinds of runs:

* constant-voltage runs like the paper's (Sec. 4), by default at 0.2, 0.5, 0.7, 1.0,
  2.0, 3.0 and 4.5 V;
* quasi-random runs for identification: random levels in [0, 5] V, each held for a
  random 0.5-2 s (whole multiples of 0.1 s).

The effect's name and parameters go to the answer file only; the data folder holds
the runs and ``dataset.json`` (preset, encoder resolution, sample rate).

Hidden effects (``HIDDEN_EFFECTS``): each has a magnitude with a documented
detectable range it is drawn from, log-uniformly, unless ``magnitude`` is given; its
other parameters (phases, second harmonic, frequency, sign) are always random. The
ranges are listed in the README and in ``results/discrepancy/confusion.md``.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.measurement import MAX_ENCODER_ECCENTRICITY, MeasurementModel
from drill_env.outputs import atomic_write_text
from drill_env.params import IDENTIFIED_PARAMETERS, ModelEffects, RigParams, load_params
from drill_env.recordings.dataset import (
    MAX_RATE_HZ,
    MAX_RUN_BYTES,
    MIN_DURATION_S,
    MIN_RATE_HZ,
    MeasuredRun,
    write_dataset,
)
from drill_env.sensors import MAX_ANGLE_NOISE_RAD

__all__ = [
    "HiddenEffect",
    "HIDDEN_EFFECTS",
    "SynthConfig",
    "SynthResult",
    "make_dataset",
    "make_plant_dataset",
    "write_synthetic",
]

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class HiddenEffect:
    """A truth-model effect: how its magnitude maps to ModelEffects fields."""

    name: str
    magnitude_meaning: str  # what --magnitude sets, with units
    low: float  # documented detectable range of the magnitude
    high: float
    build: Callable[[float, np.random.Generator], dict[str, float]]
    in_library: bool = True
    max_magnitude: float = math.inf  # hard validity limit of the magnitude
    # "plant": ModelEffects fields of the truth model; "measurement": an error of the angle
    # readings (the plant is the preset's), applied before the encoder's quantisation
    kind: str = "plant"

    def draw(self, rng: np.random.Generator) -> float:
        if self.low == self.high:
            return self.low
        # log-uniform: every octave of the range is equally represented
        return float(math.exp(rng.uniform(math.log(self.low), math.log(self.high))))


def _position(prefix: str) -> Callable[[float, np.random.Generator], dict[str, float]]:
    def build(a1: float, rng: np.random.Generator) -> dict[str, float]:
        return {
            f"{prefix}_position_amp_1": a1,
            f"{prefix}_position_phase_1": float(rng.uniform(0.0, _TWO_PI)),
            f"{prefix}_position_amp_2": float(a1 * rng.uniform(0.0, 0.5)),
            f"{prefix}_position_phase_2": float(rng.uniform(0.0, _TWO_PI)),
        }

    return build


def _drift(rate: float, rng: np.random.Generator) -> dict[str, float]:
    return {"friction_drift": float(rate * rng.choice([-1.0, 1.0]))}


def _heating(kappa: float, rng: np.random.Generator) -> dict[str, float]:
    return {
        "friction_heating": float(kappa * rng.choice([-1.0, 1.0])),
        "thermal_time": float(math.exp(rng.uniform(math.log(40.0), math.log(200.0)))),
    }


def _eccentricity(disk: str) -> Callable[[float, np.random.Generator], dict[str, float]]:
    def build(a: float, rng: np.random.Generator) -> dict[str, float]:
        return {f"{disk}_encoder_eccentricity": a, f"{disk}_encoder_phase": float(rng.uniform(0.0, _TWO_PI))}

    return build


def reading_error(fields_: dict[str, float], disk: str, theta: np.ndarray) -> np.ndarray:
    """The angle reading error of a disk's encoder [rad]: ``a sin(theta + phi)`` for an
    eccentric encoder disk (once per revolution), zero without one."""
    return MeasurementModel(**fields_).reading_error(disk, theta)


def _external(amp: float, rng: np.random.Generator) -> dict[str, float]:
    return {
        "disturbance_amp": amp,
        "disturbance_freq": float(math.exp(rng.uniform(math.log(0.5), math.log(4.0)))),
        "disturbance_phase": float(rng.uniform(0.0, _TWO_PI)),
    }


HIDDEN_EFFECTS: dict[str, HiddenEffect] = {
    e.name: e
    for e in (
        HiddenEffect("none", "(no magnitude)", 0.0, 0.0, lambda m, rng: {}),
        HiddenEffect(
            "position_friction_lower",
            "a1 [-]: once-per-revolution modulation of the lower static + Stribeck friction "
            "(a2 = a1 x U(0, 0.5); phases uniform)",
            0.01,
            0.2,
            _position("lower"),
            max_magnitude=0.66,
        ),
        HiddenEffect(
            "position_friction_upper",
            "a1 [-]: once-per-revolution modulation of the upper static friction "
            "(a2 = a1 x U(0, 0.5); phases uniform)",
            0.04,
            0.3,
            _position("upper"),
            max_magnitude=0.66,
        ),
        HiddenEffect(
            "string_damping",
            "b_theta [N m s/rad]: torsional damping of the string",
            5e-4,
            0.01,
            lambda m, rng: {"string_damping": m},
        ),
        HiddenEffect(
            "motor_inductance",
            "tau_m = L_r/(R_i + R_r) [s]: lag of the motor torque",
            2e-3,
            0.05,
            lambda m, rng: {"motor_lag": m},
        ),
        HiddenEffect(
            "friction_memory",
            "tau_f [s]: frictional lag of the Stribeck part of the lower friction",
            0.02,
            0.5,
            lambda m, rng: {"friction_lag": m},
        ),
        HiddenEffect(
            "friction_drift",
            "|rate| [1/s]: relative change of the lower friction level per second (sign random)",
            1e-4,
            2e-3,
            _drift,
            max_magnitude=0.005,
        ),
        HiddenEffect(
            "friction_temperature",
            "|kappa| [1/W]: relative change of the lower friction level per watt of the lagged power "
            "it dissipates (sign random), thermal time log-uniform in [40, 200] s; at 2-4 V (0.5-0.75 W) "
            "the level rises about 5-37 % at thermal equilibrium, 1-16 % during a 150 s recording after "
            "the pre-roll",
            0.1,
            0.5,
            _heating,
            max_magnitude=1.0,
        ),
        HiddenEffect(
            "external_torque",
            "A [N m]: external torque A sin(w t + phi) on the lower disk, w log-uniform in "
            "[0.5, 4] rad/s, unrelated to rotation (outside the candidate library)",
            5e-3,
            0.03,
            _external,
            in_library=False,
        ),
        HiddenEffect(
            "encoder_eccentricity_lower",
            "a [rad]: once-per-revolution reading error a sin(theta_l + phi) of the lower encoder "
            "(an eccentric encoder disk; phase uniform), a measurement effect: the plant is the preset's",
            2e-3,
            2e-2,
            _eccentricity("lower"),
            max_magnitude=MAX_ENCODER_ECCENTRICITY,
            kind="measurement",
        ),
        HiddenEffect(
            "encoder_eccentricity_upper",
            "a [rad]: once-per-revolution reading error a sin(theta_u + phi) of the upper encoder "
            "(an eccentric encoder disk; phase uniform), a measurement effect: the plant is the preset's",
            2e-3,
            2e-2,
            _eccentricity("upper"),
            max_magnitude=MAX_ENCODER_ECCENTRICITY,
            kind="measurement",
        ),
    )
}


@dataclass(frozen=True)
class SynthConfig:
    """Experiment design of a synthetic dataset (SI units)."""

    preset: str = "brake"
    voltages: tuple[float, ...] = (0.2, 0.5, 0.7, 1.0, 2.0, 3.0, 4.5)  # constant-voltage runs [V]
    random_runs: int = 3  # quasi-random voltage runs
    duration_s: float = 150.0  # recorded length of each run [s]
    pre_roll_s: float = 60.0  # simulated before the recording starts [s]
    sample_rate_hz: float = 500.0
    encoder_counts_per_rev: int = 2000
    angle_noise_std: float = 1e-3  # [rad] Gaussian angle noise before quantisation
    hold_min_s: float = 0.5  # quasi-random runs: hold time of a level [s]
    hold_max_s: float = 2.0
    hold_quantum_s: float = 0.1
    level_max_v: float = 5.0
    level_min_v: float = 0.0  # quasi-random levels are uniform in [level_min_v, level_max_v]
    param_error: float = 0.0  # [-] relative error of every identified parameter (uniform +-)
    time_jitter: float = 0.0  # [periods] time-stamp error, uniform +-, of a jittered DAQ clock

    def __post_init__(self) -> None:
        for v in self.voltages:
            if not (math.isfinite(v) and abs(v) <= 5.0):
                raise ValueError(f"voltages: {v!r} V is outside the rig's range [-5, 5] V")
        if (
            isinstance(self.random_runs, bool)
            or not isinstance(self.random_runs, int)
            or self.random_runs < 0
        ):
            raise ValueError(f"random_runs: expected an integer >= 0, got {self.random_runs!r}")
        if len(self.voltages) + self.random_runs > MAX_SYNTH_RUNS:
            raise ValueError(
                f"voltages/random_runs: {len(self.voltages)} + {self.random_runs} runs; a dataset holds at most "
                f"{MAX_SYNTH_RUNS}"
            )
        if not self.voltages and self.random_runs == 0:
            raise ValueError("voltages/random_runs: the dataset would hold no run")
        # the ranges of the loader (drill_env.recordings.dataset): a dataset synth writes is one
        # the workflow reads
        if not (math.isfinite(self.sample_rate_hz) and MIN_RATE_HZ <= self.sample_rate_hz <= MAX_RATE_HZ):
            raise ValueError(
                f"sample_rate_hz: {self.sample_rate_hz!r} is outside [{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}] Hz"
            )
        if not (math.isfinite(self.duration_s) and MIN_DURATION_S <= self.duration_s <= MAX_SYNTH_DURATION_S):
            raise ValueError(
                f"duration_s: {self.duration_s!r} is outside [{MIN_DURATION_S:g}, {MAX_SYNTH_DURATION_S:g}] s"
            )
        n_rec = int(round(self.duration_s * self.sample_rate_hz)) + 1
        if n_rec * CSV_ROW_BYTES > MAX_RUN_BYTES:
            longest = (MAX_RUN_BYTES // CSV_ROW_BYTES - 1) / self.sample_rate_hz
            raise ValueError(
                f"duration_s: {self.duration_s:g} s at {self.sample_rate_hz:g} Hz makes run files of up to "
                f"{n_rec * CSV_ROW_BYTES / 2**30:.3g} GiB; the loader reads at most {MAX_RUN_BYTES / 2**30:g} GiB "
                f"per run: at most {math.floor(longest):g} s at this rate"
            )
        if not 0.0 <= self.pre_roll_s <= 600.0:
            raise ValueError(f"pre_roll_s: {self.pre_roll_s!r} is outside [0, 600] s")
        if not 1 <= self.encoder_counts_per_rev <= 1 << 26:
            raise ValueError(f"encoder_counts_per_rev: {self.encoder_counts_per_rev!r} is outside [1, 2^26]")
        if not (math.isfinite(self.angle_noise_std) and 0.0 <= self.angle_noise_std <= MAX_ANGLE_NOISE_RAD):
            raise ValueError(
                f"angle_noise_std: {self.angle_noise_std!r} is outside [0, {MAX_ANGLE_NOISE_RAD:g}] rad"
            )
        if not (math.isfinite(self.param_error) and 0.0 <= self.param_error <= 0.3):
            raise ValueError(f"param_error: {self.param_error!r} is outside [0, 0.3]")
        if not (math.isfinite(self.time_jitter) and 0.0 <= self.time_jitter <= 0.1):
            raise ValueError(f"time_jitter: {self.time_jitter!r} is outside [0, 0.1] periods")
        if not 0.0 < self.level_max_v <= 5.0:
            raise ValueError(f"level_max_v: {self.level_max_v!r} is outside (0, 5] V")
        if not -5.0 <= self.level_min_v < self.level_max_v:
            raise ValueError(f"level_min_v: {self.level_min_v!r} is outside [-5, level_max_v) V")


# The longest run synth records [s] (about an hour, as the rig's recordings), and the most
# bytes one CSV row can take (four numbers of 12 significant digits with signs, exponents,
# commas): a run whose file could exceed the loader's MAX_RUN_BYTES is refused up front.
MAX_SYNTH_DURATION_S = 3600.0
CSV_ROW_BYTES = 4 * 19 + 4
# Angle noise beyond a radian is no encoder's (the sensors' bound, MAX_ANGLE_NOISE_RAD).
MAX_SYNTH_RUNS = 100  # runs of one dataset


@dataclass
class SynthResult:
    runs: list[MeasuredRun]
    truth: RigParams
    answer: dict[str, Any] = field(default_factory=dict)


# The identified parameters of the paper (eq. 11, 13, 15, 17), RigParams field names.
IDENTIFIED = IDENTIFIED_PARAMETERS
_RATES = ("lower_hump_rate_1", "lower_hump_rate_2")  # not torques: unchanged by a common scale


def _parameter_errors(
    preset: str, rel: float, overrides: dict[str, float] | None, seed: int
) -> dict[str, float]:
    """Truth values of the identified parameters that differ from the preset."""
    base = load_params(preset)
    out: dict[str, float] = {}
    if rel > 0.0:
        rng = np.random.default_rng([seed, 7919])  # a stream of its own: the runs stay the same
        for name, e in zip(IDENTIFIED, rng.uniform(-rel, rel, len(IDENTIFIED)), strict=True):
            out[name] = float(getattr(base, name)) * (1.0 + float(e))
    effect_fields = {f.name for f in fields(ModelEffects)}
    for name, value in (overrides or {}).items():
        if name not in IDENTIFIED and name not in effect_fields:
            raise ValueError(
                f"truth_overrides: {name!r} is neither an identified parameter nor an effect field; "
                f"allowed: {list(IDENTIFIED)} and {sorted(effect_fields)}"
            )
        out[name] = float(value)
    return out


def _at_nominal_stiffness(preset: str, truth: RigParams) -> dict[str, float]:
    """The identified parameters of the equivalent truth whose string stiffness is the preset's."""
    c = load_params(preset).string_stiffness / truth.string_stiffness
    return {n: float(getattr(truth, n)) * (1.0 if n in _RATES else c) for n in IDENTIFIED}


def _truth_params(preset: str, effect: str, magnitude: float | None, rng: np.random.Generator):
    if effect not in HIDDEN_EFFECTS:
        raise ValueError(f"effect: unknown effect {effect!r}; allowed: {sorted(HIDDEN_EFFECTS)}")
    spec = HIDDEN_EFFECTS[effect]
    if effect == "none":
        if magnitude not in (None, 0.0):
            raise ValueError("magnitude: the effect 'none' takes no magnitude")
        return load_params(preset), spec, 0.0, {}
    mag = spec.draw(rng) if magnitude is None else float(magnitude)
    if not (math.isfinite(mag) and 0.0 < mag < spec.max_magnitude):
        raise ValueError(
            f"magnitude: {magnitude!r} is outside the allowed range (0, {spec.max_magnitude:g}) for {effect} "
            f"({spec.magnitude_meaning}); detectable range [{spec.low:g}, {spec.high:g}]"
        )
    fields_ = spec.build(mag, rng)
    if spec.kind == "measurement":
        return load_params(preset), spec, mag, fields_
    return load_params(preset, **fields_), spec, mag, fields_


def _random_levels(cfg: SynthConfig, total_s: float, rng: np.random.Generator) -> np.ndarray:
    """Zero-order-hold levels, one per hold quantum, covering ``total_s``."""
    n = int(math.ceil(total_s / cfg.hold_quantum_s)) + 1
    out = np.empty(n)
    i = 0
    lo = int(round(cfg.hold_min_s / cfg.hold_quantum_s))
    hi = int(round(cfg.hold_max_s / cfg.hold_quantum_s))
    while i < n:
        k = int(rng.integers(lo, hi + 1))
        out[i : i + k] = rng.uniform(cfg.level_min_v, cfg.level_max_v)
        i += k
    return out


def _design_record(cfg: SynthConfig, param_error: float | None = None) -> dict[str, Any]:
    """How a dataset was recorded, for its answer file (``param_error``: the one applied, when
    the truth does not come from ``cfg``'s)."""
    return {
        "voltages": list(cfg.voltages),
        "random_runs": cfg.random_runs,
        "duration_s": cfg.duration_s,
        "pre_roll_s": cfg.pre_roll_s,
        "sample_rate_hz": cfg.sample_rate_hz,
        "encoder_counts_per_rev": cfg.encoder_counts_per_rev,
        "angle_noise_std": cfg.angle_noise_std,
        "param_error": cfg.param_error if param_error is None else param_error,
        "time_jitter": cfg.time_jitter,
    }


def _simulate_run(
    truth: RigParams,
    u_levels,
    cdt,
    cfg: SynthConfig,
    rng,
    name: str,
    reading: MeasurementModel | None = None,
    delay_s: float = 0.0,
    amplifier: tuple[float, float] = (1.0, 0.0),
) -> MeasuredRun:
    from drill_env.sensors import SensorConfig, measure
    from drill_env.simulator import simulate

    dt = 1.0 / cfg.sample_rate_hz
    n_pre = int(round(cfg.pre_roll_s / dt))
    n_rec = int(round(cfg.duration_s / dt)) + 1
    t0 = -n_pre * dt
    t_final = (n_rec - 1) * dt
    angle0 = float(rng.uniform(0.0, _TWO_PI))
    x0 = {"theta_u": angle0, "theta_l": angle0}
    gain, offset = amplifier  # the amplifier applies gain u + offset for the asked-for u
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a failed run is an error, below
        if np.ndim(u_levels) == 0:
            res = simulate(truth, gain * float(u_levels) + offset, t_final, x0=x0, dt=dt, t0=t0)
        else:
            applied = gain * np.asarray(u_levels, dtype=float) + offset
            res = simulate(truth, applied, t_final, x0=x0, dt=dt, t0=t0, control_dt=cdt)
    if res.status != 0:  # never write the frozen angles of a run that stopped
        raise ValueError(
            f"magnitude: the truth model of run {name} could not be simulated ({res.message.rstrip('.')}); "
            "choose a magnitude in the effect's detectable range"
        )
    k0 = res.t.size - n_rec
    t_true = res.t[k0:]
    if abs(t_true[0]) > 1e-6 * dt + 1e-9:
        raise RuntimeError(f"internal: recording grid misaligned (t[0] = {t_true[0]!r})")
    theta_u, theta_l = res.theta_u[k0:], res.theta_l[k0:]
    jitter = np.zeros(n_rec)
    if cfg.time_jitter > 0.0:
        # A jittered DAQ clock: the angles of sample k read at k dt + e_k. Drawn from a stream of its own, so
        # that the dataset without jitter is the same draw; the angles at those instants by cubic
        # Hermite interpolation on the simulated angles and speeds (exact to O(dt^4)).
        from scipy.interpolate import CubicHermiteSpline

        jrng = np.random.default_rng(rng.bit_generator.seed_seq.spawn(1)[0])
        jitter = jrng.uniform(-cfg.time_jitter, cfg.time_jitter, n_rec) * dt
        jitter[0] = 0.0
        t_at = t_true + jitter
        theta_u = CubicHermiteSpline(res.t, res.theta_u, res.x2)(t_at)
        theta_l = CubicHermiteSpline(res.t, res.theta_l, res.x3)(t_at)
    if np.ndim(u_levels) == 0:
        u = np.full(n_rec, float(u_levels))
    else:
        # the voltage of sample k is the one the DAQ holds over step k (its output, updated on
        # its own clock, logged with the sample), whatever the time stamp's jitter; with an
        # actuator delay, the one applied delay_s later
        idx = np.floor((t_true + delay_s - t0) / cdt + 1e-9).astype(int)
        u = np.asarray(u_levels)[np.minimum(idx, len(u_levels) - 1)]
    sensors = SensorConfig(
        counts_per_rev=cfg.encoder_counts_per_rev,
        sample_rate_hz=cfg.sample_rate_hz,
        angle_noise_std=cfg.angle_noise_std,
    )
    if reading is not None and reading.active:
        theta_u, theta_l = reading.read(theta_u, theta_l)
    meas = measure(
        theta_u,
        theta_l,
        sensors,
        initial_speeds=(float(res.x2[k0]), float(res.x3[k0])),
        seed=rng,
    )
    # the recording clock starts wherever it started
    t_start = float(np.round(rng.uniform(0.0, 100.0) / dt) * dt)
    return MeasuredRun(
        name=name,
        t=t_start + dt * np.arange(n_rec) + jitter,
        u=u,
        theta_u=meas.upper_angle,
        theta_l=meas.lower_angle,
    )


def make_dataset(
    effect: str,
    *,
    seed: int,
    magnitude: float | None = None,
    config: SynthConfig | None = None,
    truth_overrides: dict[str, float] | None = None,
    second_effect: str | None = None,
    second_magnitude: float | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SynthResult:
    """Simulate a truth model with one hidden effect and record it like the rig.

    ``second_effect`` adds a second library effect (another one than ``effect``, which must
    be a library effect too), of ``second_magnitude`` or drawn like the first from its own
    random stream, so that the first effect, the runs and the noise are those of the
    one-effect dataset of the same seed. ``truth_overrides`` sets identified parameters of
    the truth (RigParams field names) on top of the drawn ``config.param_error``, or
    :class:`~drill_env.params.ModelEffects` fields; all go to the answer only."""
    cfg = config or SynthConfig()
    rng = np.random.default_rng(seed)
    truth, spec, mag, fields_ = _truth_params(cfg.preset, effect, magnitude, rng)
    second: dict[str, Any] = {}
    if second_effect is not None:
        library = sorted(e for e, h in HIDDEN_EFFECTS.items() if h.in_library and e != "none")
        for name, value in (("effect", effect), ("second_effect", second_effect)):
            if value not in library:
                raise ValueError(f"{name}: {value!r} cannot be one of two effects; allowed: {library}")
        if second_effect == effect:
            raise ValueError(f"second_effect: must differ from effect, got {second_effect!r} twice")
        rng2 = np.random.default_rng([seed, 2])
        _, spec2, mag2, fields2 = _truth_params(cfg.preset, second_effect, second_magnitude, rng2)
        if spec.kind == "measurement" or spec2.kind == "measurement":
            raise ValueError(
                "second_effect: two effects are plant effects; a measurement effect "
                f"({effect if spec.kind == 'measurement' else second_effect}) comes alone"
            )
        truth = truth.replace(**fields2)
        second = {
            "effect": second_effect,
            "magnitude": mag2,
            "magnitude_meaning": spec2.magnitude_meaning,
            "model_effects": fields2,
        }
    changes = _parameter_errors(cfg.preset, cfg.param_error, truth_overrides, seed)
    if changes:
        truth = truth.replace(**changes)
    errors = {n: v for n, v in changes.items() if n in IDENTIFIED}
    extra = {n: v for n, v in changes.items() if n not in IDENTIFIED}
    runs: list[MeasuredRun] = []
    total = len(cfg.voltages) + cfg.random_runs
    designs: list[Any] = [float(v) for v in cfg.voltages]
    for _ in range(cfg.random_runs):
        designs.append(_random_levels(cfg, cfg.pre_roll_s + cfg.duration_s, rng))
    for i, design in enumerate(designs):
        reading = MeasurementModel(**fields_) if spec.kind == "measurement" else None
        runs.append(_simulate_run(truth, design, cfg.hold_quantum_s, cfg, rng, f"run{i + 1:02d}", reading))
        if progress is not None:
            progress(i + 1, total)
    answer = {
        "effect": effect,
        "in_library": spec.in_library,
        "magnitude": mag,
        "magnitude_meaning": spec.magnitude_meaning,
        "detectable_range": [spec.low, spec.high],
        "model_effects": fields_ if spec.kind == "plant" else {},
        "measurement_effects": fields_ if spec.kind == "measurement" else {},
        "effects": [effect] + ([second_effect] if second_effect else []) if effect != "none" else [],
        "second_effect": second or None,
        "extra_effects": extra,
        "parameter_errors": {
            n: v / float(getattr(load_params(cfg.preset), n)) - 1.0 for n, v in errors.items()
        },
        "parameters": {n: float(getattr(truth, n)) for n in IDENTIFIED},
        "parameters_at_nominal_string_stiffness": _at_nominal_stiffness(cfg.preset, truth),
        "seed": seed,
        "preset": cfg.preset,
        "design": _design_record(cfg),
    }
    return SynthResult(runs=runs, truth=truth, answer=answer)


def _named_effects(truth: RigParams) -> list[str]:
    """The library effects (HIDDEN_EFFECTS names) whose fields ``truth`` has switched on."""
    active = set(truth.effects.active)
    rng = np.random.default_rng(0)
    return [
        name
        for name, h in HIDDEN_EFFECTS.items()
        if name != "none" and h.in_library and active & set(h.build(max(h.low, 1e-3), rng))
    ]


def make_plant_dataset(
    truth: RigParams,
    *,
    seed: int,
    config: SynthConfig | None = None,
    delay_s: float = 0.0,
    source: str = "plant file",
    progress: Callable[[int, int], None] | None = None,
    measurement: MeasurementModel | None = None,
    amplifier_gain: float = 1.0,
    amplifier_offset_v: float = 0.0,
) -> SynthResult:
    """Record a given truth plant (a plant file's rig, effects included) like the rig: the runs
    of ``config`` through its encoders. ``delay_s`` [s] is the plant's actuator delay: the
    recorded (asked-for) voltage leads the applied one by it; ``measurement`` the reading errors
    of its encoders (a plant file's ``measurement:`` section), applied to the true angles before
    the encoders' quantisation; ``amplifier_gain`` and ``amplifier_offset_v`` [V] its amplifier's
    errors (it applies ``gain u + offset`` when ``u`` is asked for and recorded). The answer names
    the plant's effects and parameters."""
    if not isinstance(truth, RigParams):
        raise ValueError(f"truth: expected RigParams, got {type(truth).__name__}")
    if not (math.isfinite(delay_s) and 0.0 <= delay_s <= 1.0):
        raise ValueError(f"actuator_delay: {delay_s!r} is outside the allowed range [0, 1] s")
    if measurement is not None and not isinstance(measurement, MeasurementModel):
        raise ValueError(f"measurement: expected a MeasurementModel, got {type(measurement).__name__}")
    cfg = config or SynthConfig()
    rng = np.random.default_rng(seed)
    total = len(cfg.voltages) + cfg.random_runs
    designs: list[Any] = [float(v) for v in cfg.voltages]
    for _ in range(cfg.random_runs):
        designs.append(_random_levels(cfg, cfg.pre_roll_s + cfg.duration_s, rng))
    runs: list[MeasuredRun] = []
    for i, design in enumerate(designs):
        runs.append(
            _simulate_run(
                truth,
                design,
                cfg.hold_quantum_s,
                cfg,
                rng,
                f"run{i + 1:02d}",
                measurement,
                delay_s=delay_s,
                amplifier=(float(amplifier_gain), float(amplifier_offset_v)),
            )
        )
        if progress is not None:
            progress(i + 1, total)
    nominal = load_params(cfg.preset)
    effects = {k: v for k, v in truth.to_dict().get("effects", {}).items()}
    answer = {
        "effect": "plant",
        "source": source,
        "in_library": True,
        "model_effects": effects,
        "measurement_effects": measurement.to_dict() if measurement is not None else {},
        "effects": _named_effects(truth)
        + [f"encoder_eccentricity_{d}" for d in (measurement.active if measurement is not None else ())],
        "actuator_delay": delay_s,
        "amplifier": {"gain": float(amplifier_gain), "offset_v": float(amplifier_offset_v)},
        "parameter_errors": {
            n: float(getattr(truth, n)) / float(getattr(nominal, n)) - 1.0
            for n in IDENTIFIED
            if float(getattr(truth, n)) != float(getattr(nominal, n))
        },
        "parameters": {n: float(getattr(truth, n)) for n in IDENTIFIED},
        "parameters_at_nominal_string_stiffness": _at_nominal_stiffness(cfg.preset, truth),
        "seed": seed,
        "preset": cfg.preset,
        "design": _design_record(cfg, param_error=0.0),
    }
    return SynthResult(runs=runs, truth=truth, answer=answer)


def write_synthetic(result: SynthResult, out: str | Path, answer_file: str | Path, *, preset: str) -> None:
    """Write the runs to ``out`` and the answer (effect and parameters) to ``answer_file`` only."""
    out = Path(out).resolve()
    answer_file = Path(answer_file).resolve()
    if out == answer_file.parent or out in answer_file.parents:
        raise ValueError(
            f"answer: {answer_file} lies inside the data folder {out}; the answer must be kept apart from the data"
        )
    write_dataset(
        out,
        result.runs,
        preset=preset,
        encoder_counts_per_rev=int(result.answer["design"]["encoder_counts_per_rev"]),
    )
    answer_file.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(answer_file, json.dumps(result.answer, indent=2) + "\n")
