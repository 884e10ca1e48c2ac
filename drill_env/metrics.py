"""Steady-state measures of torsional vibration, shared by the CLI, benchmark and analysis."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["StickSlipMetrics", "stick_slip_metrics", "dominant_period"]


@dataclass(frozen=True)
class StickSlipMetrics:
    """Measures of the lower-disk speed over a window (SI units)."""

    mean_speed: float  # [rad/s]
    min_speed: float  # [rad/s]
    max_speed: float  # [rad/s]
    amplitude: float  # max - min [rad/s]
    stick_fraction: float  # fraction of samples with the lower disk stuck [-]
    severity: float  # (max - min) / (2 mean), the stick-slip severity [-]; nan if mean = 0
    period: float  # dominant period [s]; nan when there is no oscillation

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def dominant_period(t: np.ndarray, signal: np.ndarray, min_rel_amplitude: float = 1e-6) -> float:
    """Period of the strongest spectral line of ``signal`` (uniform ``t``) [s].

    The peak of the Hann-windowed periodogram is refined by parabolic interpolation of
    the log-magnitude. Returns nan for a signal whose peak-to-peak amplitude is below
    ``min_rel_amplitude`` times its mean magnitude (plus a tiny absolute floor).
    """
    x = np.asarray(signal, dtype=float)
    t = np.asarray(t, dtype=float)
    if x.size < 8:
        return float("nan")
    span = float(np.ptp(x))
    if span <= min_rel_amplitude * max(abs(float(np.mean(x))), 1e-9) or span < 1e-12:
        return float("nan")
    dt = float(t[1] - t[0])
    n = x.size
    nfft = 1 << int(np.ceil(np.log2(n)) + 2)  # zero-padding for a finer grid
    spec = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(n), nfft))
    freqs = np.fft.rfftfreq(nfft, dt)
    k = int(np.argmax(spec[1:])) + 1
    if 1 <= k < spec.size - 1 and spec[k - 1] > 0 and spec[k + 1] > 0:
        a, b, c = np.log(spec[k - 1]), np.log(spec[k]), np.log(spec[k + 1])
        denom = a - 2 * b + c
        shift = 0.5 * (a - c) / denom if denom != 0 else 0.0
        f = freqs[k] + shift * (freqs[1] - freqs[0])
    else:
        f = freqs[k]
    return float(1.0 / f) if f > 0 else float("nan")


def stick_slip_metrics(
    t: np.ndarray, lower_speed: np.ndarray, stuck: np.ndarray | None = None
) -> StickSlipMetrics:
    """Measures of a (steady) window of the lower-disk speed."""
    x = np.asarray(lower_speed, dtype=float)
    mean = float(np.mean(x))
    lo, hi = float(np.min(x)), float(np.max(x))
    amp = hi - lo
    stick = float(np.mean(stuck)) if stuck is not None else float(np.mean(x == 0.0))
    severity = amp / (2.0 * abs(mean)) if mean != 0.0 else float("nan")
    return StickSlipMetrics(
        mean_speed=mean,
        min_speed=lo,
        max_speed=hi,
        amplitude=amp,
        stick_fraction=stick,
        severity=severity,
        period=dominant_period(t, x),
    )
