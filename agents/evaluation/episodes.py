"""The one evaluation path: environment + controller + operating point + seed -> metrics.

Every controller, classical or learned, is run by :func:`run_episode` through SB3's
``predict`` protocol and scored by :func:`evaluate` from the environment's *true* state
(``info["true_state"]`` every control period and the 1 kHz true samples of
:meth:`~drill_env.envs.drill_string.DrillStringEnv.last_step_samples` in the scoring
window), never from the sensors the controller sees.

An evaluation episode: ``env.reset(seed=seed, options={"nominal_voltage": u})`` runs the
rig open loop from rest at the nominal voltage for ``warmup_time + U(0, warmup_jitter)``
seconds (the environment's ``start="open_loop"``), so the controller is switched on
where the paper's experiments are: on the open-loop equilibrium, limit cycle or
stick-slip cycle, at a random phase. It then runs for ``duration`` seconds; the steady
state is measured over the last ``window`` seconds. Everything random about an episode
(warm-up length, sensor noise) is drawn from the seed alone, before and independently
of the controller's actions: the same seed gives every controller the same initial state
and the same noise.

Metrics (:class:`RunMetrics`), over the window unless stated:

* ``amplitude``: max - min of the lower-disk speed x3 [rad/s];
* ``open_loop_amplitude``: max - min of x3 on the open-loop limit cycle that the
  bifurcation analysis (:func:`drill_env.analysis.limit_cycle`, nominal model) predicts
  at the nominal voltage; 0 where it predicts a stable equilibrium and no cycle;
* ``suppression = 1 - amplitude / open_loop_amplitude`` where a cycle is predicted, NaN
  elsewhere (1: cycle removed; 0: as open loop; negative: worse); a *stalled* run scores
  ``min(suppression, 0)``: no better than the open loop;
* ``stalled``: the run failed to turn the lower disk at the target: stuck over more than
  :data:`STALL_STUCK_FRACTION` (half) of the window, or its mean speed off the target by more
  than :data:`STALL_SPEED_ERROR` (half) of the target. A disk that stops has no cycle left,
  so its raw suppression is near 1; the flag makes it a failure in every summary;
* ``plant_open_loop_regime``: how the *plant* behaves open loop at the voltage, measured
  (the open-loop run on it, when the caller passes one) or, on the design model itself,
  predicted by the analysis: ``equilibrium`` (no cycle above the benchmark's floor),
  ``limit_cycle`` (a cycle without sticking) or ``stick_slip``; beside ``regime``, the design
  model's label, so that a plant that oscillates where the model predicts an equilibrium is
  visible;
* ``stick_fraction``: fraction of the 1 kHz samples with the lower disk stuck;
* ``severity``: the stick-slip severity (max - min) / (2 mean) of x3;
* ``rms_error``: RMS of x3 - w* (the target speed) [rad/s];
* ``u_mean_abs``, ``u_peak_abs`` [V], ``u_limit_fraction``: mean and peak |u| and the
  fraction of control periods at the +-5 V limit (a request at or beyond it), over the
  whole closed-loop episode (transients included);
* ``x3_peak_abs``: the largest |x3| over the whole closed-loop episode (every control
  period and the window's 1 kHz samples) [rad/s]; ``beyond_identified_range``: True when it
  exceeds the speed up to which the preset's friction was identified
  (:data:`IDENTIFIED_SPEED`: 12.6 rad/s for the brake, Sec. 4 of the paper), i.e. the run
  left what the model vouches for;
* ``episode_return``: the environment's reward summed over the episode, on the env version
  the controller runs on (v0 for the classical controllers, a policy's own version for a
  learned one): from v3 the tracking term is the absolute speed error, so returns compare
  within a version only.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import gymnasium as gym
import numpy as np

from drill_env.agents.controllers.base import PolicyPredictor
from drill_env.envs import ENV_IDS, ENV_VERSIONS, make_version
from drill_env.envs.task import VOLTAGE_LIMIT
from drill_env.metrics import stick_slip_metrics
from drill_env.params import IDENTIFIED_SPEED_RAD_S

__all__ = [
    "IDENTIFIED_SPEED",
    "STALL_SPEED_ERROR",
    "STALL_STUCK_FRACTION",
    "EpisodeSettings",
    "RunMetrics",
    "Trajectory",
    "env_id_of",
    "evaluate",
    "make_env",
    "known_open_loop_cycles",
    "open_loop_cycle",
    "run_episode",
    "is_stalled",
    "open_loop_regime",
    "suppression",
]

# The registered id of each preset and observation version (classical controllers run on
# version 0; a learned policy on the version it was trained on, see drill_env.agents.registry).
ENV_ID_OF = {(preset, ENV_VERSIONS[env_id]): env_id for env_id, preset in ENV_IDS.items()}
PRESET_ENV_IDS = {preset: env_id for (preset, version), env_id in ENV_ID_OF.items() if version == 0}
LIMIT_TOL = 1e-6  # [V] a voltage within this of +-5 V counts as at the limit
# [rad/s] the lower-disk speed up to which a preset's friction was identified from rig data:
# the brake's measured friction reached about 12.6 rad/s (Sec. 4 of the paper); the no-brake
# friction has no stated limit.
IDENTIFIED_SPEED: dict[str, float] = IDENTIFIED_SPEED_RAD_S
# A run is stalled (a failure, whatever its amplitude) when the lower disk is stuck over more
# than this fraction of the scoring window ...
STALL_STUCK_FRACTION = 0.5
# ... or its mean speed is off the target by more than this fraction of the target.
STALL_SPEED_ERROR = 0.5


def env_id_of(preset: str, observation_version: int = 0) -> str:
    """The registered environment of a preset and observation version
    (``brake`` -> ``DrillString-v0``, ``("brake", 1)`` -> ``DrillString-v1``)."""
    if preset not in PRESET_ENV_IDS:
        raise ValueError(f"preset: {preset!r} is not one of {sorted(PRESET_ENV_IDS)}")
    key = (preset, observation_version)
    if key not in ENV_ID_OF:
        versions = sorted(v for p, v in ENV_ID_OF if p == preset)
        raise ValueError(f"observation_version: {observation_version!r} is not one of {versions}")
    return ENV_ID_OF[key]


# The longest closed-loop time or warm-up of one evaluation episode [s]: 1e6 control steps at
# the 10 ms control period, some minutes of computing per run; the rig's runs last minutes.
MAX_EPISODE_S = 1e4


def _positive(name: str, value: Any, *, allow_zero: bool = False, upper: float = MAX_EPISODE_S) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero) or v > upper:
        raise ValueError(
            f"{name}: {value!r} is outside the allowed range {'[0' if allow_zero else '(0'}, {upper:g}] s"
        )
    return v


@dataclass(frozen=True)
class EpisodeSettings:
    """How an evaluation episode runs (see the module docstring)."""

    duration: float = 90.0  # [s] closed-loop time
    window: float = 20.0  # [s] steady-state window at the end (about 5 torsional periods)
    warmup_time: float = 60.0  # [s] open-loop run from rest before the controller is switched on
    warmup_jitter: float = 4.0  # [s] random extra warm-up: the phase of the cycle at switch-on
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)  # further DrillStringEnv arguments

    def __post_init__(self) -> None:
        _positive("duration", self.duration)
        _positive("window", self.window)
        _positive("warmup_time", self.warmup_time, allow_zero=True)
        _positive("warmup_jitter", self.warmup_jitter, allow_zero=True)
        if self.window > self.duration:
            raise ValueError(f"window: {self.window!r} s must not exceed duration ({self.duration!r} s)")
        if not isinstance(self.env_kwargs, Mapping):
            raise ValueError(
                f"env_kwargs: expected a mapping of DrillStringEnv arguments, got {self.env_kwargs!r}"
            )
        reserved = {
            "params",
            "design_params",
            "warmup_time",
            "warmup_jitter",
            "max_episode_steps",
            "task",
        } & set(self.env_kwargs)
        if reserved:
            raise ValueError(f"env_kwargs: {sorted(reserved)} are set by the evaluation itself")
        object.__setattr__(self, "env_kwargs", dict(self.env_kwargs))

    def n_steps(self, control_dt: float) -> int:
        return int(round(self.duration / control_dt))

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def make_env(
    preset: str,
    settings: EpisodeSettings,
    observation_version: int = 0,
    params: Any = None,
    overrides: Mapping[str, Any] | None = None,
    design_params: Any = None,
) -> gym.Env:
    """The registered environment of ``preset`` (observation version ``observation_version``)
    configured for evaluation episodes. The versions differ only in what is observed: the
    same seed gives the same episode. ``params`` (a ``RigParams``, preset name or YAML path)
    replaces the preset's rig: the *plant* the controller runs on, the truth. What the
    controller, the task and the regime labels know (target speed, nominal voltage, regime)
    comes from the *design model* ``design_params``: by default the preset's model, whatever
    the plant (a controller on a real rig does not know the rig's equilibrium speed).
    ``overrides`` (e.g. ``{"sensors": {...}}`` of a plant's measurement chain) replace
    arguments of ``settings.env_kwargs``."""
    kwargs = {**settings.env_kwargs, **(overrides or {})}
    if params is not None:
        kwargs["params"] = params
        kwargs["design_params"] = preset if design_params is None else design_params
    elif design_params is not None:
        kwargs["design_params"] = design_params
    # an older version is chosen on purpose (the classical controllers' and a policy's own):
    # gymnasium's "out of date" is not news to the user here
    return make_version(
        env_id_of(preset, observation_version),
        max_episode_steps=10**9,  # the evaluation decides the length
        warmup_time=settings.warmup_time,
        warmup_jitter=settings.warmup_jitter,
        **kwargs,
    )


@dataclass
class Trajectory:
    """One closed-loop episode: per control period, and the true 1 kHz samples of the window."""

    t: np.ndarray  # [s] end of each control period
    voltage: np.ndarray  # [V] applied
    voltage_requested: np.ndarray  # [V]
    true_state: np.ndarray  # (n, 5) twist, upper speed, lower speed, upper angle, lower angle
    reward: np.ndarray
    window_t: np.ndarray  # [s] 1 kHz samples of the scoring window
    window_lower_speed: np.ndarray  # [rad/s]
    window_lower_stuck: np.ndarray  # bool
    reset_info: dict[str, Any]
    sim_status: int

    def to_pandas(self):
        import pandas as pd

        return pd.DataFrame(
            {
                "t": self.t,
                "u": self.voltage,
                "u_requested": self.voltage_requested,
                "x1": self.true_state[:, 0],
                "x2": self.true_state[:, 1],
                "x3": self.true_state[:, 2],
                "reward": self.reward,
            }
        )


def run_episode(
    env: gym.Env,
    controller: PolicyPredictor,
    *,
    seed: int,
    n_steps: int,
    options: Mapping[str, Any] | None = None,
    window_steps: int = 0,
    deterministic: bool = True,
) -> Trajectory:
    """Run ``controller`` on ``env`` for ``n_steps`` control periods from ``env.reset(seed, options)``.

    The controller is called exactly as SB3 calls a policy: ``predict(obs, state,
    episode_start, deterministic)``. The 1 kHz true samples of the last ``window_steps``
    periods are kept.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: expected an integer >= 0, got {seed!r}")
    if n_steps < 1:
        raise ValueError(f"n_steps: expected an integer >= 1, got {n_steps!r}")
    obs, info = env.reset(seed=int(seed), options=dict(options or {}))
    base = env.unwrapped
    state = None
    start = np.ones((1,), dtype=bool)
    t = np.zeros(n_steps)
    u = np.zeros(n_steps)
    u_req = np.zeros(n_steps)
    xs = np.zeros((n_steps, 5))
    rew = np.zeros(n_steps)
    w_t, w_x3, w_stuck = [], [], []
    status = 0
    k = 0
    for k in range(n_steps):
        action, state = controller.predict(obs, state=state, episode_start=start, deterministic=deterministic)
        start = np.zeros((1,), dtype=bool)
        obs, r, terminated, truncated, step_info = env.step(action)
        t[k] = step_info["time"]
        u[k] = step_info["voltage"]
        u_req[k] = step_info["voltage_requested"]
        xs[k] = step_info["true_state"]
        rew[k] = r
        if k >= n_steps - window_steps:
            s = base.last_step_samples()
            w_t.append(s["t"])
            w_x3.append(s["lower_speed"])
            w_stuck.append(s["lower_stuck"])
        status = int(step_info["sim_status"])
        if terminated or truncated:
            break
    n = k + 1
    return Trajectory(
        t=t[:n],
        voltage=u[:n],
        voltage_requested=u_req[:n],
        true_state=xs[:n],
        reward=rew[:n],
        window_t=np.concatenate(w_t) if w_t else np.zeros(0),
        window_lower_speed=np.concatenate(w_x3) if w_x3 else np.zeros(0),
        window_lower_stuck=np.concatenate(w_stuck) if w_stuck else np.zeros(0, dtype=bool),
        reset_info=info,
        sim_status=status,
    )


_OPEN_LOOP_CYCLES: dict[tuple[str, float], dict[str, float]] = {}


def open_loop_cycle(preset: str, voltage: float) -> dict[str, float]:
    """The open-loop limit cycle the analysis predicts at ``voltage`` on the nominal model:
    amplitude (max - min of x3, 0 if there is no stable cycle), period, stick fraction,
    and x3 min/max (the equilibrium speed twice if there is no cycle). Computed once per
    process (or taken from :func:`known_open_loop_cycles`)."""
    key = (str(preset), float(voltage))
    cycle = _OPEN_LOOP_CYCLES.get(key)
    if cycle is None:
        cycle = _OPEN_LOOP_CYCLES[key] = _analysed_open_loop_cycle(*key)
    return cycle


def known_open_loop_cycles(cycles: Mapping[tuple[str, float], dict[str, float]]) -> None:
    """Take open-loop cycles (:func:`open_loop_cycle`'s results) computed by another process:
    the one that starts a pool of workers computes them once, so that the workers neither
    compute them again nor compile the analysis each."""
    _OPEN_LOOP_CYCLES.update({(str(p), float(v)): dict(c) for (p, v), c in cycles.items()})


def _analysed_open_loop_cycle(preset: str, voltage: float) -> dict[str, float]:
    from drill_env.analysis import limit_cycle, slip_equilibrium
    from drill_env.params import load_params

    params = load_params(preset)
    cyc = limit_cycle(params, float(voltage))
    if cyc is None or not cyc.stable:
        eq = slip_equilibrium(params, float(voltage))
        w = 0.0 if eq is None else float(eq.x3)
        return {"amplitude": 0.0, "period": math.nan, "stick_fraction": 0.0, "x3_min": w, "x3_max": w}
    return {
        "amplitude": float(cyc.amplitude),
        "period": float(cyc.period),
        "stick_fraction": float(cyc.stick_fraction),
        "x3_min": float(cyc.x3_min),
        "x3_max": float(cyc.x3_max),
    }


def suppression(amplitude: float, open_loop_amplitude: float) -> float:
    """``1 - amplitude / open_loop_amplitude``; NaN where the analysis predicts no cycle."""
    a, a0 = float(amplitude), float(open_loop_amplitude)
    if not (math.isfinite(a) and a >= 0):
        raise ValueError(f"amplitude: expected a finite number >= 0 rad/s, got {amplitude!r}")
    if not (math.isfinite(a0) and a0 >= 0):
        raise ValueError(
            f"open_loop_amplitude: expected a finite number >= 0 rad/s, got {open_loop_amplitude!r}"
        )
    return 1.0 - a / a0 if a0 > 0 else math.nan


def is_stalled(stick_fraction: float, mean_speed: float, target_speed: float) -> bool:
    """The stalled rule (module docstring): stuck over more than :data:`STALL_STUCK_FRACTION`
    of the window, or the mean speed off the target by more than :data:`STALL_SPEED_ERROR`
    of it."""
    w = float(target_speed)
    if not (math.isfinite(w) and w > 0):
        return False
    off = abs(float(mean_speed) - w) > STALL_SPEED_ERROR * w if math.isfinite(float(mean_speed)) else True
    return bool(float(stick_fraction) > STALL_STUCK_FRACTION or off)


def open_loop_regime(amplitude: float, stick_fraction: float, floor: float = 0.0) -> str:
    """The regime an open-loop run shows: ``equilibrium`` (amplitude at or below ``floor``
    [rad/s]), ``stick_slip`` (the lower disk sticks) or ``limit_cycle``."""
    if not amplitude > floor:
        return "equilibrium"
    return "stick_slip" if stick_fraction > 0 else "limit_cycle"


@dataclass(frozen=True)
class RunMetrics:
    """One controller at one operating point and seed (the benchmark's CSV row)."""

    controller: str
    preset: str
    voltage: float  # [V] nominal voltage of the operating point
    seed: int
    regime: str  # of the design model at this voltage (equilibrium, limit_cycle, stick_slip)
    plant_open_loop_regime: str  # what the plant does open loop at this voltage (same labels)
    target_speed: float  # [rad/s] the design model's slip-equilibrium speed
    stalled: bool  # the lower disk stuck or far off the target (a failure; module docstring)
    amplitude: float  # [rad/s]
    open_loop_amplitude: float  # [rad/s] predicted by the analysis
    suppression: float  # [-] min(., 0) when stalled
    stick_fraction: float  # [-]
    severity: float  # [-]
    rms_error: float  # [rad/s]
    mean_speed: float  # [rad/s]
    x3_min: float  # [rad/s]
    x3_max: float  # [rad/s]
    period: float  # [s] dominant period of x3 in the window (nan: none)
    u_mean_abs: float  # [V]
    u_peak_abs: float  # [V]
    u_limit_fraction: float  # [-]
    x3_peak_abs: float  # [rad/s] over the whole closed-loop episode
    beyond_identified_range: bool  # x3_peak_abs above IDENTIFIED_SPEED[preset]
    episode_return: float
    sim_status: int
    wall_time: float  # [s]

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


METRIC_COLUMNS = tuple(f.name for f in fields(RunMetrics))


def evaluate(
    controller: PolicyPredictor,
    preset: str,
    voltage: float,
    seed: int,
    settings: EpisodeSettings | None = None,
    *,
    name: str | None = None,
    env: gym.Env | None = None,
    open_loop_amplitude: float | None = None,
    plant_open_loop_regime: str | None = None,
) -> RunMetrics:
    """Run one evaluation episode and score it (see the module docstring).

    ``env`` may be passed to reuse an environment made by :func:`make_env` with the same
    preset and settings (and possibly another plant). ``open_loop_amplitude`` [rad/s]
    replaces the analysis' prediction as the reference of the suppression (for a plant the
    analysis does not cover: the open-loop run on that plant), ``plant_open_loop_regime``
    what that run showed (:func:`open_loop_regime`; default: the analysis' prediction on the
    preset's model where no reference is given, else from the reference amplitude alone).
    """
    settings = settings or EpisodeSettings()
    v = float(voltage)
    if not (math.isfinite(v) and 0 < v <= VOLTAGE_LIMIT):
        raise ValueError(f"voltage: {voltage!r} is outside the allowed range (0, {VOLTAGE_LIMIT:g}] V")
    t0 = time.perf_counter()
    own = env is None
    if own:
        env = make_env(preset, settings)
    try:
        dt = env.unwrapped.control_dt
        n = settings.n_steps(dt)
        nw = max(1, int(round(settings.window / dt)))
        traj = run_episode(
            env, controller, seed=seed, n_steps=n, options={"nominal_voltage": v}, window_steps=nw
        )
    finally:
        if own:
            env.close()
    info = traj.reset_info
    w = float(info["target_speed"])
    m = stick_slip_metrics(traj.window_t, traj.window_lower_speed, traj.window_lower_stuck)
    ol = (
        open_loop_cycle(preset, v)
        if open_loop_amplitude is None
        else {"amplitude": float(open_loop_amplitude)}
    )
    if plant_open_loop_regime is None:
        if open_loop_amplitude is None:
            plant_open_loop_regime = open_loop_regime(ol["amplitude"], ol["stick_fraction"])
        else:
            plant_open_loop_regime = "equilibrium" if not ol["amplitude"] > 0 else "limit_cycle"
    stalled = is_stalled(m.stick_fraction, m.mean_speed, w)
    supp = suppression(m.amplitude, ol["amplitude"])
    if stalled and math.isfinite(supp):
        supp = min(supp, 0.0)
    err = traj.window_lower_speed - w
    at_limit = np.abs(traj.voltage_requested) >= VOLTAGE_LIMIT - LIMIT_TOL
    peak = float(np.max(np.abs(traj.true_state[:, 2])))
    if traj.window_lower_speed.size:
        peak = max(peak, float(np.max(np.abs(traj.window_lower_speed))))
    return RunMetrics(
        controller=name or getattr(controller, "name", type(controller).__name__),
        preset=preset,
        voltage=v,
        seed=int(seed),
        regime=str(info["regime"]),
        plant_open_loop_regime=str(plant_open_loop_regime),
        target_speed=w,
        stalled=stalled,
        amplitude=m.amplitude,
        open_loop_amplitude=ol["amplitude"],
        suppression=supp,
        stick_fraction=m.stick_fraction,
        severity=m.severity,
        rms_error=float(np.sqrt(np.mean(err * err))),
        mean_speed=m.mean_speed,
        x3_min=m.min_speed,
        x3_max=m.max_speed,
        period=m.period,
        u_mean_abs=float(np.mean(np.abs(traj.voltage))),
        u_peak_abs=float(np.max(np.abs(traj.voltage))),
        u_limit_fraction=float(np.mean(at_limit)),
        x3_peak_abs=peak,
        beyond_identified_range=bool(peak > IDENTIFIED_SPEED.get(preset, math.inf)),
        episode_return=float(np.sum(traj.reward)),
        sim_status=traj.sim_status,
        wall_time=time.perf_counter() - t0,
    )
