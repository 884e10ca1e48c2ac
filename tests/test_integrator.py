"""The compiled DOP853 step against SciPy's implementation of the same method."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate._ivp import dop853_coefficients as scipy_dop
from scipy.integrate._ivp.rk import rk_step

import drill_env
from drill_env import _dop853
from drill_env import _layout as L
from drill_env.dynamics import rhs
from drill_env.integrator import N_STAGES, step


@pytest.mark.parametrize("name", ["A", "B", "C", "E3", "E5", "D"])
def test_the_coefficient_table_is_scipys_to_the_bit(name):
    assert np.array_equal(getattr(_dop853, name), getattr(scipy_dop, name))


def test_the_table_sizes_are_scipys():
    assert _dop853.N_STAGES == scipy_dop.N_STAGES
    assert _dop853.N_STAGES_EXTENDED == scipy_dop.N_STAGES_EXTENDED
    assert _dop853.INTERPOLATOR_POWER == scipy_dop.INTERPOLATOR_POWER


def test_importing_the_package_does_not_load_scipy_integrate():
    import subprocess
    import sys

    code = "import sys, drill_env; print('scipy.integrate' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize(("modes", "h"), [((1, 1), 0.05), ((1, 0), 0.2), ((-1, 1), 0.01), ((1, -1), 0.1)])
def test_one_step_equals_scipys_rk_step_to_round_off(modes, h):
    p = drill_env.load_params("brake").as_array()
    u = 2.0
    y0 = np.zeros(L.NY)
    y0[:4] = [0.9, 3.1, 0.7, 0.4]
    mu, ml = modes
    if ml == -1:
        y0[L.X3] = -0.7

    def f(t, y):
        dy = np.empty(L.NY)
        rhs(t, y, u, p, mu, ml, dy)
        return dy

    f0 = f(0.0, y0)
    K = np.empty((16, L.NY))
    y_new = np.empty(L.NY)
    ytmp = np.empty(L.NY)
    step(0.0, y0, f0, h, u, None, False, np.inf, p, mu, ml, K, y_new, ytmp, 1e-9, 1e-9)
    K_ref = np.empty((N_STAGES + 1, L.NY))
    y_ref, f_ref = rk_step(
        f, 0.0, y0, f0, h, scipy_dop.A[:N_STAGES, :N_STAGES], scipy_dop.B, scipy_dop.C[:N_STAGES], K_ref
    )
    scale = np.abs(y0) + np.abs(y_ref) + 1.0
    assert np.all(np.abs(y_new - y_ref) <= 1e-14 * scale)
    assert np.allclose(K[: N_STAGES + 1], K_ref, rtol=1e-13, atol=1e-13)
