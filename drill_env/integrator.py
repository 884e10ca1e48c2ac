"""Dormand–Prince 8(5,3) steps with 7th-order dense output, compiled.

The method and its coefficients are those of Hairer, Norsett & Wanner, *Solving
Ordinary Differential Equations I* (DOP853), tabulated in :mod:`drill_env._dop853` in
SciPy's arrangement so that the two implementations can be compared one to one. Within one friction mode the rig's
vector field is analytic, so a high-order method takes long steps; the dense output
serves both the sampling of the solution and the location of switching events.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from drill_env import _dop853 as _dop
from drill_env import _layout as L
from drill_env.dynamics import n_active, rhs

# The compiled functions here never allocate, so they run without numba's reference
# counting (_nrt=False): with it, every call that passes arrays pays atomic increments
# and decrements, which cost as much as the arithmetic of a step.
_JIT = dict(cache=True, nogil=True, fastmath=False, error_model="numpy", _nrt=False)
_INLINE = dict(_JIT, inline="always")

N_STAGES = _dop.N_STAGES  # 12
A = np.ascontiguousarray(_dop.A[:N_STAGES, :N_STAGES])
B = np.ascontiguousarray(_dop.B)
C = np.ascontiguousarray(_dop.C[:N_STAGES])
E3 = np.ascontiguousarray(_dop.E3)
E5 = np.ascontiguousarray(_dop.E5)
D = np.ascontiguousarray(_dop.D)
A_EXTRA = np.ascontiguousarray(_dop.A[N_STAGES + 1 :])
C_EXTRA = np.ascontiguousarray(_dop.C[N_STAGES + 1 :])
N_EXT = _dop.N_STAGES_EXTENDED  # 16
INTERP = _dop.INTERPOLATOR_POWER  # 7
assert INTERP == 7, "dense_eval is unrolled for SciPy's 7-coefficient DOP853 interpolant"
ORDER_EXP = 1.0 / 8.0

# Components of the state under error control: the twist, both speeds and the two
# internal states of the optional effects. The lower angle is the integral of the
# lower speed and follows its accuracy; it is excluded so that its growing size does
# not loosen the relative tolerance of the others.
ERR_MASK = np.array([1.0, 1.0, 1.0, 0.0, 1.0, 1.0])


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
    """One DOP853 step from (t, y) with derivative f0; fills K and y_new.

    The voltage at each stage time comes from :func:`input_at`. Returns the scaled
    error norm (accept when <= 1). K[12] holds f(t + h, y_new).
    """
    n = n_active(p)
    for j in range(n, L.NY):
        ytmp[j] = y[j]
    for j in range(L.NY):
        K[0, j] = f0[j]
    for s in range(1, N_STAGES):
        for j in range(n):
            acc = 0.0
            for r in range(s):
                acc += A[s, r] * K[r, j]
            ytmp[j] = y[j] + h * acc
        ts = t + C[s] * h
        # y_new serves as the derivative's scratch until the stages are done: writing
        # straight into a row view K[s] would cost two atomic reference-count updates.
        rhs(ts, ytmp, input_at(ts, us, u_func, use_func, u_limit), p, mu, ml, y_new)
        for j in range(L.NY):
            K[s, j] = y_new[j]
    for j in range(n):
        acc = 0.0
        for r in range(N_STAGES):
            acc += B[r] * K[r, j]
        y_new[j] = y[j] + h * acc
    for j in range(n, L.NY):
        y_new[j] = y[j]
    rhs(t + h, y_new, input_at(t + h, us, u_func, use_func, u_limit), p, mu, ml, ytmp)
    for j in range(L.NY):
        K[N_STAGES, j] = ytmp[j]

    err5 = 0.0
    err3 = 0.0
    m = 0.0
    for j in range(n):
        if ERR_MASK[j] == 0.0:
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


@nb.njit(**_JIT)
def prepare_dense(t, y, y_new, h, us, u_func, use_func, u_limit, p, mu, ml, K, F, ytmp, kd):
    """Three extra stages and the interpolation coefficients F (INTERP x NY); ``kd`` is
    scratch for a stage derivative."""
    n = n_active(p)
    for j in range(n, L.NY):
        for i in range(INTERP):
            F[i, j] = 0.0
    for k in range(A_EXTRA.shape[0]):
        s = N_STAGES + 1 + k
        for j in range(n):
            acc = 0.0
            for r in range(s):
                acc += A_EXTRA[k, r] * K[r, j]
            ytmp[j] = y[j] + h * acc
        ts = t + C_EXTRA[k] * h
        rhs(ts, ytmp, input_at(ts, us, u_func, use_func, u_limit), p, mu, ml, kd)
        for j in range(L.NY):
            K[s, j] = kd[j]
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


@nb.njit(**_JIT)
def dense_eval(theta, y, F, out):
    """State at fraction ``theta`` of the step (0 = start, 1 = end)."""
    for j in range(L.NY):
        out[j] = dense_component(theta, y, F, j)
