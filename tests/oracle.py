"""An independent reference solution of the rig: SciPy's ``solve_ivp`` with terminal events.

Written from the model equations alone, eq. (10)/(36) of Mihajlovic et al. (2004) with
the friction laws (12) and (14), and sharing no code with the package's kernels: only
:class:`drill_env.RigParams` is read, for the parameter values. It is deliberately the
straightforward construction -- a NumPy right-hand side per friction mode, one
``solve_ivp`` call per smooth piece, each ending at the first switching event -- so
that it serves both as a test oracle and as the baseline of the speed benchmark.

State: ``(x1, x2, x3, theta_l)`` with ``x1 = theta_u - theta_l``. Disk modes: +1 slip
forward, -1 slip backward, 0 stick (speed held at exactly 0).

Switching rules (the set-valued friction laws):

* a slipping disk whose speed reaches 0 sticks if the torque that would hold it lies
  in its closed static band, and otherwise slips towards the side it leaves the band;
* a stuck disk starts to slip, towards that side, when the holding torque crosses an
  edge of its band.

One effect of the package's model extensions is supported, the external torque on the
lower disk ``A sin(w t + phi)`` (``effects.disturbance_*``): it adds to the lower disk's
torque balance and to the torque that holds it at rest.

Stuck disks under time-varying inputs. ``solve_ivp`` looks at its event functions only
at the ends of its steps, so a holding torque that leaves its band and comes back within
one step is not seen; and while both disks stick the vector field is zero and its steps
grow without bound. Hence:

* while both disks stick under a function ``u(t)`` or the external torque, the state is
  constant and ``solve_ivp`` is not used: the holding torques, explicit functions of
  time, are sampled every ``scan_dt`` (default 1e-4 s, at most ``max_step``), chunk by
  chunk; each local maximum of the band violation that comes close to the edge is refined
  (bounded scalar maximisation between its neighbours), and the first exit is bracketed
  and located with ``brentq``;
* with ``scan_dt`` given, the same scan runs on the dense output of every ``solve_ivp``
  piece in which one disk sticks, and an exit found before the solver's own event ends
  the piece there;
* ``max_step`` bounds every ``solve_ivp`` step.

An input that leaves and re-enters a band within less than ``scan_dt`` (and is not
caught by the refinement of a local maximum, e.g. a rectangular pulse narrower than the
grid) is missed: choose ``scan_dt`` below the input's own time scale.

The friction of eq. (14) is written with the paper's ``1 - 2/(1 + exp(beta w))``, and
each slip branch with ``w = mode * x3`` (which is |x3| on the branch) so that the
vector field of a branch stays smooth a little past its zero crossing, where the
solver's last step before an event may look.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, minimize_scalar

from drill_env.params import RigParams

__all__ = ["OracleResult", "oracle_simulate", "rig_constants"]


def rig_constants(params: RigParams) -> dict[str, float]:
    """The paper's symbols for the parameter values (SI)."""
    return {
        "km": params.motor_constant,
        "Ju": params.upper_inertia,
        "Tsup": params.upper_static_pos,
        "Tsun": params.upper_static_neg,
        "bup": params.upper_viscous_pos,
        "bun": params.upper_viscous_neg,
        "Jl": params.lower_inertia,
        "kth": params.string_stiffness,
        "Tsl": params.lower_static,
        "bl": params.lower_viscous,
        "T1": params.lower_hump_1,
        "T2": params.lower_hump_2,
        "beta1": params.lower_hump_rate_1,
        "beta2": params.lower_hump_rate_2,
    }


@dataclass
class OracleResult:
    """Samples of the reference solution and its switching events."""

    t: np.ndarray  # [s]
    y: np.ndarray  # (n, 4): x1, x2, x3, theta_l
    modes: np.ndarray  # (n, 2): upper, lower mode of the piece a sample lies in
    event_t: list[float] = field(default_factory=list)
    event_disk: list[int] = field(default_factory=list)  # 0 upper, 1 lower
    event_before: list[int] = field(default_factory=list)
    event_after: list[int] = field(default_factory=list)
    event_state: list[np.ndarray] = field(default_factory=list)
    nfev: int = 0
    pieces: int = 0
    final_state: np.ndarray | None = None
    final_modes: tuple[int, int] = (0, 0)

    @property
    def x1(self) -> np.ndarray:
        return self.y[:, 0]

    @property
    def x2(self) -> np.ndarray:
        return self.y[:, 1]

    @property
    def x3(self) -> np.ndarray:
        return self.y[:, 2]

    @property
    def theta_l(self) -> np.ndarray:
        return self.y[:, 3]


class _Rig:
    """Vector field, holding torques and event functions of the rig in given modes."""

    def __init__(self, params: RigParams, u: Callable[[float], float]):
        c = rig_constants(params)
        self.c = c
        self.u = u
        e = params.effects
        self.dist = (float(e.disturbance_amp), float(e.disturbance_freq), float(e.disturbance_phase))

    def disturbance(self, t: float) -> float:
        """External torque on the lower disk [N m]."""
        a, w, phi = self.dist
        return a * math.sin(w * t + phi) if a != 0.0 else 0.0

    def lower_slip_friction(self, x3: float, mode: int) -> float:
        c = self.c
        w = mode * x3  # |x3| on the branch
        hump = c["T1"] * (1.0 - 2.0 / (1.0 + math.exp(c["beta1"] * w))) + c["T2"] * (
            1.0 - 2.0 / (1.0 + math.exp(c["beta2"] * w))
        )
        return mode * (c["Tsl"] + hump) + c["bl"] * x3

    def upper_slip_friction(self, x2: float, mode: int) -> float:
        c = self.c
        if mode > 0:
            return c["Tsup"] + c["bup"] * x2
        return -c["Tsun"] + c["bun"] * x2

    def upper_holding(self, t: float, y: np.ndarray) -> float:
        """Friction torque that keeps the upper disk at rest: km u - k_theta x1."""
        return self.c["km"] * self.u(t) - self.c["kth"] * y[0]

    def lower_holding(self, t: float, y: np.ndarray) -> float:
        """Friction torque that keeps the lower disk at rest: k_theta x1 + disturbance."""
        return self.c["kth"] * y[0] + self.disturbance(t)

    def rhs(self, modes: tuple[int, int]) -> Callable[[float, np.ndarray], np.ndarray]:
        c = self.c
        mu, ml = modes

        def f(t, y):
            x1, x2, x3 = y[0], y[1], y[2]
            dx2 = 0.0
            if mu != 0:
                dx2 = (c["km"] * self.u(t) - c["kth"] * x1 - self.upper_slip_friction(x2, mu)) / c["Ju"]
            dx3 = 0.0
            if ml != 0:
                dx3 = (c["kth"] * x1 + self.disturbance(t) - self.lower_slip_friction(x3, ml)) / c["Jl"]
            return np.array([x2 - x3, dx2, dx3, x3])

        return f

    def holding_many(self, disk: int, ts: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """Holding torque of ``disk`` (0 upper, 1 lower) at times ``ts``, states ``ys`` (4, n)."""
        c = self.c
        if disk == 0:
            u = np.array([self.u(float(s)) for s in ts], dtype=float)
            return c["km"] * u - c["kth"] * ys[0]
        a, w, phi = self.dist
        dist = a * np.sin(w * ts + phi) if a != 0.0 else 0.0
        return c["kth"] * ys[0] + dist

    def band_violation(self, disk: int, ts: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """How far a stuck disk's holding torque lies outside its static band (> 0 outside,
        <= 0 in the closed band)."""
        c = self.c
        need = self.holding_many(disk, ts, ys)
        if disk == 0:
            return np.maximum(need - c["Tsup"], -c["Tsun"] - need)
        return np.maximum(need - c["Tsl"], -c["Tsl"] - need)

    def decide_upper(self, t: float, y: np.ndarray) -> int:
        need = self.upper_holding(t, y)
        if need > self.c["Tsup"]:
            return 1
        if need < -self.c["Tsun"]:
            return -1
        return 0

    def decide_lower(self, t: float, y: np.ndarray) -> int:
        need = self.lower_holding(t, y)
        if need > self.c["Tsl"]:
            return 1
        if need < -self.c["Tsl"]:
            return -1
        return 0

    def events(self, modes: tuple[int, int]) -> list[tuple[Callable, int, int]]:
        """(event function, disk, mode after) for each switching surface of the modes.

        ``mode after`` is None for a speed reaching zero (decided at the event).
        """
        c = self.c
        mu, ml = modes
        out = []
        if mu != 0:
            out.append((_event(lambda t, y: y[1], -mu), 0, None))
        else:
            out.append((_event(lambda t, y: self.upper_holding(t, y) - c["Tsup"], 1), 0, 1))
            out.append((_event(lambda t, y: self.upper_holding(t, y) + c["Tsun"], -1), 0, -1))
        if ml != 0:
            out.append((_event(lambda t, y: y[2], -ml), 1, None))
        else:
            out.append((_event(lambda t, y: self.lower_holding(t, y) - c["Tsl"], 1), 1, 1))
            out.append((_event(lambda t, y: self.lower_holding(t, y) + c["Tsl"], -1), 1, -1))
        return out


def _event(fn: Callable, direction: int) -> Callable:
    def g(t, y):
        return fn(t, y)

    g.terminal = True
    g.direction = direction
    return g


_SCAN_CHUNK = 2000  # grid points per chunk of a scan


def _first_band_exit(
    rig: _Rig,
    disks: Sequence[int],
    states: Callable[[np.ndarray], np.ndarray],
    a: float,
    b: float,
    dt: float,
) -> tuple[float, list[tuple[int, int]]] | None:
    """First instant in (a, b] at which the holding torque of one of the stuck ``disks``
    is outside its static band, and the (disk, slip direction) pairs that leave there.

    ``states(ts)`` gives the state (4, n) at times ``ts``. The band violation is sampled
    on a grid of spacing <= ``dt``; the first positive sample brackets an exit, and every
    interior local maximum before it that comes within twice its rise of the edge is
    refined by bounded maximisation between its neighbours (an exit and return between
    two samples). The exit itself is located by ``brentq``.
    """
    if not b > a:
        return None
    n = max(1, math.ceil((b - a) / dt))

    def viol(disk: int, t: float) -> float:
        ts = np.array([t])
        return float(rig.band_violation(disk, ts, states(ts))[0])

    start = 0
    while True:
        stop = min(n, start + _SCAN_CHUNK)
        idx = np.arange(start, stop + 1)
        ts = a + (b - a) * idx / n
        ts[idx == n] = b
        ys = states(ts)
        brackets = []  # (left, right, disk) of the first exit of each disk in this chunk
        for disk in disks:
            g = rig.band_violation(disk, ts, ys)
            if start == 0 and g[0] > 0.0:  # already outside at the start of the scan
                brackets.append((a, a, disk))
                continue
            pos = np.flatnonzero(g[1:] > 0.0)
            first = int(pos[0]) + 1 if pos.size else None
            # interior local maxima (each global index is interior to exactly one chunk)
            end = first if first is not None else g.size - 1
            found = None
            g_mid = g[1:-1]
            rise = np.maximum(g_mid - g[:-2], g_mid - g[2:])
            peaks = np.flatnonzero((g_mid >= g[:-2]) & (g_mid >= g[2:]) & (g_mid + 2.0 * rise > 0.0)) + 1
            for j in peaks[peaks < end]:
                opt = minimize_scalar(
                    lambda t, disk=disk: -viol(disk, t),
                    bounds=(ts[j - 1], ts[j + 1]),
                    method="bounded",
                    options={"xatol": 1e-14},
                )
                if -opt.fun > 0.0:
                    found = (ts[j - 1], float(opt.x), disk)
                    break
            if found is None and first is not None:
                found = (ts[first - 1], ts[first], disk)
            if found is not None:
                brackets.append(found)
        if brackets:
            roots = []
            for left, right, disk in brackets:
                if left == right:
                    t_x = left
                else:
                    t_x = _exit_instant(lambda t, disk=disk: viol(disk, t), left, right)
                roots.append((t_x, disk))
            t_x = min(r[0] for r in roots)
            leaving = []
            for t_r, disk in sorted(roots, key=lambda r: r[1]):
                if t_r - t_x <= 1e-12:
                    # the side of the band it leaves, where it is outside (t_r, not t_x)
                    ts1 = np.array([t_r])
                    need = float(rig.holding_many(disk, ts1, states(ts1))[0])
                    leaving.append((disk, 1 if need >= 0.0 else -1))
            return t_x, leaving
        if stop >= n:
            return None
        start = stop - 1  # two points of overlap: the last one becomes interior


def _exit_instant(g: Callable[[float], float], left: float, right: float) -> float:
    """The first instant at which ``g`` (<= 0 at ``left``, > 0 at ``right``) is > 0, to
    a few units in the last place: ``brentq`` for the root, then the bracket around it
    narrowed by bisection so that the instant returned lies on the outside (a jump of a
    discontinuous input is located to the floating-point number where it happens)."""
    if g(left) > 0.0:
        return float(left)
    r = brentq(g, left, right, xtol=1e-15, rtol=1e-15)
    if g(r) > 0.0:
        lo, hi = left, r
        d = math.ulp(r)
        while d < r - left and g(r - d) > 0.0:  # walk back to the inside
            hi = r - d
            d *= 2.0
        lo = max(left, r - d)
    else:
        lo, hi = r, right
        d = math.ulp(r)
        while d < right - r and g(r + d) <= 0.0:  # walk out
            lo = r + d
            d *= 2.0
        hi = min(right, r + d)
    while True:  # g(lo) <= 0 < g(hi)
        mid = 0.5 * (lo + hi)
        if not lo < mid < hi:
            return float(hi)
        if g(mid) > 0.0:
            hi = mid
        else:
            lo = mid


def _input(
    u, control_dt: float | None, t0: float
) -> tuple[Callable[[float], float] | None, list[float], np.ndarray]:
    """The voltage as a function of time, or the instants and values of a zero-order hold."""
    if callable(u):
        return u, [], np.empty(0)
    arr = np.asarray(u, dtype=float)
    if arr.ndim == 0:
        return None, [], arr.reshape(1)
    if control_dt is None:
        raise ValueError("control_dt is required with a voltage sequence")
    return None, [t0 + k * control_dt for k in range(1, arr.size)], arr.copy()


def oracle_simulate(
    params: RigParams,
    u: float | Sequence[float] | Callable[[float], float],
    t_final: float,
    x0: Sequence[float] | None = None,
    t_eval: np.ndarray | None = None,
    *,
    rtol: float = 1e-12,
    atol: float = 1e-14,
    method: str = "DOP853",
    control_dt: float | None = None,
    t0: float = 0.0,
    max_pieces: int = 1_000_000,
    max_step: float = math.inf,
    scan_dt: float | None = None,
) -> OracleResult:
    """Integrate the rig from ``t0`` to ``t_final`` piece by piece between switching events.

    ``u`` is a constant voltage, a zero-order-hold sequence (one value per
    ``control_dt``) or a Python function of time. ``x0`` is ``(x1, x2, x3)`` or
    ``(x1, x2, x3, theta_l)``; default the rig at rest. ``t_eval``: sample times
    (default: every 0.01 s). ``max_step`` bounds every ``solve_ivp`` step. ``scan_dt``:
    grid spacing on which stuck disks' band exits are searched (see the module
    docstring); default 1e-4 s (or ``max_step`` if smaller) while both disks stick under
    a function input or the external torque, and no scan of ``solve_ivp`` pieces.
    """
    if scan_dt is not None and not scan_dt > 0.0:
        raise ValueError(f"scan_dt must be > 0, got {scan_dt!r}")
    u_of_t, breaks, held = _input(u, control_dt, t0)
    rig = _Rig(params, u_of_t if u_of_t is not None else (lambda t: float(held[0])))
    time_varying = u_of_t is not None or rig.dist[0] != 0.0
    frozen_dt = min(scan_dt if scan_dt is not None else 1e-4, max_step)
    y = np.zeros(4)
    if x0 is not None:
        x0 = np.asarray(x0, dtype=float)
        y[: x0.size] = x0
    if t_eval is None:
        t_eval = t0 + 0.01 * np.arange(int(round((t_final - t0) / 0.01)) + 1)
    t_eval = np.asarray(t_eval, dtype=float)
    result = OracleResult(
        t=t_eval, y=np.full((t_eval.size, 4), np.nan), modes=np.zeros((t_eval.size, 2), int)
    )
    bounds = [b for b in breaks if t0 < b < t_final] + [t_final]

    def log(t_ev: float, disk: int, before: int, after: int, y_ev: np.ndarray) -> None:
        result.event_t.append(t_ev)
        result.event_disk.append(disk)
        result.event_before.append(before)
        result.event_after.append(after)
        result.event_state.append(y_ev.copy())

    t = t0
    modes = (0, 0)
    k = 0  # next sample to fill
    seg_start = True
    repeats = 0
    while t < t_final:
        if seg_start:
            if u_of_t is None:
                # The held value of the segment that starts here (no rounding of t).
                segment = min(sum(1 for b in breaks if b <= t), held.size - 1)
                value = float(held[segment])
                rig.u = lambda t, value=value: value
            # Modes follow from the state at the start of each input segment.
            mu = int(np.sign(y[1])) or rig.decide_upper(t, y)
            ml = int(np.sign(y[2])) or rig.decide_lower(t, y)
            if t > t0:  # a jump of the input may release a stuck disk: log it as an event
                for disk, (old, new) in enumerate(zip(modes, (mu, ml), strict=True)):
                    if old != new:
                        log(t, disk, old, new, y)
            modes = (mu, ml)
            seg_start = False
        t_end = next(b for b in bounds if b > t)
        while k < t_eval.size and t_eval[k] < t:
            k += 1
        if modes == (0, 0):
            # Both disks stuck: the state is constant. Under a held voltage and no external
            # torque nothing changes until the voltage does (and an event function resting
            # at exactly zero on a band edge must not be taken for a crossing); otherwise
            # the holding torques are explicit functions of time, scanned for a band exit.
            exit_ = None
            if time_varying:
                y_rest = y.copy()
                exit_ = _first_band_exit(
                    rig,
                    (0, 1),
                    lambda ts, y_rest=y_rest: np.repeat(y_rest[:, None], ts.size, 1),
                    t,
                    t_end,
                    frozen_dt,
                )
            t_stop = t_end if exit_ is None else exit_[0]
            last_piece = exit_ is None and t_end >= t_final
            j = k
            while j < t_eval.size and (t_eval[j] < t_stop or (last_piece and t_eval[j] <= t_stop)):
                j += 1
            result.y[k:j] = y
            result.modes[k:j] = modes
            k = j
            result.pieces += 1
            t = t_stop
            if exit_ is None:
                seg_start = True
                continue
            if result.event_t and t - result.event_t[-1] <= 1e-14 * max(1.0, abs(t)):
                repeats += 1
                if repeats > 8:
                    raise RuntimeError(f"switching events repeat at one instant (chattering) at t = {t}")
            else:
                repeats = 0
            new = list(modes)
            for disk, after in exit_[1]:
                log(t, disk, 0, after, y)
                new[disk] = after
            modes = (new[0], new[1])
            continue
        evs = rig.events(modes)
        # A disk set in motion from rest (or reversed) starts on its switching surface;
        # a short first step resolves its first excursion, so that a quick return to
        # zero speed is seen as a sign change and not mistaken for the start.
        on_surface = (modes[0] != 0 and y[1] == 0.0) or (modes[1] != 0 and y[2] == 0.0)
        sol = solve_ivp(
            rig.rhs(modes),
            (t, t_end),
            y,
            method=method,
            rtol=rtol,
            atol=atol,
            events=[e[0] for e in evs],
            dense_output=True,
            first_step=min(1e-9, t_end - t) if on_surface else None,
            max_step=max_step,
        )
        if sol.status < 0:
            raise RuntimeError(f"solve_ivp failed at t = {t}: {sol.message}")
        result.nfev += sol.nfev
        result.pieces += 1
        if result.pieces > max_pieces:
            raise RuntimeError(f"more than {max_pieces} pieces: chattering at t = {t}")
        t_stop = float(sol.t[-1])
        # The switching at the end of the piece, if any: [(disk, mode after)], state, time.
        switch: list[tuple[int, int]] = []
        if sol.status == 1:
            # A terminal event: find it (solve_ivp records only the first one).
            i = next(i for i, te in enumerate(sol.t_events) if len(te))
            _, disk, after = evs[i]
            y_ev = np.asarray(sol.y_events[i][0], dtype=float).copy()
            t_stop = float(sol.t_events[i][0])
            if after is None:  # a speed reached zero: at rest, then decided
                y_ev[1 + disk] = 0.0
                after = rig.decide_upper(t_stop, y_ev) if disk == 0 else rig.decide_lower(t_stop, y_ev)
            switch = [(disk, after)]
        stuck = [d for d in (0, 1) if modes[d] == 0]
        if scan_dt is not None and stuck:
            # The holding torque of a stuck disk may leave its band and come back between
            # two of the solver's steps: scan the dense output of the piece.
            exit_ = _first_band_exit(rig, stuck, sol.sol, t, t_stop, min(scan_dt, max_step))
            if exit_ is not None and (exit_[0] < t_stop - 1e-11 or not switch):
                t_stop = exit_[0]
                switch = exit_[1]
                y_ev = sol.sol(t_stop).copy()
        last_piece = not switch and t_end >= t_final
        # Samples in [t, t_stop) belong to this piece; the final sample closes the last one.
        j = k
        while j < t_eval.size and (t_eval[j] < t_stop or (last_piece and t_eval[j] <= t_stop)):
            j += 1
        if j > k:
            result.y[k:j] = sol.sol(t_eval[k:j]).T
            result.modes[k:j] = modes
            k = j
        if not switch:
            y = sol.y[:, -1].copy()
            t = t_stop
            if t_end >= t_final:
                break
            seg_start = True
            continue
        y = y_ev
        t = t_stop
        if result.event_t and t - result.event_t[-1] <= 1e-14 * max(1.0, abs(t)):
            repeats += 1
            if repeats > 8:
                raise RuntimeError(f"switching events repeat at one instant (chattering) at t = {t}")
        else:
            repeats = 0
        new = list(modes)
        for disk, after in switch:
            log(t, disk, modes[disk], after, y)
            new[disk] = after
        modes = (new[0], new[1])
    if k < t_eval.size:  # samples at the very end, after an event exactly there
        result.y[k:] = y
        result.modes[k:] = modes
    result.final_state = y
    result.final_modes = modes
    return result
