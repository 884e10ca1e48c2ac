"""Configuration shared by the single and the vector environment.

:class:`EnvSettings` turns the keyword arguments of ``gymnasium.make`` into validated
objects and compiled-kernel vectors once; :meth:`EnvSettings.draw_episode` draws
everything random about an episode from one ``np.random.Generator``, so a single
environment and a rig of the vector environment with the same seed draw the same
numbers in the same order.

Design model vs true plant (one rule): what a controller, the task and the regime labels
know (the target speed, the nominal voltage, the regime) comes from the *design model*
(``design_params``; by default the paper's model of ``params``, its effects left out); only
the simulated plant (``params``, randomised per episode with domain randomisation) is the
truth. The equilibrium start state is the design model's at the episode's voltage.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from drill_env import _layout as L
from drill_env.envs import _core as C
from drill_env.envs.task import (
    REGIMES,
    VOLTAGE_LIMIT,
    OperatingPoint,
    OperatingPointSampler,
    TaskConfig,
    equilibrium_state,
    nominal_params,
)
from drill_env.params import ParameterError, RigParams, resolve_params
from drill_env.sensors import SensorConfig, config_from_any, rng_state
from drill_env.simulator import DEFAULT_ATOL, DEFAULT_RTOL

__all__ = [
    "RewardWeights",
    "DomainRandomization",
    "EnvSettings",
    "EpisodeSetup",
    "START_STATES",
    "OBSERVATION_NAMES",
    "OBSERVATION_UNITS",
    "OBSERVATION_SCALES",
    "OBSERVATION_VERSIONS",
    "ACTION_MODES",
    "CORRECTION_RANGE",
    "observation_layout",
    "TRUE_STATE_NAMES",
    "REWARD_NAMES",
    "check_seed",
    "numeric_action",
]

START_STATES = {"rest": C.START_REST, "equilibrium": C.START_EQUILIBRIUM, "open_loop": C.START_OPEN_LOOP}

OBSERVATION_NAMES = (
    "lower_speed",
    "upper_speed",
    "twist",
    "lower_speed_mean",
    "upper_speed_mean",
    "voltage",
    "target_speed",
    "nominal_voltage",
)
OBSERVATION_UNITS = ("rad/s", "rad/s", "rad", "rad/s", "rad/s", "V", "rad/s", "V")
SPEED_SCALE = 10.0  # [rad/s] about the equilibrium speed at 5 V (8.85 rad/s with the brake)
TWIST_SCALE = 2.0  # [rad] above the static twist T_sl/k_theta = 1.2 rad (brake)
OBSERVATION_SCALES = (
    SPEED_SCALE,
    SPEED_SCALE,
    TWIST_SCALE,
    SPEED_SCALE,
    SPEED_SCALE,
    VOLTAGE_LIMIT,
    SPEED_SCALE,
    VOLTAGE_LIMIT,
)
# Safe bounds of the observation in physical units. With |u| <= 5 V the motor can feed at
# most (5 km)^2 / (4 b_up) = 40 W more than the upper disk dissipates, so in a 20 s episode
# the string's energy stays below ~810 J: speeds below ~230 rad/s, twist below ~150 rad.
# The bounds are far outside anything the rig reaches; they exist because the spaces
# must be finite.
SPEED_BOUND = 1000.0  # [rad/s]
TWIST_BOUND = 1000.0  # [rad]
OBSERVATION_LOW = (
    -SPEED_BOUND,
    -SPEED_BOUND,
    -TWIST_BOUND,
    -SPEED_BOUND,
    -SPEED_BOUND,
    -VOLTAGE_LIMIT,
    0.0,
    0.0,
)
OBSERVATION_HIGH = (
    SPEED_BOUND,
    SPEED_BOUND,
    TWIST_BOUND,
    SPEED_BOUND,
    SPEED_BOUND,
    VOLTAGE_LIMIT,
    SPEED_BOUND,
    VOLTAGE_LIMIT,
)

# -- observation version 1: the v0 entries, then what the encoders give beyond them -------------
# sin/cos of each disk's encoder angle within the revolution (from the whole counts) and the
# integrated speed error of the lower disk, theta_l_enc(t) - theta_l_enc(t0) - w* (t - t0).
OBSERVATION_NAMES_V1 = OBSERVATION_NAMES + (
    "lower_angle_sin",
    "lower_angle_cos",
    "upper_angle_sin",
    "upper_angle_cos",
    "lower_speed_error_integral",
)
OBSERVATION_UNITS_V1 = OBSERVATION_UNITS + ("-", "-", "-", "-", "rad")
# One revolution: +-1 is the bit a whole turn ahead of (+) or behind (-) its reference
# angle. A controller that holds the speed keeps it well inside +-1 (a PI's integrator holds
# (u - u_nom) / k_i, a fraction of a radian); open-loop stick-slip loses ~0.1-1 rad/s
# against the target, a few revolutions per 20 s episode.
INTEGRAL_SCALE = 2.0 * math.pi  # [rad]
# Clip bound: 50 revolutions. In a registered episode (20 s) the bit cannot get that far
# from its reference angle: standing still at the fastest target (8.9 rad/s, the equilibrium
# speed at 5 V) it lags 178 rad = 28 revolutions. Longer episodes with a stalled or runaway
# bit can reach it; then the entry is clipped and info["integral_clipped"] says so.
INTEGRAL_BOUND = 100.0 * math.pi  # [rad]
OBSERVATION_SCALES_V1 = OBSERVATION_SCALES + (1.0, 1.0, 1.0, 1.0, INTEGRAL_SCALE)
OBSERVATION_LOW_V1 = OBSERVATION_LOW + (-1.0, -1.0, -1.0, -1.0, -INTEGRAL_BOUND)
OBSERVATION_HIGH_V1 = OBSERVATION_HIGH + (1.0, 1.0, 1.0, 1.0, INTEGRAL_BOUND)
OBSERVATION_VERSIONS = (0, 1)
# how an action becomes the requested voltage: normalized u = 5 V a, voltage u = a,
# correction u = u_nom + action_range a (the episode's nominal voltage plus a correction)
ACTION_MODES = ("normalized", "voltage", "correction")
# [V] default action_range of the correction mode (the v2 action): the tuned LQI's largest
# correction over the benchmark's quick grid is 1.55 V (brake, 5 V: 1.2 V at 4 V, 0.6 V at
# 1 V; no brake 1.2 V at 1 V), so +-2 V holds every correction a suppressing controller
# made, and an action of 0.01 is 20 mV
CORRECTION_RANGE = 2.0
assert len(OBSERVATION_NAMES) == C.NOBS_V0 and len(OBSERVATION_NAMES_V1) == C.NOBS


def observation_layout(version: int) -> dict[str, tuple]:
    """Names, units, scales and physical bounds (low, high) of observation ``version``."""
    if version == 0:
        return {
            "names": OBSERVATION_NAMES,
            "units": OBSERVATION_UNITS,
            "scales": OBSERVATION_SCALES,
            "low": OBSERVATION_LOW,
            "high": OBSERVATION_HIGH,
        }
    if version == 1:
        return {
            "names": OBSERVATION_NAMES_V1,
            "units": OBSERVATION_UNITS_V1,
            "scales": OBSERVATION_SCALES_V1,
            "low": OBSERVATION_LOW_V1,
            "high": OBSERVATION_HIGH_V1,
        }
    raise ValueError(f"observation_version: {version!r} is not one of {list(OBSERVATION_VERSIONS)}")


TRUE_STATE_NAMES = ("twist", "upper_speed", "lower_speed", "upper_angle", "lower_angle")
REWARD_NAMES = ("tracking", "stick", "oscillation", "effort", "integral", "overdrive")
assert len(REWARD_NAMES) == len(C.REWARD_SLOTS)
SPEED_REF_FLOOR = 1.0  # [rad/s] reward terms are normalised by max(target speed, this) or by this
# The tracking term: "relative_squared" ((x3 - w*) / max(w*, 1 rad/s))^2 (up to v2) or
# "absolute" |x3 - w*| / (1 rad/s) (v3: an error costs the same at every operating point).
TRACKING_COSTS = ("relative_squared", "absolute")
SETTLE_TIME = 0.2  # [s] sensors run at the end of an open-loop warm-up before the episode
MAX_RANDOMIZATION_TRIES = 100
MAX_WARMUP_RETRIES = 5


def _number(name: str, value: Any, lo: float, hi: float = math.inf, *, lo_incl: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    v = float(value)
    ok = math.isfinite(v) and (v >= lo if lo_incl else v > lo) and v <= hi
    if not ok:
        lb = "[" if lo_incl else "("
        rb = "]" if math.isfinite(hi) else ")"
        raise ValueError(f"{name}: {value!r} is outside the allowed range {lb}{lo:g}, {hi:g}{rb}")
    return v


def check_seed(seed: Any, name: str = "seed") -> int | None:
    """A reset seed as Gymnasium takes it: None or an integer >= 0; NumPy integers count as
    integers (Gymnasium itself accepts only Python ints), bools and floats are refused."""
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"{name}: expected an integer >= 0 or None, got {seed!r}")
    if seed < 0:
        raise ValueError(f"{name}: expected an integer >= 0 or None, got {seed!r}")
    return int(seed)


def numeric_action(action: Any, name: str) -> np.ndarray:
    """``action`` as a float64 array, refusing what is not a real number: bools, strings,
    bytes, complex and object values (NumPy would convert ``True`` and ``"0.5"`` silently)."""
    try:
        arr = np.asarray(action)
    except (TypeError, ValueError):  # ragged nesting
        arr = np.asarray(None)
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{name}: expected real numbers (int or float), got {action!r} of dtype {arr.dtype}")
    return arr.astype(np.float64)


def check_actions(action: Any, name: str, shape: tuple[int, ...], high: float) -> np.ndarray:
    """``action`` as float64 of exactly ``shape``, every entry finite and within the action
    space ``[-high, high]`` (a float32 rounding beyond it allowed: the space is float32);
    otherwise a ValueError naming the argument, the shape and the range. Nothing is reshaped
    or clipped here; the amplifier's own +-5 V limit acts in the rig (``info["voltage_clipped"]``)."""
    arr = numeric_action(action, name)
    expected = "(" + ", ".join(str(n) for n in shape) + ("," if len(shape) == 1 else "") + ")"
    if arr.shape != shape:
        raise ValueError(
            f"{name}: expected shape {expected}, got shape {arr.shape} (allowed range "
            f"[{-high:g}, {high:g}] per entry)"
        )
    flat = arr.reshape(-1)
    bad = np.flatnonzero(~(np.abs(flat) <= high * (1.0 + float(np.finfo(np.float32).eps))))
    if bad.size:
        where = name if arr.size == 1 else f"{name}[{bad[0]}]"
        raise ValueError(
            f"{where}: {float(flat[bad[0]])!r} is outside the action space: allowed range "
            f"[{-high:g}, {high:g}], finite (shape {expected})"
        )
    return arr


# A reward weight beyond this makes no sense beside the others (1 for tracking) and lets a
# reward overflow; weights are finite and within [0, MAX_REWARD_WEIGHT].
MAX_REWARD_WEIGHT = 1e6


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the reward terms; reward = -(sum of weight * term), see the env docstring.
    Each weight is finite, from 0 to :data:`MAX_REWARD_WEIGHT`."""

    tracking: float = 1.0
    stick: float = 1.0
    oscillation: float = 0.5
    effort: float = 0.1
    integral: float = 0.0
    overdrive: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(
                self,
                f.name,
                _number(f"reward_weights.{f.name}", getattr(self, f.name), 0.0, MAX_REWARD_WEIGHT),
            )


_FRICTION_FIELDS = (
    "upper_static_pos",
    "upper_static_neg",
    "upper_viscous_pos",
    "upper_viscous_neg",
    "lower_static",
    "lower_viscous",
    "lower_hump_1",
    "lower_hump_2",
    "lower_hump_rate_1",
    "lower_hump_rate_2",
)
_INERTIA_FIELDS = ("upper_inertia", "lower_inertia")


@dataclass(frozen=True)
class DomainRandomization:
    """Per-episode randomisation of the true plant and the sensors (off unless requested).

    Each friction coefficient (upper static and viscous levels, lower static, viscous,
    hump amplitudes and rates) and each inertia is multiplied by its own factor drawn
    uniformly from ``[1 - rel, 1 + rel]``; a draw that makes the lower friction
    non-dissipative (eq. 4) is redrawn. The encoder resolution is drawn from
    ``encoder_counts`` (empty: keep the sensors' value) and the noise levels uniformly
    from their ``(low, high)`` ranges. ``effects`` maps fields of
    :class:`~drill_env.params.ModelEffects` to ``(low, high)``: each is drawn uniformly per
    episode (after the factors, in the order of ModelEffects' fields), e.g.
    ``{"lower_position_amp_1": (0, 0.15), "lower_position_phase_1": (0, 6.2832)}``; the
    other effects keep the preset's values.
    """

    friction_rel: float = 0.1  # [-]
    inertia_rel: float = 0.05  # [-]
    stiffness_rel: float = 0.0  # [-] string stiffness k_theta
    motor_constant_rel: float = 0.0  # [-] k_m
    encoder_counts: tuple[int, ...] = (1000, 2000, 4000)  # [counts/rev]
    angle_noise_std: tuple[float, float] = (0.0, 5e-4)  # [rad]
    speed_noise_std: tuple[float, float] = (0.0, 0.05)  # [rad/s]
    effects: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)  # SI units

    def __post_init__(self) -> None:
        for name in ("friction_rel", "inertia_rel", "stiffness_rel", "motor_constant_rel"):
            _number(f"domain_randomization.{name}", getattr(self, name), 0.0, 0.5)
        counts = self.encoder_counts
        if isinstance(counts, (int, np.integer)) and not isinstance(counts, bool):
            counts = (int(counts),)
        try:
            counts = tuple(counts)
        except TypeError:
            raise ValueError(
                f"domain_randomization.encoder_counts: expected a sequence of integers, got {counts!r}"
            ) from None
        for c in counts:
            if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or not 1 <= int(c) < 2**31:
                raise ValueError(f"domain_randomization.encoder_counts: {c!r} is not an integer in [1, 2^31)")
        object.__setattr__(self, "encoder_counts", tuple(int(c) for c in counts))
        for name in ("angle_noise_std", "speed_noise_std"):
            rng = getattr(self, name)
            try:
                lo, hi = (float(v) for v in rng)
            except (TypeError, ValueError):
                raise ValueError(f"domain_randomization.{name}: expected (low, high), got {rng!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo <= hi):
                raise ValueError(
                    f"domain_randomization.{name}: expected finite 0 <= low <= high, got {rng!r}"
                )
            object.__setattr__(self, name, (lo, hi))
        object.__setattr__(self, "effects", _effect_ranges(self.effects))

    @classmethod
    def from_any(cls, value: Any) -> DomainRandomization | None:
        if value is None or value is False:
            return None
        if value is True:
            return cls()
        return config_from_any(cls, value, "domain_randomization")


def _effect_ranges(value: Any) -> dict[str, tuple[float, float]]:
    """Validated ``domain_randomization.effects``: ModelEffects fields (in their order) to
    finite ``(low, high)``, both ends valid effect values and the largest magnitudes
    together a valid ModelEffects."""
    from drill_env.params import ModelEffects

    if not isinstance(value, Mapping):
        raise ValueError(
            f"domain_randomization.effects: expected a mapping of effect names to (low, high), got {value!r}"
        )
    order = [f.name for f in fields(ModelEffects)]
    unknown = sorted(set(value) - set(order))
    if unknown:
        raise ValueError(f"domain_randomization.effects: unknown effect(s) {unknown}; allowed: {order}")
    out: dict[str, tuple[float, float]] = {}
    for name in order:
        if name not in value:
            continue
        rng = value[name]
        field_name = f"domain_randomization.effects.{name}"
        try:
            if isinstance(rng, (str, bytes)):
                raise TypeError
            lo, hi = (float(v) for v in rng)
        except (TypeError, ValueError):
            raise ValueError(f"{field_name}: expected (low, high), got {rng!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"{field_name}: expected finite low <= high, got {rng!r}")
        for v in (lo, hi):
            try:
                ModelEffects(**{name: v})
            except ParameterError as exc:
                raise ValueError(f"domain_randomization.{exc}") from None
        out[name] = (lo, hi)
    worst = {n: max(abs(lo), abs(hi)) for n, (lo, hi) in out.items() if "_position_amp_" in n}
    try:
        ModelEffects(**worst)
    except ParameterError as exc:
        raise ValueError(f"domain_randomization.{exc} at the ends of the ranges") from None
    return out


@dataclass(frozen=True)
class EpisodeSetup:
    """Everything random about one episode, drawn before the rig is simulated."""

    point: OperatingPoint
    start: int
    warm_ticks: int
    plant: RigParams  # the true plant of this episode (randomised or nominal)
    params: np.ndarray  # plant.as_array()
    sensor_config: SensorConfig  # the episode's measurement chain
    sensors: np.ndarray  # sensor_config.as_array()
    rng: np.ndarray  # uint64[4], noise generator state
    y0: np.ndarray  # kernel state at the start (before the warm-up)


MAX_SENSOR_SAMPLES_PER_STEP = 100_000  # sensor samples in one control period (memory per step)


class EnvSettings:
    """Validated configuration of a drill-string environment (see DrillStringEnv's arguments)."""

    def __init__(
        self,
        params: RigParams | str | Path = "brake",
        params_overrides: Mapping[str, Any] | None = None,
        control_dt: float = 0.05,
        sensors: SensorConfig | Mapping[str, Any] | None = None,
        task: TaskConfig | Mapping[str, Any] | None = None,
        start: str = "open_loop",
        warmup_time: float = 20.0,
        warmup_jitter: float = 5.0,
        reward_weights: RewardWeights | Mapping[str, float] | None = None,
        domain_randomization: DomainRandomization | Mapping[str, Any] | bool | None = None,
        action_mode: str = "normalized",
        normalize_observation: bool = True,
        rtol: float = DEFAULT_RTOL,
        atol: float = DEFAULT_ATOL,
        observation_version: int = 0,
        start_angle: float | str = 0.0,
        design_params: RigParams | str | Path | None = None,
        action_range: float | None = None,
        tracking_cost: str = "relative_squared",
        scenario: Any = None,
    ):
        from drill_env.envs.scenarios import get_scenario

        # a scenario of the suite (drill_env.envs.scenarios): its start and sensor fields replace
        # those given; its set points and friction changes run in the episode
        self.scenario = None if scenario is None else get_scenario(scenario)
        if self.scenario is not None:
            start = self.scenario.start
        if params_overrides is not None and not isinstance(params_overrides, Mapping):
            raise ValueError(
                f"params_overrides: expected a dict of parameter values, got {params_overrides!r}"
            )
        self.params = resolve_params(params, **dict(params_overrides or {}))
        # the model the operating points and regimes belong to (its effects kept for the
        # controllers that use them; the task uses its paper model)
        self.design_params = (
            nominal_params(self.params) if design_params is None else resolve_params(design_params)
        )
        self.sensors = SensorConfig.from_any(sensors)
        if self.scenario is not None and self.scenario.sensors:
            self.sensors = dataclasses.replace(self.sensors, **self.scenario.sensors)
        ts = self.sensors.sample_period
        self.control_dt = _number("control_dt", control_dt, 0.0, 60.0, lo_incl=False)
        n_sub = int(round(self.control_dt / ts))
        if n_sub < 1 or abs(n_sub * ts - self.control_dt) > 1e-9 * self.control_dt:
            raise ValueError(
                f"control_dt: {control_dt!r} s must be a whole number (>= 1) of sensor periods "
                f"(1/sample_rate_hz = {ts:g} s)"
            )
        if n_sub > MAX_SENSOR_SAMPLES_PER_STEP:
            raise ValueError(
                f"control_dt: {control_dt!r} s is {n_sub} sensor samples at sample_rate_hz = "
                f"{self.sensors.sample_rate_hz:g} Hz; allowed: at most {MAX_SENSOR_SAMPLES_PER_STEP} per control step"
            )
        self.n_sub = n_sub
        self.task = TaskConfig.from_any(task)
        if start not in START_STATES:
            raise ValueError(f"start: {start!r} is not one of {sorted(START_STATES)}")
        self.start = start
        self.warmup_time = _number("warmup_time", warmup_time, 0.0, 3600.0)
        self.warmup_jitter = _number("warmup_jitter", warmup_jitter, 0.0, 3600.0)
        if start_angle == "random":
            self.start_angle: float | str = "random"
        else:
            if isinstance(start_angle, str):
                raise ValueError(
                    f"start_angle: expected a number in [0, 2 pi) rad or 'random', got {start_angle!r}"
                )
            self.start_angle = _number("start_angle", start_angle, 0.0, 2.0 * math.pi)
            if self.start_angle >= 2.0 * math.pi:
                raise ValueError(f"start_angle: {start_angle!r} is outside the allowed range [0, 2 pi) rad")
        self.reward_weights = config_from_any(RewardWeights, reward_weights, "reward_weights")
        if not isinstance(tracking_cost, str) or tracking_cost not in TRACKING_COSTS:
            raise ValueError(f"tracking_cost: {tracking_cost!r} is not one of {list(TRACKING_COSTS)}")
        self.tracking_cost = tracking_cost
        self.randomization = DomainRandomization.from_any(domain_randomization)
        if action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode: {action_mode!r} is not one of {list(ACTION_MODES)}")
        self.action_mode = action_mode
        if action_range is None:
            action_range = CORRECTION_RANGE if action_mode == "correction" else VOLTAGE_LIMIT
        elif action_mode != "correction":
            raise ValueError(
                f"action_range: applies to action_mode='correction' only (got action_mode={action_mode!r})"
            )
        # [V] the voltage of action 1 (normalized: 5 V; voltage: unused)
        self.action_range = _number("action_range", action_range, 0.0, 2.0 * VOLTAGE_LIMIT, lo_incl=False)
        if not isinstance(normalize_observation, (bool, np.bool_)):
            raise ValueError(f"normalize_observation: expected True or False, got {normalize_observation!r}")
        self.normalize_observation = bool(normalize_observation)
        if (
            isinstance(observation_version, (bool, np.bool_))
            or not isinstance(observation_version, (int, np.integer))
            or int(observation_version) not in OBSERVATION_VERSIONS
        ):
            raise ValueError(
                f"observation_version: {observation_version!r} is not one of {list(OBSERVATION_VERSIONS)}"
            )
        self.observation_version = int(observation_version)
        layout = observation_layout(self.observation_version)
        self.n_obs = C.n_obs(self.observation_version)
        self.observation_names: tuple[str, ...] = layout["names"]
        self.observation_units: tuple[str, ...] = layout["units"]
        self._obs_low = np.asarray(layout["low"], dtype=np.float64)
        self._obs_high = np.asarray(layout["high"], dtype=np.float64)
        self.rtol = _number("rtol", rtol, 1e-14, 1e-3)
        self.atol = _number("atol", atol, 1e-16, 1e-3)
        self.sampler = OperatingPointSampler(self.design_params, self.task)
        self.action_to_volts = 1.0 if action_mode == "voltage" else self.action_range
        # correction: the action is the voltage added to the episode's nominal voltage
        self.action_offset = action_mode == "correction"
        settle_time = max(SETTLE_TIME, (self.sensors.delay_samples + 50) * ts)
        self.settle_periods = max(1, int(math.ceil(settle_time / self.control_dt - 1e-9)))
        self.ecfg = self._env_vector()
        self.schedule = self._scenario_schedule()
        self._p_nominal = self.params.as_array()
        self._scfg_nominal = self.sensors.as_array()

    def observation_space(self):
        """The observation Box (normalised or physical units)."""
        from gymnasium import spaces

        scale = self.observation_scales
        low = self._obs_low / scale
        high = self._obs_high / scale
        return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)

    @property
    def observation_scales(self) -> np.ndarray:
        """Divisor of each observation entry (physical = obs * scale; all 1 unnormalised)."""
        return self.ecfg[C.EC_SCALE : C.EC_SCALE + self.n_obs].copy()

    def action_space(self):
        """The action Box: the voltage / 5 V (normalized) or the voltage [V]."""
        from gymnasium import spaces

        amax = VOLTAGE_LIMIT if self.action_mode == "voltage" else 1.0
        return spaces.Box(-amax, amax, shape=(1,), dtype=np.float32)

    def _env_vector(self) -> np.ndarray:
        e = np.zeros(C.NEC)
        e[C.EC_RTOL] = self.rtol
        e[C.EC_ATOL] = self.atol
        e[C.EC_NSUB] = self.n_sub
        w = self.reward_weights
        e[C.EC_W_TRACK] = w.tracking
        e[C.EC_W_STICK] = w.stick
        e[C.EC_W_OSC] = w.oscillation
        e[C.EC_W_EFFORT] = w.effort
        e[C.EC_W_INTEGRAL] = w.integral
        e[C.EC_W_OVERDRIVE] = w.overdrive
        e[C.EC_SPEED_REF] = SPEED_REF_FLOOR
        e[C.EC_TRACK_ABS] = 1.0 if self.tracking_cost == "absolute" else 0.0
        e[C.EC_VMAX] = VOLTAGE_LIMIT
        e[C.EC_SETTLE] = self.settle_periods
        e[C.EC_MAX_STEPS] = max(100_000, 20_000 * self.n_sub)
        e[C.EC_OBS_VERSION] = self.observation_version
        e[C.EC_INT_BOUND] = INTEGRAL_BOUND
        e[C.EC_SCALE : C.EC_SCALE + C.NOBS] = 1.0
        if self.normalize_observation:
            e[C.EC_SCALE : C.EC_SCALE + self.n_obs] = observation_layout(self.observation_version)["scales"]
        return e

    def _scenario_schedule(self) -> Any:
        """The scenario's set points on the design model, for a scenario that changes something
        during the episode (None otherwise)."""
        if self.scenario is None or not self.scenario.time_varying:
            return None
        from drill_env.envs.scenarios import ScenarioSchedule

        voltages = self.scenario.set_point_voltages(self.design_params.name)
        points = [self.sampler.point_from_voltage(v) for v in voltages]
        return ScenarioSchedule(
            self.scenario, points, self.ecfg[C.EC_SCALE + C.OB_TARGET], self.ecfg[C.EC_SCALE + C.OB_UNOM]
        )

    @property
    def sensor_state_size(self) -> int:
        from drill_env.sensors import state_size

        return state_size(self.sensors.delay_samples)

    # -- per episode ---------------------------------------------------------------------------
    def parse_options(self, options: Mapping[str, Any] | None) -> dict[str, Any]:
        """Validate ``reset(options=...)``: at most one of target_speed / nominal_voltage /
        regime, and optionally start."""
        if options is None:
            options = {}
        if not isinstance(options, Mapping):
            raise ValueError(f"options: expected a dict, got {type(options).__name__}")
        allowed = {"target_speed", "nominal_voltage", "regime", "start"}
        unknown = sorted(set(options) - allowed - {"reset_mask"})
        if unknown:
            raise ValueError(f"options: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
        chosen = [k for k in ("target_speed", "nominal_voltage", "regime") if k in options]
        if len(chosen) > 1:
            raise ValueError(
                f"options: give at most one of target_speed, nominal_voltage, regime; got {chosen}"
            )
        out: dict[str, Any] = {}
        s = self.sampler
        if "target_speed" in options:
            v = options["target_speed"]
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ValueError(
                    f"target_speed: expected a number in (0, {s.speed_max:.6g}] rad/s, got {v!r}"
                )
            out["point"] = s.point_from_speed(float(v))
        elif "nominal_voltage" in options:
            v = options["nominal_voltage"]
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ValueError(f"nominal_voltage: expected a number in ({s.uc1:.6g}, 5] V, got {v!r}")
            out["point"] = s.point_from_voltage(float(v))
        elif "regime" in options:
            if options["regime"] not in REGIMES:
                raise ValueError(f"regime: {options['regime']!r} is not one of {REGIMES}")
            out["regime"] = options["regime"]
        if "start" in options:
            if options["start"] not in START_STATES:
                raise ValueError(f"start: {options['start']!r} is not one of {sorted(START_STATES)}")
            out["start"] = options["start"]
        if self.scenario is not None and "point" not in out and "regime" not in out:
            # the scenario's first set point unless the options choose one
            v0 = self.scenario.set_point_voltages(self.design_params.name)[0]
            out["point"] = s.point_from_voltage(v0)
        return out

    def draw_episode(self, rng: np.random.Generator, opts: Mapping[str, Any]) -> EpisodeSetup:
        """Draw an episode (operating point, warm-up length, plant, sensors, noise seed)."""
        if "point" in opts:
            point = opts["point"]
        elif "regime" in opts:
            point = self.sampler.point_in_regime(opts["regime"], rng)
        else:
            point = self.sampler.sample(rng)
        start = START_STATES[opts.get("start", self.start)]
        warm_ticks = self.draw_warm_ticks(rng)
        plant = self.params
        p = self._p_nominal
        sensors = self.sensors
        scfg = self._scfg_nominal
        dr = self.randomization
        if dr is not None:
            plant = self._randomized_params(rng, dr)
            p = plant.as_array()
            sensors = self._randomized_sensors(rng, dr)
            scfg = sensors.as_array()
        words = rng.integers(0, 2**64, size=4, dtype=np.uint64)
        if start == C.START_EQUILIBRIUM:
            y0 = equilibrium_state(self.sampler.params, point.nominal_voltage)
            y0[L.TM] = p[L.KM] * point.nominal_voltage
        else:
            y0 = np.zeros(L.NY)
            if start == C.START_OPEN_LOOP:
                y0[L.TM] = p[L.KM] * point.nominal_voltage
        # where the (untwisted) disks stand at the start; drawn last, so that the other draws
        # of a seed do not depend on it
        y0[L.THL] = 2.0 * math.pi * float(rng.uniform()) if self.start_angle == "random" else self.start_angle
        return EpisodeSetup(point, start, warm_ticks, plant, p, sensors, scfg, rng_state(words), y0)

    def draw_warm_ticks(self, rng: np.random.Generator) -> int:
        """Length of the open-loop warm-up in sensor ticks (drawn for every start state, so
        the random stream does not depend on it)."""
        t = self.warmup_time + self.warmup_jitter * float(rng.uniform())
        return int(round(t / self.sensors.sample_period))

    def _randomized_params(self, rng: np.random.Generator, dr: DomainRandomization) -> RigParams:
        rels = (
            [(f, dr.friction_rel) for f in _FRICTION_FIELDS]
            + [(f, dr.inertia_rel) for f in _INERTIA_FIELDS]
            + [("string_stiffness", dr.stiffness_rel), ("motor_constant", dr.motor_constant_rel)]
        )
        base = self.params
        for _ in range(MAX_RANDOMIZATION_TRIES):
            factors = rng.uniform(-1.0, 1.0, size=len(rels))
            changes = {
                name: getattr(base, name) * (1.0 + rel * f)
                for (name, rel), f in zip(rels, factors, strict=True)
                if rel > 0
            }
            if dr.effects:
                changes.update({n: float(rng.uniform(lo, hi)) for n, (lo, hi) in dr.effects.items()})
            try:
                return base.replace(**changes)
            except ParameterError:
                continue  # non-dissipative lower friction: draw again
        raise ValueError(
            "domain_randomization: no valid plant found in "
            f"{MAX_RANDOMIZATION_TRIES} draws; reduce friction_rel ({dr.friction_rel:g})"
        )

    def _randomized_sensors(self, rng: np.random.Generator, dr: DomainRandomization) -> SensorConfig:
        cfg = self.sensors
        changes: dict[str, Any] = {}
        if dr.encoder_counts:
            changes["counts_per_rev"] = dr.encoder_counts[int(rng.integers(len(dr.encoder_counts)))]
        changes["angle_noise_std"] = float(rng.uniform(*dr.angle_noise_std))
        changes["speed_noise_std"] = float(rng.uniform(*dr.speed_noise_std))
        return dataclasses.replace(cfg, **changes)
