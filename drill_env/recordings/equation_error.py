"""Filtered equation error: where the measured angles disagree with the nominal torques.

For a disk with inertia J, the second difference of its angle over a span h is the
triangle-kernel double integral of its acceleration,

    theta(t+h) - 2 theta(t) + theta(t-h) = int_{-h}^{h} (h - |s|) theta''(t+s) ds,

and J theta'' is the sum of the torques on the disk. Both sides are smoothed by one
more short box filter B (width ``smooth_s``): this averages the encoder quantisation
of the three end angles without breaking the identity, because the same filter is
applied to the torque side (the kernel becomes ``k = triangle * B``, and
``int k theta'' = int k'' theta``). So, per window centred at t,

    r(t) = [J (B*Delta^2 theta)(t) - K[nominal torques](t)] / h^2      [N m]

is the mean unexplained torque on the disk over the window: zero up to noise when the
nominal model is right, ``K[delta T]/h^2`` when an extra torque delta T acts.

The nominal torques use the measured twist ``x1 = theta_u - theta_l`` directly; the
viscous terms ``b x`` and string damping use ``K[theta'] = int k'(s) theta(t+s) ds``, a
weighted sum of angles (no differentiation); only the Stribeck part of the lower-disk
friction needs a speed, from a cubic Savitzky-Golay derivative whose window is, per
sample, the shortest one over which the disk moves ``speed_counts`` encoder counts
(slow motion needs long windows to see through the quantisation). The voltage is a
zero-order hold, for which the kernel sum is exact. Windows where a disk is slow or
stuck (set-valued friction) or reverses are dropped, for that disk only.

Noise: what an encoder tells. A reading is the floor of the true angle (plus whatever
noise, "dither", is added before the quantiser) in counts: the true angle is known only
to within one count. The reading error ``e`` is white only with enough dither (Widrow,
Kollar & Liu, IEEE TIM 1996: about a count); an incremental encoder adds none. As a
Fourier series in the true angle,

    e = -step/2 + n + step sum_m sin(2 pi m (theta + n)/step) / (pi m),

and given the true angle the m-th harmonic keeps the coherent amplitude
``rho_m step/(pi m)``, ``rho_m = exp(-2 pi^2 m^2 s^2/step^2)`` for Gaussian dither n of
standard deviation s; the rest is independent from sample to sample. At a count rate of
c counts per sample harmonic m is a spectral line at the digital frequency ``m c``
(mod 1) (Kavanagh, IEEE TIM 2000), with the encoder's unknown sub-count offset as its
phase. Every window residual is a fixed linear combination ``sum_k a_k e_k`` of the
errors of both encoders (exact linearisation, the Savitzky-Golay speed of the Stribeck
term included), so its noise variance is the white rest times ``sum a_k^2`` plus, for
each line, its power times ``|A(f)|^2`` at the line's frequency (:func:`line_variance`).
Where the line is, is known only as well as the count rate, and the lines that matter
most are high harmonics that alias close to a peak of ``|A|^2`` (at 2000 counts/rev and
500 Hz, harmonic 22 of a disk at 0.409 counts/sample sits 0.004 cycles/sample from zero
frequency, where a rate error of 1e-4 moves it off the peak). The endpoint counts of the
support fix the rate only to 1/N; averaging the lines over that band put the floor of a
steady run three times too low. So the rate is the slope of the readings
over the longest span (1, 3, 9, 27 supports) on which it is steady (the slope of a
least-squares cubic, which a bending rate does not bias), its standard error is that of
the slope (itself a weighted sum of the encoder error, computed the same way), and line
m is averaged over ``m (sqrt(3) error + spread/2)`` about ``m c``, spread the change of
that slope within the support (harmonics 1-256 as lines, the few beyond as white).
The outcome, for the same undithered data: a window in which a line aliases into its
pass band (a near-integer or near-p/q number of counts per sample at near-constant
speed) gets a noise variance up to 40 times the white model's and a small weight; a
window whose lines all alias outside its pass band gets one 10 or more times below it. With dither the
lines fade and the white model comes back (1 mrad at 2000 counts/rev: rho_1^2 = 0.02).
The dither s is what the third differences show above the quantisation floor
(:func:`estimate_angle_noise`). Windows do not share samples, so the white part of their
noise is independent; at a constant rate the lines can make the windows of one run
depend on each other, which the structure tests of :mod:`drill_env.discrepancy.verdict`
allow for.

Every extra effect of the candidate library enters linearly (or, for the two lag
effects, through a first-order filter of a measured signal) as a column of the same
kernel sums; see :mod:`drill_env.recordings.effects`.
"""

from __future__ import annotations

import functools
import math
import weakref
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import polynomial as P
from scipy.ndimage import maximum_filter1d, minimum_filter1d
from scipy.signal import oaconvolve, savgol_filter
from scipy.signal import savgol_coeffs as _scipy_savgol_coeffs

from drill_env.friction import hump_slope, hump_torque
from drill_env.params import RigParams

__all__ = [
    "EquationErrorConfig",
    "AngleNoise",
    "DiskWindows",
    "RunEquations",
    "estimate_angle_noise",
    "quantisation_weights",
    "line_variance",
    "stribeck",
    "stribeck_slope",
]


@dataclass(frozen=True)
class EquationErrorConfig:
    """Choices of the equation-error windows (SI units)."""

    span_s: float = 0.25  # h, half-width of the triangle kernel [s]
    smooth_s: float = 0.1  # width of the box that averages the end angles [s]
    speed_windows_s: tuple[float, ...] = (0.05, 0.1, 0.2, 0.4)  # Savitzky-Golay windows [s]
    speed_counts: float = 16.0  # the shortest window over which the disk moves this many counts is used
    min_speed_rad_s: float = 0.03  # a disk slower than this in a window drops the window [rad/s]
    # the same for the lower disk alone, when above min_speed_rad_s (None: min_speed_rad_s): a
    # model whose lower friction is fitted only from some slip up is tested at those slips only
    min_speed_lower_rad_s: float | None = None
    noise_lag_s: float = 0.01  # lag of the third differences that estimate the angle noise [s]
    quantisation_harmonics: int = 256  # harmonics of the quantisation error treated as spectral lines
    rate_span_factors: tuple[int, ...] = (1, 3, 9, 27)  # spans tried for the count rate [x window support]
    accel_window_s: float = 0.2  # cubic Savitzky-Golay window of the acceleration bound [s]
    accel_margin: float = 1.5  # factor on the largest smoothed acceleration (a jump is smoothed)


def stribeck(params: RigParams, w: np.ndarray) -> np.ndarray:
    """Stribeck/hump part S(w) of the lower friction at w = |x3| [N m]."""
    return hump_torque(params, w)


def stribeck_slope(params: RigParams, w: np.ndarray) -> np.ndarray:
    """dS/dw [N m s / rad]."""
    return hump_slope(params, w)


@dataclass(frozen=True)
class AngleNoise:
    """Angle noise per disk, quantisation included [rad]."""

    upper: float
    lower: float
    quantisation: float  # step / sqrt(12), the floor set by the encoder alone
    samples_used: int  # third differences behind the estimate (0: quantisation only)

    @property
    def step(self) -> float:
        """One encoder count [rad]."""
        return self.quantisation * math.sqrt(12.0)

    def additive(self, disk: str) -> float:
        """Standard deviation of the noise added before quantisation (dither) [rad]."""
        total = self.upper if disk == "upper" else self.lower
        return math.sqrt(max(total * total - self.quantisation**2, 0.0))

    def as_dict(self) -> dict[str, float]:
        return {
            "upper_rad": self.upper,
            "lower_rad": self.lower,
            "quantisation_rad": self.quantisation,
            "additive_upper_rad": self.additive("upper"),
            "additive_lower_rad": self.additive("lower"),
            "samples_used": self.samples_used,
        }


def estimate_angle_noise(runs, encoder_step: float, config: EquationErrorConfig | None = None) -> AngleNoise:
    """Angle noise from third differences of the angles where the disk moves.

    At a lag where the disk moves at least two counts per lag the quantisation error is
    close to white, the signal's third difference is negligible and the noise's has
    variance 20 sigma^2; sigma clipping ignores the jerks of stick-slip. Never below
    the quantisation floor step/sqrt(12); what lies above it is taken as dither
    (:meth:`AngleNoise.additive`), which decides how much of the quantisation error is
    white (see the module docstring).
    """
    cfg = config or EquationErrorConfig()
    q_floor = encoder_step / math.sqrt(12.0)
    out = {}
    used = 0
    for disk in ("upper", "lower"):
        pieces = []
        for r in runs:
            th = r.theta_u if disk == "upper" else r.theta_l
            lag = max(1, int(round(cfg.noise_lag_s / r.dt)))
            if th.size <= 3 * lag:
                continue
            a, b, c, d = th[: -3 * lag], th[lag : -2 * lag], th[2 * lag : -lag], th[3 * lag :]
            moving = np.minimum(np.minimum(np.abs(b - a), np.abs(c - b)), np.abs(d - c)) >= 2.0 * encoder_step
            d3 = (d - 3.0 * c + 3.0 * b - a)[moving]
            pieces.append(d3)
        d3 = np.concatenate(pieces) if pieces else np.empty(0)
        if d3.size >= 1000:
            # sigma-clipped standard deviation: the readings are whole counts, so a
            # median-based scale would snap to a multiple of the step
            keep = np.ones(d3.size, dtype=bool)
            for _ in range(5):
                s = float(np.std(d3[keep]))
                new = np.abs(d3) <= 5.0 * s + 1e-15
                if np.array_equal(new, keep):
                    break
                keep = new
            sigma = float(np.std(d3[keep])) / math.sqrt(20.0)
            used += int(keep.sum())
        else:
            sigma = 0.0
        out[disk] = max(sigma, q_floor)
    return AngleNoise(upper=out["upper"], lower=out["lower"], quantisation=q_floor, samples_used=used)


@dataclass
class DiskWindows:
    """Equation-error windows of one disk in one run."""

    disk: str  # "upper" or "lower"
    centers: np.ndarray  # sample index of each window centre
    t: np.ndarray  # centre time since the start of the recording [s]
    sign: np.ndarray  # direction of slip (+1/-1) in the window
    residual: np.ndarray  # unexplained mean torque [N m]
    sigma: np.ndarray  # its noise standard deviation [N m]
    n_total: int  # windows before dropping slow/stuck ones
    line_share: np.ndarray | None = None  # share of the spectral lines of the quantisation error in sigma^2

    @property
    def z(self) -> np.ndarray:
        return self.residual / self.sigma

    def __len__(self) -> int:
        return int(self.centers.size)


def run_counts(run, noise: AngleNoise) -> float:
    """Encoder counts per revolution implied by the quantisation floor."""
    return 2.0 * math.pi / (noise.quantisation * math.sqrt(12.0))


@functools.lru_cache(maxsize=256)
def _savgol_coeffs_cached(n: int, order: int, deriv: int, delta: float, use: str) -> np.ndarray:
    c = _scipy_savgol_coeffs(n, order, deriv=deriv, delta=delta, use=use)
    c.flags.writeable = False
    return c


def savgol_coeffs(n: int, order: int, *, deriv: int = 0, delta: float = 1.0, use: str = "conv") -> np.ndarray:
    """scipy's ``savgol_coeffs``, computed once per window (read-only: shared)."""
    return _savgol_coeffs_cached(int(n), int(order), int(deriv), float(delta), use)


def _savgol(x: np.ndarray, half: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """Cubic Savitzky-Golay filter (``mode="interp"``), by FFT convolution away from the ends
    (direct convolution costs a window length per sample: minutes at 10 kHz)."""
    n = 2 * half + 1
    if x.size <= 4 * n:
        return savgol_filter(x, n, 3, deriv=deriv, delta=delta, mode="interp")
    coeffs = savgol_coeffs(n, 3, deriv=deriv, delta=delta)  # convolution order
    out = np.empty_like(x)
    out[half:-half] = oaconvolve(x, coeffs, mode="valid")
    # the ends, as mode="interp": the cubic fitted to the first (last) window, evaluated there
    t = np.arange(n, dtype=float)
    for piece, sl in ((x[:n], slice(0, half)), (x[-n:], slice(n - half, n))):
        c = P.polyder(P.polyfit(t, piece, 3), deriv) / delta**deriv
        vals = P.polyval(t[sl], c)
        if sl.start == 0:
            out[:half] = vals
        else:
            out[-half:] = vals
    return out


# the adaptive speeds of a run's angles, computed once per array (they do not depend on the
# model): every RunEquations of a run (each pass of the fit, each model tested) reuses them
_SPEED_CACHE: dict[tuple, tuple[weakref.ref, tuple[np.ndarray, np.ndarray]]] = {}


def _adaptive_speed(theta, halves, dt, travel):
    """Per sample, the Savitzky-Golay speed of the shortest window that covers ``travel`` [rad],
    the index of that window in ``halves``, and the speed of every window (a tuple)."""
    key = (id(theta), tuple(halves), float(dt), float(travel))
    hit = _SPEED_CACHE.get(key)
    if hit is not None and hit[0]() is theta:
        return hit[1]
    out = _adaptive_speed_of(theta, halves, dt, travel)
    for v in (out[0], out[1], *out[2]):
        v.flags.writeable = False
    try:
        ref = weakref.ref(theta)
    except TypeError:  # not weakly referenceable: not cached
        return out
    for k in [k for k, (r, _) in _SPEED_CACHE.items() if r() is None]:
        del _SPEED_CACHE[k]
    if len(_SPEED_CACHE) >= 256:
        _SPEED_CACHE.pop(next(iter(_SPEED_CACHE)))
    _SPEED_CACHE[key] = (ref, out)
    return out


def _adaptive_speed_of(theta, halves, dt, travel):
    speeds = [_savgol(theta, g, deriv=1, delta=dt) for g in halves]
    choice = np.full(theta.size, len(halves) - 1, dtype=np.int64)
    for i in range(len(halves) - 2, -1, -1):
        ok = np.abs(speeds[i]) * (2 * halves[i] * dt) >= travel
        choice[ok] = i
    v = np.choose(choice, speeds)
    return v, choice, tuple(speeds)


@functools.lru_cache(maxsize=64)
def speed_bias_bound(half: int, dt: float) -> float:
    """Largest error of the cubic Savitzky-Golay speed over 2 half + 1 samples for an angle whose
    acceleration is at most 1 rad/s^2 [rad/s per rad/s^2].

    The filter ``sum_k c_k theta(t + k dt)`` is exact for a line, so by Taylor's theorem its
    error is ``int_0^{half dt} (K+(s) theta''(t + s) + K-(s) theta''(t - s)) ds`` with the Peano
    kernels ``K+(s) = sum_{k>0} c_k (k dt - s)_+`` and ``K-(s) = sum_{k<0} c_k (|k| dt - s)_+``;
    the bound is ``int |K+| + int |K-|``, the kernels being linear between samples (integrated
    exactly, zero crossings included). About a third of the cruder ``sum |c_k| (k dt)^2 / 2``.
    """
    c = savgol_coeffs(2 * half + 1, 3, deriv=1, delta=dt, use="dot")
    total = 0.0
    for side in (c[half + 1 :], c[:half][::-1]):  # c_{+k}, c_{-k} for k = 1..half
        k = np.arange(1, half + 1, dtype=float) * dt
        knots = np.arange(0, half + 1, dtype=float) * dt  # K at s = j dt, j = 0..half
        vals = np.array([float(side @ np.clip(k - x, 0.0, None)) for x in knots])
        a, b = vals[:-1], vals[1:]
        same = a * b >= 0.0
        seg = np.where(
            same,
            0.5 * np.abs(a + b),
            0.5 * (a * a + b * b) / np.maximum(np.abs(a) + np.abs(b), 1e-300),
        )
        total += float(seg.sum()) * dt
    return total


def quantisation_weights(noise: AngleNoise, disk: str, harmonics: int) -> tuple[np.ndarray, float]:
    """Power of each spectral line of the encoder error, and the white power left [rad^2].

    The error of a floor-quantised reading of ``theta + n`` (n Gaussian dither of standard
    deviation s) is ``e = -step/2 + n + step sum_m sin(2 pi m (theta + n)/step) / (pi m)``.
    Given the true angle, its m-th harmonic keeps the coherent amplitude ``rho_m step/(pi m)``
    with ``rho_m = exp(-2 pi^2 m^2 s^2 / step^2)`` (Widrow, Kollar & Liu 1996: the error is
    white only when the rho_m vanish); the rest of the error is independent from sample to
    sample. Returns the line powers ``step^2 rho_m^2 / (2 pi^2 m^2)`` for m = 1..harmonics,
    and the per-sample variance of the independent rest, ``s^2 + step^2/12`` minus their sum
    (the few harmonics beyond ``harmonics`` are counted there).
    """
    step = noise.step
    s = noise.additive(disk)
    m = np.arange(1, harmonics + 1, dtype=float)
    rho2 = np.exp(-4.0 * math.pi**2 * m**2 * (s / step) ** 2)
    weights = step**2 * rho2 / (2.0 * math.pi**2 * m**2)
    white = s * s + step**2 / 12.0 - float(weights.sum())
    return weights, white


def line_variance(
    coef: np.ndarray,
    rate: np.ndarray,
    spread: np.ndarray,
    weights: np.ndarray,
    rate_error: np.ndarray | None = None,
    chunk: int = 1_000_000,
) -> np.ndarray:
    """Variance of ``sum_k coef_k e_k`` from the spectral lines of the quantisation error [rad^2 x coef^2].

    At a count rate of c counts per sample the m-th harmonic of the error is a line at the
    digital frequency ``m c`` (mod 1) (Kavanagh 2000); with the encoder's sub-count offset
    uniform it adds ``weights[m-1] |C(m c)|^2`` to the variance, C the Fourier transform of
    the window's coefficients. The rate is known to within ``rate_error`` (default 1/N, what
    the counts at the ends of a support of N samples tell), and it changes by ``spread``
    over the support, so harmonic m may sit anywhere within ``m (rate_error + spread/2)`` of
    ``m c``: its term is ``|C|^2`` averaged over that band (over the whole circle, i.e.
    white, once the band covers it).

    Args:
        coef: (windows, N) coefficients of each window on its support.
        rate: (windows,) mean count rate on the support [counts/sample].
        spread: (windows,) max - min of the count rate on the support [counts/sample].
        weights: line powers of harmonics 1, 2, ... (:func:`quantisation_weights`).
        rate_error: (windows,) half-width of the band in which the rate lies [counts/sample];
            None: 1/N.
    """
    n, N = coef.shape
    out = np.zeros(n)
    if n == 0 or weights.size == 0:
        return out
    P = 1 << int(math.ceil(math.log2(2 * N)))
    m = np.arange(1, weights.size + 1, dtype=float)
    if coef.strides[0] == 0 or n == 1:
        # one kernel for every window (a broadcast row): its spectrum once, the bands per window
        power1 = np.abs(np.fft.fft(coef[0], P)) ** 2
        cum1 = np.concatenate([[0.0], np.cumsum(np.concatenate([power1, power1]))])
        err = 1.0 / N if rate_error is None else rate_error[:, None]
        half = m[None, :] * (err + 0.5 * spread[:, None])  # [cycles/sample]
        centre = np.mod(m[None, :] * np.abs(rate[:, None]), 1.0)
        lo = np.floor((centre - half) * P + 0.5).astype(np.int64) % P
        width = np.maximum(np.floor(2.0 * half * P + 0.5).astype(np.int64), 1)
        white = width >= P
        width = np.minimum(width, P)
        band = (cum1[lo + width] - cum1[lo]) / width
        band = np.where(white, power1.mean(), band)
        return band @ weights
    rows = max(1, chunk // P)
    for a in range(0, n, rows):
        b = min(n, a + rows)
        power = np.abs(np.fft.fft(coef[a:b], P, axis=1)) ** 2
        cum = np.concatenate(
            [np.zeros((b - a, 1)), np.cumsum(np.concatenate([power, power], axis=1), axis=1)], axis=1
        )
        err = 1.0 / N if rate_error is None else rate_error[a:b, None]
        half = m[None, :] * (err + 0.5 * spread[a:b, None])  # [cycles/sample]
        centre = np.mod(m[None, :] * np.abs(rate[a:b, None]), 1.0)
        lo = np.floor((centre - half) * P + 0.5).astype(np.int64) % P
        width = np.maximum(np.floor(2.0 * half * P + 0.5).astype(np.int64), 1)
        white = width >= P
        width = np.minimum(width, P)
        band = (np.take_along_axis(cum, lo + width, axis=1) - np.take_along_axis(cum, lo, axis=1)) / width
        band = np.where(white, power.mean(axis=1)[:, None], band)
        out[a:b] = band @ weights
    return out


def _box(n: int) -> np.ndarray:
    return np.full(n, 1.0 / n)


class RunEquations:
    """Kernel sums, nominal residuals and their noise for one measured run."""

    def __init__(self, run, params: RigParams, noise: AngleNoise, config: EquationErrorConfig | None = None):
        cfg = config or EquationErrorConfig()
        self.run = run
        self.params = params
        self.config = cfg
        self.noise = noise
        dt = run.dt
        self.dt = dt
        n = run.t.size
        m = max(2, int(round(cfg.span_s / dt)))
        self.m = m
        self.h = m * dt
        nb = max(1, int(round(cfg.smooth_s / dt)))
        nb += 1 - nb % 2  # odd, centred
        halves = sorted({max(2, int(round(0.5 * w / dt))) for w in cfg.speed_windows_s})
        g_half = halves[-1]
        self.g_half = g_half
        # Kernel weights on offsets -L..L about the centre.
        L = m + nb // 2 + 1
        self.L = L
        off = np.arange(-L, L + 1)
        self.offsets = off
        box = _box(nb)
        j = np.arange(-(m - 1), m)
        tri = dt * dt * (m - np.abs(j)).astype(float)  # triangle on samples, sums to h^2
        self.w_tri = self._place(np.convolve(tri, box), -(m - 1) - nb // 2)
        # Zero-order-hold input: the triangle applied to (u[i-1] + u[i]) / 2.
        tri_zoh = 0.5 * (np.concatenate([tri, [0.0]]) + np.concatenate([[0.0], tri]))  # offsets -m..m-1
        self.w_zoh = self._place(np.convolve(tri_zoh, box), -m - nb // 2)
        # K[theta'] = sum_{j=1}^{m} c_j (theta[k+j] - theta[k-j]) dt, c_m = 1/2 (trapezoid).
        rate = np.zeros(2 * m + 1)
        cj = np.ones(m)
        cj[-1] = 0.5
        rate[m + 1 :] = dt * cj
        rate[:m] = -dt * cj[::-1]
        self.w_rate = self._place(np.convolve(rate, box), -m - nb // 2)
        d2 = np.zeros(2 * m + 1)
        d2[0], d2[m], d2[-1] = 1.0, -2.0, 1.0
        self.w_d2 = self._place(np.convolve(d2, box), -m - nb // 2)
        # Exponential-decay kernel pieces for a first-order lag (see kernel_lag).
        jj = np.arange(-m, m)
        self._lag_a = np.where(jj >= 0, (m - jj) * dt, (m + jj) * dt)
        self._lag_b = np.where(jj >= 0, -1.0, 1.0)
        self._lag_box = box
        self._lag_first = -m - nb // 2

        self.t_rel = run.t - run.t[0]
        self.theta_u = run.theta_u
        self.theta_l = run.theta_l
        self.u = run.u
        self.twist = run.theta_u - run.theta_l
        step = 2.0 * math.pi / run_counts(run, noise)
        self.sg = [savgol_coeffs(2 * g + 1, 3, deriv=1, delta=dt, use="dot") for g in halves]
        self.speed_u, self.choice_u, _ = _adaptive_speed(run.theta_u, halves, dt, cfg.speed_counts * step)
        self.speed_l, self.choice_l, self._speeds_l = _adaptive_speed(
            run.theta_l, halves, dt, cfg.speed_counts * step
        )
        self.halves = halves
        self.step = step
        self._rates: dict[tuple[str, int], np.ndarray] = {}  # count rates, see _moving_rate
        self._column_noise: dict[str, np.ndarray] = {}  # see column_noise
        self._truncation: np.ndarray | None = None  # see _speed_truncation
        self.q_upper = quantisation_weights(noise, "upper", cfg.quantisation_harmonics)
        self.q_lower = quantisation_weights(noise, "lower", cfg.quantisation_harmonics)

        # Non-overlapping windows whose whole support (angles, speeds) lies in the run.
        reach = L + g_half
        stride = 2 * reach + 1
        self.stride = stride  # samples between neighbouring windows
        centers = np.arange(reach + g_half, n - reach - g_half, stride)
        self.n_windows = centers.size
        self.upper = self._windows("upper", centers, self.speed_u, reach)
        self.lower = self._windows("lower", centers, self.speed_l, reach)

    def neighbour_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Indices, into the windows of both disks stacked (upper, then lower), of each pair of
        windows that are neighbours on the window grid (kept windows of one disk, one stride
        apart)."""
        first, second = [], []
        offset = 0
        for w in (self.upper, self.lower):
            if len(w) >= 2:
                adj = np.flatnonzero(np.diff(w.centers) == self.stride)
                first.append(offset + adj)
                second.append(offset + adj + 1)
            offset += len(w)
        if not first:
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        return np.concatenate(first), np.concatenate(second)

    # -- kernel machinery --------------------------------------------------------------------
    def _place(self, w: np.ndarray, first: int) -> np.ndarray:
        """Put weights starting at offset ``first`` on the common offsets -L..L."""
        out = np.zeros(2 * self.L + 1)
        i0 = first + self.L
        out[i0 : i0 + w.size] = w
        return out

    def gather(self, x: np.ndarray, centers: np.ndarray) -> np.ndarray:
        return x[centers[:, None] + self.offsets[None, :]]

    def _slope_kernel(self, reach: int) -> np.ndarray:
        """Slope at the centre of the least-squares cubic through 2 reach + 1 samples [per
        sample], weights in sample order (a rate that changes linearly or bends does not
        bias it)."""
        return savgol_coeffs(2 * reach + 1, 3, deriv=1, use="dot")

    def _moving_rate(self, disk: str, reach: int) -> np.ndarray:
        """Count rate per sample: the least-squares slope over +-reach samples about each
        sample [counts/sample] (cached per disk and reach)."""
        key = (disk, reach)
        if key not in self._rates:
            theta = self.theta_u if disk == "upper" else self.theta_l
            a = self._slope_kernel(reach)
            out = np.empty(theta.size)
            if theta.size > a.size:
                out[reach:-reach] = oaconvolve(theta, a[::-1], mode="valid") / self.step
                out[:reach] = out[reach]
                out[-reach:] = out[-reach - 1]
            else:
                out[:] = (theta[-1] - theta[0]) / (self.step * max(theta.size - 1, 1))
            self._rates[key] = out
        return self._rates[key]

    def _range(self, x: np.ndarray, reach: int, centers: np.ndarray) -> np.ndarray:
        """max - min of x over +-reach samples about each centre."""
        span = 2 * reach + 1
        top = maximum_filter1d(x, span, mode="nearest")
        return (top - minimum_filter1d(x, span, mode="nearest"))[centers]

    def _rate_error(self, disk: str, centers: np.ndarray, reach: int, rate: np.ndarray) -> np.ndarray:
        """Standard deviation of the least-squares count rate over +-reach [counts/sample].

        The slope is a weighted sum of the readings, so its error is one of the encoder
        error: with the lines where the rate puts them, or averaged over the 1/N that the
        counts alone leave open, whichever is larger. The first is right when the rate is
        known well (at 6/7 counts per sample the harmonics 7, 14, ... pile up next to zero
        frequency, where a slope over N samples responds most); the second where the rate
        itself hides the error (at a whole number of counts per sample every line sits at
        zero frequency, where a slope does not respond, and the readings are a perfect line
        whatever the rate within 1/N)."""
        weights, white = self.q_upper if disk == "upper" else self.q_lower
        a = np.broadcast_to(self._slope_kernel(reach), (centers.size, 2 * reach + 1))
        zero = np.zeros(centers.size)
        point = line_variance(a, rate, zero, weights, rate_error=zero)
        band = line_variance(a, rate, zero, weights)
        return np.sqrt(white * float(a[0] @ a[0]) + np.maximum(point, band)) / self.step

    def _rate_error_bound(self, disk: str, reach: int, rate: np.ndarray) -> np.ndarray:
        """Largest standard deviation of the count rate over +-reach (:meth:`_slope_kernel`) for
        a true rate within 1/N of ``rate`` [counts/sample]: each line at its worst place in
        the band that the counts leave open."""
        weights, white = self.q_upper if disk == "upper" else self.q_lower
        a = self._slope_kernel(reach)
        N = a.size
        P = 1 << int(math.ceil(math.log2(2 * N)))
        # sliding maxima of the power over 2^j bins (circular), for O(1) band maxima
        levels = [np.abs(np.fft.fft(a, P)) ** 2]
        while (2 << (len(levels) - 1)) <= P:
            prev = levels[-1]
            levels.append(np.maximum(prev, np.roll(prev, -(1 << (len(levels) - 1)))))
        top = np.stack(levels)
        m = np.arange(1, weights.size + 1)
        width = 2 * np.ceil(m * P / N).astype(np.int64) + 1
        whole = width >= P
        width = np.minimum(width, P)
        lo = (
            np.floor(np.mod(m[None, :] * np.abs(rate[:, None]), 1.0) * P + 0.5).astype(np.int64) - width // 2
        ) % P
        j = np.floor(np.log2(width)).astype(np.int64)
        hi = (lo + width - (1 << j)) % P
        band_max = np.maximum(top[j[None, :], lo], top[j[None, :], hi])
        band_max = np.where(whole[None, :], top[0].max(), band_max)
        return np.sqrt(white * float(a @ a) + band_max @ weights) / self.step

    def _count_rate(self, disk: str, centers: np.ndarray, reach: int):
        """Count rate of each window, its standard error and its change over the support +-reach
        [counts/sample].

        The rate is the slope of the least-squares cubic through the readings over the
        longest span (``reach`` times 1, 3, 9, ...) on which it is steady: the next longer
        span's slope must agree with the shorter one's, at the centre and at both ends of
        the support, within twice the largest error the shorter one can have
        (:meth:`_rate_error_bound`). At a steady rate a long span knows the rate far better
        than the window's own support (the error falls as span^-3/2 or span^-1 near a
        whole number of counts per sample); a span over which the rate swings fails the
        test. The error is :meth:`_rate_error` of the chosen span; the change of the rate
        over the support is the range of the chosen slope, evaluated at every sample of it.
        """
        n = self.theta_u.size
        moving = self._moving_rate(disk, reach)
        rate = moving[centers]
        spread = self._range(moving, reach, centers)
        error = self._rate_error(disk, centers, reach, rate)
        ok = np.ones(centers.size, dtype=bool)
        prev_moving, prev_bound = moving, self._rate_error_bound(disk, reach, rate)
        for factor in self.config.rate_span_factors:
            span_reach = reach * factor
            ok &= (centers - span_reach >= 0) & (centers + span_reach < n)
            if factor <= 1 or not ok.any():
                continue
            moving = self._moving_rate(disk, span_reach)
            r = moving[centers]
            # steady: the slopes agree at the centre and at both ends of the support
            for shift in (0, -reach, reach):
                at = np.clip(centers + shift, 0, n - 1)
                ok &= np.abs(moving[at] - prev_moving[at]) <= 2.0 * prev_bound
            if not ok.any():
                break
            sel = np.flatnonzero(ok)
            e = np.full(centers.size, np.inf)
            e[sel] = self._rate_error(disk, centers[sel], span_reach, r[sel])
            sp = self._range(moving, reach, centers)
            rate = np.where(ok, r, rate)
            error = np.where(ok, e, error)
            spread = np.where(ok, sp, spread)
            b = np.full(centers.size, np.inf)
            b[sel] = self._rate_error_bound(disk, span_reach, r[sel])
            prev_moving, prev_bound = moving, b
        return rate, error, spread

    def _angle_variance(self, disk: str, centers: np.ndarray, coef: np.ndarray, reach: int):
        """Variance of ``sum_k coef_k e_k`` over the support +-reach of each window, e the
        encoder error of ``disk``: white rest plus spectral lines [rad^2 x coef^2], and the
        share of the lines in it. The lines sit at the count rate of :meth:`_count_rate`,
        known to within a uniform band of its standard error."""
        weights, white = self.q_upper if disk == "upper" else self.q_lower
        coef = np.broadcast_to(coef, (centers.size, 2 * reach + 1))
        rate, error, spread = self._count_rate(disk, centers, reach)
        lines = line_variance(coef, rate, spread, weights, rate_error=math.sqrt(3.0) * error)
        return white * np.sum(coef * coef, axis=1) + lines, lines

    def column_noise(self, disk: str) -> np.ndarray:
        """Covariance of the encoder error in the disk's three angle columns, per window:
        (windows, 3, 3) for the columns of its inertia, the string stiffness and its viscous
        friction [N m^2 per unit^2], under the same noise model as :attr:`DiskWindows.sigma`.

        These columns are kernel sums of the measured angles, so they carry the reading error:
        a fit that minimises the squared equation error is drawn towards the parameters for which
        that error weighs least (errors in the variables). The covariance gives the shift it
        causes (:func:`drill_env.identify.joint.joint_fit`). Computed when first asked for."""
        cached = self._column_noise.get(disk)
        if cached is not None:
            return cached
        w = self.upper if disk == "upper" else self.lower
        other = "lower" if disk == "upper" else "upper"
        c = w.centers
        q = np.zeros((c.size, 3, 3))
        if c.size:
            basis = (self.w_d2, self.w_tri, self.w_rate)
            var = [self._angle_variance(disk, c, b, self.L)[0] for b in basis]
            for i in range(3):
                q[:, i, i] = var[i]
                for j in range(i + 1, 3):
                    both = self._angle_variance(disk, c, basis[i] + basis[j], self.L)[0]
                    q[:, i, j] = q[:, j, i] = 0.5 * (both - var[i] - var[j])
            # the twist's other end: the other encoder's error, independent of this one's
            q[:, 1, 1] += self._angle_variance(other, c, self.w_tri, self.L)[0]
            q /= self.h**4
        self._column_noise[disk] = q
        return q

    def kernel(self, x: np.ndarray, disk: str) -> np.ndarray:
        """K[x]/h^2 at the disk's windows for a signal sampled at the samples [units of x]."""
        c = self.upper.centers if disk == "upper" else self.lower.centers
        return self.gather(x, c) @ self.w_tri / self.h**2

    def kernel_rate(self, theta: np.ndarray, disk: str) -> np.ndarray:
        """K[theta']/h^2 from angles alone [rad/s]."""
        c = self.upper.centers if disk == "upper" else self.lower.centers
        return self.gather(theta, c) @ self.w_rate / self.h**2

    def kernel_lag(self, delta: np.ndarray, tau: float, disk: str) -> np.ndarray:
        """K[d]/h^2 for d(t) = delta[i] exp(-(t - t_i)/tau) on each sample interval (exact)."""
        dt = self.dt
        e = math.exp(-dt / tau)
        e0 = tau * (1.0 - e)
        e1 = tau * tau * (1.0 - e) - tau * dt * e
        w = e0 * self._lag_a + e1 * self._lag_b  # on offsets -m..m-1
        w = self._place(np.convolve(w, self._lag_box), self._lag_first)
        c = self.upper.centers if disk == "upper" else self.lower.centers
        return self.gather(delta, c) @ w / self.h**2

    def _turns_one_way(self, disk: str, centers: np.ndarray, sign: np.ndarray) -> np.ndarray:
        """Per window, whether the readings show the disk turning one way throughout its kernel
        support (friction of one sign): the smoothed speed alone cannot tell, since at a coarse
        encoder it is a long window's, which averages a short stop or reversal away (a
        binary sequence that reverses the voltage while the disk is slow).

        A disk that stops (or reverses) at t* with |theta''| <= A moves at most
        A (t - t*)^2 / 2 away from its angle there. So, for an encoder without dither, the count
        it is in at t* is held at least sqrt(2 step / A) (it must cover a whole count on both
        sides of t*), and a reversal shows as a count against the direction; a window is kept
        only when no count is held that long and none goes back. With dither (readings that
        flicker by ``k`` counts), every span of length T about the support must advance by more
        than A T^2/4 + (1 + 2k) step, T = 2 sqrt((1 + 2k) step / A). A is the largest acceleration
        in the support of a cubic Savitzky-Golay fit (``accel_window_s``), times
        ``accel_margin``, plus three standard deviations of its noise: it depends on the
        readings alone, so the windows are the same for every model tested.

        The count test is needed only where the smoothing could hide a stop. Where the smoothed
        speed itself bounds the true speed away from zero over the support (:meth:`_speed_one_way`:
        a slow but steady slip, whose speed window is long but whose acceleration is small), the
        window is kept without it: near the stick boundary the counts of a dithered encoder
        advance too few steps per span for the count test, and dropping those windows loses the
        data that sets the static friction levels."""
        if centers.size == 0:
            return np.zeros(0, dtype=bool)
        cfg = self.config
        theta = self.theta_u if disk == "upper" else self.theta_l
        dt, step, L = self.dt, self.step, self.L
        g = max(2, int(round(0.5 * cfg.accel_window_s / dt)))
        acc = np.abs(_savgol(theta, g, deriv=2, delta=dt))
        coef = savgol_coeffs(2 * g + 1, 3, deriv=2, delta=dt)
        noise = self.noise.upper if disk == "upper" else self.noise.lower
        a_noise = 3.0 * noise * float(np.sqrt(coef @ coef))
        a_max = cfg.accel_margin * maximum_filter1d(acc, 2 * L + 1, mode="nearest")[centers] + a_noise
        a_max = np.maximum(a_max, 1e-12)
        # the speed test: per sample, the bound over that sample's own speed window
        a_local = np.stack(
            [
                cfg.accel_margin * maximum_filter1d(acc, 2 * h + 1, mode="nearest") + a_noise
                for h in self.halves
            ]
        )
        by_speed = self._speed_one_way(disk, centers, sign, a_local)
        counts = np.round(theta / step)
        dither = self.noise.additive(disk)
        k = int(math.ceil(4.0 * dither / step)) if dither > 0.0 else 0
        d = np.diff(counts)
        ok = np.ones(centers.size, dtype=bool)
        if k == 0:
            # counts against the direction, per sample (change i -> i+1 charged to sample i)
            back_pos = maximum_filter1d((d < 0).astype(np.int8), 2 * L + 1, mode="nearest")
            back_neg = maximum_filter1d((d > 0).astype(np.int8), 2 * L + 1, mode="nearest")
            ci = np.minimum(centers, d.size - 1)
            ok &= np.where(sign > 0, back_pos[ci] == 0, back_neg[ci] == 0)
            # how long the count each sample reads is held (+1 sample: the crossings lie between)
            change = np.flatnonzero(d != 0)
            edges = np.concatenate([[-1], change, [counts.size - 1]])
            lengths = (np.diff(edges) + 1) * dt
            held = np.repeat(lengths, np.diff(edges))
            longest = maximum_filter1d(held, 2 * L + 1, mode="nearest")[centers]
            ok &= longest < np.sqrt(2.0 * step / a_max)
            return ok | by_speed
        e = (1.0 + 2.0 * k) * step
        for i, (c, s) in enumerate(zip(centers, sign, strict=True)):
            if by_speed[i]:
                continue
            T = max(1, int(round(2.0 * math.sqrt(e / a_max[i]) / dt)))
            lo, hi = max(c - L - T // 2, 0), min(c + L + T // 2 + 1, counts.size)
            y = s * counts[lo:hi] * step
            if y.size <= T:
                ok[i] = False
                continue
            need = a_max[i] * (T * dt) ** 2 / 4.0 + e
            ok[i] = bool(np.all(y[T:] - y[:-T] > need))
        return ok

    def _speed_one_way(
        self, disk: str, centers: np.ndarray, sign: np.ndarray, a_local: np.ndarray
    ) -> np.ndarray:
        """Per window, whether the smoothed speed alone proves the disk turning one way over its
        kernel support (offsets -L..L), given |theta''| <= ``a_local[j, i]`` over the speed window
        ``j`` (of :attr:`halves`) about sample i.

        The cubic Savitzky-Golay derivative ``sum_k c_k theta(t + k dt)`` is exact for a line, so
        its error is the angle's curvature seen through the Peano kernel of the filter,
        ``int K(s) theta''(t + s) ds``, at most ``a int |K|`` (:func:`speed_bias_bound`), plus
        the reading error: the quantisation error spans one count, ``step/2 sum |c_k|`` at most
        (a hard bound, since the spectral lines of an undithered encoder are not random), and the
        dither ``4 s |c|``. The window is kept when the speed of its direction exceeds this bound,
        plus ``a dt`` for the motion between samples, at every sample of the support."""
        if centers.size == 0:
            return np.zeros(0, dtype=bool)
        dt, step = self.dt, self.step
        speed = self.speed_u if disk == "upper" else self.speed_l
        choice = self.choice_u if disk == "upper" else self.choice_l
        dither = self.noise.additive(disk)
        bias = np.array([speed_bias_bound(g, dt) for g in self.halves])
        reading = np.array(
            [0.5 * step * float(np.abs(c).sum()) + 4.0 * dither * float(np.sqrt(c @ c)) for c in self.sg]
        )
        v = sign[:, None] * self.gather(speed, centers)
        ch = self.gather(choice, centers)
        idx = centers[:, None] + self.offsets[None, :]
        margin = a_local[ch, idx] * (bias[ch] + dt) + reading[ch]
        return np.all(v > margin, axis=1)

    def _speed_truncation(self, centers: np.ndarray) -> np.ndarray:
        """The truncation error of the lower disk's speed on each window's support (offsets -L..L),
        Richardson's estimate [rad/s].

        The cubic Savitzky-Golay speed at a window's centre is exact for an angle of degree four, so
        its error grows as the fourth power of the window: ``v_g - v = C g^4``, and with the window
        of half the length, ``v_g - v_(g/2) = (15/16) C g^4``. Where the disk turns slowly through
        the sharp bottom of a torsional cycle the long window it needs (to see through the counts)
        spans a change of the acceleration itself: 0.06 rad/s off at 0.23 rad/s, at 1 kHz and 1024
        counts, its Stribeck torque six noise standard deviations off in every cycle, whatever
        the parameters (a false alarm). The estimate carries the shorter window's reading error too,
        which the kernel's sum averages down; the windows take it in their variance, a bias they are
        not weighted on as if it were known to be absent."""
        if self._truncation is None:
            speeds = self._speeds_l  # every window's, as the adaptive speed computed them
            est = np.zeros(self.theta_l.size)
            for i in range(1, len(self.halves)):
                if self.halves[i] == 2 * self.halves[i - 1]:
                    at = self.choice_l == i
                    est[at] = (16.0 / 15.0) * (speeds[i][at] - speeds[i - 1][at])
            self._truncation = est
        return self.gather(np.abs(self.speed_l - self._truncation) - np.abs(self.speed_l), centers)

    # -- nominal residuals ---------------------------------------------------------------------
    def _windows(self, disk, centers, speed, reach) -> DiskWindows:
        p = self.params
        vmin = self.config.min_speed_rad_s
        if disk == "lower" and self.config.min_speed_lower_rad_s is not None:
            vmin = max(vmin, self.config.min_speed_lower_rad_s)
        fwd = minimum_filter1d(speed, 2 * reach + 1, mode="nearest")
        bwd = maximum_filter1d(speed, 2 * reach + 1, mode="nearest")
        sign = np.where(fwd[centers] >= vmin, 1.0, np.where(bwd[centers] <= -vmin, -1.0, 0.0))
        keep = sign != 0.0
        keep[keep] = self._turns_one_way(disk, centers[keep], sign[keep])
        c = centers[keep]
        s = sign[keep]
        if c.size == 0:  # the disk never turns one way for a whole window (a stuck run)
            empty = np.zeros(0)
            return DiskWindows(disk, c, empty, s, empty, empty, int(centers.size), empty)
        h2 = self.h**2
        off = self.offsets
        if disk == "lower":
            th = self.gather(self.theta_l, c)
            thu = self.gather(self.theta_u, c)
            v = self.gather(self.speed_l, c)
            w = np.abs(v)
            r = (
                p.lower_inertia * (th @ self.w_d2)
                - p.string_stiffness * ((thu - th) @ self.w_tri)
                + s * ((stribeck(p, w)) @ self.w_tri)
                + p.lower_viscous * (th @ self.w_rate)
            ) / h2 + s * p.lower_static
            # Noise: coefficients of r on the lower angles (offsets -L-G..L+G) and upper angles.
            G = self.g_half
            lin = np.zeros(2 * (self.L + G) + 1)
            lin[G : G + off.size] = (
                p.lower_inertia * self.w_d2 + p.string_stiffness * self.w_tri + p.lower_viscous * self.w_rate
            )
            slope = stribeck_slope(p, w) * self.w_tri[None, :]  # d r / d|v| per sample
            choice = self.gather(self.choice_l, c)
            coef = np.tile(lin, (c.size, 1))
            for i in range(c.size):
                for ci, (g, sg) in enumerate(zip(self.halves, self.sg, strict=False)):
                    a = np.where(choice[i] == ci, slope[i], 0.0)
                    if a.any():
                        lo = G - g
                        coef[i, lo : lo + a.size + 2 * g] += np.convolve(a, sg)
            var, lines = self._angle_variance("lower", c, coef, self.L + G)
            var_o, lines_o = self._angle_variance("upper", c, p.string_stiffness * self.w_tri, self.L)
            # the speed's truncation error (not noise: the same in every reading of that motion)
            trunc = np.sum(slope * self._speed_truncation(c), axis=1)
            var = var + trunc * trunc
        else:
            th = self.gather(self.theta_u, c)
            thl = self.gather(self.theta_l, c)
            b = np.where(s > 0, p.upper_viscous_pos, p.upper_viscous_neg)
            ts = np.where(s > 0, p.upper_static_pos, -p.upper_static_neg)
            r = (
                p.upper_inertia * (th @ self.w_d2)
                - p.motor_constant * (self.gather(self.u, c) @ self.w_zoh)
                + p.string_stiffness * ((th - thl) @ self.w_tri)
                + b * (th @ self.w_rate)
            ) / h2 + ts
            coef = (
                p.upper_inertia * self.w_d2
                + p.string_stiffness * self.w_tri
                + b[:, None] * self.w_rate[None, :]
            )
            var, lines = self._angle_variance("upper", c, coef, self.L)
            var_o, lines_o = self._angle_variance("lower", c, p.string_stiffness * self.w_tri, self.L)
        var = var + var_o
        line_share = (lines + lines_o) / np.maximum(var, 1e-300)
        var /= h2**2
        return DiskWindows(
            disk=disk,
            centers=c,
            t=self.t_rel[c],
            sign=s,
            residual=r,
            sigma=np.sqrt(var),
            n_total=int(centers.size),
            line_share=line_share,
        )
