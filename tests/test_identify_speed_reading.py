"""The speed's reading error bends the hump columns: tanh of a noisy speed is biased by its
curvature (a bias common to every window at that speed, which no average removes). The fit
widens its intervals by the shift this bias gives."""

from __future__ import annotations

import numpy as np

from drill_env.identify.joint import RunRows


def _rows(speed: np.ndarray, var: np.ndarray | None) -> RunRows:
    n, support = speed.shape
    return RunRows(
        name="r",
        constant=False,
        x_lin=np.zeros((n, 1)),
        sigma=np.ones(n),
        lower=np.arange(n),
        sign_l=np.ones(n),
        speed_l=speed,
        kernel=np.full(support, 1.0 / support),
        negative_upper=0,
        speed_var_l=var,
    )


def test_the_hump_correction_is_the_bias_of_tanh_at_a_noisy_speed():
    rng = np.random.default_rng(0)
    w = np.linspace(0.1, 2.0, 20)
    sd = 0.1 * w
    draws = 40000
    measured = w + sd * rng.standard_normal((draws, w.size))
    beta = 3.0
    truth = _rows(np.tile(w, (1, 1)), None).hump(beta)[0]
    seen = _rows(measured, np.tile(sd**2, (draws, 1))).hump(beta).mean()
    bias = seen - truth  # what the noisy speed does to the column, on average
    pred = _rows(w[None, :], (sd**2)[None, :]).hump_correction(beta)[0]
    mc_error = 0.5 * beta * float(sd.mean()) / np.sqrt(draws * w.size)  # a generous bound
    assert abs(bias) > 10 * mc_error  # the bias is real
    assert abs(pred - bias) < 0.1 * abs(bias) + 3 * mc_error, (pred, bias)
    # no reading error given: no correction
    assert not _rows(w[None, :], None).hump_correction(beta).any()
