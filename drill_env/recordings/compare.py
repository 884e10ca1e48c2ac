"""Compare a model with measured runs in sensor space: short horizons, spectra, steady state.

The model is simulated exactly with each run's measured voltage from a state estimated
from the measured angles, and its angles are passed through the rig's measurement
chain (:func:`drill_env.sensors.measure`: the dataset's encoder resolution, the
estimated angle noise, numerical differentiation and the 200 rad/s low-pass); the
measured angles go through the same differentiation and filter (for the spectra), and
through the same smooth speed estimate the equation error uses (for the time-domain
views, where the raw difference quotient of whole counts would be mostly noise).
Three views:

* *short horizon*: restart from the measured state every ``horizon_s`` and compare the
  lower-disk angle and speed over the horizon (what a one-step-ahead predictor sees);
* *spectra*: Welch power spectra of the lower-disk speed of the free-running model and
  of the measurement, and the frequencies where they differ;
* *steady state*, for constant-voltage runs: mean, min and max of the lower-disk speed,
  dominant period and fraction of time stuck over the second half of the run (the
  points of an experimental bifurcation diagram).

With a measurement model (an eccentric encoder, :class:`~drill_env.measurement.MeasurementModel`)
the simulated angles are read through it before the chain, and each simulation starts from
the true state behind the measured readings.

Each gap is quoted with a noise floor: the angle noise for angles, the noise of the
measured speed (measured speed minus a smooth fit) for speeds and spectra.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.signal import welch

from drill_env.metrics import dominant_period
from drill_env.params import RigParams
from drill_env.recordings.equation_error import RunEquations, _adaptive_speed

__all__ = ["CompareConfig", "RunComparison", "compare_run", "sensor_speed", "SteadyFeatures"]


@dataclass(frozen=True)
class CompareConfig:
    horizon_s: float = 2.0  # restart period of the short-horizon comparison [s]
    spectrum_band_hz: tuple[float, float] = (0.01, 2.0)
    spectrum_segment_s: float = 100.0  # Welch segment (frequency resolution 1/segment)
    disagree_db: float = 6.0  # a spectral difference larger than this is reported


@dataclass(frozen=True)
class SteadyFeatures:
    mean_speed: float  # [rad/s]
    min_speed: float
    max_speed: float
    period: float  # [s], nan without oscillation
    stick_fraction: float  # [-]

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass
class RunComparison:
    """One model against one run."""

    run: str
    voltage: float  # nan for varying-voltage runs
    short_angle_rms: float  # [rad] lower-disk angle, short horizons
    short_speed_rms: float  # [rad/s] lower-disk speed, short horizons
    spectrum_distance_db: float  # RMS log-ratio of the lower-speed spectra over the band [dB]
    disagreeing_hz: list[float]  # frequencies of the largest spectral differences
    features_measured: SteadyFeatures | None
    features_model: SteadyFeatures | None
    floors: dict[str, float]
    stopped_simulations: int  # simulations the simulator stopped early (e.g. chattering)
    # arrays kept for the figures
    t: np.ndarray | None = field(repr=False, default=None)
    measured_speed: np.ndarray | None = field(repr=False, default=None)
    short_speed: np.ndarray | None = field(repr=False, default=None)
    free_speed: np.ndarray | None = field(repr=False, default=None)
    freqs: np.ndarray | None = field(repr=False, default=None)
    psd_measured: np.ndarray | None = field(repr=False, default=None)
    psd_model: np.ndarray | None = field(repr=False, default=None)
    psd_short_residual: np.ndarray | None = field(repr=False, default=None)

    def summary(self) -> dict[str, Any]:
        out = {
            "run": self.run,
            "voltage": self.voltage,
            "short_horizon_angle_rms_rad": self.short_angle_rms,
            "short_horizon_speed_rms_rad_s": self.short_speed_rms,
            "spectrum_distance_db": self.spectrum_distance_db,
            "disagreeing_frequencies_hz": self.disagreeing_hz,
            "noise_floor": self.floors,
            "stopped_simulations": self.stopped_simulations,
        }
        if self.features_measured is not None and self.features_model is not None:  # set together
            out["steady_measured"] = self.features_measured.as_dict()
            out["steady_model"] = self.features_model.as_dict()
        return out


def _sensor_config(eq: RunEquations, counts: int | None, noise: float):
    from drill_env.sensors import SensorConfig

    return SensorConfig(
        counts_per_rev=counts,
        sample_rate_hz=1.0 / eq.dt,
        angle_noise_std=noise,
        cutoff_rad_s=min(200.0, 0.45 * math.pi / eq.dt),
    )


def sensor_speed(eq: RunEquations, theta_u, theta_l, *, counts=None, noise=0.0, initial=(0.0, 0.0), seed=0):
    """Readings of the rig's chain: (lower speed after differentiation and low-pass,
    encoder reading of the lower angle, and the smooth speed the equation error uses)."""
    from drill_env.sensors import measure

    m = measure(theta_u, theta_l, _sensor_config(eq, counts, noise), initial_speeds=initial, seed=seed)
    travel = (
        eq.config.speed_counts
        * 2.0
        * math.pi
        / (counts or 2.0 * math.pi / (eq.noise.quantisation * math.sqrt(12)))
    )
    smooth, _, _ = _adaptive_speed(m.lower_angle, eq.halves, eq.dt, travel)
    return m.lower_speed, m.lower_angle, smooth


def _state(eq: RunEquations, k: int, measurement=None) -> dict[str, float]:
    vmin = eq.config.min_speed_rad_s
    x2 = float(eq.speed_u[k])
    x3 = float(eq.speed_l[k])
    theta_l = float(eq.theta_l[k])
    twist = float(eq.twist[k])
    if measurement is not None and measurement.active:
        # the readings of an eccentric encoder: the true angles and speeds behind them
        theta_u = theta_l + twist
        true_u = measurement.true_angle("upper", theta_u)
        true_l = measurement.true_angle("lower", theta_l)
        x2 /= measurement.reading_slope("upper", true_u)
        x3 /= measurement.reading_slope("lower", true_l)
        theta_l, twist = true_l, true_u - true_l
    return {
        "theta_l": theta_l,
        "x1": twist,
        "x2": x2 if abs(x2) >= vmin else 0.0,
        "x3": x3 if abs(x3) >= vmin else 0.0,
    }


def _thermal(params: RigParams, eq: RunEquations) -> np.ndarray:
    """The thermal state of a heated rig along the run, estimated from the data once per run."""
    from drill_env.recordings.effects import thermal_trajectory

    cache = eq.__dict__.setdefault("_thermal_cache", {})
    if params not in cache:
        cache[params] = thermal_trajectory(eq, params)
    return cache[params]


def _simulate(params: RigParams, eq: RunEquations, k0: int, k1: int, measurement=None):
    """Simulate samples k0..k1-1 from the measured state at k0; (theta_u, theta_l, x2, x3, stopped):
    the readings of the simulated angles through ``measurement`` when given."""
    import warnings

    from drill_env.simulator import simulate

    dt = eq.dt
    t0 = float(eq.t_rel[k0])
    n = k1 - k0
    x0 = _state(eq, k0, measurement)
    if params.effects.friction_heating != 0.0:
        x0["thermal_state"] = float(_thermal(params, eq)[k0])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = simulate(params, eq.u[k0:k1], t0 + (n - 1) * dt, x0=x0, dt=dt, control_dt=dt, t0=t0)
    stopped = res.status != 0 or any(issubclass(w.category, RuntimeWarning) for w in caught)
    thu, thl = res.theta_u[:n], res.theta_l[:n]
    if stopped:
        # the simulator stopped early (e.g. chattering): only the samples it reached count
        ok = np.isfinite(thu) & np.isfinite(thl)
        m = int(np.argmin(ok)) if not ok.all() else thu.size
        thu, thl = thu[:m], thl[:m]
    v2, v3 = res.x2[0], res.x3[0]
    if measurement is not None and measurement.active:
        v2 *= measurement.reading_slope("upper", float(res.theta_u[0]))
        v3 *= measurement.reading_slope("lower", float(res.theta_l[0]))
        thu, thl = measurement.read(thu, thl)
    return thu, thl, v2, v3, stopped


OSCILLATION_AVERAGE_S = 0.25  # [s] moving average before the oscillation test (see _features)


def _features(t, speed, stuck_speed, noise, counts) -> SteadyFeatures:
    """Steady-state features over the second half of a run.

    An oscillation (and so a period) is reported only when the speed averaged over
    :data:`OSCILLATION_AVERAGE_S` still swings by more than 5 % of its mean and clearly more
    than what noise and encoder quantisation leave after that average: the averaged speed is
    an angle difference over the window, so quantisation moves it by at most
    2 (2 pi / counts) / window, and white noise by noise / sqrt(samples). The rig's cycles
    (Hopf and stick-slip, periods of seconds; a once-per-revolution friction variation at a
    few rad/s) pass the average almost unchanged; a run at a stable equilibrium has no period.
    """
    half = t >= t[0] + 0.5 * (t[-1] - t[0])
    x = speed[half]
    th = t[half]
    dt = float(th[1] - th[0]) if th.size > 1 else 1.0
    m = max(1, min(x.size, int(round(OSCILLATION_AVERAGE_S / dt))))
    avg = np.convolve(x, np.ones(m) / m, mode="valid")
    floor = 2.0 * (2.0 * math.pi / counts) / (m * dt) + 8.0 * noise / math.sqrt(m)
    oscillates = float(np.ptp(avg)) > max(0.05 * abs(float(np.mean(x))), floor)
    return SteadyFeatures(
        mean_speed=float(np.mean(x)),
        min_speed=float(np.min(x)),
        max_speed=float(np.max(x)),
        period=float(dominant_period(th[: avg.size] + 0.5 * (m - 1) * dt, avg))
        if oscillates
        else float("nan"),
        stick_fraction=float(np.mean(np.abs(x) < stuck_speed)),
    )


def compare_run(
    params: RigParams,
    eq: RunEquations,
    counts: int,
    config: CompareConfig | None = None,
    *,
    measured_cache: dict | None = None,
    measurement=None,
) -> RunComparison:
    """``params`` against one run in sensor space; ``measurement`` (a
    :class:`~drill_env.measurement.MeasurementModel`) reads the simulated angles as the rig's
    encoders do (None: exact readings)."""
    cfg = config or CompareConfig()
    run = eq.run
    n = run.t.size
    dt = eq.dt
    q = 2.0 * math.pi / counts
    sigma_pre = math.sqrt(max(eq.noise.lower**2 - q * q / 12.0, 0.0))  # noise before quantisation
    if measured_cache is not None and run.name in measured_cache:
        meas_chain, speed_noise = measured_cache[run.name]
    else:
        meas_chain, _, _ = sensor_speed(eq, run.theta_u, run.theta_l, initial=(eq.speed_u[0], eq.speed_l[0]))
        speed_noise = float(np.std(meas_chain - eq.speed_l))
        if measured_cache is not None:
            measured_cache[run.name] = (meas_chain, speed_noise)
    meas_speed = eq.speed_l
    smooth_noise = float(eq.noise.lower * np.linalg.norm(eq.sg[min(1, len(eq.sg) - 1)]))
    # short horizons
    step = max(2, int(round(cfg.horizon_s / dt)))
    short_speed = np.full(n, np.nan)
    ang_errs: list[np.ndarray] = []
    stopped = 0
    for k0 in range(0, n - 1, step):
        k1 = min(n, k0 + step + 1)
        thu, thl, v2, v3, stop = _simulate(params, eq, k0, k1, measurement)
        stopped += int(stop)
        if thl.size < 8:
            continue
        _, qa, sp = sensor_speed(eq, thu, thl, counts=counts, noise=sigma_pre, initial=(v2, v3), seed=k0)
        m = thl.size
        short_speed[k0 : k0 + m] = sp
        ang_errs.append(qa - run.theta_l[k0 : k0 + m] - (qa[0] - run.theta_l[k0]))
    ang_err = np.concatenate(ang_errs) if ang_errs else np.array([np.nan])
    short_speed_rms = float(np.sqrt(np.nanmean((short_speed - meas_speed) ** 2)))
    # free run from the first sample
    thu, thl, v2, v3, stop = _simulate(params, eq, 0, n, measurement)
    stopped += int(stop)
    free_chain, _, free_speed = sensor_speed(
        eq, thu, thl, counts=counts, noise=sigma_pre, initial=(v2, v3), seed=1
    )
    if free_speed.size < n:  # a run the simulator stopped early: pad with its last value
        pad = n - free_speed.size
        free_speed = np.concatenate([free_speed, np.full(pad, free_speed[-1])])
        free_chain = np.concatenate([free_chain, np.full(pad, free_chain[-1])])
    nper = min(n, int(round(cfg.spectrum_segment_s / dt)))
    f, p_meas = welch(meas_chain, fs=1.0 / dt, nperseg=nper)
    _, p_mod = welch(free_chain, fs=1.0 / dt, nperseg=nper)
    _, p_res = welch(np.nan_to_num(short_speed - meas_speed), fs=1.0 / dt, nperseg=nper)
    _, p_noise = welch(meas_chain - eq.speed_l, fs=1.0 / dt, nperseg=nper)
    lo, hi = cfg.spectrum_band_hz
    band = (f >= lo) & (f <= hi)
    floor = np.maximum(p_noise, 1e-30)
    valid = band & ((p_meas > 3 * floor) | (p_mod > 3 * floor))
    ratio_db = 10.0 * np.log10(np.maximum(p_meas, floor) / np.maximum(p_mod, floor))
    dist = float(np.sqrt(np.mean(ratio_db[valid] ** 2))) if valid.any() else 0.0
    order = np.argsort(-np.abs(np.where(valid, ratio_db, 0.0)))
    disagree = [float(f[i]) for i in order[:3] if valid[i] and abs(ratio_db[i]) > cfg.disagree_db]
    stuck_speed = max(eq.config.min_speed_rad_s, 3.0 * smooth_noise)
    feats_m = feats_s = None
    if run.is_constant_voltage:
        feats_m = _features(eq.t_rel, meas_speed, stuck_speed, smooth_noise, counts)
        feats_s = _features(eq.t_rel, free_speed, stuck_speed, smooth_noise, counts)
    return RunComparison(
        run=run.name,
        voltage=run.voltage,
        short_angle_rms=float(np.sqrt(np.nanmean(ang_err**2))),
        short_speed_rms=short_speed_rms,
        spectrum_distance_db=dist,
        disagreeing_hz=disagree,
        features_measured=feats_m,
        features_model=feats_s,
        floors={
            "angle_rad": float(eq.noise.lower),
            "speed_rad_s": smooth_noise,
            "sensor_speed_rad_s": speed_noise,
        },
        stopped_simulations=stopped,
        t=eq.t_rel,
        measured_speed=meas_speed,
        short_speed=short_speed,
        free_speed=free_speed,
        freqs=f,
        psd_measured=p_meas,
        psd_model=p_mod,
        psd_short_residual=p_res,
    )


def aggregate(comparisons: list[RunComparison]) -> dict[str, float]:
    """Mean gaps over runs (the per-metric numbers of gap_before / gap_after)."""
    if not comparisons:
        return {}
    out = {
        "short_horizon_angle_rms_rad": float(np.mean([c.short_angle_rms for c in comparisons])),
        "short_horizon_speed_rms_rad_s": float(np.mean([c.short_speed_rms for c in comparisons])),
        "spectrum_distance_db": float(np.mean([c.spectrum_distance_db for c in comparisons])),
    }
    # (model, measured) steady features of the constant-voltage runs (both or neither are set)
    const = [
        (c.features_model, c.features_measured)
        for c in comparisons
        if c.features_model is not None and c.features_measured is not None
    ]
    if const:
        for key in ("mean_speed", "min_speed", "max_speed", "stick_fraction"):
            out[f"steady_{key}_abs_error"] = float(
                np.mean([abs(getattr(model, key) - getattr(measured, key)) for model, measured in const])
            )
        per = [
            abs(model.period - measured.period)
            for model, measured in const
            if math.isfinite(model.period) and math.isfinite(measured.period)
        ]
        out["steady_period_abs_error_s"] = float(np.mean(per)) if per else 0.0
        out["steady_period_presence_mismatch"] = float(
            np.mean(
                [math.isfinite(model.period) != math.isfinite(measured.period) for model, measured in const]
            )
        )
    return out
