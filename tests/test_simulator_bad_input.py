"""Bad arguments of simulate / simulate_batch: a ValueError naming the argument, before any
work or allocation; nothing silently reinterpreted."""

from __future__ import annotations

import numpy as np
import pytest

import drill_env
from drill_env.simulator import MAX_RESULT_BYTES, OutputSizeError


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(u=None), r"u: expected a voltage .* got None"),
        (dict(u="2.0"), r"u: expected a voltage .* got '2.0'"),
        (dict(u=b"2"), r"u: expected a voltage"),
        (dict(u=True), r"u: expected a voltage"),
        (dict(u=["1.0", "2.0"], control_dt=0.5), r"u: expected numbers"),
        (dict(u=[True, False], control_dt=0.5), r"u: expected numbers"),
        (dict(u=[]), r"u: expected .* shape \(0,\)"),
        (dict(u=2.0, control_dt=-5), r"control_dt: must be finite and > 0, got -5"),
        (dict(u=2.0, control_dt=float("nan")), r"control_dt"),
        (dict(u=2.0, control_dt="0.1"), r"control_dt"),
    ],
)
def test_simulate_refuses_bad_inputs(kwargs, match):
    with pytest.raises(ValueError, match=match):
        drill_env.simulate("brake", t_final=1.0, **kwargs)


def test_a_constant_voltage_with_a_valid_control_dt_is_unchanged(brake):
    a = drill_env.simulate(brake, 2.0, 5.0)
    b = drill_env.simulate(brake, 2.0, 5.0, control_dt=0.05)
    np.testing.assert_array_equal(a.x3, b.x3)


def test_an_oversized_result_is_refused_before_allocation():
    n = int(1e7 / 0.01) + 1  # 1e7 s at the default 10 ms
    with pytest.raises(OutputSizeError, match=r"dt: .* GiB; the limit is 2 GiB: raise dt"):
        drill_env.simulate("brake", 2.0, 1e7)
    assert n * 58 > MAX_RESULT_BYTES
    with pytest.raises(OutputSizeError, match=r"x 1000 rigs"):
        drill_env.simulate_batch("brake", np.linspace(0.5, 4.5, 1000), 1e4)
    # the README's 1000-rig example stays inside the limit (720 MB)
    assert 1000 * 10001 * (8 * 6 + 16 + 8) < MAX_RESULT_BYTES


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        (("brake", []), {}, r"u: expected .* shape \(0,\)"),
        (("brake", np.zeros((2, 0))), dict(control_dt=0.1), r"u: expected .* shape \(2, 0\)"),
        (("brake", np.zeros((2, 2, 2))), {}, r"u: expected"),
        (([], [1.0]), {}, r"params: an empty sequence"),
        ((5, [1.0]), {}, r"params: expected"),
        (("brake", [1.0]), dict(n=0), r"n: expected an integer >= 1"),
        (("brake", 1.0), dict(n=-3), r"n: expected an integer >= 1"),
        (("brake", 1.0), dict(n=2.5), r"n: expected an integer >= 1"),
        (("brake", 1.0), dict(control_dt=-1.0), r"control_dt"),
        (("brake", "1.0"), {}, r"u: expected a voltage"),
        (("brake", None), {}, r"u: expected a voltage"),
    ],
)
def test_simulate_batch_refuses_bad_inputs(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        drill_env.simulate_batch(*args, t_final=1.0, **kwargs)


def test_simulate_batch_with_n_agrees_with_single_runs(brake):
    batch = drill_env.simulate_batch(brake, 1.5, 5.0, n=2)
    single = drill_env.simulate(brake, 1.5, 5.0)
    assert batch.x3.shape[0] == 2
    for i in range(2):
        np.testing.assert_allclose(batch.x3[i], single.x3, atol=1e-9)
