"""Dormand–Prince 8(5,3) steps with 7th-order dense output, and event location on it, compiled.

The method and its coefficients are those of Hairer, Norsett & Wanner, *Solving
Ordinary Differential Equations I* (DOP853), tabulated in :mod:`drill_env._dop853` in
SciPy's arrangement so that the two implementations can be compared one to one.
Within one friction mode the rig's vector field is analytic, so a high-order method
takes long steps; the dense output serves both the sampling of the solution and the
location of switching events.

This module is the one numerical core of the two integrators of the package, the
simulator's kernel (:mod:`drill_env.kernel`, the rig's vector field) and the flow with
sensitivities of the analysis (:mod:`drill_env.analysis.variational`, the augmented
field). Everything that does not evaluate a vector field lives here, once: the stage
states, the 8th-order solution, the error norm, the step-size factors, the dense-output
coefficients and their evaluation, and event location on the dense output -- the
Illinois bracket with its one time tolerance, the rule for chattering, and the rules
for the two grazing cases of a slipping disk (a dip of its speed to zero inside a step,
a step that starts with the disk at rest). Each integrator keeps only its loop over the
stages, which calls its own field. One stage loop taking the field as a function
argument would defeat numba's on-disk cache: a compiled function that passes a field to
it is refused by the cache ("uses dynamic globals"), and one called from Python with a
function argument is compiled afresh in every process.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from drill_env import _dop853 as _dop
from drill_env import _layout as L
from drill_env._numba import INLINE, JIT
from drill_env.dynamics import n_active, rhs

# The compiled functions here never allocate, so they run without numba's reference
# counting (_nrt=False): with it, every call that passes arrays pays atomic increments
# and decrements, which cost as much as the arithmetic of a step.
_JIT = JIT
_INLINE = INLINE

N_STAGES = _dop.N_STAGES  # 12
A = np.ascontiguousarray(_dop.A[:N_STAGES, :N_STAGES])
B = np.ascontiguousarray(_dop.B)
C = np.ascontiguousarray(_dop.C[:N_STAGES])
E3 = np.ascontiguousarray(_dop.E3)
E5 = np.ascontiguousarray(_dop.E5)
D = np.ascontiguousarray(_dop.D)
A_EXTRA = np.ascontiguousarray(_dop.A[N_STAGES + 1 :])
C_EXTRA = np.ascontiguousarray(_dop.C[N_STAGES + 1 :])
N_EXTRA = A_EXTRA.shape[0]  # 3 extra stages for the interpolant
N_EXT = _dop.N_STAGES_EXTENDED  # 16
INTERP = _dop.INTERPOLATOR_POWER  # 7
assert INTERP == 7, "dense_component is unrolled for SciPy's 7-coefficient DOP853 interpolant"
ORDER_EXP = 1.0 / 8.0

# Components of the state under error control: the twist, both speeds, the two lag
# states of the optional effects and the thermal state. The lower angle is the integral
# of the lower speed and follows its accuracy; it is excluded so that its growing size
# does not loosen the relative tolerance of the others.
ERR_MASK = np.array([1.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0])

# Event location. The bracket of an event is closed to this width in time: the state at
# the located instant is then off by at most |f| * EVENT_TIME_TOL, below 4e-11 for the
# rig at +-5 V (|f| < 40 rad/s^2), under what the steps themselves are allowed at the
# tolerances either integrator runs at. A narrower bracket would not even be
# representable late in a run (doubles near t = 1e4 s are 1.8e-12 s apart).
EVENT_TIME_TOL = 1e-12  # [s]
MAX_EVENTS_AT_ONE_INSTANT = 12  # more switches in a row at one instant are chattering
H_MIN = 1e-12  # [s] smallest step size
MAX_BRACKET_ITERATIONS = 200
GOLDEN = 0.6180339887498949  # (sqrt(5) - 1) / 2
DIP_WIDTH = 1e-13  # fraction of a step to which the bottom of a speed dip is bracketed
SURFACE_WALK_START = 2.0**-50  # first fraction sampled after a start on a switching surface
EPS = 2.0**-52  # spacing of doubles at 1
INSIDE = 5e-324  # the least positive double: a violation of -INSIDE is inside a band, barely


# -- the step: stage states, solution, error norm --------------------------------------


@nb.njit(**_INLINE)
def stage_state(s, y, K, h, n, out):
    """State at which stage ``s`` (1..N_STAGES-1) evaluates the field: the first ``n``
    components of y + h * sum_r A[s, r] K[r]."""
    for j in range(n):
        acc = 0.0
        for r in range(s):
            acc += A[s, r] * K[r, j]
        out[j] = y[j] + h * acc


@nb.njit(**_INLINE)
def extra_stage_state(k, y, K, h, n, out):
    """State of extra stage ``k`` (0..N_EXTRA-1, stage N_STAGES + 1 + k) of the interpolant."""
    s = N_STAGES + 1 + k
    for j in range(n):
        acc = 0.0
        for r in range(s):
            acc += A_EXTRA[k, r] * K[r, j]
        out[j] = y[j] + h * acc


@nb.njit(**_INLINE)
def solution(y, K, h, n, out):
    """The 8th-order solution at the end of the step (first ``n`` components)."""
    for j in range(n):
        acc = 0.0
        for r in range(N_STAGES):
            acc += B[r] * K[r, j]
        out[j] = y[j] + h * acc


@nb.njit(**_INLINE)
def error_norm(y, y_new, K, h, n, mask, rtol, atol):
    """Scaled error of the step (accept when <= 1): DOP853's combination of the 5th- and
    3rd-order estimates, RMS over the first ``n`` components where ``mask`` is nonzero.
    K[N_STAGES] must hold f(t + h, y_new)."""
    err5 = 0.0
    err3 = 0.0
    m = 0.0
    for j in range(n):
        if mask[j] == 0.0:
            continue
        m += 1.0
        sc = atol + rtol * max(abs(y[j]), abs(y_new[j]))
        e5 = 0.0
        e3 = 0.0
        for r in range(N_STAGES + 1):
            e5 += E5[r] * K[r, j]
            e3 += E3[r] * K[r, j]
        e5 /= sc
        e3 /= sc
        err5 += e5 * e5
        err3 += e3 * e3
    if err5 == 0.0 and err3 == 0.0:
        return 0.0
    return abs(h) * err5 / np.sqrt((err5 + 0.01 * err3) * m)


@nb.njit(**_INLINE)
def growth_factor(err):
    """Factor on the size of an accepted step for the next one."""
    if err == 0.0:
        return 10.0
    return min(10.0, max(0.2, 0.9 * err ** (-ORDER_EXP)))


@nb.njit(**_INLINE)
def shrink_factor(err):
    """Factor on the size of a rejected step for the retry (err > 1 or not finite)."""
    if math.isfinite(err):
        return max(0.2, 0.9 * err ** (-ORDER_EXP))
    return 0.2


# -- dense output --------------------------------------------------------------------------


@nb.njit(**_INLINE)
def dense_coefficients(y, y_new, K, h, n, F):
    """Interpolation coefficients F (INTERP rows) of the first ``n`` components; K holds
    all N_EXT stages (the extra ones included)."""
    for j in range(n):
        dyj = y_new[j] - y[j]
        F[0, j] = dyj
        F[1, j] = h * K[0, j] - dyj
        F[2, j] = 2.0 * dyj - h * (K[N_STAGES, j] + K[0, j])
        for i in range(D.shape[0]):
            acc = 0.0
            for r in range(N_EXT):
                acc += D[i, r] * K[r, j]
            F[3 + i, j] = h * acc


@nb.njit(**_INLINE)
def dense_component(theta, y, F, j):
    """Component j of the state at fraction ``theta`` of the step (0 = start, 1 = end).

    Horner's scheme in the alternating factors theta and (1 - theta) of Hairer's
    CONTD8; components that do not evolve have zero coefficients and stay exact.
    """
    x1 = 1.0 - theta
    acc = F[6, j] * theta + F[5, j]
    acc = acc * x1 + F[4, j]
    acc = acc * theta + F[3, j]
    acc = acc * x1 + F[2, j]
    acc = acc * theta + F[1, j]
    acc = acc * x1 + F[0, j]
    return y[j] + acc * theta


@nb.njit(**_INLINE)
def dense_roundoff(theta, F, j):
    """Bound on the rounding error of the change of component j from the start of the
    step to fraction ``theta`` as :func:`dense_component` evaluates it, for small theta:
    a few units in the last place of the coefficients, times theta."""
    s = 0.0
    for i in range(INTERP):
        s += abs(F[i, j])
    return 8.0 * EPS * theta * s


@nb.njit(**_JIT)
def dense_eval(theta, y, F, n, out):
    """First ``n`` components of the state at fraction ``theta`` of the step."""
    for j in range(n):
        out[j] = dense_component(theta, y, F, j)


# -- event location on the dense output ------------------------------------------------
#
# An event is where an indicator g (<= 0 while a mode holds) first reaches 0 inside a
# step. The bracket [a, b] of fractions of the step has g(a) < 0 <= g(b) and is closed by
# the Illinois method to EVENT_TIME_TOL; the located fraction is b, on the switching side.
# Callers whose indicator needs the model (a stuck disk's torques, a section, an
# extremum) loop over illinois_point / illinois_update themselves; a slipping disk's
# indicator is its speed, a dense component, and is handled here whole.


@nb.njit(**_INLINE)
def events_at_instant(t_ev, last_event_t, count):
    """Number of switches in a row at one instant (within 10 EVENT_TIME_TOL of each
    other), after a switch at t_ev; the previous one was at last_event_t, ``count`` before
    it. Above MAX_EVENTS_AT_ONE_INSTANT the integration stops (chattering)."""
    if t_ev - last_event_t <= 10.0 * EVENT_TIME_TOL:
        return count + 1
    return 0


@nb.njit(**_INLINE)
def bracket_closed(a, b, h):
    """Whether the bracket [a, b] (fractions of a step of size h) is narrow enough."""
    return (b - a) * abs(h) <= EVENT_TIME_TOL


@nb.njit(**_INLINE)
def illinois_point(a, b, ga, gb, h):
    """Next fraction to evaluate: the secant point, or the midpoint when the secant point
    falls outside the bracket or within a quarter tolerance of an end (where it would
    barely shrink the bracket)."""
    c = (a * gb - b * ga) / (gb - ga)
    if (
        not (a < c < b)
        or (c - a) * abs(h) < 0.25 * EVENT_TIME_TOL
        or (b - c) * abs(h) < 0.25 * EVENT_TIME_TOL
    ):
        c = 0.5 * (a + b)
    return c


@nb.njit(**_INLINE)
def illinois_update(a, b, ga, gb, side, c, gc):
    """The bracket after g(c) = gc: (a, b, ga, gb, side). The end kept twice in a row has
    its value halved (the Illinois modification of regula falsi)."""
    if gc >= 0.0:
        if side == -1:
            ga *= 0.5
        return a, c, ga, gc, -1
    if side == 1:
        gb *= 0.5
    return c, b, gc, gb, 1


@nb.njit(**_JIT)
def speed_dip(j, mode, y, F):
    """Fraction of the step at which the speed ``mode * y[j]`` of a slipping disk is least,
    if it reaches zero there, else 2.0.

    For a step at whose start the speed falls and at whose end it rises (so that it has
    one minimum inside): a grazing dip to zero that the ends alone would not show.
    Golden-section search on the dense output, stopped at the first point at or below zero.
    """
    a = 0.0
    b = 1.0
    c = b - GOLDEN * (b - a)
    d = a + GOLDEN * (b - a)
    fc = mode * dense_component(c, y, F, j)
    fd = mode * dense_component(d, y, F, j)
    for _ in range(80):
        if fc <= 0.0:
            return c
        if fd <= 0.0:
            return d
        if b - a < DIP_WIDTH:
            break
        if fc < fd:
            b = d
            d = c
            fd = fc
            c = b - GOLDEN * (b - a)
            fc = mode * dense_component(c, y, F, j)
        else:
            a = c
            c = d
            fc = fd
            d = a + GOLDEN * (b - a)
            fd = mode * dense_component(d, y, F, j)
    return 2.0


@nb.njit(**_JIT)
def speed_zero(j, mode, y, F, h, b0):
    """Fraction of the step at which a slipping disk's speed ``y[j]`` (slip direction
    ``mode``) first comes to zero or turns against ``mode``; the indicator -mode * speed
    is >= 0 at fraction ``b0`` (the end of the step, or the bottom of a dip inside it).

    A step that starts with the disk at rest (just set in motion, or just reversed) is
    on the switching surface at its start. The speed first moves into the slip direction
    and the event is where it comes back to zero, not the start: the fractions
    SURFACE_WALK_START, 2 SURFACE_WALK_START, 4 ... are walked through to bracket the end
    of that first excursion, so that it is found however short it is. The excursion starts
    with the first sample beyond the round-off of the dense output (:func:`dense_roundoff`):
    where the speed leaves zero at second order (a breakaway with zero acceleration), the
    samples closest to the start are round-off of either sign, and an excursion read from
    them would end at once and put the disk back where it broke away. A disk whose speed
    shows no such excursion switches at the first sample at which its speed is against
    ``mode`` beyond round-off (any excursion before it is below what the dense output
    resolves), or at once (0.0) if there is none.
    """
    a = 0.0
    b = b0
    ga = -mode * y[j]
    gb = -mode * dense_component(b, y, F, j)
    if ga > 0.0:
        return 0.0
    if ga == 0.0:
        found = False
        against = 0.0  # first fraction at which the speed is against the mode beyond round-off
        c = SURFACE_WALK_START
        while c < b0:
            gc = -mode * dense_component(c, y, F, j)
            if gc < 0.0 and (found or gc < -dense_roundoff(c, F, j)):
                a = c
                ga = gc
                found = True
            elif found:
                b = c
                gb = gc
                break
            elif against == 0.0 and gc > dense_roundoff(c, F, j):
                against = c
            c *= 2.0
        if not found:
            return against
    side = 0
    for _ in range(MAX_BRACKET_ITERATIONS):
        if bracket_closed(a, b, h):
            break
        c = illinois_point(a, b, ga, gb, h)
        gc = -mode * dense_component(c, y, F, j)
        a, b, ga, gb, side = illinois_update(a, b, ga, gb, side, c, gc)
    return b


# -- the rig's vector field: the simulator's stage loops ---------------------------------


@nb.njit(**_INLINE)
def input_at(t, u_seg, u_func, use_func, u_limit):
    """Voltage applied at time t: the segment's value or ``u_func(t)``, clipped to the limit.

    ``u_func`` is a C function float64(float64) or None (zero-order hold only); numba
    prunes the call at compile time when it is None.
    """
    if u_func is None:
        u = u_seg
    else:
        u = u_func(t) if use_func else u_seg
    if u > u_limit:
        return u_limit
    if u < -u_limit:
        return -u_limit
    return u


@nb.njit(**_JIT)
def step(t, y, f0, h, us, u_func, use_func, u_limit, p, mu, ml, K, y_new, ytmp, rtol, atol):
    """One DOP853 step of the rig from (t, y) with derivative f0; fills K and y_new.

    The voltage at each stage time comes from :func:`input_at`. Returns the scaled
    error norm (accept when <= 1). K[12] holds f(t + h, y_new).
    """
    n = n_active(p)
    for j in range(n, L.NY):
        ytmp[j] = y[j]
    for j in range(L.NY):
        K[0, j] = f0[j]
    for s in range(1, N_STAGES):
        stage_state(s, y, K, h, n, ytmp)
        ts = t + C[s] * h
        # y_new serves as the derivative's scratch until the stages are done: writing
        # straight into a row view K[s] would cost two atomic reference-count updates.
        rhs(ts, ytmp, input_at(ts, us, u_func, use_func, u_limit), p, mu, ml, y_new)
        for j in range(L.NY):
            K[s, j] = y_new[j]
    solution(y, K, h, n, y_new)
    for j in range(n, L.NY):
        y_new[j] = y[j]
    rhs(t + h, y_new, input_at(t + h, us, u_func, use_func, u_limit), p, mu, ml, ytmp)
    for j in range(L.NY):
        K[N_STAGES, j] = ytmp[j]
    return error_norm(y, y_new, K, h, n, ERR_MASK, rtol, atol)


@nb.njit(**_JIT)
def prepare_dense(t, y, y_new, h, us, u_func, use_func, u_limit, p, mu, ml, K, F, ytmp, kd):
    """Three extra stages and the interpolation coefficients F (INTERP x NY); ``kd`` is
    scratch for a stage derivative."""
    n = n_active(p)
    for j in range(n, L.NY):
        for i in range(INTERP):
            F[i, j] = 0.0
    for k in range(N_EXTRA):
        extra_stage_state(k, y, K, h, n, ytmp)
        ts = t + C_EXTRA[k] * h
        rhs(ts, ytmp, input_at(ts, us, u_func, use_func, u_limit), p, mu, ml, kd)
        for j in range(L.NY):
            K[N_STAGES + 1 + k, j] = kd[j]
    dense_coefficients(y, y_new, K, h, n, F)
