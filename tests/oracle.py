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
torque balance and to the torque that holds it at rest. While both disks stick under a
time-varying input or torque the vector field is zero, and ``solve_ivp`` looks at its
event functions only at step ends: pass ``max_step`` (below the input's own time scale)
so that no band exit falls between two steps.

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
) -> OracleResult:
    """Integrate the rig from ``t0`` to ``t_final`` piece by piece between switching events.

    ``u`` is a constant voltage, a zero-order-hold sequence (one value per
    ``control_dt``) or a Python function of time. ``x0`` is ``(x1, x2, x3)`` or
    ``(x1, x2, x3, theta_l)``; default the rig at rest. ``t_eval``: sample times
    (default: every 0.01 s). ``max_step`` bounds every solver step (see the module
    docstring: needed while both disks stick under a time-varying input or torque).
    """
    u_of_t, breaks, held = _input(u, control_dt, t0)
    rig = _Rig(params, u_of_t if u_of_t is not None else (lambda t: float(held[0])))
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
                        result.event_t.append(t)
                        result.event_disk.append(disk)
                        result.event_before.append(old)
                        result.event_after.append(new)
                        result.event_state.append(y.copy())
            modes = (mu, ml)
            seg_start = False
        t_end = next(b for b in bounds if b > t)
        while k < t_eval.size and t_eval[k] < t:
            k += 1
        if modes == (0, 0) and u_of_t is None and rig.dist[0] == 0.0:
            # Both disks stuck under a held voltage: an equilibrium, nothing changes until
            # the voltage does (and an event function resting at exactly zero on a band
            # edge must not be taken for a crossing).
            j = k
            while j < t_eval.size and (t_eval[j] < t_end or (t_end >= t_final and t_eval[j] <= t_end)):
                j += 1
            result.y[k:j] = y
            result.modes[k:j] = modes
            k = j
            result.pieces += 1
            t = t_end
            seg_start = True
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
        t_stop = sol.t[-1]
        last_piece = sol.status == 0 and t_end >= t_final
        # Samples in [t, t_stop) belong to this piece; the final sample closes the last one.
        j = k
        while j < t_eval.size and (t_eval[j] < t_stop or (last_piece and t_eval[j] <= t_stop)):
            j += 1
        if j > k:
            result.y[k:j] = sol.sol(t_eval[k:j]).T
            result.modes[k:j] = modes
            k = j
        y = sol.y[:, -1].copy()
        t = t_stop
        if sol.status == 0:
            if t_end >= t_final:
                break
            seg_start = True
            continue
        # A terminal event: find it (solve_ivp records only the first one).
        fired = [i for i, te in enumerate(sol.t_events) if len(te)]
        i = fired[0]
        _, disk, after = evs[i]
        y = np.asarray(sol.y_events[i][0], dtype=float).copy()
        t = float(sol.t_events[i][0])
        mu, ml = modes
        if disk == 0:
            if after is None:
                y[1] = 0.0
                after = rig.decide_upper(t, y)
            new = (after, ml)
        else:
            if after is None:
                y[2] = 0.0
                after = rig.decide_lower(t, y)
            new = (mu, after)
        if result.event_t and t - result.event_t[-1] <= 1e-14 * max(1.0, abs(t)):
            repeats += 1
            if repeats > 8:
                raise RuntimeError(f"switching events repeat at one instant (chattering) at t = {t}")
        else:
            repeats = 0
        result.event_t.append(t)
        result.event_disk.append(disk)
        result.event_before.append(modes[disk])
        result.event_after.append(after)
        result.event_state.append(y.copy())
        modes = new
    if k < t_eval.size:  # samples at the very end, after an event exactly there
        result.y[k:] = y
        result.modes[k:] = modes
    result.final_state = y
    result.final_modes = modes
    return result
