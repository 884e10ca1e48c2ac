"""The event-driven integrator of the nonsmooth rig, compiled.

One call integrates one rig over a list of input segments (constant voltage within a
segment: a zero-order hold) or with a compiled function of time as input, sampling
the solution on a given time grid from the dense output.

Switching events, each located by root-finding on the dense output of the step in
which its indicator changes sign:

* a slipping disk reaches zero speed: it sticks if the torque that would hold it lies
  in its (closed) static band, otherwise it keeps or reverses its direction;
* the torque that holds a stuck disk leaves the band: it slips towards that side. A
  stuck disk whose torque sits exactly on an edge of its band leaves it at once if the
  torque's rate points out of the band (its next nonzero derivative, where the rate is
  zero), and otherwise stays stuck until the torque is beyond the edge.

A slipping disk's speed can also touch zero and recover inside one step (next to a
grazing orbit), with the same sign at both ends: when the speed falls at the start of a
step and rises at its end, the bottom of that dip is searched on the dense output too.
The step, the dense output, the event bracket and these grazing rules are the shared
numerical core of :mod:`drill_env.integrator`; this module adds the rig's switching
logic, the input segments and the sampling.

The two disks decouple at zero speed (a stuck disk's acceleration is zero), so each
disk's decision needs only the state, never the other disk's friction.

Status codes are listed in :data:`STATUS_MESSAGES`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from drill_env import _layout as L
from drill_env._numba import INLINE, JIT, JIT_ALLOC
from drill_env.dynamics import (
    decide_lower,
    decide_upper,
    lower_band_half,
    lower_edge_rate,
    lower_required,
    n_active,
    rhs,
    upper_band,
    upper_edge_rate,
    upper_required,
)
from drill_env.integrator import (
    ERR_MASK,
    EVENT_TIME_TOL,
    GOLDEN,
    H_MIN,
    INSIDE,
    INTERP,
    MAX_BRACKET_ITERATIONS,
    MAX_EVENTS_AT_ONE_INSTANT,
    N_EXT,
    N_STAGES,
    ORDER_EXP,
    SURFACE_WALK_START,
    C,
    bracket_closed,
    dense_component,
    dense_eval,
    events_at_instant,
    growth_factor,
    illinois_point,
    illinois_update,
    input_at,
    prepare_dense,
    shrink_factor,
    speed_dip,
    speed_zero,
    step,
)

# Everything but run() (which allocates its scratch space) runs without numba's reference
# counting (_nrt=False): with it, every call that passes arrays pays atomic increments and
# decrements, which cost as much as the arithmetic of a step.
_JIT = JIT
_JIT_ALLOC = JIT_ALLOC
_INLINE = INLINE

STATUS_MESSAGES = {
    0: "The end of the integration interval was reached.",
    1: "The maximum number of steps was reached before the end.",
    2: "The step size fell below its minimum (the vector field may be non-finite).",
    3: "Switching events repeated at one instant (chattering); integration stopped.",
    4: "The input voltage was not a finite number (the input function failed or returned NaN/inf).",
    5: "Interrupted (a stop was requested, e.g. Ctrl-C); the run ended early.",
}

# Slots of the stats vector returned by the kernels.
ST_STEPS, ST_REJECTED, ST_RHS, ST_EVENTS, ST_STATUS, ST_H, ST_T, ST_LOGGED, ST_BAD_T = range(9)
N_STATS = 9
# A stats vector one slot longer than N_STATS carries a stop request: another thread sets
# stats[ST_STOP] != 0 and the run ends after the current step with status 5 (the kernel
# releases the GIL, so a Ctrl-C reaches the caller's thread while it runs).
ST_STOP = N_STATS

SIMULTANEOUS_TOL = 1e-10  # [s] events closer than this are handled at one instant
H_MAX = 1.0  # [s]
# While a disk sticks under a time-varying input or torque (a function u(t), the external
# torque effect, friction drift), the vector field can be zero and the error control
# would let steps grow to H_MAX: steps are bounded by this, and the exit condition of
# every stuck disk is sampled STUCK_SAMPLES times inside each step (and its largest value
# refined), so a breakaway is found however briefly the load leaves the band.
STUCK_H_MAX = 0.01  # [s]
STUCK_SAMPLES = 8


# The voltage as a function of time reaches the compiled code as a C function pointer of
# signature float64(float64): one type for every such function, so the kernels compile
# once and stay cached on disk, whatever function a user passes. A zero-order hold
# passes None instead (see integrator.input_at).
INPUT_SIGNATURE = "float64(float64)"


@nb.njit(**_JIT)
def _sign_mode(v):
    if v > 0.0:
        return 1
    if v < 0.0:
        return -1
    return 0


@nb.njit(**_JIT)
def _violation_upper(p, y, u, mu):
    """<= 0 while the upper disk's mode holds, > 0 once it must switch."""
    if mu != 0:
        return -mu * y[L.X2]
    need = upper_required(p, y, u)
    lo, hi = upper_band(p, y)
    return max(need - hi, lo - need)


@nb.njit(**_JIT)
def _violation_lower(p, t, y, ml):
    if ml != 0:
        return -ml * y[L.X3]
    need = lower_required(p, t, y)
    half = lower_band_half(p, t, y)
    return max(need - half, -half - need)


@nb.njit(**_JIT)
def _violation(disk, p, t, y, u, mu, ml):
    if disk == 0:
        return _violation_upper(p, y, u, mu)
    return _violation_lower(p, t, y, ml)


@nb.njit(**_JIT)
def _stuck_violation(disk, p, t, h, c, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp):
    dense_eval(c, y, F, L.NY, ytmp)
    tc = t + c * h
    return _violation(disk, p, tc, ytmp, input_at(tc, u_seg, u_func, use_func, u_limit), mu, ml)


@nb.njit(**_JIT)
def _edge_direction(disk, p, t, h, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp, b0):
    """Whether a stuck disk whose load sits exactly on an edge of its (closed) band at the
    start of the step leaves the band there (+1) or not (-1).

    Decided by the rate of the load relative to the edge, from the vector field; when that
    rate is zero (both disks at rest), by the next nonzero derivative: the side to which the
    load first moves on the dense output, walked through at the fractions
    SURFACE_WALK_START, 2 SURFACE_WALK_START, ... below ``b0``.
    """
    u = input_at(t, u_seg, u_func, use_func, u_limit)
    rhs(t, y, u, p, mu, ml, ytmp)
    rate = upper_edge_rate(p, y, u, ytmp) if disk == 0 else lower_edge_rate(p, t, y, ytmp)
    if rate > 0.0:
        return 1
    if rate < 0.0:
        return -1
    c = SURFACE_WALK_START
    while c < b0:
        g = _stuck_violation(disk, p, t, h, c, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp)
        if g > 0.0:
            return 1
        if g < 0.0:
            return -1
        c *= 2.0
    return -1


@nb.njit(**_JIT)
def _stuck_exit(disk, p, t, h, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp):
    """Fraction of the step at which a stuck disk's load is outside its band, if anywhere
    inside the step, else 2.0 (the step's end points are checked by the caller).

    The exit condition is sampled at STUCK_SAMPLES - 1 interior points of the dense
    output. If none is outside the band but the largest sample is interior and close
    enough to the edge that the load may have left the band and come back between two
    samples, that maximum is refined by golden-section search.
    """
    n = STUCK_SAMPLES
    g_prev = _stuck_violation(disk, p, t, h, 0.0, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp)
    if (
        g_prev == 0.0
        and _edge_direction(disk, p, t, h, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp, 1.0) > 0
    ):
        return 0.0  # on the edge and leaving the band at once, however briefly
    best = g_prev
    i_best = 0
    rise = 0.0  # largest change between neighbouring samples next to the maximum
    for i in range(1, n + 1):
        g = _stuck_violation(disk, p, t, h, i / n, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp)
        if g > 0.0 and i < n:
            return i / n
        if not math.isfinite(g):
            return 2.0  # the step's own checks report non-finite values
        if g > best:
            best = g
            i_best = i
            rise = abs(g - g_prev)
        elif i == i_best + 1:
            rise = max(rise, abs(g - g_prev))
        g_prev = g
    if i_best == 0 or i_best == n or best + 2.0 * rise < 0.0:
        return 2.0  # the largest value is at an end of the step, or far inside the band
    gr = GOLDEN
    a = (i_best - 1) / n
    b = (i_best + 1) / n
    c = b - gr * (b - a)
    d = a + gr * (b - a)
    fc = _stuck_violation(disk, p, t, h, c, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp)
    fd = _stuck_violation(disk, p, t, h, d, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp)
    for _ in range(100):
        if fc > 0.0:
            return c
        if fd > 0.0:
            return d
        if (b - a) * abs(h) < 1e3 * EVENT_TIME_TOL:
            break
        if fc > fd:
            b = d
            d = c
            fd = fc
            c = b - gr * (b - a)
            fc = _stuck_violation(disk, p, t, h, c, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp)
        else:
            a = c
            c = d
            fc = fd
            d = a + gr * (b - a)
            fd = _stuck_violation(disk, p, t, h, d, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp)
    return 2.0


@nb.njit(**_JIT)
def _bad_input_time(t, h, us, u_func, use_func, u_limit):
    """First stage time of a step at which the input is not finite, else NaN."""
    for s in range(N_STAGES):
        ts = t + C[s] * h
        if not math.isfinite(input_at(ts, us, u_func, use_func, u_limit)):
            return ts
    if not math.isfinite(input_at(t + h, us, u_func, use_func, u_limit)):
        return t + h
    return math.nan


@nb.njit(**_JIT)
def _locate(disk, p, t, h, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp, b0):
    """Fraction of the step at which ``disk``'s violation first becomes >= 0.

    The violation is >= 0 at fraction ``b0`` (the end of the step, or the bottom of a dip
    of the speed inside it). A slipping disk's event is its speed's return to zero
    (:func:`~drill_env.integrator.speed_zero`); a stuck disk's, its load's exit from the
    static band, bracketed on the dense output by the Illinois method.
    """
    mode = mu if disk == 0 else ml
    if mode != 0:
        return speed_zero(L.X2 if disk == 0 else L.X3, mode, y, F, h, b0)
    a = 0.0
    b = b0
    ga = _violation(disk, p, t, y, input_at(t, u_seg, u_func, use_func, u_limit), mu, ml)
    if ga > 0.0:
        return 0.0  # outside the band already at the start: switch at once
    on_edge = ga == 0.0
    if on_edge:
        if _edge_direction(disk, p, t, h, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp, b0) > 0:
            return 0.0  # on the (closed) band's edge and leaving it: switch at once
        # The load moves into the band: the event is where it is next beyond the edge, so
        # a load still exactly on the edge counts as inside.
        ga = -INSIDE
    gb = _stuck_violation(disk, p, t, h, b, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp)
    side = 0
    for _ in range(MAX_BRACKET_ITERATIONS):
        if bracket_closed(a, b, h):
            break
        c = illinois_point(a, b, ga, gb, h)
        gc = _stuck_violation(disk, p, t, h, c, y, F, mu, ml, u_seg, u_func, use_func, u_limit, ytmp)
        if on_edge and gc == 0.0:
            gc = -INSIDE
        a, b, ga, gb, side = illinois_update(a, b, ga, gb, side, c, gc)
    return b


@nb.njit(**_JIT)
def _initial_step(t, y, f0, us, u_func, use_func, u_limit, p, mu, ml, rtol, atol, h_max, ytmp, f1):
    """Starting step after a restart, from the sizes of y, f and f' (Hairer's rule).

    The norms run over the error-controlled components of the rig's state, the thermal
    state only where the rig has it (without it a run is what it was before that state)."""
    n_norm = L.NY if p[L.HEAT] != 0.0 else L.NY_LAG
    d0 = 0.0
    d1 = 0.0
    m = 0.0
    for j in range(n_norm):
        if ERR_MASK[j] == 0.0:
            continue
        sc = atol + rtol * abs(y[j])
        d0 += (y[j] / sc) ** 2
        d1 += (f0[j] / sc) ** 2
        m += 1.0
    d0 = math.sqrt(d0 / m)
    d1 = math.sqrt(d1 / m)
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, h_max)
    for j in range(L.NY):
        ytmp[j] = y[j] + h0 * f0[j]
    t1 = t + h0
    rhs(t1, ytmp, input_at(t1, us, u_func, use_func, u_limit), p, mu, ml, f1)
    d2 = 0.0
    for j in range(n_norm):
        if ERR_MASK[j] == 0.0:
            continue
        sc = atol + rtol * abs(y[j])
        d2 += ((f1[j] - f0[j]) / sc) ** 2
    d2 = math.sqrt(d2 / m) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** ORDER_EXP
    return min(100.0 * h0, h1, h_max)


@nb.njit(**_INLINE)
def _emit(k, theta, y, F, n, mu, ml, u, samples):
    """Write sample k from the dense output of the current step (n evolving components)."""
    _, Y_out, M_out, U_out = samples
    for j in range(n):
        Y_out[k, j] = dense_component(theta, y, F, j)
    for j in range(n, L.NY):
        Y_out[k, j] = y[j]
    M_out[k, 0] = mu
    M_out[k, 1] = ml
    U_out[k] = u


@nb.njit(**_JIT)
def _held_samples(k, t, y, mu, ml, u, samples):
    """Samples at or before ``t`` (the start of a segment) are the state there; returns the
    next sample."""
    t_out, Y_out, M_out, U_out = samples
    while k < t_out.shape[0] and t_out[k] <= t:
        for j in range(L.NY):
            Y_out[k, j] = y[j]
        M_out[k, 0] = mu
        M_out[k, 1] = ml
        U_out[k] = u
        k += 1
    return k


@nb.njit(**_INLINE)
def _step_samples(k, t_end, closed, t, h, y, F, n, mu, ml, u_hold, us, u_func, use_func, u_limit, samples):
    """Samples before ``t_end`` (also at it when ``closed``) from the dense output of the
    step of size h from t. Returns the next sample and NaN, or the sample time at which
    the input was not finite."""
    t_out = samples[0]
    while k < t_out.shape[0] and (t_out[k] < t_end or (closed and t_out[k] == t_end)):
        uk = input_at(t_out[k], us, u_func, use_func, u_limit) if use_func else u_hold
        if not math.isfinite(uk):
            return k, t_out[k]
        _emit(k, (t_out[k] - t) / h, y, F, n, mu, ml, uk, samples)
        k += 1
    return k, math.nan


@nb.njit(**_JIT)
def _final_samples(k, y, mu, ml, status, samples):
    """Samples past a premature stop keep the last state (flagged by the status)."""
    t_out, Y_out, M_out, U_out = samples
    while k < t_out.shape[0]:
        for j in range(L.NY):
            Y_out[k, j] = y[j]
        M_out[k, 0] = mu
        M_out[k, 1] = ml
        U_out[k] = np.nan if status != 0 else U_out[k - 1] if k > 0 else 0.0
        k += 1


@nb.njit(**_JIT)
def _log_event(t, disk, old, new, y, log, stats):
    ev_t, ev_disk, ev_from, ev_to, ev_y = log
    i = int(stats[ST_EVENTS])
    if i < ev_t.shape[0]:
        ev_t[i] = t
        ev_disk[i] = disk
        ev_from[i] = old
        ev_to[i] = new
        for j in range(L.NY):
            ev_y[i, j] = y[j]
        stats[ST_LOGGED] = i + 1
    stats[ST_EVENTS] = i + 1


@nb.njit(**_JIT)
def _segment_modes(p, t, y, u, mu, ml, first, log, stats):
    """Modes at the start of an input segment, from the state: a moving disk slips, a disk
    at rest is decided by its torque balance (this is also where an input jump releases a
    stuck disk). Changes are logged, except at the very start."""
    new_mu = _sign_mode(y[L.X2])
    if new_mu == 0:
        new_mu = decide_upper(p, y, u)
    new_ml = _sign_mode(y[L.X3])
    if new_ml == 0:
        new_ml = decide_lower(p, t, y)
    if not first and new_mu != mu:
        _log_event(t, 0, mu, new_mu, y, log, stats)
    if not first and new_ml != ml:
        _log_event(t, 1, ml, new_ml, y, log, stats)
    return new_mu, new_ml


@nb.njit(**_INLINE)
def _events_in_step(
    t, h, t_new, y, y_new, f0, p, mu, ml, frozen_when_stuck, us, u_func, use_func, u_limit, scratch, stats
):
    """First switching event of each disk inside an accepted step from t to t_new = t + h,
    as fractions of the step (th_u, th_l; 2.0 for none), and whether the dense output has
    been prepared. ``scratch`` = (K, F, ytmp, ytmp2): the step's stages, the dense-output
    coefficients and two state-sized vectors."""
    K, F, ytmp, ytmp2 = scratch
    u_end = input_at(t_new, us, u_func, use_func, u_limit)
    vu = _violation_upper(p, y_new, u_end, mu)
    vl = _violation_lower(p, t_new, y_new, ml)
    ev_up = vu > 0.0 if mu == 0 else vu >= 0.0
    ev_lo = vl > 0.0 if ml == 0 else vl >= 0.0
    # A slipping disk whose speed falls at the start of the step and rises at its end
    # may touch zero and recover inside the step, with no sign change at the ends: look
    # for the bottom of that dip on the dense output.
    dip_u = not ev_up and mu != 0 and mu * f0[L.X2] < 0.0 and mu * K[N_STAGES, L.X2] > 0.0
    dip_l = not ev_lo and ml != 0 and ml * f0[L.X3] < 0.0 and ml * K[N_STAGES, L.X3] > 0.0
    b_u = 1.0
    b_l = 1.0
    dense = False
    if dip_u or dip_l:
        prepare_dense(t, y, y_new, h, us, u_func, use_func, u_limit, p, mu, ml, K, F, ytmp, ytmp2)
        stats[ST_RHS] += 3
        dense = True
        if dip_u:
            b_u = speed_dip(L.X2, mu, y, F)
            ev_up = b_u <= 1.0
        if dip_l:
            b_l = speed_dip(L.X3, ml, y, F)
            ev_lo = b_l <= 1.0
    # A stuck disk's load may leave its band inside the step and come back before its
    # end (the other disk swings, the input or a torque changes with time).
    mon_u = mu == 0 and not ev_up
    mon_l = ml == 0 and not ev_lo
    if (mon_u or mon_l) and not (frozen_when_stuck and mu == 0 and ml == 0):
        if not dense:
            prepare_dense(t, y, y_new, h, us, u_func, use_func, u_limit, p, mu, ml, K, F, ytmp, ytmp2)
            stats[ST_RHS] += 3
            dense = True
        if mon_u:
            b_u = _stuck_exit(0, p, t, h, y, F, mu, ml, us, u_func, use_func, u_limit, ytmp)
            ev_up = b_u <= 1.0
        if mon_l:
            b_l = _stuck_exit(1, p, t, h, y, F, mu, ml, us, u_func, use_func, u_limit, ytmp)
            ev_lo = b_l <= 1.0
    th_u = 2.0
    th_l = 2.0
    if ev_up or ev_lo:
        if not dense:
            prepare_dense(t, y, y_new, h, us, u_func, use_func, u_limit, p, mu, ml, K, F, ytmp, ytmp2)
            stats[ST_RHS] += 3
            dense = True
        if ev_up:
            th_u = _locate(0, p, t, h, y, F, mu, ml, us, u_func, use_func, u_limit, ytmp, b_u)
        if ev_lo:
            th_l = _locate(1, p, t, h, y, F, mu, ml, us, u_func, use_func, u_limit, ytmp, b_l)
    return th_u, th_l, dense


@nb.njit(**_JIT)
def _switch(p, t_ev, y_ev, u_ev, mu, ml, do_u, do_l, log, stats):
    """New modes of the disks switching at t_ev (state y_ev, voltage u_ev); logs them.

    A slipping disk that reached zero speed is put exactly at rest first, so that both
    decisions see the state at the switching instant. A stuck disk breaks away towards
    the side of its band its load left by.
    """
    if do_u and mu != 0:
        y_ev[L.X2] = 0.0
    if do_l and ml != 0:
        y_ev[L.X3] = 0.0
    nmu = mu
    nml = ml
    if do_u:
        if mu != 0:
            nmu = decide_upper(p, y_ev, u_ev)
        else:
            need = upper_required(p, y_ev, u_ev)
            lo, hi = upper_band(p, y_ev)
            nmu = 1 if need - hi >= lo - need else -1
    if do_l:
        if ml != 0:
            nml = decide_lower(p, t_ev, y_ev)
        else:
            need = lower_required(p, t_ev, y_ev)
            nml = 1 if need >= 0.0 else -1
    if do_u:
        _log_event(t_ev, 0, mu, nmu, y_ev, log, stats)
    if do_l:
        _log_event(t_ev, 1, ml, nml, y_ev, log, stats)
    return nmu, nml


# Rows of the scratch array of :func:`run_ws`: RK stages, interpolation coefficients and
# five state-sized vectors.
WORK_ROWS = N_EXT + INTERP + 5


@nb.njit(**_JIT_ALLOC)
def run(
    p,
    y,
    modes,
    seg_t,
    seg_u,
    u_func,
    use_func,
    u_limit,
    t_out,
    rtol,
    atol,
    h_init,
    max_steps,
    Y_out,
    M_out,
    U_out,
    ev_t,
    ev_disk,
    ev_from,
    ev_to,
    ev_y,
    stats,
):
    """Integrate one rig from ``seg_t[0]`` to ``seg_t[-1]``; ``y`` is updated in place.

    ``modes`` (int64[2]) receives the final modes. ``t_out`` must be sorted within
    ``[seg_t[0], seg_t[-1]]``; row k of Y_out/M_out/U_out is the state, modes and
    applied voltage at t_out[k]. Allocates its scratch space; callers that integrate
    many short intervals pass their own to :func:`run_ws`, which takes the same
    arguments grouped.
    """
    work = np.empty((WORK_ROWS, L.NY))
    return run_ws(
        p,
        y,
        modes,
        (seg_t, seg_u, use_func, u_limit),
        u_func,
        (rtol, atol, h_init, max_steps),
        (t_out, Y_out, M_out, U_out),
        (ev_t, ev_disk, ev_from, ev_to, ev_y),
        stats,
        work,
    )


@nb.njit(**_JIT)
def run_ws(p, y, modes, inputs, u_func, control, samples, log, stats, work):
    """:func:`run` with its arguments grouped and a caller-owned scratch array.

    * ``inputs`` = (seg_t, seg_u, use_func, u_limit): the input segments and their held
      voltages, whether ``u_func`` (a C function float64(float64), or None; passed on its
      own so that numba prunes it when it is None) gives the voltage instead, and the
      voltage limit;
    * ``control`` = (rtol, atol, h_init, max_steps);
    * ``samples`` = (t_out, Y_out, M_out, U_out): the output grid and its rows;
    * ``log`` = (ev_t, ev_disk, ev_from, ev_to, ev_y): the event log;
    * ``work``: scratch of shape (WORK_ROWS, NY).
    """
    seg_t, seg_u, use_func, u_limit = inputs
    rtol, atol, h_init, max_steps = control
    t_out = samples[0]
    K = work[:N_EXT]
    F = work[N_EXT : N_EXT + INTERP]
    f0 = work[N_EXT + INTERP]
    y_new = work[N_EXT + INTERP + 1]
    ytmp = work[N_EXT + INTERP + 2]
    y_ev = work[N_EXT + INTERP + 3]
    ytmp2 = work[N_EXT + INTERP + 4]
    scratch = (K, F, ytmp, ytmp2)
    for j in range(N_STATS):
        stats[j] = 0.0
    n_act = n_active(p)
    n_out = t_out.shape[0]
    k = 0
    h_prop = h_init if h_init > 0.0 else 1e-3  # proposed size before truncation to a segment end
    mu = modes[0]
    ml = modes[1]
    first = True
    status = 0
    n_steps = 0
    t = seg_t[0]
    last_event_t = -math.inf
    events_here = 0
    rejected = False
    n_rejected = 0
    bad_t = math.nan  # where the input was not finite (status 4)
    # Inputs or torques that change with time while a disk sticks (see STUCK_H_MAX); with
    # neither, two stuck disks (and no lag states) are an equilibrium until the next segment.
    time_varying = use_func or p[L.DIST_A] != 0.0 or p[L.DRIFT] != 0.0
    frozen_when_stuck = not time_varying and n_act == 4
    stoppable = stats.shape[0] > ST_STOP

    for seg in range(seg_t.shape[0] - 1):
        tb = seg_t[seg + 1]
        us = seg_u[seg]
        t = seg_t[seg]
        u = input_at(t, us, u_func, use_func, u_limit)
        u_hold = u  # the held voltage of this segment (a zero-order hold)
        if not math.isfinite(u):
            status = 4
            bad_t = t
            break
        mu, ml = _segment_modes(p, t, y, u, mu, ml, first, log, stats)
        first = False
        k = _held_samples(k, t, y, mu, ml, u, samples)
        rhs(t, y, u, p, mu, ml, f0)
        stats[ST_RHS] += 1

        while t < tb:
            if n_steps + n_rejected >= max_steps:  # rejected attempts count too
                status = 1
                break
            if stoppable and stats[ST_STOP] != 0.0:
                status = 5
                break
            h = h_prop
            if time_varying and (mu == 0 or ml == 0) and h > STUCK_H_MAX:
                h = STUCK_H_MAX
            last = False
            # Snap to the segment end when the rest would be a sliver of this step (the
            # window scales with the step, never with |t|, so that late start times work).
            if t + h >= tb or (tb - t - h) < min(1e-12 * max(1.0, abs(tb)), 1e-3 * h):
                h = tb - t
                last = True
            err = step(t, y, f0, h, us, u_func, use_func, u_limit, p, mu, ml, K, y_new, ytmp, rtol, atol)
            stats[ST_RHS] += 12
            if not (err <= 1.0):  # also catches NaN
                stats[ST_REJECTED] += 1
                n_rejected += 1
                rejected = True
                if not math.isfinite(err) and use_func:
                    tb_bad = _bad_input_time(t, h, us, u_func, use_func, u_limit)
                    if math.isfinite(tb_bad):
                        status = 4
                        bad_t = tb_bad
                        break
                h_prop = h * shrink_factor(err)
                if not (h_prop >= H_MIN):  # also catches NaN
                    status = 2
                    break
                continue
            t_new = tb if last else t + h
            if not (t_new > t):  # the step is below the resolution of t
                status = 2
                break
            n_steps += 1
            th_u, th_l, dense = _events_in_step(
                t,
                h,
                t_new,
                y,
                y_new,
                f0,
                p,
                mu,
                ml,
                frozen_when_stuck,
                us,
                u_func,
                use_func,
                u_limit,
                scratch,
                stats,
            )
            th = min(th_u, th_l)
            if not dense and k < n_out and t_out[k] <= t_new:
                prepare_dense(t, y, y_new, h, us, u_func, use_func, u_limit, p, mu, ml, K, F, ytmp, ytmp2)
                stats[ST_RHS] += 3
            if th <= 1.0:
                # A switching event inside the step: the samples before it, then the
                # switch, then a restart from the event.
                t_ev = t + th * h
                k, bad_t = _step_samples(
                    k, t_ev, False, t, h, y, F, n_act, mu, ml, u_hold, us, u_func, use_func, u_limit, samples
                )
                if math.isfinite(bad_t):
                    status = 4
                    break
                dense_eval(th, y, F, L.NY, y_ev)
                u_ev = input_at(t_ev, us, u_func, use_func, u_limit)
                if not math.isfinite(u_ev):
                    status = 4
                    bad_t = t_ev
                    break
                do_u = th_u <= 1.0 and (th_u - th) * abs(h) <= SIMULTANEOUS_TOL
                do_l = th_l <= 1.0 and (th_l - th) * abs(h) <= SIMULTANEOUS_TOL
                mu, ml = _switch(p, t_ev, y_ev, u_ev, mu, ml, do_u, do_l, log, stats)
                events_here = events_at_instant(t_ev, last_event_t, events_here)
                if events_here > MAX_EVENTS_AT_ONE_INSTANT:
                    status = 3
                    for j in range(L.NY):
                        y[j] = y_ev[j]
                    t = t_ev
                    break
                last_event_t = t_ev
                for j in range(L.NY):
                    y[j] = y_ev[j]
                t = t_ev
                if th >= 1.0:
                    t = t_new
                rhs(t, y, u_ev, p, mu, ml, f0)
                h_prop = _initial_step(
                    t, y, f0, us, u_func, use_func, u_limit, p, mu, ml, rtol, atol, H_MAX, ytmp, ytmp2
                )
                stats[ST_RHS] += 2
                rejected = False
                continue  # the restart chose its own step size
            # A sample on the end of an input segment belongs to the next segment: the
            # zero-order hold switches at that instant (except at the very end).
            held = last and seg < seg_t.shape[0] - 2
            k, bad_t = _step_samples(
                k, t_new, not held, t, h, y, F, n_act, mu, ml, u_hold, us, u_func, use_func, u_limit, samples
            )
            if math.isfinite(bad_t):
                status = 4
                break
            for j in range(L.NY):
                y[j] = y_new[j]
                f0[j] = K[N_STAGES, j]
            t = t_new
            # Step-size control after an accepted step: no growth right after a rejection
            # (Hairer's DOP853); a step shortened to end a segment does not shrink the proposal.
            fac = growth_factor(err)
            if rejected:
                fac = min(fac, 1.0)
                rejected = False
            h_prop = min(max(h * fac, h_prop if last else 0.0), H_MAX)
        if status != 0:
            break

    _final_samples(k, y, mu, ml, status, samples)
    modes[0] = mu
    modes[1] = ml
    stats[ST_STEPS] = n_steps
    stats[ST_STATUS] = status
    stats[ST_H] = h_prop
    stats[ST_T] = t
    stats[ST_BAD_T] = bad_t
    return status
