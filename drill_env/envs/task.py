"""Operating points of the rig and the regimes the analysis predicts for them.

An operating point is a nominal (constant) input voltage ``u`` and the lower-disk speed
it gives at the slip equilibrium of eq. (20),

    km u = T_sup + b_up w + T_l(w),   x2 = x3 = w,   x1 = T_l(w) / k_theta,

which is unique for every ``u > uc1`` by condition (21). The regimes along ``u``
(Fig. 8 of the paper):

* ``equilibrium``: the slip equilibrium is stable and reached open loop from rest;
* ``limit_cycle``: torsional limit cycle without stick-slip (beyond the Hopf point B,
  and for the no-brake rig also between E and F where a stable cycle coexists with
  the stable equilibrium beyond the subcritical Hopf point C);
* ``stick_slip``: the limit cycle has stick phases of the lower disk (beyond D).

How the boundaries are found (:func:`operating_regimes`):

* A = uc1 = (T_sup + T_sl)/km, where the rig starts to move (closed form);
* Hopf points: Routh-Hurwitz on the linearisation of eq. (23) gives a critical friction
  slope ``d_crit`` (-0.00114 N m s/rad for the paper's parameters); the equilibrium is
  stable iff ``dT_l/dx3 > d_crit`` at its speed; the crossings are solved with brentq;
* stick-slip and coexistence boundaries (D, E, F) are not local bifurcations of the
  equilibrium, so they come from simulation: the exact simulator runs from rest at a
  grid of voltages between the Hopf points, each run is classified over a late window
  (a lower-disk stick event means stick-slip; a sustained oscillation on the stable
  side means a coexisting cycle), and each change of class is refined by repeated
  subdivision to about a tenth of a millivolt.

The regimes belong to the *nominal* model (the paper's eq. (36), effects of
:class:`~drill_env.params.ModelEffects` ignored): it is what a controller designer knows.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np
from scipy.optimize import brentq

from drill_env import _layout as L
from drill_env.friction import lower_friction_curve, lower_friction_slope
from drill_env.kernel import N_STATS, ST_EVENTS, ST_LOGGED, STATUS_MESSAGES, run
from drill_env.params import ModelEffects, RigParams

__all__ = [
    "REGIMES",
    "VOLTAGE_LIMIT",
    "OperatingPoint",
    "OperatingRegimes",
    "TaskConfig",
    "critical_friction_slope",
    "equilibrium_speed",
    "equilibrium_state",
    "hopf_voltages",
    "nominal_voltage",
    "operating_regimes",
]

REGIMES = ("equilibrium", "limit_cycle", "stick_slip")
VOLTAGE_LIMIT = 5.0  # [V] the amplifier input range of the rig is [-5, 5] V (Sec. 2.1)

_JIT = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")  # see drill_env._cache


def nominal_params(params: RigParams) -> RigParams:
    """The paper's model of ``params``: the same coefficients, no extra effects."""
    if params.effects.active:
        return dataclasses.replace(params, effects=ModelEffects())
    return params


# -- equilibrium of eq. (20) ----------------------------------------------------------------------


def nominal_voltage(params: RigParams, speed: float) -> float:
    """Voltage whose slip equilibrium turns the lower disk at ``speed`` > 0 [rad/s] -> [V]."""
    w = float(speed)
    return (
        params.upper_static_pos + params.upper_viscous_pos * w + float(lower_friction_curve(params, w))
    ) / (params.motor_constant)


def _torque_balance(params: RigParams, u: float):
    """km u - T_up(w) - T_l(w) at the slip equilibrium, as a scalar function of w (math only:
    it is solved at every episode start)."""
    tsup, bup, km = params.upper_static_pos, params.upper_viscous_pos, params.motor_constant
    tsl, bl = params.lower_static, params.lower_viscous
    t1, t2 = params.lower_hump_1, params.lower_hump_2
    h1, h2 = 0.5 * params.lower_hump_rate_1, 0.5 * params.lower_hump_rate_2
    tanh = math.tanh

    def f(w: float) -> float:
        return km * u - (tsup + bup * w + tsl + t1 * tanh(h1 * w) + t2 * tanh(h2 * w) + bl * w)

    return f


def equilibrium_speed(params: RigParams, voltage: float) -> float:
    """Lower-disk speed of the slip equilibrium at ``voltage`` [V] -> [rad/s]; 0 if u <= uc1.

    The torque balance is increasing in w by condition (21), so the root is unique.
    """
    u = float(voltage)
    if u <= params.uc1:
        return 0.0
    f = _torque_balance(params, u)
    hi = 1.0
    while f(hi) > 0.0:
        hi *= 2.0
        if hi > 1e6:
            raise ValueError(f"voltage: no equilibrium speed found for {u:g} V")
    return float(brentq(f, 0.0, hi, xtol=1e-14, rtol=1e-13, maxiter=200))


def equilibrium_state(params: RigParams, voltage: float) -> np.ndarray:
    """Kernel state on the slip equilibrium at ``voltage`` (at rest for u <= uc1)."""
    w = equilibrium_speed(params, voltage)
    y = np.zeros(L.NY)
    if w > 0.0:
        y[L.X1] = float(lower_friction_curve(params, w)) / params.string_stiffness
        y[L.X2] = w
        y[L.X3] = w
        y[L.WL] = w
    y[L.TM] = params.motor_constant * float(voltage)
    return y


def critical_friction_slope(params: RigParams) -> float:
    """Routh-Hurwitz threshold on d_l = dT_l/dx3 [N m s/rad]: the slip equilibrium is stable
    iff ``d_l > critical_friction_slope``.

    The linearisation (eq. 23) has the characteristic polynomial
    ``s^3 + a2 s^2 + a1 s + a0`` with ``a2 = b/Ju + d/Jl``,
    ``a1 = k/Ju + k/Jl + b d/(Ju Jl)``, ``a0 = k (b + d)/(Ju Jl)`` (b = b_up, k = k_theta);
    the binding condition is ``a2 a1 - a0 > 0``, a quadratic in d whose larger root is
    the threshold.
    """
    ju, jl = params.upper_inertia, params.lower_inertia
    k, b = params.string_stiffness, params.upper_viscous_pos
    # a2 a1 - a0 = c2 d^2 + c1 d + c0
    c2 = b / (ju * jl * jl)
    c1 = (k / ju + k / jl) / jl + b * b / (ju * ju * jl) - k / (ju * jl)
    c0 = (b / ju) * (k / ju + k / jl) - k * b / (ju * jl)
    disc = c1 * c1 - 4.0 * c2 * c0
    return float((-c1 + math.sqrt(disc)) / (2.0 * c2))


def _stable_at_speed(params: RigParams, w: float, d_crit: float) -> bool:
    return float(lower_friction_slope(params, w)) > d_crit


def hopf_voltages(params: RigParams, u_max: float = VOLTAGE_LIMIT) -> tuple[float, ...]:
    """Voltages in (uc1, u_max) where the slip equilibrium changes stability (Hopf points)."""
    d_crit = critical_friction_slope(params)
    w_max = equilibrium_speed(params, u_max)
    if w_max <= 0.0:
        return ()
    w = np.linspace(0.0, w_max, 20001)[1:]
    g = lower_friction_slope(params, w) - d_crit
    out = []
    for i in np.flatnonzero(np.sign(g[1:]) != np.sign(g[:-1])):
        wc = brentq(lambda x: float(lower_friction_slope(params, x)) - d_crit, w[i], w[i + 1], xtol=1e-14)
        out.append(nominal_voltage(params, wc))
    return tuple(out)


# -- classification by simulation ------------------------------------------------------------------


@nb.njit(**_JIT)
def _classify_runs(P, volts, t_settle, t_window, n_window, rtol, atol, max_steps, res):
    """From rest at each voltage: settle, then watch a window. res[i] = (lower stick events,
    x3 range first half, x3 range second half, mean x3, status)."""
    cap = 8192
    ev_t = np.empty(cap)
    ev_disk = np.empty(cap, dtype=np.int64)
    ev_from = np.empty(cap, dtype=np.int64)
    ev_to = np.empty(cap, dtype=np.int64)
    ev_y = np.empty((cap, L.NY))
    stats = np.zeros(N_STATS)
    modes = np.zeros(2, dtype=np.int64)
    seg_t = np.empty(2)
    seg_u = np.empty(1)
    t1 = np.empty(1)
    Y1 = np.empty((1, L.NY))
    M1 = np.empty((1, 2), dtype=np.int64)
    U1 = np.empty(1)
    t_out = np.empty(n_window)
    Y = np.empty((n_window, L.NY))
    M = np.empty((n_window, 2), dtype=np.int64)
    U = np.empty(n_window)
    for k in range(n_window):
        t_out[k] = t_settle + (k + 1) * (t_window / n_window)
    for i in range(volts.shape[0]):
        y = np.zeros(L.NY)
        y[L.TM] = P[i, L.KM] * volts[i]
        modes[:] = 0
        seg_u[0] = volts[i]
        seg_t[0] = 0.0
        seg_t[1] = t_settle
        t1[0] = t_settle
        status = run(
            P[i],
            y,
            modes,
            seg_t,
            seg_u,
            None,
            False,
            np.inf,
            t1,
            rtol,
            atol,
            0.0,
            max_steps,
            Y1,
            M1,
            U1,
            ev_t,
            ev_disk,
            ev_from,
            ev_to,
            ev_y,
            stats,
        )
        h = stats[5]
        if status == 0:
            seg_t[0] = t_settle
            seg_t[1] = t_settle + t_window
            status = run(
                P[i],
                y,
                modes,
                seg_t,
                seg_u,
                None,
                False,
                np.inf,
                t_out,
                rtol,
                atol,
                h,
                max_steps,
                Y,
                M,
                U,
                ev_t,
                ev_disk,
                ev_from,
                ev_to,
                ev_y,
                stats,
            )
        sticks = 0.0
        logged = int(stats[ST_LOGGED])
        for e in range(logged):
            if ev_disk[e] == 1 and ev_to[e] == 0:
                sticks += 1.0
        if stats[ST_EVENTS] > logged:
            sticks += stats[ST_EVENTS] - logged  # overflow: count the rest as possible sticks
        half = n_window // 2
        lo1 = np.inf
        hi1 = -np.inf
        lo2 = np.inf
        hi2 = -np.inf
        mean = 0.0
        for k in range(n_window):
            x3 = Y[k, L.X3]
            mean += x3
            if M[k, 1] == 0:
                sticks = max(sticks, 1.0)
            if k < half:
                lo1 = min(lo1, x3)
                hi1 = max(hi1, x3)
            else:
                lo2 = min(lo2, x3)
                hi2 = max(hi2, x3)
        res[i, 0] = sticks
        res[i, 1] = hi1 - lo1
        res[i, 2] = hi2 - lo2
        res[i, 3] = mean / n_window
        res[i, 4] = status


_SETTLE = 150.0  # [s] open-loop run from rest before the classification window
_WINDOW = 50.0  # [s] about a dozen periods of the torsional cycle
_N_WINDOW = 5000
_MAX_STEPS = 10_000_000  # passed as an argument: a literal would compile the kernel a second time
_SUSTAINED_REL = 0.05  # a cycle on the stable side: range > 5 % of the mean speed ...
_SUSTAINED_RATIO = 0.9  # ... and not decaying between the halves of the window


def _classify(params: RigParams, volts: np.ndarray, d_crit: float) -> list[str]:
    volts = np.asarray(volts, dtype=float)
    p = params.as_array()
    res = np.zeros((volts.size, 5))
    _classify_runs(
        np.tile(p, (volts.size, 1)), volts, _SETTLE, _WINDOW, _N_WINDOW, 1e-9, 1e-11, _MAX_STEPS, res
    )
    # A run that the kernel could not finish is repeated at a voltage a few parts per
    # million off (its trajectory then avoids the failing instant).
    for attempt in range(1, 4):
        bad = np.flatnonzero(res[:, 4] != 0)
        if bad.size == 0:
            break
        sub = np.zeros((bad.size, 5))
        _classify_runs(
            np.tile(p, (bad.size, 1)),
            volts[bad] * (1.0 + 3e-6 * attempt),
            _SETTLE,
            _WINDOW,
            _N_WINDOW,
            1e-9,
            1e-11,
            _MAX_STEPS,
            sub,
        )
        res[bad] = sub
    bad = np.flatnonzero(res[:, 4] != 0)
    if bad.size:
        raise RuntimeError(
            f"operating_regimes: the simulation at {volts[bad[0]]:g} V failed: "
            f"{STATUS_MESSAGES[int(res[bad[0], 4])]}"
        )
    out = []
    for u, (sticks, amp1, amp2, mean, _) in zip(volts, res, strict=True):
        if sticks > 0:
            out.append("stick_slip")
            continue
        w = equilibrium_speed(params, u)
        if not _stable_at_speed(params, w, d_crit):
            out.append("limit_cycle")
        elif amp2 > _SUSTAINED_REL * max(abs(mean), 1e-3) and amp2 >= _SUSTAINED_RATIO * amp1:
            out.append("limit_cycle")  # a stable cycle coexists and attracts the start from rest
        else:
            out.append("equilibrium")
    return out


@dataclass(frozen=True)
class OperatingRegimes:
    """The voltage axis (uc1, u_max] of the nominal model split into regimes.

    ``intervals`` are (regime, low, high) voltage intervals [V] in increasing order;
    ``hopf`` the Hopf voltages (closed form), ``transitions`` the boundaries found by
    simulation.
    """

    uc1: float  # [V] point A
    u_max: float  # [V]
    critical_slope: float  # [N m s / rad] Routh-Hurwitz threshold on dT_l/dx3
    hopf: tuple[float, ...]  # [V]
    transitions: tuple[float, ...]  # [V]
    intervals: tuple[tuple[str, float, float], ...]

    def regime_of(self, voltage: float) -> str:
        """Regime at a nominal voltage in (uc1, u_max]."""
        u = float(voltage)
        if not self.uc1 < u <= self.u_max:
            raise ValueError(f"voltage: {u!r} is outside ({self.uc1:.6g}, {self.u_max:g}] V")
        for name, lo, hi in self.intervals:
            if lo < u <= hi:
                return name
        return self.intervals[-1][0]

    def intervals_of(self, regime: str) -> list[tuple[float, float]]:
        if regime not in REGIMES:
            raise ValueError(f"regime: {regime!r} is not one of {REGIMES}")
        return [(lo, hi) for name, lo, hi in self.intervals if name == regime]

    def describe(self) -> str:
        return "\n".join(f"{name:12s} {lo:8.4f} .. {hi:8.4f} V" for name, lo, hi in self.intervals)


@functools.lru_cache(maxsize=16)
def _operating_regimes(params: RigParams, u_max: float, spacing: float) -> OperatingRegimes:
    a = params.uc1
    if not u_max > a:
        raise ValueError(f"u_max: {u_max:g} V must exceed uc1 = {a:.6g} V")
    d_crit = critical_friction_slope(params)
    hopf = hopf_voltages(params, u_max)
    edges = [a, *hopf, u_max]
    # Grid points inside each stretch of constant linear stability, kept away from its
    # ends (a decaying oscillation near a Hopf point decays arbitrarily slowly).
    stretches = []
    grid = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        margin = min(0.02, 0.25 * (hi - lo))
        n = max(2, int(math.ceil((hi - lo - 2 * margin) / spacing)) + 1)
        pts = np.linspace(lo + margin, hi - margin, n)
        stretches.append((lo, hi, len(grid), len(grid) + n))
        grid.extend(pts)
    grid = np.array(grid)
    cls = _classify(params, grid, d_crit)
    # Brackets of class changes within a stretch, refined by subdivision.
    brackets = []
    for _, _, i0, i1 in stretches:
        for i in range(i0, i1 - 1):
            if cls[i] != cls[i + 1]:
                brackets.append([grid[i], grid[i + 1], cls[i], cls[i + 1]])
    for _ in range(4):
        if not brackets:
            break
        inner = [np.linspace(b[0], b[1], 9)[1:-1] for b in brackets]
        flat = _classify(params, np.concatenate(inner), d_crit)
        for j, b in enumerate(brackets):
            c = flat[7 * j : 7 * j + 7]
            pts = [b[0], *inner[j], b[1]]
            cs = [b[2], *c, b[3]]
            k = next(k for k in range(8) if cs[k] != cs[k + 1])
            brackets[j] = [pts[k], pts[k + 1], cs[k], cs[k + 1]]
    transitions = sorted(0.5 * (b[0] + b[1]) for b in brackets)
    # Assemble: within a stretch the class is constant between consecutive transitions.
    pieces: list[list[Any]] = []
    for lo, hi, i0, i1 in stretches:
        cuts = [lo, *[t for t in transitions if lo < t < hi], hi]
        for j in range(len(cuts) - 1):
            members = [cls[i] for i in range(i0, i1) if cuts[j] <= grid[i] <= cuts[j + 1]]
            # Every piece holds a grid point except the margins at the stretch ends, which
            # take the class of the nearest grid point.
            name = members[0] if members else (cls[i0] if j == 0 else cls[i1 - 1])
            if pieces and pieces[-1][0] == name:
                pieces[-1][2] = cuts[j + 1]
            else:
                pieces.append([name, cuts[j], cuts[j + 1]])
    return OperatingRegimes(
        uc1=a,
        u_max=float(u_max),
        critical_slope=d_crit,
        hopf=tuple(float(h) for h in hopf),
        transitions=tuple(float(t) for t in transitions),
        intervals=tuple((n, float(lo), float(hi)) for n, lo, hi in pieces),
    )


def operating_regimes(
    params: RigParams, u_max: float = VOLTAGE_LIMIT, spacing: float = 0.1
) -> OperatingRegimes:
    """Regimes of the nominal model along the voltage axis (uc1, u_max], computed once per
    parameter set (cached): Hopf points in closed form, the rest by simulation from rest.

    Takes about half a second for the paper's presets.
    """
    u_max = float(u_max)
    spacing = float(spacing)
    if not (math.isfinite(u_max) and u_max > 0):
        raise ValueError(f"u_max: must be finite and > 0, got {u_max!r}")
    if not (math.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing: must be finite and > 0, got {spacing!r}")
    return _operating_regimes(nominal_params(params), u_max, spacing)


# -- the task: drawing operating points -------------------------------------------------------------


@dataclass(frozen=True)
class OperatingPoint:
    """An episode's operating point."""

    regime: str
    nominal_voltage: float  # [V]
    target_speed: float  # [rad/s] slip-equilibrium speed of the nominal model at nominal_voltage


@dataclass(frozen=True)
class TaskConfig:
    """How each episode draws its operating point.

    By default a regime is drawn uniformly from ``regimes`` and then the nominal voltage
    uniformly over that regime's voltage intervals, above the voltage of
    ``min_target_speed``. ``voltage_range`` (nominal voltage uniform in [lo, hi] V) or
    ``target_speed_range`` (target speed uniform in [lo, hi] rad/s) replace the regime draw.
    """

    regimes: tuple[str, ...] = REGIMES
    voltage_range: tuple[float, float] | None = None  # [V]
    target_speed_range: tuple[float, float] | None = None  # [rad/s]
    min_target_speed: float = 0.1  # [rad/s] floor of regime draws (the paper's lowest: 0.0911 rad/s)

    def __post_init__(self) -> None:
        regimes = self.regimes
        if isinstance(regimes, str):
            regimes = (regimes,)
        if not isinstance(regimes, Sequence) or len(regimes) == 0:
            raise ValueError(f"regimes: expected a non-empty sequence of {REGIMES}, got {self.regimes!r}")
        for r in regimes:
            if r not in REGIMES:
                raise ValueError(f"regimes: {r!r} is not one of {REGIMES}")
        if len(set(regimes)) != len(regimes):
            raise ValueError(f"regimes: duplicate entries in {tuple(regimes)!r}")
        object.__setattr__(self, "regimes", tuple(regimes))
        if self.voltage_range is not None and self.target_speed_range is not None:
            raise ValueError("voltage_range, target_speed_range: give at most one of them")
        for name in ("voltage_range", "target_speed_range"):
            rng = getattr(self, name)
            if rng is None:
                continue
            try:
                lo, hi = (float(v) for v in rng)
            except (TypeError, ValueError):
                raise ValueError(f"{name}: expected (low, high), got {rng!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo <= hi):
                raise ValueError(f"{name}: expected finite 0 < low <= high, got {rng!r}")
            object.__setattr__(self, name, (lo, hi))
        m = self.min_target_speed
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not (math.isfinite(m) and m >= 0.0):
            raise ValueError(f"min_target_speed: expected a finite number >= 0 rad/s, got {m!r}")

    @classmethod
    def from_any(cls, value: TaskConfig | Mapping[str, Any] | None) -> TaskConfig:
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, Mapping):
            allowed = {f.name for f in dataclasses.fields(cls)}
            unknown = sorted(set(value) - allowed)
            if unknown:
                raise ValueError(f"task: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
            return cls(**value)
        raise ValueError(f"task: expected TaskConfig, a dict or None, got {type(value).__name__}")


class OperatingPointSampler:
    """Draws operating points for one nominal model (validated against it once)."""

    def __init__(self, params: RigParams, config: TaskConfig):
        self.params = nominal_params(params)
        self.config = config
        self.u_max = VOLTAGE_LIMIT
        self.speed_max = equilibrium_speed(self.params, self.u_max)
        self.uc1 = self.params.uc1
        self._regimes: OperatingRegimes | None = None
        self._pools: dict[str, list[tuple[float, float]]] = {}
        if config.voltage_range is not None:
            lo, hi = config.voltage_range
            if not (self.uc1 < lo and hi <= self.u_max):
                raise ValueError(
                    f"voltage_range: ({lo:g}, {hi:g}) must lie in ({self.uc1:.6g}, {self.u_max:g}] V "
                    "(the rig turns above uc1; the amplifier stops at 5 V)"
                )
        elif config.target_speed_range is not None:
            lo, hi = config.target_speed_range
            if hi > self.speed_max:
                raise ValueError(
                    f"target_speed_range: ({lo:g}, {hi:g}) must lie in (0, {self.speed_max:.6g}] rad/s "
                    "(the equilibrium speed at 5 V)"
                )
        else:
            u_floor = (
                nominal_voltage(self.params, config.min_target_speed)
                if config.min_target_speed > 0
                else self.uc1
            )
            regimes = self.regimes
            for name in config.regimes:
                pool = [(max(lo, u_floor), hi) for lo, hi in regimes.intervals_of(name) if hi > u_floor]
                if not pool:
                    raise ValueError(
                        f"regimes: {name!r} does not occur between {u_floor:.4g} V and {self.u_max:g} V for "
                        f"these parameters; regimes found: {regimes.describe()}"
                    )
                self._pools[name] = pool

    @property
    def regimes(self) -> OperatingRegimes:
        if self._regimes is None:
            self._regimes = operating_regimes(self.params, self.u_max)
        return self._regimes

    def point_from_voltage(self, voltage: float) -> OperatingPoint:
        u = float(voltage)
        if not (math.isfinite(u) and self.uc1 < u <= self.u_max):
            raise ValueError(
                f"nominal_voltage: {voltage!r} is outside the allowed range ({self.uc1:.6g}, {self.u_max:g}] V"
            )
        return OperatingPoint(self.regimes.regime_of(u), u, equilibrium_speed(self.params, u))

    def point_from_speed(self, speed: float) -> OperatingPoint:
        w = float(speed)
        if not (math.isfinite(w) and 0.0 < w <= self.speed_max):
            raise ValueError(
                f"target_speed: {speed!r} is outside the allowed range (0, {self.speed_max:.6g}] rad/s"
            )
        # A speed so small that its voltage rounds to uc1 gets the next voltage above uc1.
        u = min(max(nominal_voltage(self.params, w), math.nextafter(self.uc1, math.inf)), self.u_max)
        return OperatingPoint(self.regimes.regime_of(u), u, w)

    def point_in_regime(self, regime: str, rng: np.random.Generator) -> OperatingPoint:
        if regime not in REGIMES:
            raise ValueError(f"regime: {regime!r} is not one of {REGIMES}")
        pool = self._pools.get(regime)
        if pool is None:
            u_floor = (
                nominal_voltage(self.params, self.config.min_target_speed)
                if self.config.min_target_speed > 0
                else self.uc1
            )
            pool = [(max(lo, u_floor), hi) for lo, hi in self.regimes.intervals_of(regime) if hi > u_floor]
            if not pool:
                raise ValueError(f"regime: {regime!r} does not occur for these parameters")
            self._pools[regime] = pool
        total = sum(hi - lo for lo, hi in pool)
        x = float(rng.uniform(0.0, total))
        for lo, hi in pool:
            if x <= hi - lo:
                u = lo + x
                break
            x -= hi - lo
        else:
            u = pool[-1][1]
        return OperatingPoint(regime, u, equilibrium_speed(self.params, u))

    def sample(self, rng: np.random.Generator) -> OperatingPoint:
        cfg = self.config
        if cfg.voltage_range is not None:
            return self.point_from_voltage(rng.uniform(*cfg.voltage_range))
        if cfg.target_speed_range is not None:
            return self.point_from_speed(rng.uniform(*cfg.target_speed_range))
        regime = cfg.regimes[int(rng.integers(len(cfg.regimes)))]
        return self.point_in_regime(regime, rng)
