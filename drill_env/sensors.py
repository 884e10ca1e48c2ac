"""The rig's measurement chain: incremental encoders, numerical differentiation, low-pass filter.

Sec. 2.1 of Mihajlovic et al. (2004): the angles of both disks come from incremental
encoders; the speeds are numerical derivatives of the angles, low-pass filtered with a
cut-off of 200 rad/s (31.8 Hz). The paper gives neither the encoder resolution nor the
filter order nor the sample rate (its power spectra reach 500 Hz, which points to 1 kHz
sampling), so these are the documented, configurable assumptions of :class:`SensorConfig`.

Per sensor sample (period ``Ts``), for each disk:

1. *delay*: the angle seen now is the true angle ``delay_samples`` samples ago;
2. *noise*: optional Gaussian angle noise (encoder edge jitter, shaft vibration) [rad];
3. *encoder*: the angle is floor-quantised to whole counts, ``q = floor(theta / r) r`` with
   ``r = 2 pi / counts_per_rev`` (an incremental encoder counts edges, so the reading
   lags the true angle by less than one count, in the sense of increasing angle);
4. *differentiation*: backward difference ``(q_k - q_{k-1}) / Ts``;
5. *filter*: Butterworth low-pass of order 1 or 2, discretised with the bilinear
   (Tustin) transform with frequency prewarping, so the digital filter has its -3 dB
   point exactly at ``cutoff_rad_s`` (the difference quotient itself has gain
   ``sin(w Ts / 2) / (w Ts / 2)``, 0.9983 at 200 rad/s and 1 kHz, so the whole chain's
   -3 dB point moves by less than 0.2 %);
6. *speed noise*: optional Gaussian noise added to the filtered speed [rad/s].

The compiled functions here keep all state (previous counts, filter memory, delay line,
noise generator) in flat arrays so that the state persists across control periods of the
Gymnasium environment and across pickling. :func:`measure` applies the same chain to
whole arrays of angles, e.g. to turn a simulated trajectory into measured-like data.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numba as nb
import numpy as np
from numpy.typing import ArrayLike

from drill_env._numba import INLINE, JIT, JIT_ALLOC

__all__ = [
    "SensorConfig",
    "Measurements",
    "measure",
    "lowpass_coefficients",
    "quantize_angle",
    "MAX_DELAY_SAMPLES",
]

_JIT_ALLOC = JIT_ALLOC
_JIT = JIT  # allocates nothing: no reference counting
_INLINE = INLINE

MAX_DELAY_SAMPLES = 10_000  # [samples] bound of the delay line (10 s at 1 kHz)

# -- layout of the compiled configuration vector ---------------------------------------------
C_RES = 0  # encoder resolution 2 pi / counts [rad]; 0 = ideal (unquantised) angles
C_TS = 1  # sample period [s]
C_B0, C_B1, C_B2, C_A1, C_A2 = 2, 3, 4, 5, 6  # filter: y = (b0 + b1 z^-1 + b2 z^-2)/(1 + a1 z^-1 + a2 z^-2) x
C_ANGLE_NOISE = 7  # [rad]
C_SPEED_NOISE = 8  # [rad/s]
C_DELAY = 9  # [samples]
C_INV_RES = 10  # 1 / resolution [1/rad] (0 for ideal angles)
C_INV_TS = 11  # sample rate [1/s]
NCFG = 12

# -- layout of the compiled state vector (per rig) -------------------------------------------
S_QU, S_QL = 0, 1  # last measured (quantised) angles, upper / lower [rad]
S_ZU1, S_ZU2, S_ZL1, S_ZL2 = 2, 3, 4, 5  # filter memories (transposed direct form II)
S_VU, S_VL = 6, 7  # filtered speed estimates, incl. speed noise [rad/s]
S_DU, S_DL = 8, 9  # last raw difference quotients [rad/s]
S_RING_POS = 10  # write position of the delay line
S_RING = 11  # delay line of true angles: 2 * (delay + 1) values, (upper, lower) pairs
NSTATE_BASE = S_RING


def state_size(delay_samples: int) -> int:
    """Length of the sensor state vector for a given delay."""
    return NSTATE_BASE + 2 * (int(delay_samples) + 1)


# Bounds of the measurement chain: a sensor clock beyond 1 MHz (memory per control step grows
# with it) or noise beyond these levels (observations of no rig) is refused.
MAX_SAMPLE_RATE_HZ = 1e6  # [Hz]
MAX_ANGLE_NOISE_RAD = 1.0  # [rad]
MAX_SPEED_NOISE_RAD_S = 1e3  # [rad/s]


@dataclass(frozen=True)
class SensorConfig:
    """Measurement chain of the rig (Sec. 2.1), SI units.

    The encoder resolution is an assumption: the paper does not state it. The default,
    2000 counts per revolution, is a 500-line encoder read in quadrature (a common
    laboratory encoder), i.e. 3.14 mrad per count; at 1 kHz one count per sample is a
    speed step of 3.14 rad/s before the filter, which is the noise of the numerical
    differentiation that the paper mentions (Sec. 4.1).
    """

    counts_per_rev: int | None = 2000  # [counts/rev] after quadrature decoding; None = ideal angles
    sample_rate_hz: float = 1000.0  # [Hz] sensor sampling, differentiation and filter clock
    cutoff_rad_s: float = 200.0  # [rad/s] -3 dB point of the speed filter (paper: 200 rad/s)
    filter_order: int = 2  # 1 or 2: Butterworth order (the paper does not state it)
    angle_noise_std: float = 0.0  # [rad] Gaussian noise on the angle before quantisation
    speed_noise_std: float = 0.0  # [rad/s] Gaussian noise on the filtered speed
    delay_samples: int = 0  # [samples] transport delay of the measurements

    def __post_init__(self) -> None:
        if self.counts_per_rev is not None:
            _check_int("counts_per_rev", self.counts_per_rev, 1, 2**31 - 1)
        rate = _check_float("sample_rate_hz", self.sample_rate_hz, 0.0, MAX_SAMPLE_RATE_HZ, lo_incl=False)
        nyquist = math.pi * rate
        _check_float(
            "cutoff_rad_s",
            self.cutoff_rad_s,
            0.0,
            nyquist,
            lo_incl=False,
            hi_incl=False,
            hint="(must lie below the Nyquist frequency pi * sample_rate_hz)",
        )
        _check_int("filter_order", self.filter_order, 1, 2)
        _check_float("angle_noise_std", self.angle_noise_std, 0.0, MAX_ANGLE_NOISE_RAD)
        _check_float("speed_noise_std", self.speed_noise_std, 0.0, MAX_SPEED_NOISE_RAD_S)
        _check_int("delay_samples", self.delay_samples, 0, MAX_DELAY_SAMPLES)

    @classmethod
    def from_any(
        cls, value: SensorConfig | Mapping[str, Any] | None, *, name: str = "sensors"
    ) -> SensorConfig:
        """A config from an instance, a mapping of field overrides, or None (defaults)."""
        return config_from_any(cls, value, name)

    @property
    def sample_period(self) -> float:
        """Ts [s]."""
        return 1.0 / self.sample_rate_hz

    @property
    def resolution(self) -> float:
        """Angle of one encoder count [rad]; 0 for ideal angles."""
        return 0.0 if self.counts_per_rev is None else 2.0 * math.pi / self.counts_per_rev

    def filter_coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) of the discrete speed filter, as for ``scipy.signal.lfilter``."""
        return lowpass_coefficients(self.cutoff_rad_s, self.sample_rate_hz, self.filter_order)

    def as_array(self) -> np.ndarray:
        """The flat float64 vector read by the compiled sensor functions."""
        b, a = self.filter_coefficients()
        c = np.zeros(NCFG)
        c[C_RES] = self.resolution
        c[C_TS] = self.sample_period
        c[C_B0], c[C_B1], c[C_B2] = b
        c[C_A1], c[C_A2] = a[1], a[2]
        c[C_ANGLE_NOISE] = self.angle_noise_std
        c[C_SPEED_NOISE] = self.speed_noise_std
        c[C_DELAY] = self.delay_samples
        c[C_INV_RES] = 0.0 if self.counts_per_rev is None else self.counts_per_rev / (2.0 * math.pi)
        c[C_INV_TS] = self.sample_rate_hz
        return c


def config_from_any(cls, value, name):
    """A frozen config dataclass ``cls`` from an instance, a mapping of field overrides, or
    None (defaults); an unknown key or another type is a ValueError naming ``name``."""
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        allowed = {f.name for f in fields(cls)}
        unknown = sorted(set(value) - allowed)
        if unknown:
            raise ValueError(f"{name}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
        return cls(**value)
    raise ValueError(f"{name}: expected {cls.__name__}, a dict or None, got {type(value).__name__}")


def _check_float(name, value, lo, hi, *, lo_incl=True, hi_incl=True, hint=""):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    v = float(value)
    ok = math.isfinite(v) and (v >= lo if lo_incl else v > lo) and (v <= hi if hi_incl else v < hi)
    if not ok:
        lb = "[" if lo_incl else "("
        rb = "]" if hi_incl else ")"
        raise ValueError(
            f"{name}: {value!r} is outside the allowed range {lb}{lo:g}, {hi:g}{rb} {hint}".rstrip()
        )
    return v


def _check_int(name, value, lo, hi):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name}: expected an integer in [{lo}, {hi}], got {value!r}")
    if not lo <= int(value) <= hi:
        raise ValueError(f"{name}: {value!r} is outside the allowed range [{lo}, {hi}]")
    return int(value)


def lowpass_coefficients(
    cutoff_rad_s: float, sample_rate_hz: float, order: int = 2
) -> tuple[np.ndarray, np.ndarray]:
    """Digital Butterworth low-pass (order 1 or 2) by the prewarped bilinear transform.

    Returns ``(b, a)`` with three coefficients each (``a[0] = 1``; zeros pad order 1).
    The magnitude response is exactly ``1/sqrt(2)`` at ``cutoff_rad_s``.
    """
    ts = 1.0 / sample_rate_hz
    k = math.tan(0.5 * cutoff_rad_s * ts)  # prewarped analog cut-off times Ts/2
    if order == 1:
        # H(s) = wa / (s + wa), s = (2/Ts)(1 - z^-1)/(1 + z^-1)
        b0 = k / (1.0 + k)
        return np.array([b0, b0, 0.0]), np.array([1.0, (k - 1.0) / (k + 1.0), 0.0])
    if order == 2:
        # H(s) = wa^2 / (s^2 + sqrt(2) wa s + wa^2)
        r2 = math.sqrt(2.0)
        norm = 1.0 / (1.0 + r2 * k + k * k)
        b0 = k * k * norm
        return (
            np.array([b0, 2.0 * b0, b0]),
            np.array([1.0, 2.0 * (k * k - 1.0) * norm, (1.0 - r2 * k + k * k) * norm]),
        )
    raise ValueError(f"order: {order!r} is not supported; allowed: 1, 2")


def quantize_angle(theta: ArrayLike, counts_per_rev: int | None) -> np.ndarray:
    """Encoder reading of the angle ``theta`` [rad]: floor-quantised to whole counts
    (computed as the compiled chain does it)."""
    th = np.asarray(theta, dtype=float)
    if counts_per_rev is None:
        return th.copy()
    return np.floor(th * (counts_per_rev / (2.0 * math.pi))) * (2.0 * math.pi / counts_per_rev)


# -- noise generator (xoshiro256**), state in a uint64[4] array ---------------------------------


@nb.njit(**_INLINE)
def _rotl(x, k):
    return (x << np.uint64(k)) | (x >> np.uint64(64 - k))


@nb.njit(**_JIT)
def rng_next(s):
    """Next 64-bit output of xoshiro256** (Blackman & Vigna); advances ``s`` in place."""
    result = _rotl(s[1] * np.uint64(5), 7) * np.uint64(9)
    t = s[1] << np.uint64(17)
    s[2] ^= s[0]
    s[3] ^= s[1]
    s[1] ^= s[2]
    s[0] ^= s[3]
    s[2] ^= t
    s[3] = _rotl(s[3], 45)
    return result


@nb.njit(**_JIT)
def rng_uniform(s):
    """Uniform on [0, 1) with 53 random bits."""
    return float(rng_next(s) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@nb.njit(**_JIT)
def rng_normal_pair(s):
    """Two independent standard normals (Box-Muller)."""
    u1 = 1.0 - rng_uniform(s)  # (0, 1]
    u2 = rng_uniform(s)
    r = math.sqrt(-2.0 * math.log(u1))
    a = 2.0 * math.pi * u2
    return r * math.cos(a), r * math.sin(a)


def rng_state(seed_words: ArrayLike) -> np.ndarray:
    """A generator state from four 64-bit words (not all zero)."""
    s = np.asarray(seed_words, dtype=np.uint64).reshape(4).copy()
    if not s.any():
        s[0] = np.uint64(0x9E3779B97F4A7C15)
    return s


# -- the chain ----------------------------------------------------------------------------------


@nb.njit(**_INLINE)
def _quantize(theta, res, inv_res):
    if res > 0.0:
        return math.floor(theta * inv_res) * res
    return theta


@nb.njit(**_JIT)
def sensor_reset(cfg, st, theta_u, theta_l, speed_u, speed_l):
    """Start the chain on a rig turning steadily at (speed_u, speed_l) [rad/s].

    The delay line is filled with the angles of that steady motion, the previous encoder
    readings are the current ones (no noise), and the filters are at their steady state
    for those speeds, so a rig at rest reads exactly zero speed.
    """
    ts = cfg[C_TS]
    d = int(cfg[C_DELAY])
    n = d + 1
    for j in range(n):
        back = (d - j) * ts  # slot j holds the angle of d - j samples ago
        st[S_RING + 2 * j] = theta_u - speed_u * back
        st[S_RING + 2 * j + 1] = theta_l - speed_l * back
    st[S_RING_POS] = 0.0  # next write goes to slot 0, overwriting the oldest (d samples ago)
    res = cfg[C_RES]
    st[S_QU] = _quantize(st[S_RING], res, cfg[C_INV_RES])
    st[S_QL] = _quantize(st[S_RING + 1], res, cfg[C_INV_RES])
    b0, b2, a2 = cfg[C_B0], cfg[C_B2], cfg[C_A2]
    for z1, z2, v in ((S_ZU1, S_ZU2, speed_u), (S_ZL1, S_ZL2, speed_l)):
        st[z1] = (1.0 - b0) * v
        st[z2] = (b2 - a2) * v
    st[S_VU] = speed_u
    st[S_VL] = speed_l
    st[S_DU] = speed_u
    st[S_DL] = speed_l


@nb.njit(**_JIT)
def sensor_noise(cfg, rng, noise):
    """Draw the noise of ``noise.shape[0]`` samples into ``noise``: columns are the angle noise
    of the upper and lower encoder [rad] and the speed noise of the upper and lower estimate
    [rad/s]; zeros where the level is zero (no numbers are drawn for those)."""
    sa = cfg[C_ANGLE_NOISE]
    sv = cfg[C_SPEED_NOISE]
    for k in range(noise.shape[0]):
        if sa > 0.0:
            z0, z1 = rng_normal_pair(rng)
            noise[k, 0] = sa * z0
            noise[k, 1] = sa * z1
        else:
            noise[k, 0] = 0.0
            noise[k, 1] = 0.0
        if sv > 0.0:
            z0, z1 = rng_normal_pair(rng)
            noise[k, 2] = sv * z0
            noise[k, 3] = sv * z1
        else:
            noise[k, 2] = 0.0
            noise[k, 3] = 0.0


@nb.njit(**_INLINE)
def sensor_sample(cfg, st, theta_u, theta_l, noise, k):
    """Process one sample of the true angles [rad] with row ``k`` of ``noise`` (see
    :func:`sensor_noise`); updates ``st``: readings at S_QU/S_QL, raw differences at
    S_DU/S_DL, speed estimates at S_VU/S_VL.

    Free of calls on purpose: it runs 1000 times per simulated second and rig.
    """
    if cfg[C_DELAY] > 0.0:
        # The ring holds the last d + 1 true angles; after writing the newest, the oldest
        # (d samples ago) sits in the next slot.
        d = int(cfg[C_DELAY])
        pos = int(st[S_RING_POS])
        iw = S_RING + 2 * pos
        st[iw] = theta_u
        st[iw + 1] = theta_l
        pos += 1
        if pos > d:
            pos = 0
        ir = S_RING + 2 * pos
        theta_u = st[ir]
        theta_l = st[ir + 1]
        st[S_RING_POS] = pos
    theta_u += noise[k, 0]
    theta_l += noise[k, 1]
    res = cfg[C_RES]
    inv_res = cfg[C_INV_RES]
    qu = _quantize(theta_u, res, inv_res)
    ql = _quantize(theta_l, res, inv_res)
    inv_ts = cfg[C_INV_TS]
    du = (qu - st[S_QU]) * inv_ts
    dl = (ql - st[S_QL]) * inv_ts
    st[S_QU] = qu
    st[S_QL] = ql
    st[S_DU] = du
    st[S_DL] = dl
    # Butterworth low-pass, transposed direct form II, both disks.
    b0 = cfg[C_B0]
    b1 = cfg[C_B1]
    b2 = cfg[C_B2]
    a1 = cfg[C_A1]
    a2 = cfg[C_A2]
    vu = b0 * du + st[S_ZU1]
    st[S_ZU1] = b1 * du - a1 * vu + st[S_ZU2]
    st[S_ZU2] = b2 * du - a2 * vu
    vl = b0 * dl + st[S_ZL1]
    st[S_ZL1] = b1 * dl - a1 * vl + st[S_ZL2]
    st[S_ZL2] = b2 * dl - a2 * vl
    st[S_VU] = vu + noise[k, 2]
    st[S_VL] = vl + noise[k, 3]


@nb.njit(**_JIT_ALLOC)
def _measure_loop(cfg, st, rng, theta_u, theta_l, qu, ql, du, dl, vu, vl):
    block = 1000
    noise = np.empty((block, 4))
    n = theta_u.shape[0]
    for k0 in range(0, n, block):
        m = min(block, n - k0)
        sensor_noise(cfg, rng, noise[:m])
        for j in range(m):
            k = k0 + j
            sensor_sample(cfg, st, theta_u[k], theta_l[k], noise, j)
            qu[k] = st[S_QU]
            ql[k] = st[S_QL]
            du[k] = st[S_DU]
            dl[k] = st[S_DL]
            vu[k] = st[S_VU]
            vl[k] = st[S_VL]


@dataclass(frozen=True)
class Measurements:
    """What the rig's computer records, one row per sensor sample (SI units)."""

    upper_angle: np.ndarray  # encoder reading of theta_u [rad]
    lower_angle: np.ndarray  # encoder reading of theta_l [rad]
    upper_speed_raw: np.ndarray  # backward difference of the upper reading [rad/s]
    lower_speed_raw: np.ndarray  # backward difference of the lower reading [rad/s]
    upper_speed: np.ndarray  # filtered upper speed estimate [rad/s]
    lower_speed: np.ndarray  # filtered lower speed estimate [rad/s]

    @property
    def twist(self) -> np.ndarray:
        """Encoder twist theta_u - theta_l [rad]."""
        return self.upper_angle - self.lower_angle


def measure(
    theta_u: ArrayLike,
    theta_l: ArrayLike,
    config: SensorConfig | dict[str, Any] | None = None,
    *,
    initial_speeds: tuple[float, float] = (0.0, 0.0),
    seed: int | np.random.Generator | None = None,
) -> Measurements:
    """Run the measurement chain over true angles sampled at ``config.sample_rate_hz``.

    Args:
        theta_u, theta_l: true angles of the upper and lower disk [rad], one per sample.
        config: :class:`SensorConfig` (or a dict of its fields); default the rig's chain.
        initial_speeds: speeds (upper, lower) [rad/s] at which the rig turned before the
            first sample; the chain starts in steady state for them (default: at rest).
        seed: seed or generator for the noise (used only when a noise level is > 0).

    Returns:
        :class:`Measurements`, arrays of the same length as the inputs. The first sample
        differentiates against the steady motion before it.
    """
    cfg_obj = SensorConfig.from_any(config, name="config")
    thu = np.ascontiguousarray(theta_u, dtype=float)
    thl = np.ascontiguousarray(theta_l, dtype=float)
    if thu.ndim != 1 or thl.shape != thu.shape:
        raise ValueError(
            f"theta_u, theta_l: expected two 1-D arrays of equal length, got {thu.shape} and {thl.shape}"
        )
    if thu.size == 0:
        raise ValueError("theta_u: at least one sample is required")
    if not (np.all(np.isfinite(thu)) and np.all(np.isfinite(thl))):
        raise ValueError("theta_u, theta_l: angles must be finite")
    v0u, v0l = (float(v) for v in initial_speeds)
    if not (math.isfinite(v0u) and math.isfinite(v0l)):
        raise ValueError(f"initial_speeds: must be finite, got {initial_speeds!r}")
    cfg = cfg_obj.as_array()
    st = np.zeros(state_size(cfg_obj.delay_samples))
    gen = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    rng = rng_state(gen.integers(0, 2**64, size=4, dtype=np.uint64))
    ts = cfg_obj.sample_period
    # The sample before the first one, on the steady motion.
    sensor_reset(cfg, st, thu[0] - v0u * ts, thl[0] - v0l * ts, v0u, v0l)
    out = [np.empty_like(thu) for _ in range(6)]
    _measure_loop(cfg, st, rng, thu, thl, *out)
    return Measurements(*out)
