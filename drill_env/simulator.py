"""Python API of the exact nonsmooth simulator: :func:`simulate` and :func:`simulate_batch`.

Three clocks, kept apart: the *integration* clock is adaptive (DOP853 steps chosen by
the error control, cut at every switching event); the *input* clock is the
zero-order hold of the voltage (``control_dt``, one value per control period); the
*output* clock samples the dense solution every ``dt``. None constrains the others:
outputs are interpolated, and steps end exactly on input changes.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numba as nb
import numpy as np
from numba.core.ccallback import CFunc

from drill_env import _layout as L
from drill_env._numba import JIT_ALLOC
from drill_env.kernel import (
    INPUT_SIGNATURE,
    N_STATS,
    ST_BAD_T,
    ST_EVENTS,
    ST_LOGGED,
    ST_STATUS,
    ST_STOP,
    STATUS_MESSAGES,
    run,
)
from drill_env.params import RigParams, resolve_params
from drill_env.result import EventLog, SimulationResult

__all__ = [
    "simulate",
    "simulate_batch",
    "initial_state",
    "InputFunctionError",
    "OutputSizeError",
    "MAX_RESULT_BYTES",
    "MAX_TIME_S",
    "MAX_DURATION_S",
    "MAX_EVENT_CAPACITY",
    "MIN_CONTROL_DT",
    "MIN_DT",
    "DEFAULT_RTOL",
    "DEFAULT_ATOL",
]

# Default tolerances (relative and absolute): 1e-9 keeps the state within ~1e-7 of a tight reference over 100 s
# of stick-slip (benchmarks/bench_simulator.py), well inside the 1e-6 the analysis needs.
DEFAULT_RTOL = 1e-9
DEFAULT_ATOL = 1e-9
_OPTIONS = {"rtol", "atol", "control_dt", "voltage_limit", "max_steps", "event_capacity", "t0"}

# Bounds of the arguments (a larger or smaller value is a ValueError naming it).
# Times: beyond 1e6 s a float64 clock resolves only ~1e-10 s and, with a time-varying input
# or effect, the run would differ from the same run started at 0; with a constant or held
# input and no time-varying effect the clock is moved to start at 0 whenever |t0| > 1e3 s,
# so any finite t0 keeps full precision there.
MAX_TIME_S = 1e6  # [s] |t0|, |t_final| of a run with an input function or a time-varying effect
MAX_DURATION_S = 1e7  # [s] t_final - t0 (about 116 days of rig time)
_SHIFT_T0 = 1e3  # [s] autonomous runs starting later than this are integrated from 0
MIN_DT = 1e-9  # [s] output sample period
MIN_CONTROL_DT = 1e-6  # [s] hold period of a voltage sequence
MAX_EVENT_CAPACITY = 1_000_000  # initial event-log size (about 80 MB; it grows by itself as needed)
MAX_MAX_STEPS = 10**12
_INTERRUPTIBLE_S = 50.0  # [s] runs this long run in a worker thread that Ctrl-C can stop


def initial_state(params: RigParams, x0: Any = None, u0: float = 0.0) -> np.ndarray:
    """Full kernel state from a user's initial condition.

    ``x0`` may be None (rig at rest, no twist), a sequence ``(x1, x2, x3)`` (the paper's
    state; angles start at theta_l = 0), a sequence ``(theta_u, theta_l, x2, x3)``, the
    kernel state ``(x1, x2, x3, theta_l, motor_torque, memory_speed)`` or the whole
    kernel state with ``thermal_state`` appended (a result's ``final_state``), or a
    mapping with keys among ``theta_u, theta_l, x1, x2, x3, motor_torque,
    memory_speed, thermal_state``. Unless given, the motor torque starts at its steady
    value km*u0, the friction memory at |x3| and the thermal state at 0 (the contact at
    its ambient level: every run starts cold unless a thermal state is passed on). A
    given motor torque, memory speed or thermal state is used as given where the rig has
    that state (effects ``motor_lag`` / ``friction_lag`` / ``friction_heating``);
    without the effect, the state does not exist and a value other than its steady one
    is rejected. Every value must be finite; the memory speed (a lagged |x3|) and the
    thermal state (a lagged power) must be >= 0.
    """
    y = np.zeros(L.NY)
    extra: dict[str, float] = {}
    if x0 is not None:
        if isinstance(x0, Mapping):
            allowed = {
                "theta_u",
                "theta_l",
                "x1",
                "x2",
                "x3",
                "motor_torque",
                "memory_speed",
                "thermal_state",
            }
            unknown = sorted(set(x0) - allowed)
            if unknown:
                raise ValueError(f"x0: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
            if "x1" in x0 and "theta_u" in x0:
                raise ValueError("x0: give either x1 or theta_u, not both")
            for key in x0:
                _finite(f"x0.{key}", x0[key])
            thl = float(x0.get("theta_l", 0.0))
            x1 = float(x0["x1"]) if "x1" in x0 else float(x0.get("theta_u", 0.0)) - thl
            vals = [x1, float(x0.get("x2", 0.0)), float(x0.get("x3", 0.0)), thl]
            extra = {k: float(x0[k]) for k in ("motor_torque", "memory_speed", "thermal_state") if k in x0}
        else:
            try:
                arr = np.asarray(x0, dtype=float).ravel()
            except (TypeError, ValueError):
                raise ValueError(f"x0: expected numbers, got {x0!r}") from None
            if arr.size == 3:
                vals = [arr[0], arr[1], arr[2], 0.0]
            elif arr.size == 4:
                vals = [arr[0] - arr[1], arr[2], arr[3], arr[1]]
            elif arr.size in (L.NY_LAG, L.NY):
                vals = [float(v) for v in arr[:4]]
                extra = {"motor_torque": float(arr[L.TM]), "memory_speed": float(arr[L.WL])}
                if arr.size == L.NY:
                    extra["thermal_state"] = float(arr[L.TH])
            else:
                raise ValueError(
                    f"x0: expected 3 values (x1, x2, x3), 4 (theta_u, theta_l, x2, x3), 6 (x1, x2, "
                    f"x3, theta_l, motor_torque, memory_speed) or 7 (the same and thermal_state), got {arr.size}"
                )
        for name, v in zip(("x1", "x2", "x3", "theta_l"), vals, strict=True):
            if not math.isfinite(v):
                raise ValueError(f"x0.{name}: must be finite, got {v!r}")
        y[:4] = vals
    y[L.TM] = params.motor_constant * u0
    y[L.WL] = abs(y[L.X3])
    eff = params.effects
    for key, slot, has_state, effect in (
        ("motor_torque", L.TM, eff.motor_lag > 0.0, "motor_lag"),
        ("memory_speed", L.WL, eff.friction_lag > 0.0, "friction_lag"),
        ("thermal_state", L.TH, eff.friction_heating != 0.0, "friction_heating"),
    ):
        if key not in extra:
            continue
        v = extra[key]
        if not math.isfinite(v):
            raise ValueError(f"x0.{key}: must be finite, got {v!r}")
        if key == "memory_speed" and v < 0.0:
            raise ValueError(f"x0.memory_speed: a lagged |x3| must be >= 0 rad/s, got {v!r}")
        if key == "thermal_state" and v < 0.0:
            raise ValueError(f"x0.thermal_state: a lagged friction power must be >= 0 W, got {v!r}")
        if has_state:
            y[slot] = v
        elif abs(v - y[slot]) > 1e-12 * max(1.0, abs(y[slot])):
            raise ValueError(
                f"x0.{key}: the rig has no such state (effects.{effect} = 0), its value is "
                f"{y[slot]:.12g}; got {v!r} (turn the effect on, or leave {key} out)"
            )
    return y


def _check_heating(params: RigParams, t: np.ndarray, thermal: np.ndarray) -> None:
    """Friction heating of negative kappa must not take the friction level below zero."""
    kappa = params.effects.friction_heating
    if kappa >= 0.0 or thermal.size == 0:
        return
    i = int(np.argmax(thermal))
    if 1.0 + kappa * thermal[i] <= 0.0:
        raise ValueError(
            f"effects.friction_heating: {kappa:g} 1/W makes the lower friction level negative: the "
            f"thermal state reaches {float(thermal[i]):.4g} W at t = {float(t[i]):g} s; allowed: "
            f"friction_heating > {-1.0 / float(thermal[i]):.4g} 1/W for this run"
        )


def _finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {v!r}")
    return v


def _check_positive(name: str, value: Any) -> float:
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name}: must be finite and > 0, got {value!r}")
    return v


# The arrays of one result (states, modes, input at every output sample) may take at most
# this much memory; a larger request is refused before anything is allocated.
MAX_RESULT_BYTES = 2 * 2**30
_BYTES_PER_SAMPLE = 8 * L.NY + 2 + 8  # simulate: states (float64), modes (int8), input
_BYTES_PER_BATCH_SAMPLE = 8 * L.NY + 2 * 8 + 8  # simulate_batch: modes are int64


class OutputSizeError(ValueError):
    """The requested output would exceed :data:`MAX_RESULT_BYTES`."""


def _check_output_size(n_samples: int, per_sample: int, t_span: float, dt: float, n_rigs: int = 1) -> None:
    size = n_samples * per_sample * n_rigs
    if size > MAX_RESULT_BYTES:
        rigs = f" x {n_rigs} rigs" if n_rigs > 1 else ""
        raise OutputSizeError(
            f"dt: {t_span:g} s sampled every {dt:g} s is {n_samples:.4g} output samples{rigs}, "
            f"{size / 2**30:.3g} GiB; the limit is {MAX_RESULT_BYTES / 2**30:g} GiB: raise dt, "
            "shorten the run or split it (pass the final state as x0 of the next)"
        )


def _n_output(t0: float, t_final: float, dt: float) -> int:
    return int(math.floor((t_final - t0) / dt * (1 + 1e-12) + 1e-9)) + 1


def _voltage_array(u: Any) -> np.ndarray:
    """``u`` as a float array; strings, None, booleans and other non-numbers are refused."""
    if u is None or isinstance(u, (str, bytes, bool, np.bool_)):
        raise ValueError(f"u: expected a voltage [V] (a number, a sequence or a function of time), got {u!r}")
    try:
        raw = np.asarray(u)
    except (TypeError, ValueError):
        raise ValueError(f"u: expected numbers [V], got {u!r}") from None
    if raw.dtype.kind not in "iuf" and not (raw.dtype.kind == "O" and raw.size == 0):
        raise ValueError(f"u: expected numbers [V], got {raw.dtype.name} values ({u!r:.80})")
    return raw.astype(float)


class InputFunctionError(ValueError):
    """The input function u(t) raised or returned a value that is not a finite number."""


def _compile_input(u: Callable[[float], float], t0: float) -> Any:
    """A user's u(t) as a compiled C function float64(float64) (see :mod:`drill_env.kernel`).

    The function is first called once in Python at ``t0`` so that its own errors (a
    NameError, say) reach the user as they are. The compiled version checks indexing
    and division, and any exception it raises comes out as NaN: the kernel stops with
    status 4 there, and :func:`_input_failure` reports the real error.
    """
    if isinstance(u, CFunc):
        return u
    py = u.py_func if isinstance(u, nb.core.registry.CPUDispatcher) else u
    try:
        v0 = py(t0)
    except Exception as exc:
        raise InputFunctionError(
            f"u: the input function raised {type(exc).__name__}: {exc} at t = {t0:g} s"
        ) from exc
    _check_input_value(v0, t0)
    try:
        inner = nb.njit(boundscheck=True, error_model="python")(py)

        def guarded(t):
            try:
                v = float(inner(t))
            except Exception:  # numba catches all exceptions alike; the Python call names it
                v = math.nan
            return v

        fn = nb.cfunc(INPUT_SIGNATURE, error_model="python")(guarded)
        fn.ctypes(t0)
    except Exception as exc:  # numba's typing errors are long; keep the cause
        raise TypeError(
            "u: a function of time must be compilable by numba (math/numpy functions of "
            "t returning a float), or pass the voltage as a zero-order-hold sequence with "
            f"control_dt; numba said: {str(exc).strip().splitlines()[0]}"
        ) from exc
    setattr(fn, "drill_env_py_func", py)  # for the error report (numba's CFunc takes attributes)  # noqa: B010
    return fn


def _check_input_value(v: Any, t: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise InputFunctionError(
            f"u: the input function returned {v!r} at t = {t:g} s; expected a number [V]"
        )
    if not math.isfinite(float(v)):
        raise InputFunctionError(
            f"u: the input function returned {float(v)!r} at t = {t:g} s; the voltage must be finite"
        )
    return float(v)


def _input_failure(fn: Any, t_bad: float) -> InputFunctionError:
    """The error to raise when the kernel stopped on a non-finite input at ``t_bad``."""
    py = getattr(fn, "drill_env_py_func", None)
    if py is not None:
        try:
            v = py(t_bad)
        except Exception as exc:
            err = InputFunctionError(
                f"u: the input function raised {type(exc).__name__}: {exc} at t = {t_bad!r} s; simulation stopped"
            )
            err.__cause__ = exc
            return err
        try:
            _check_input_value(v, t_bad)
        except InputFunctionError as exc:
            return InputFunctionError(f"{exc}; simulation stopped")
        return InputFunctionError(
            f"u: the compiled input function failed at t = {t_bad!r} s (an index out of range or a "
            f"division by zero, say; in Python it returned {v!r}); simulation stopped"
        )
    return InputFunctionError(
        f"u: the input function returned a non-finite value at t = {t_bad!r} s; simulation stopped"
    )


def _input_program(
    u: Any, t0: float, t_final: float, control_dt: float | None, voltage_limit: float
) -> tuple[np.ndarray, np.ndarray, Any, bool, float]:
    """Segments (times, voltages) of the input, or a compiled function of time."""
    lim = math.inf if voltage_limit is None else float(voltage_limit)
    if callable(u):
        fn = _compile_input(u, t0)
        return np.array([t0, t_final]), np.array([0.0]), fn, True, lim
    arr = _voltage_array(u)
    if control_dt is not None:
        control_dt = _check_positive("control_dt", control_dt)
    if arr.ndim == 0:
        if not math.isfinite(float(arr)):
            raise ValueError(f"u: the voltage must be finite, got {float(arr)!r}")
        return np.array([t0, t_final]), np.array([float(arr)]), None, False, lim
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"u: expected a number, a 1-D sequence or a function of time, got shape {arr.shape}")
    if control_dt is None:
        raise ValueError("control_dt: required when u is a sequence (one voltage per control period)")
    cdt = _check_positive("control_dt", control_dt)
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise ValueError(f"u[{bad[0]}]: the voltage must be finite, got {arr[bad[0]]!r}")
    n_needed = int(math.ceil((t_final - t0) / cdt - 1e-9))
    if arr.size < n_needed:
        raise ValueError(
            f"u: {arr.size} values cover {arr.size * cdt:g} s at control_dt={cdt:g} s, "
            f"but the simulation lasts {t_final - t0:g} s ({n_needed} values needed)"
        )
    seg_t = t0 + cdt * np.arange(n_needed + 1, dtype=float)
    seg_t[-1] = t_final
    return seg_t, arr[:n_needed].copy(), None, False, lim


def _output_grid(t0: float, t_final: float, dt: float) -> np.ndarray:
    n = _n_output(t0, t_final, dt)
    t = t0 + dt * np.arange(n)
    t[-1] = min(t[-1], t_final)
    return t


def simulate(
    params_or_preset: RigParams | str,
    u: float | Sequence[float] | np.ndarray | Callable[[float], float],
    t_final: float,
    x0: Any = None,
    dt: float = 0.01,
    **options: Any,
) -> SimulationResult:
    """Simulate the rig exactly (event-driven, set-valued friction) from t0 to ``t_final``.

    Args:
        params_or_preset: :class:`RigParams`, a preset name (``"brake"``, ``"no_brake"``)
            or a YAML file.
        u: amplifier input voltage [V]: a constant, a zero-order-hold sequence (one value
            per ``control_dt``), or a function of time ``u(t)`` that numba can compile.
            A function is called once in Python at t0 (its own errors surface as they
            are), then compiled with bounds and division checks; if it raises or returns
            a non-finite value during the run, the run stops and
            :class:`InputFunctionError` (a ValueError) names the error and its time.
            While a disk sticks under a function input (or a time-varying effect), steps
            are at most ``kernel.STUCK_H_MAX`` (10 ms) and the breakaway condition is
            sampled 8 times per step and refined, so a pulse is never stepped over unless
            it is shorter than ~1 ms; pass brief pulses as a zero-order hold (exact).
        t_final: end time [s].
        x0: initial condition, see :func:`initial_state`; default the rig at rest.
        dt: output sample period [s]; the solution is sampled from the dense output.

    Options:
        rtol, atol: integration tolerances (default 1e-9, 1e-9).
        control_dt: hold period of a voltage sequence [s].
        voltage_limit: clip u to +-limit [V] as the rig's amplifier does (default: no
            limit; the clipped voltage is what ``result.u`` holds).
        t0: start time [s] (default 0).
        max_steps: cap on integration attempts, accepted and rejected steps alike
            (default: generous); reaching it ends the run with status 1 and a warning.
        event_capacity: initial size of the event log (grown automatically).

    Bounds (docs/guides/limits.md): ``t_final - t0`` at most :data:`MAX_DURATION_S`;
    ``dt`` at least :data:`MIN_DT`; ``control_dt`` from :data:`MIN_CONTROL_DT` to
    :data:`MAX_DURATION_S`; ``event_capacity`` up to :data:`MAX_EVENT_CAPACITY`;
    ``max_steps`` up to 1e12. With a constant or held input and no time-varying effect a
    late ``t0`` gives exactly the run started at 0, shifted (the clock is moved); with a
    function ``u(t)`` or ``effects.friction_drift``, ``|t0|`` and ``|t_final|`` are at
    most :data:`MAX_TIME_S`. A run of 50 s or more in the main thread stops within a step
    on Ctrl-C (KeyboardInterrupt).

    Returns:
        :class:`SimulationResult`.

    Raises:
        ValueError: a bad argument (naming it and its allowed range), including every
            component of ``x0``; :class:`InputFunctionError` for a failing ``u(t)``.
    """
    unknown = sorted(set(options) - _OPTIONS)
    if unknown:
        raise TypeError(f"simulate: unknown option(s) {unknown}; allowed: {sorted(_OPTIONS)}")
    params = resolve_params(params_or_preset)
    t0 = _finite("t0", options.get("t0", 0.0))
    if isinstance(t_final, (str, bytes, bool, np.bool_)):
        raise ValueError(f"t_final: expected a number, got {t_final!r}")
    try:
        t_final = float(t_final)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"t_final: expected a number, got {t_final!r}") from None
    if not math.isfinite(t_final) or t_final <= t0:
        raise ValueError(f"t_final: must be finite and > t0 = {t0:g} s, got {t_final!r}")
    duration = t_final - t0
    if duration > MAX_DURATION_S:
        raise ValueError(
            f"t_final: the run would last {duration:.4g} s; allowed: at most {MAX_DURATION_S:g} s "
            "(split a longer run: pass the final state as x0 of the next)"
        )
    dt = _check_positive("dt", dt)
    if dt < MIN_DT:
        raise ValueError(f"dt: {dt!r} s is below the clock's resolution; allowed: dt >= {MIN_DT:g} s")
    rtol = _check_positive("rtol", options.get("rtol", DEFAULT_RTOL))
    atol = _check_positive("atol", options.get("atol", DEFAULT_ATOL))
    vlim = options.get("voltage_limit")
    if vlim is not None:
        vlim = _check_positive("voltage_limit", vlim)
    _check_output_size(_n_output(t0, t_final, dt), _BYTES_PER_SAMPLE, duration, dt)
    max_steps = options.get("max_steps", max(100_000, int(duration * 2000)))
    if (
        isinstance(max_steps, bool)
        or not isinstance(max_steps, (int, np.integer))
        or not 1 <= max_steps <= MAX_MAX_STEPS
    ):
        raise ValueError(f"max_steps: expected an integer from 1 to {MAX_MAX_STEPS:.0e}, got {max_steps!r}")
    max_steps = int(max_steps)
    cap = options.get("event_capacity", 256)
    if isinstance(cap, bool) or not isinstance(cap, (int, np.integer)) or not 1 <= cap <= MAX_EVENT_CAPACITY:
        raise ValueError(
            f"event_capacity: expected an integer from 1 to {MAX_EVENT_CAPACITY:.0e} (the log grows as "
            f"needed), got {cap!r}"
        )
    cap = int(cap)
    cdt = options.get("control_dt")
    if cdt is not None:
        cdt = _check_positive("control_dt", cdt)
        if not MIN_CONTROL_DT <= cdt <= MAX_DURATION_S:
            raise ValueError(f"control_dt: {cdt!r} s is outside [{MIN_CONTROL_DT:g}, {MAX_DURATION_S:g}] s")
    eff = params.effects
    time_varying = callable(u) or eff.friction_drift != 0.0
    if time_varying and max(abs(t0), abs(t_final)) > MAX_TIME_S:
        name = "t0" if abs(t0) > MAX_TIME_S else "t_final"
        raise ValueError(
            f"{name}: {t0 if name == 't0' else t_final:g} s; with "
            f"{'an input function' if callable(u) else 'effects.friction_drift'} the clock keeps full "
            f"precision only up to {MAX_TIME_S:g} s; allowed: |t0|, |t_final| <= {MAX_TIME_S:g} s"
        )
    # A run whose dynamics do not depend on the absolute time is integrated on a clock that
    # starts at 0 (a late t0 would otherwise cost precision in every step and event time).
    shift = t0 if (not time_varying and abs(t0) > _SHIFT_T0) else 0.0
    seg_t, seg_u, fn, use_func, lim = _input_program(
        u, t0 - shift, t_final - shift, cdt, vlim if vlim is not None else math.inf
    )
    if eff.friction_drift != 0.0:
        worst = 1.0 + eff.friction_drift * (t_final if eff.friction_drift < 0 else t0)
        if worst <= 0.0:
            raise ValueError(
                f"effects.friction_drift: {eff.friction_drift:g} 1/s makes the friction level "
                f"negative before t = {t_final:g} s"
            )
    u0 = float(fn.ctypes(t0)) if use_func else float(seg_u[0])
    if vlim is not None:
        u0 = max(-vlim, min(vlim, u0))
    y0 = initial_state(params, x0, u0)
    p = params.as_array()
    if shift and p[L.DIST_A] != 0.0:  # the disturbance's phase at the moved clock's 0
        p[L.DIST_P] = math.fmod(p[L.DIST_P] + math.fmod(p[L.DIST_W] * shift, 2 * math.pi), 2 * math.pi)
    t_out = _output_grid(t0, t_final, dt)
    t_run = _output_grid(0.0, duration, dt) if shift else t_out  # shift == t0: the same samples from 0
    while True:
        y = y0.copy()
        modes = np.zeros(2, dtype=np.int64)
        # Column-major: each state component is one contiguous array of the result.
        Y = np.empty((t_out.size, L.NY), order="F")
        M = np.empty((t_out.size, 2), dtype=np.int8, order="F")
        U = np.empty(t_out.size)
        ev_t = np.empty(cap)
        ev_disk = np.empty(cap, dtype=np.int64)
        ev_from = np.empty(cap, dtype=np.int64)
        ev_to = np.empty(cap, dtype=np.int64)
        ev_y = np.empty((cap, L.NY))
        stats = np.zeros(N_STATS + 1)  # the last slot: a stop request (Ctrl-C)
        inputs = (p, y, modes, seg_t, seg_u, fn, use_func, lim, t_run, rtol, atol, 0.0, max_steps)
        outputs = (Y, M, U, ev_t, ev_disk, ev_from, ev_to, ev_y, stats)
        status = _run_stoppable(inputs + outputs, stats, duration >= _INTERRUPTIBLE_S)
        if stats[ST_EVENTS] <= cap:
            break
        cap = int(stats[ST_EVENTS]) + 16
    n_ev = int(stats[ST_LOGGED])
    if status == 4:
        raise _input_failure(fn, float(stats[ST_BAD_T]))
    _check_heating(params, t_out, Y[:, L.TH])
    if status != 0:
        warnings.warn(f"simulate: {STATUS_MESSAGES[int(status)]}", RuntimeWarning, stacklevel=2)
    events = EventLog(
        t=ev_t[:n_ev] + shift,
        disk=ev_disk[:n_ev].copy(),
        mode_before=ev_from[:n_ev].copy(),
        mode_after=ev_to[:n_ev].copy(),
        state=ev_y[:n_ev].copy(),
    )
    u_requested = None
    if vlim is not None:
        if use_func:
            u_requested = np.array([fn.ctypes(float(tt)) for tt in t_out])
        else:
            idx = np.clip(np.searchsorted(seg_t, t_run, side="right") - 1, 0, seg_u.size - 1)
            u_requested = seg_u[idx]
    return SimulationResult.from_kernel(
        params=params,
        t=t_out,
        Y=Y,
        M=M,
        U=U,
        events=events,
        stats=stats,
        status=int(stats[ST_STATUS]),
        final_state=y,
        final_modes=modes,
        u_requested=u_requested,
    )


def _run_stoppable(args: tuple[Any, ...], stats: np.ndarray, long_run: bool, kernel: Any = None) -> int:
    """Run the kernel; a long run in the main thread runs in a worker thread (the kernel
    releases the GIL) so that Ctrl-C stops it within a step: the kernel is asked to stop
    (``stats[ST_STOP]``), waited for, and KeyboardInterrupt is raised again."""
    import threading

    kernel = run if kernel is None else kernel
    if not long_run or threading.current_thread() is not threading.main_thread():
        return kernel(*args)
    box: dict[str, Any] = {}
    done = threading.Event()

    def target() -> None:
        try:
            box["status"] = kernel(*args)
        except BaseException as exc:  # noqa: BLE001 (passed on to the caller)
            box["error"] = exc
        finally:
            done.set()

    worker = threading.Thread(target=target, name="drill-env-simulate", daemon=True)
    worker.start()
    try:
        while not done.wait(0.05):
            pass
    except KeyboardInterrupt:
        stats[..., ST_STOP] = 1.0  # every rig of a batch reads its own row
        # an Event, not Thread.join: a join that Ctrl-C interrupted can mark the thread as ended
        # while it still runs (Python 3.11), and a second join then returns at once
        # the kernel stops after its current step; one still being loaded (compiled code read
        # from the cache, seconds on a loaded machine) stops at its first: not waited for
        done.wait(1.0)
        raise
    if "error" in box:
        raise box["error"]
    return box["status"]


@nb.njit(**JIT_ALLOC)
def _run_batch(P, Y0, seg_t, SEG_U, t_out, rtol, atol, max_steps, Yo, Mo, Uo, stats_all, ev_count):
    n = P.shape[0]
    cap = 1
    ev_t = np.empty(cap)
    ev_disk = np.empty(cap, dtype=np.int64)
    ev_from = np.empty(cap, dtype=np.int64)
    ev_to = np.empty(cap, dtype=np.int64)
    ev_y = np.empty((cap, L.NY))
    modes = np.zeros(2, dtype=np.int64)
    for i in range(n):
        y = Y0[i].copy()
        run(
            P[i],
            y,
            modes,
            seg_t,
            SEG_U[i],
            None,
            False,
            np.inf,
            t_out,
            rtol,
            atol,
            0.0,
            max_steps,
            Yo[i],
            Mo[i],
            Uo[i],
            ev_t,
            ev_disk,
            ev_from,
            ev_to,
            ev_y,
            stats_all[i],
        )
        ev_count[i] = stats_all[i, ST_EVENTS]


def simulate_batch(
    params: RigParams | str | Sequence[RigParams],
    u: float | Sequence[float] | np.ndarray,
    t_final: float,
    x0: Any = None,
    dt: float = 0.01,
    *,
    n: int | None = None,
    control_dt: float | None = None,
    voltage_limit: float | None = None,
    rtol: float = DEFAULT_RTOL,
    atol: float = DEFAULT_ATOL,
) -> SimulationResult:
    """Simulate many rigs in one compiled call.

    ``params``: one parameter set for all rigs or a sequence (one per rig). ``u``: shape
    (N,) constant voltages, or (N, K) zero-order-hold sequences with ``control_dt``.
    ``x0``: None or an array of shape (N, 3) / (N, 4). Returns one
    :class:`SimulationResult` whose arrays have a leading rig axis; event logs are not
    kept (only their counts, in ``result.stats['events']``).
    """
    u_arr = _voltage_array(u)
    if u_arr.ndim > 2 or 0 in u_arr.shape:
        raise ValueError(
            f"u: expected a number, N voltages or N sequences (shape (N, K)), got shape {u_arr.shape}"
        )
    if isinstance(params, (RigParams, str)):
        plist = None
        base = resolve_params(params)
    else:
        try:
            plist = [resolve_params(q) for q in params]
        except TypeError:
            raise ValueError(
                f"params: expected RigParams, a preset name or a sequence of them, got {params!r:.80}"
            ) from None
        if not plist:
            raise ValueError("params: an empty sequence; give one parameter set, or one per rig")
        base = plist[0]
    if n is not None and (isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1):
        raise ValueError(f"n: expected an integer >= 1 (the number of rigs), got {n!r}")
    if control_dt is not None:
        control_dt = _check_positive("control_dt", control_dt)
    n_rigs = (
        int(n)
        if n is not None
        else (len(plist) if plist is not None else (u_arr.shape[0] if u_arr.ndim >= 1 else 1))
    )
    if plist is not None and len(plist) != n_rigs:
        raise ValueError(f"params: {len(plist)} parameter sets for {n_rigs} rigs")
    t_final = _check_positive("t_final", t_final)
    if t_final > MAX_DURATION_S:
        raise ValueError(f"t_final: {t_final:.4g} s; allowed: at most {MAX_DURATION_S:g} s")
    dt = _check_positive("dt", dt)
    if dt < MIN_DT:
        raise ValueError(f"dt: {dt!r} s is below the clock's resolution; allowed: dt >= {MIN_DT:g} s")
    if control_dt is not None and not MIN_CONTROL_DT <= control_dt <= MAX_DURATION_S:
        raise ValueError(
            f"control_dt: {control_dt!r} s is outside [{MIN_CONTROL_DT:g}, {MAX_DURATION_S:g}] s"
        )
    _check_output_size(_n_output(0.0, t_final, dt), _BYTES_PER_BATCH_SAMPLE, t_final, dt, n_rigs)
    P = (
        np.stack([q.as_array() for q in plist])
        if plist is not None
        else np.tile(base.as_array(), (n_rigs, 1))
    )
    if u_arr.ndim == 0:
        u_arr = np.full(n_rigs, float(u_arr))
    if u_arr.shape[0] != n_rigs:
        raise ValueError(f"u: leading dimension {u_arr.shape[0]} does not match {n_rigs} rigs")
    if not np.all(np.isfinite(u_arr)):
        raise ValueError("u: voltages must be finite")
    if voltage_limit is not None:
        voltage_limit = _check_positive("voltage_limit", voltage_limit)
        u_arr = np.clip(u_arr, -voltage_limit, voltage_limit)
    if u_arr.ndim == 1:
        seg_t = np.array([0.0, t_final])
        SEG_U = u_arr[:, None].copy()
    else:
        seg_t, _, _, _, _ = _input_program(u_arr[0], 0.0, t_final, control_dt, math.inf)
        SEG_U = np.ascontiguousarray(u_arr[:, : seg_t.size - 1])
    if x0 is None:
        Y0 = np.zeros((n_rigs, L.NY))
        Y0[:, L.TM] = P[:, L.KM] * SEG_U[:, 0]
    else:
        x0a = np.asarray(x0, dtype=float)
        if x0a.ndim != 2 or x0a.shape[0] != n_rigs:
            raise ValueError(f"x0: expected shape ({n_rigs}, 3) or ({n_rigs}, 4), got {x0a.shape}")
        Y0 = np.stack(
            [initial_state(plist[i] if plist else base, x0a[i], SEG_U[i, 0]) for i in range(n_rigs)]
        )
    t_out = _output_grid(0.0, t_final, dt)
    Yo = np.empty((n_rigs, t_out.size, L.NY))
    Mo = np.empty((n_rigs, t_out.size, 2), dtype=np.int64)
    Uo = np.empty((n_rigs, t_out.size))
    stats = np.zeros((n_rigs, N_STATS + 1))  # the last slot of each row: a stop request (Ctrl-C)
    ev_count = np.zeros(n_rigs)
    max_steps = max(100_000, int(t_final * 2000))
    _run_stoppable(
        (P, Y0, seg_t, SEG_U, t_out, rtol, atol, max_steps, Yo, Mo, Uo, stats, ev_count),
        stats,
        t_final * n_rigs >= _INTERRUPTIBLE_S,
        kernel=_run_batch,
    )
    stats = stats[:, :N_STATS]
    for i in range(n_rigs):
        _check_heating(plist[i] if plist is not None else base, t_out, Yo[i, :, L.TH])
    bad = np.flatnonzero(stats[:, ST_STATUS] != 0)
    if bad.size:
        warnings.warn(
            f"simulate_batch: rig {bad[0]}: {STATUS_MESSAGES[int(stats[bad[0], ST_STATUS])]}",
            RuntimeWarning,
            stacklevel=2,
        )
    return SimulationResult.from_kernel(
        params=base if plist is None else plist,
        t=t_out,
        Y=Yo,
        M=Mo,
        U=Uo,
        events=None,
        stats=stats,
        status=int(stats[:, ST_STATUS].max()),
        final_state=Yo[:, -1, :],
        final_modes=Mo[:, -1, :],
        u_requested=None,
    )
