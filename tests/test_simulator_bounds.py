"""The simulator never substitutes an input, never loops forever and takes x0 as given.

Inputs u(t) that raise or return non-finite values stop the run with an error naming
the input, its time and the error; every loop of the kernel is bounded (rejected steps
count against ``max_steps``, NaN step sizes fail, late start times terminate); every
component of an initial state is validated and used as given, or rejected.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import drill_env
from drill_env.simulator import InputFunctionError

# -- input failures are failures ----------------------------------------------------------


def _raises_late(t):
    if t > 1.0:
        raise ValueError("boom")
    return 1.0


def _divides_by_zero(t):
    return 1.0 / (t * 0.0) if t > 0.7 else 0.5


_TABLE = np.array([1.0, 2.0, 3.0])


def _indexes_out_of_range(t):
    return _TABLE[int(t)]


def _nan_late(t):
    return math.nan if t > 1.2 else 2.0


@pytest.mark.parametrize(
    ("fn", "words", "t_min", "t_max"),
    [
        (_raises_late, "raised ValueError: boom", 1.0, 1.05),
        (_divides_by_zero, "raised ZeroDivisionError", 0.7, 0.75),
        (_indexes_out_of_range, "raised IndexError", 3.0, 3.05),
        (_nan_late, "returned nan", 1.2, 1.25),
    ],
)
def test_a_failing_input_function_stops_the_run_and_names_the_error(fn, words, t_min, t_max, capfd):
    with pytest.raises(InputFunctionError) as info:
        drill_env.simulate("brake", u=fn, t_final=5.0)
    msg = str(info.value)
    assert msg.startswith("u: ") and words in msg
    t_bad = float(msg.split("at t = ")[1].split(" s")[0])
    assert t_min <= t_bad <= t_max
    # no "Exception ignored" flood from the compiled callback
    assert "Exception ignored" not in capfd.readouterr().err


def test_an_input_that_fails_at_the_start_reports_its_own_error_first():
    def uses_an_unknown_name(t):
        return np_not_imported.sin(t)  # noqa: F821

    with pytest.raises(InputFunctionError, match="NameError"):
        drill_env.simulate("brake", u=uses_an_unknown_name, t_final=1.0)


def test_an_input_returning_a_non_number_is_rejected():
    with pytest.raises(InputFunctionError, match="expected a number"):
        drill_env.simulate("brake", u=lambda t: None, t_final=1.0)


def test_input_errors_are_value_errors_for_the_command_line():
    assert issubclass(InputFunctionError, ValueError)


# -- every loop is bounded -----------------------------------------------------------------


def test_late_start_times_terminate_and_agree_with_an_early_start():
    t = time.perf_counter()
    late = drill_env.simulate("brake", u=2.0, t0=3e11, t_final=3e11 + 10, max_steps=1000, dt=1.0)
    assert time.perf_counter() - t < 30
    assert late.status == 0
    early = drill_env.simulate("brake", u=2.0, t_final=10.0, dt=1.0)
    # t has a resolution of 6e-5 s at 3e11 s, so events move by that much; accelerations
    # reach ~20 rad/s^2 in stick-slip: speeds agree to ~1e-3 rad/s, not to the tolerance
    assert np.allclose(late.x3, early.x3, atol=5e-3)
    assert len(late.events.t) == len(early.events.t)


def test_rejected_steps_count_against_max_steps():
    # a huge voltage makes every step fail the error test near the start
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = drill_env.simulate("brake", u=1e300, t_final=1.0, max_steps=50)
    assert res.status != 0
    assert res.stats["steps"] + res.stats["rejected"] <= 50 + 1


@pytest.mark.parametrize("bad", [0, -3, 2.5, "5", True])
def test_max_steps_must_be_a_positive_integer(bad):
    with pytest.raises(ValueError, match="max_steps"):
        drill_env.simulate("brake", u=2.0, t_final=1.0, max_steps=bad)


_finite_or_not = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([0.0, -0.0, 1e-300, 1e300, -1e300, math.nan, math.inf]),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    x0=st.lists(_finite_or_not, min_size=6, max_size=6),
    t0=st.one_of(st.sampled_from([0.0, -1e6, 1e9, 3e11, 1e15]), st.floats(-1e12, 1e12)),
    span=st.sampled_from([1e-9, 1e-3, 0.5, 3.0]),
    u=st.sampled_from([0.0, 2.0, -5.0, 1e6]),
)
def test_any_initial_state_and_interval_terminates_or_is_rejected(x0, t0, span, u):
    """Fuzz over x0 (all six components), t0 and t_final: a clear ValueError, or a
    result within a bounded number of attempts and a bounded wall time."""
    t_final = t0 + span
    if not t_final > t0:  # span below the resolution of t0
        with pytest.raises(ValueError, match="t_final"):
            drill_env.simulate("brake", u=u, t0=t0, t_final=t_final, x0=x0, max_steps=2000)
        return
    start = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            res = drill_env.simulate("brake", u=u, t0=t0, t_final=t_final, x0=x0, max_steps=2000, dt=span)
    except ValueError as exc:
        assert str(exc).startswith(("x0", "t0", "t_final"))
        return
    assert time.perf_counter() - start < 20.0
    assert res.stats["steps"] + res.stats["rejected"] <= 2001
    assert all(math.isfinite(v) for v in x0[:4])  # a non-finite state was never accepted


# -- x0 as given ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "x0",
    [
        {"motor_torque": math.nan, "memory_speed": 0.0},
        {"memory_speed": math.inf},
        {"memory_speed": -0.1},
        [0.0, 0.0, 0.0, 0.0, math.nan, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, math.inf],
        {"x2": "fast"},
    ],
)
def test_every_component_of_x0_is_validated(x0):
    params = drill_env.load_params("brake", motor_lag=0.02, friction_lag=0.1)
    with pytest.raises(ValueError, match=r"^x0"):
        drill_env.simulate(params, u=2.0, t_final=1.0, x0=x0)


def test_extended_state_is_used_as_given_where_the_rig_has_it():
    params = drill_env.load_params("brake", motor_lag=0.02, friction_lag=0.1)
    res = drill_env.simulate(params, u=2.0, t_final=0.01, x0={"motor_torque": 7.0}, dt=0.01)
    assert res.motor_torque[0] == 7.0
    # memory_speed alone is used too (it used to need motor_torque beside it)
    y = drill_env.simulator.initial_state(params, {"memory_speed": 3.0}, 2.0)
    assert y[5] == 3.0 and y[4] == pytest.approx(params.motor_constant * 2.0)
    y = drill_env.simulator.initial_state(params, [0.1, 0.2, 0.3, 0.4, 5.0, 6.0], 2.0)
    assert list(y) == [0.1, 0.2, 0.3, 0.4, 5.0, 6.0, 0.0]  # no friction heating: cold


@pytest.mark.parametrize(("key", "effect"), [("motor_torque", "motor_lag"), ("memory_speed", "friction_lag")])
def test_a_state_the_rig_does_not_have_is_rejected_not_dropped(key, effect):
    with pytest.raises(ValueError, match=rf"x0.{key}: .*effects.{effect} = 0"):
        drill_env.simulate("brake", u=2.0, t_final=1.0, x0={key: 3.0})
    # its steady value is accepted (a full state read back from a result, say)
    km_u = drill_env.load_params("brake").motor_constant * 2.0
    y = drill_env.simulator.initial_state(drill_env.load_params("brake"), [0, 0, 0, 0, km_u, 0.0], 2.0)
    assert y[4] == km_u
