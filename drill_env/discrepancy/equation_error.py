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
stuck (set-valued friction) or reverses are dropped, for that disk only. Windows do
not share samples, so their noise is independent; the noise standard deviation of
each window is the exact linear propagation of the angle noise (estimated from the
data, see :func:`estimate_angle_noise`) through all of the above.

Every extra effect of the candidate library enters linearly (or, for the two lag
effects, through a first-order filter of a measured signal) as a column of the same
kernel sums; see :mod:`drill_env.discrepancy.effects`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d
from scipy.signal import savgol_coeffs, savgol_filter

from drill_env.friction import hump_slope, hump_torque
from drill_env.params import RigParams

__all__ = [
    "EquationErrorConfig",
    "AngleNoise",
    "DiskWindows",
    "RunEquations",
    "estimate_angle_noise",
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
    noise_lag_s: float = 0.01  # lag of the third differences that estimate the angle noise [s]


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

    def as_dict(self) -> dict[str, float]:
        return {
            "upper_rad": self.upper,
            "lower_rad": self.lower,
            "quantisation_rad": self.quantisation,
            "samples_used": self.samples_used,
        }


def estimate_angle_noise(runs, encoder_step: float, config: EquationErrorConfig | None = None) -> AngleNoise:
    """Angle noise from third differences of the angles where the disk moves.

    At a lag where the disk moves at least two counts per lag the quantisation error is
    close to white, the signal's third difference is negligible and the noise's has
    variance 20 sigma^2; sigma clipping ignores the jerks of stick-slip. Never below
    the quantisation floor step/sqrt(12).
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

    @property
    def z(self) -> np.ndarray:
        return self.residual / self.sigma

    def __len__(self) -> int:
        return int(self.centers.size)


def run_counts(run, noise: AngleNoise) -> float:
    """Encoder counts per revolution implied by the quantisation floor."""
    return 2.0 * math.pi / (noise.quantisation * math.sqrt(12.0))


def _adaptive_speed(theta, halves, dt, travel):
    """Per sample, the Savitzky-Golay speed of the shortest window that covers ``travel`` [rad]."""
    speeds = [savgol_filter(theta, 2 * g + 1, 3, deriv=1, delta=dt, mode="interp") for g in halves]
    choice = np.full(theta.size, len(halves) - 1, dtype=np.int64)
    for i in range(len(halves) - 2, -1, -1):
        ok = np.abs(speeds[i]) * (2 * halves[i] * dt) >= travel
        choice[ok] = i
    v = np.choose(choice, speeds)
    return v, choice


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
        self.speed_u, self.choice_u = _adaptive_speed(run.theta_u, halves, dt, cfg.speed_counts * step)
        self.speed_l, self.choice_l = _adaptive_speed(run.theta_l, halves, dt, cfg.speed_counts * step)
        self.halves = halves

        # Non-overlapping windows whose whole support (angles, speeds) lies in the run.
        reach = L + g_half
        stride = 2 * reach + 1
        centers = np.arange(reach + g_half, n - reach - g_half, stride)
        self.n_windows = centers.size
        sig_u = self.noise.upper
        sig_l = self.noise.lower
        self.upper = self._windows("upper", centers, self.speed_u, reach, sig_u, sig_l)
        self.lower = self._windows("lower", centers, self.speed_l, reach, sig_u, sig_l)

    # -- kernel machinery --------------------------------------------------------------------
    def _place(self, w: np.ndarray, first: int) -> np.ndarray:
        """Put weights starting at offset ``first`` on the common offsets -L..L."""
        out = np.zeros(2 * self.L + 1)
        i0 = first + self.L
        out[i0 : i0 + w.size] = w
        return out

    def gather(self, x: np.ndarray, centers: np.ndarray) -> np.ndarray:
        return x[centers[:, None] + self.offsets[None, :]]

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

    # -- nominal residuals ---------------------------------------------------------------------
    def _windows(self, disk, centers, speed, reach, sig_u, sig_l) -> DiskWindows:
        p = self.params
        vmin = self.config.min_speed_rad_s
        fwd = minimum_filter1d(speed, 2 * reach + 1, mode="nearest")
        bwd = maximum_filter1d(speed, 2 * reach + 1, mode="nearest")
        sign = np.where(fwd[centers] >= vmin, 1.0, np.where(bwd[centers] <= -vmin, -1.0, 0.0))
        keep = sign != 0.0
        c = centers[keep]
        s = sign[keep]
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
            var = np.empty(c.size)
            for i in range(c.size):
                coef = lin.copy()
                for ci, (g, sg) in enumerate(zip(self.halves, self.sg, strict=False)):
                    a = np.where(choice[i] == ci, slope[i], 0.0)
                    if a.any():
                        lo = G - g
                        coef[lo : lo + a.size + 2 * g] += np.convolve(a, sg)
                var[i] = sig_l**2 * float(coef @ coef)
            var += sig_u**2 * p.string_stiffness**2 * float(self.w_tri @ self.w_tri)
            var /= h2**2
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
            var = np.empty(c.size)
            for bv in np.unique(b):
                coef = p.upper_inertia * self.w_d2 + p.string_stiffness * self.w_tri + bv * self.w_rate
                var[b == bv] = sig_u**2 * float(coef @ coef)
            var += sig_l**2 * p.string_stiffness**2 * float(self.w_tri @ self.w_tri)
            var /= h2**2
        return DiskWindows(
            disk=disk,
            centers=c,
            t=self.t_rel[c],
            sign=s,
            residual=r,
            sigma=np.sqrt(var),
            n_total=int(centers.size),
        )
