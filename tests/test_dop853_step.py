"""One DOP853 step of the package's numerical core against SciPy's ``DOP853`` solver.

From the same state and with the same step size, SciPy's solver (its own stage loop,
error norm and dense output, ``scipy.integrate.DOP853``) and each stage loop of the
package -- the simulator's (:func:`drill_env.integrator.step`), the sensitivity flow's
(:mod:`drill_env.analysis.variational`) and a plain one on a known ODE built from the
shared pieces of :mod:`drill_env.integrator` -- must give the same new state, the same
error estimate and the same dense output, to round-off. The step sizes are chosen so
that the error estimate is of order one (the step is accepted, but the estimate is not
negligible), and the known ODE's exact solution checks that the step is a step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
import pytest
from scipy.integrate import DOP853

import drill_env
from drill_env import _layout as L
from drill_env import integrator as I
from drill_env.analysis import variational as V
from drill_env.dynamics import rhs

EPS = np.finfo(float).eps
THETAS = (0.0, 0.13, 0.5, 0.77, 1.0)


@dataclass
class ScipyStep:
    y_new: np.ndarray
    err: float  # error norm over the masked components
    K: np.ndarray  # all 16 stages
    dense: object  # SciPy's dense output of the step
    rtol: float
    atol: float


def scipy_step(fun, t0, y0, h, rtol, atol, mask=None) -> ScipyStep:
    """One step of SciPy's DOP853 from (t0, y0) with step h (accepted at once)."""
    solver = DOP853(fun, t0, y0, t_bound=t0 + 4.0 * h, rtol=rtol, atol=atol, first_step=h)
    solver.step()
    assert solver.status == "running" and solver.t == t0 + h, "SciPy rejected the step: choose a smaller h"
    y_new = solver.y.copy()
    mask = np.ones(y0.size, dtype=bool) if mask is None else mask
    scale = atol + np.maximum(np.abs(y0), np.abs(y_new)) * rtol
    err = solver._estimate_error_norm(solver.K[:, mask], h, scale[mask])
    dense = solver.dense_output()  # fills the three extra stages of K_extended
    return ScipyStep(y_new, err, solver.K_extended.copy(), dense, rtol, atol)


def assert_same_step(y0, h, y_new, err, F, ref, mask=None, check_value=None):
    """Round-off comparison of one step (y_new, err, dense coefficients F and the dense
    output at THETAS) with SciPy's ``ref``; each bound is a small multiple of the unit
    round-off times the sizes of the terms of the sum that forms the value."""
    y_ref, err_ref, K_ref, dense_ref = ref.y_new, ref.err, ref.K, ref.dense
    mask = np.ones(y0.size, dtype=bool) if mask is None else mask
    aK = np.abs(K_ref)
    # the new state: y0 + h * sum(B K)
    assert np.all(np.abs(y_new - y_ref) <= 16 * EPS * (np.abs(y0) + abs(h) * np.abs(I.B) @ aK[: I.N_STAGES]))
    # the error norm: the sums e = E K / scale cancel heavily; a round-off of at most d_j
    # in e_j changes sum(e_j^2) by at most 2 sum(|e_j| d_j), and the norm
    # (|h| S5 / sqrt((S5 + 0.01 S3) m)) relatively by at most twice the larger of those
    scale = (ref.atol + np.maximum(np.abs(y0), np.abs(y_ref)) * ref.rtol)[mask]
    K13 = K_ref[: I.N_STAGES + 1][:, mask]
    rel = 0.0
    for E in (I.E5, I.E3):
        e = (E @ K13) / scale
        d = 16 * EPS * (np.abs(E) @ np.abs(K13)) / scale
        rel = max(rel, 2 * float(np.sum(np.abs(e) * d) / np.sum(e * e)))
    assert 0.05 < err_ref < 1.0  # the estimate matters, and the step is accepted
    assert abs(err - err_ref) <= (2 * rel + 16 * EPS) * err_ref
    # the dense output: coefficients, then values
    # (the first three rows are differences with y_new, and carry its round-off)
    ay = np.abs(y0) + np.abs(y_ref)
    size = np.vstack(
        [
            ay,
            abs(h) * aK[0] + ay,
            abs(h) * (aK[0] + aK[I.N_STAGES]) + 2 * ay,
            abs(h) * np.abs(I.D) @ aK,
        ]
    )
    assert np.all(np.abs(F - dense_ref.F) <= 64 * EPS * size)
    for theta in THETAS:
        value = np.array([I.dense_component(theta, y0, F, j) for j in range(y0.size)])
        value_ref = dense_ref(dense_ref.t_old + theta * h)
        assert np.all(np.abs(value - value_ref) <= 64 * EPS * size.sum(axis=0))
        if check_value is not None:
            check_value(theta, value)


# -- a known ODE through the shared pieces --------------------------------------------------
#
#   y0' = -2 t y0^2        (y0 = 1 / (1 + t^2) from y0(0) = 1): nonlinear, time-dependent
#   y1' = y2, y2' = -y1    (a harmonic oscillator)


@nb.njit
def known_field(t, y, out):
    out[0] = -2.0 * t * y[0] * y[0]
    out[1] = y[2]
    out[2] = -y[1]


def known_exact(t):
    return np.array([1.0 / (1.0 + t * t), np.sin(t + 0.3), np.cos(t + 0.3)])


@nb.njit
def known_step(t, y, h, K, y_new, ytmp, F, rtol, atol):
    """A DOP853 step with dense output in the integrators' pattern: the stage loop calls
    the field, everything else is the shared core. Returns the error norm."""
    n = y.shape[0]
    known_field(t, y, ytmp)
    for j in range(n):
        K[0, j] = ytmp[j]
    for s in range(1, I.N_STAGES):
        I.stage_state(s, y, K, h, n, ytmp)
        known_field(t + I.C[s] * h, ytmp, K[s])
    I.solution(y, K, h, n, y_new)
    known_field(t + h, y_new, K[I.N_STAGES])
    err = I.error_norm(y, y_new, K, h, n, np.ones(n), rtol, atol)
    for k in range(I.N_EXTRA):
        I.extra_stage_state(k, y, K, h, n, ytmp)
        known_field(t + I.C_EXTRA[k] * h, ytmp, K[I.N_STAGES + 1 + k])
    I.dense_coefficients(y, y_new, K, h, n, F)
    return err


@pytest.mark.parametrize(("t0", "h", "tol"), [(0.5, 0.25, 1e-9), (0.0, 0.0625, 5e-13), (-1.0, 0.375, 1e-8)])
def test_a_step_on_a_known_ode_is_scipys(t0, h, tol):
    y0 = known_exact(t0)

    def fun(t, y):
        out = np.empty(3)
        known_field(t, y, out)
        return out

    ref = scipy_step(fun, t0, y0, h, tol, tol)
    K = np.empty((I.N_EXT, 3))
    F = np.empty((I.INTERP, 3))
    y_new = np.empty(3)
    err = known_step(t0, y0, h, K, y_new, np.empty(3), F, tol, tol)

    def near_exact(theta, value):
        # the step is a step of the ODE: within a few times its own error estimate
        assert np.all(np.abs(value - known_exact(t0 + theta * h)) <= 10 * tol * (1 + np.abs(value)))

    assert_same_step(y0, h, y_new, err, F, ref, check_value=near_exact)


@pytest.mark.parametrize(
    ("modes", "h", "tol"), [((1, 1), 0.0625, 1e-9), ((1, 0), 0.125, 1e-9), ((1, -1), 0.03125, 2e-10)]
)
def test_a_step_of_the_simulator_is_scipys(modes, h, tol):
    p = drill_env.load_params("brake").as_array()
    u = 2.0
    mu, ml = modes
    y0 = np.zeros(L.NY)
    y0[:4] = [0.9, 3.1, 0.7 if ml >= 0 else -0.7, 0.4]
    if ml == 0:
        y0[L.X3] = 0.0
    t0 = 0.25
    rtol = atol = tol

    def fun(t, y):
        dy = np.empty(L.NY)
        rhs(t, y, u, p, mu, ml, dy)
        return dy

    # the simulator integrates the four components of the paper's model and controls the
    # error of all but the lower angle
    n = 4
    mask = np.array([True, True, True, False])
    ref = scipy_step(lambda t, y: fun(t, np.r_[y, 0.0, 0.0])[:n], t0, y0[:n], h, rtol, atol, mask)
    K = np.empty((I.N_EXT, L.NY))
    F = np.empty((I.INTERP, L.NY))
    y_new = np.empty(L.NY)
    ytmp = np.empty(L.NY)
    err = I.step(t0, y0, fun(t0, y0), h, u, None, False, np.inf, p, mu, ml, K, y_new, ytmp, rtol, atol)
    I.prepare_dense(t0, y0, y_new, h, u, None, False, np.inf, p, mu, ml, K, F, ytmp, np.empty(L.NY))
    assert np.array_equal(y_new[n:], y0[n:]) and not F[:, n:].any()

    def also_dense_eval(theta, value):
        out = np.empty(L.NY)
        I.dense_eval(theta, y0, F, L.NY, out)
        assert np.array_equal(out[:n], value) and np.array_equal(out[n:], y0[n:])

    assert_same_step(y0[:n], h, y_new[:n], err, F[:, :n], ref, mask, check_value=also_dense_eval)


@pytest.mark.parametrize(
    ("preset", "u", "modes", "h", "tol"),
    [("brake", 2.0, (1, 1), 0.03125, 5e-11), ("no_brake", 0.3, (1, 0), 0.0625, 2e-11)],
)
def test_a_step_of_the_sensitivity_flow_is_scipys(preset, u, modes, h, tol):
    p = drill_env.load_params(preset).as_array()
    mu, ml = modes
    z0 = V.augmented_initial(np.array([0.9, 3.1, 0.7 if ml else 0.0]))
    z0[V.NX :] += np.linspace(-0.3, 0.4, V.NZ - V.NX)  # a sensitivity that is not the identity
    rtol = atol = tol

    def fun(t, z):
        dz = np.empty(V.NZ)
        V.aug_rhs(z, u, p, mu, ml, dz)
        return dz

    ref = scipy_step(fun, 0.0, z0, h, rtol, atol)
    K = np.empty((I.N_EXT, V.NZ))
    F = np.empty((I.INTERP, V.NZ))
    z_new = np.empty(V.NZ)
    ztmp = np.empty(V.NZ)
    err = V._step(z0, fun(0.0, z0), h, u, p, mu, ml, K, z_new, ztmp, rtol, atol)
    V._prepare_dense(z0, z_new, h, u, p, mu, ml, K, F, ztmp)
    assert_same_step(z0, h, z_new, err, F, ref)
