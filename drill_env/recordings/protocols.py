"""Recording protocols a lab uses besides the identification plan, for synthetic recordings.

Each protocol is a list of runs, a run a voltage program: a constant [V], or a zero-order
hold sequence on a 0.1 s grid covering the settle (not recorded) and the recording.

* ``staircase``: steps of 0.5 V held 10 s, up from 0 V to 4.5 V and down again; a second run
  through negative voltages (-4.5 ... 4.5 V);
* ``slow_ramp``: triangles 0 -> 5 -> 0 V and -5 -> 5 -> -5 V over the recording (a fine
  staircase of 0.1 s steps), and one at a third of the slope;
* ``prbs``: pseudo-random binary sequences between two levels (bits of 0.3-1.5 s): 1.5/3.5 V,
  -3/3 V and 0.5/4.5 V;
* ``constant_from_rest``: constant voltages recorded from the rig at rest (the start-up
  transient recorded, no settle);
* ``constant_after_settle``: constant voltages recorded after 60 s at the voltage;
* ``closed_loop_pi``: a PI controller (10 Hz, on the lower encoder's speed) holding lower-disk
  speed set points that step every 15-30 s (the rig's own voltage limit clips it, visibly);
* ``mixed``: a lab's week: one staircase, one slow ramp, one PRBS, a closed-loop run and four
  constant runs (two from rest, two after a settle).

:func:`record_protocol` records a truth plant (effects included) with one of them through
the rig's encoders, at any sample rate and resolution the loader reads.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from drill_env.measurement import MeasurementModel
from drill_env.params import IDENTIFIED_PARAMETERS, RigParams
from drill_env.recordings.dataset import MeasuredRun
from drill_env.recordings.synth import SynthConfig, SynthResult, _simulate_run

__all__ = ["PROTOCOLS", "ProtocolRun", "protocol_runs", "record_protocol"]

PROTOCOLS = (
    "staircase",
    "slow_ramp",
    "prbs",
    "constant_from_rest",
    "constant_after_settle",
    "closed_loop_pi",
    "mixed",
)
QUANTUM_S = 0.1  # hold period of the voltage programs [s]
PI_DT_S = 0.1  # period of the closed-loop PI [s]


@dataclass(frozen=True)
class ProtocolRun:
    """One run of a protocol: ``kind`` and its program (see the module docstring)."""

    kind: str  # "constant", "program" (zero-order hold on QUANTUM_S) or "closed_loop"
    settle_s: float  # simulated before the recording starts [s]
    voltage: float = 0.0  # constant runs [V]
    levels: tuple[float, ...] = ()  # programs: one level per QUANTUM_S, settle included
    set_points: tuple[float, ...] = ()  # closed loop: lower-disk speeds [rad/s], one per QUANTUM_S
    label: str = ""


def _grid(total_s: float) -> int:
    return int(math.ceil(total_s / QUANTUM_S)) + 1


def _staircase(
    lo: float, hi: float, step: float, hold_s: float, total_s: float, settle_s: float
) -> np.ndarray:
    ups = np.arange(lo, hi + 1e-9, step)
    cycle = np.concatenate([ups, ups[-2:0:-1]]) if ups.size > 2 else ups
    per = max(1, int(round(hold_s / QUANTUM_S)))
    seq = np.repeat(cycle, per)
    n = _grid(total_s)
    reps = int(math.ceil(n / seq.size)) + 1
    out = np.tile(seq, reps)[:n]
    out[: int(round(settle_s / QUANTUM_S))] = lo  # settled at the first step
    return out


def _triangle(lo: float, hi: float, period_s: float, total_s: float, settle_s: float) -> np.ndarray:
    t = np.arange(_grid(total_s)) * QUANTUM_S - settle_s
    phase = np.mod(np.maximum(t, 0.0) / period_s, 1.0)
    tri = 1.0 - np.abs(2.0 * phase - 1.0)  # 0 -> 1 -> 0 over a period
    return lo + (hi - lo) * tri


def _prbs(a: float, b: float, total_s: float, rng: np.random.Generator) -> np.ndarray:
    n = _grid(total_s)
    out = np.empty(n)
    i, level = 0, a
    while i < n:
        k = int(rng.integers(3, 16))  # 0.3-1.5 s
        out[i : i + k] = level
        level = b if level == a else a
        i += k
    return out


def _set_points(speeds: Sequence[float], total_s: float, rng: np.random.Generator) -> np.ndarray:
    n = _grid(total_s)
    out = np.empty(n)
    i = 0
    while i < n:
        k = int(rng.integers(150, 301))  # 15-30 s
        out[i : i + k] = float(rng.choice(np.asarray(speeds)))
        i += k
    return out


def protocol_runs(protocol: str, duration_s: float, rng: np.random.Generator) -> list[ProtocolRun]:
    """The runs of ``protocol`` (see the module docstring) for recordings of ``duration_s``."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol: {protocol!r}; allowed: {', '.join(PROTOCOLS)}")
    settle = 30.0
    total = settle + duration_s
    prog = lambda levels, label: ProtocolRun("program", settle, levels=tuple(map(float, levels)), label=label)  # noqa: E731
    runs: list[ProtocolRun] = []
    if protocol in ("staircase", "mixed"):
        runs.append(prog(_staircase(0.0, 4.5, 0.5, 10.0, total, settle), "staircase 0-4.5 V"))
    if protocol == "staircase":
        runs.append(prog(_staircase(-4.5, 4.5, 0.75, 8.0, total, settle), "staircase -4.5-4.5 V"))
        runs.append(prog(_staircase(0.25, 2.0, 0.25, 12.0, total, settle), "staircase 0.25-2 V"))
    if protocol in ("slow_ramp", "mixed"):
        runs.append(prog(_triangle(-5.0, 5.0, duration_s / 2.0, total, settle), "ramps -5-5 V"))
    if protocol == "slow_ramp":
        runs.append(prog(_triangle(0.0, 5.0, duration_s / 2.0, total, settle), "ramps 0-5 V"))
        runs.append(prog(_triangle(0.0, 5.0, duration_s * 1.5, total, settle), "slow ramp 0-5 V"))
    if protocol in ("prbs", "mixed"):
        runs.append(prog(_prbs(-3.0, 3.0, total, rng), "PRBS -3/3 V"))
    if protocol == "prbs":
        runs.append(prog(_prbs(1.5, 3.5, total, rng), "PRBS 1.5/3.5 V"))
        runs.append(prog(_prbs(0.5, 4.5, total, rng), "PRBS 0.5/4.5 V"))
    if protocol in ("closed_loop_pi", "mixed"):
        sp = tuple(_set_points((2.0, 4.0, 6.0, 9.0), total, rng))
        runs.append(ProtocolRun("closed_loop", settle, set_points=sp, label="closed-loop PI"))
    if protocol == "closed_loop_pi":
        sp = tuple(_set_points((1.0, 3.0, 5.0), total, rng))
        runs.append(ProtocolRun("closed_loop", settle, set_points=sp, label="closed-loop PI, slow"))
    if protocol in ("constant_from_rest", "mixed"):
        vs = (0.6, 2.5) if protocol == "mixed" else (0.3, 0.8, 1.5, 3.0, 4.5)
        runs += [ProtocolRun("constant", 0.0, voltage=v, label=f"{v:g} V from rest") for v in vs]
    if protocol in ("constant_after_settle", "mixed"):
        vs = (1.2, 4.0) if protocol == "mixed" else (0.3, 0.8, 1.5, 3.0, 4.5)
        runs += [ProtocolRun("constant", 60.0, voltage=v, label=f"{v:g} V after a settle") for v in vs]
    return runs


def _closed_loop_levels(truth: RigParams, run: ProtocolRun, cfg: SynthConfig, rng: np.random.Generator):
    """The PI's voltage on its PI_DT_S clock, from a simulation of the truth in closed loop
    (the speed read from the lower encoder over one period; anti-windup by clamping)."""
    from drill_env.simulator import simulate

    step = 2.0 * math.pi / cfg.encoder_counts_per_rev
    n = int(round((run.settle_s + cfg.duration_s) / PI_DT_S)) + 2
    kp, ki = 0.08, 0.25  # [V s/rad], [V/rad]
    u = np.zeros(n)
    x0: Any = None
    integ = 0.0
    theta_prev = 0.0
    for k in range(n):
        sp = run.set_points[min(int(k * PI_DT_S / QUANTUM_S), len(run.set_points) - 1)]
        t0 = k * PI_DT_S
        res = simulate(truth, float(u[k - 1]) if k else 0.0, t0 + PI_DT_S, x0=x0, dt=PI_DT_S, t0=t0)
        if res.status != 0:
            raise ValueError(f"closed loop: the truth could not be simulated ({res.message})")
        theta = math.floor(float(res.theta_l[-1]) / step) * step
        speed = (theta - theta_prev) / PI_DT_S
        theta_prev = theta
        err = sp - speed
        raw = kp * err + ki * (integ + err * PI_DT_S)
        if -5.0 < raw < 5.0:
            integ += err * PI_DT_S
        u[k] = float(np.clip(kp * err + ki * integ, -5.0, 5.0))
        x0 = _continued(truth, res.final_state)
    return u


def _continued(truth: RigParams, y: np.ndarray) -> dict[str, float]:
    """The initial condition that continues a run from its final kernel state ``y``."""
    from drill_env import _layout as L

    x0 = {
        "x1": float(y[L.X1]),
        "theta_l": float(y[L.THL]),
        "x2": float(y[L.X2]),
        "x3": float(y[L.X3]),
    }
    e = truth.effects
    if e.motor_lag > 0:
        x0["motor_torque"] = float(y[L.TM])
    if e.friction_lag > 0:
        x0["memory_speed"] = max(float(y[L.WL]), 0.0)
    if e.friction_heating != 0:
        x0["thermal_state"] = max(float(y[L.TH]), 0.0)
    return x0


def record_protocol(
    truth: RigParams,
    protocol: str,
    *,
    seed: int,
    duration_s: float = 150.0,
    sample_rate_hz: float = 500.0,
    encoder_counts_per_rev: int = 2000,
    angle_noise_std: float = 0.0,
    measurement: MeasurementModel | None = None,
    preset: str | None = None,
) -> SynthResult:
    """Record ``truth`` (effects included; ``measurement``: its encoders' reading errors) on
    ``protocol``: the runs through the rig's encoders, the answer (truth parameters, effects,
    protocol) apart."""
    rng = np.random.default_rng([seed, 4242])
    runs_spec = protocol_runs(protocol, duration_s, rng)
    base = SynthConfig(
        preset=preset or "brake",
        duration_s=duration_s,
        sample_rate_hz=sample_rate_hz,
        encoder_counts_per_rev=encoder_counts_per_rev,
        angle_noise_std=angle_noise_std,
        hold_quantum_s=QUANTUM_S,
    )
    runs: list[MeasuredRun] = []
    for i, spec in enumerate(runs_spec):
        cfg = replace(base, pre_roll_s=spec.settle_s)
        name = f"run{i + 1:02d}"
        if spec.kind == "constant":
            design: Any = float(spec.voltage)
            cdt = QUANTUM_S
        elif spec.kind == "program":
            design, cdt = np.asarray(spec.levels), QUANTUM_S
        else:
            design, cdt = _closed_loop_levels(truth, spec, cfg, rng), PI_DT_S
        runs.append(
            _simulate_run(truth, design, cdt, replace(cfg, hold_quantum_s=cdt), rng, name, measurement)
        )
    answer = {
        "protocol": protocol,
        "runs": [s.label for s in runs_spec],
        "parameters": {n: float(getattr(truth, n)) for n in IDENTIFIED_PARAMETERS},
        "model_effects": dict(truth.to_dict().get("effects", {})),
        "measurement_effects": measurement.to_dict() if measurement is not None else {},
        "seed": seed,
        "design": {
            "duration_s": duration_s,
            "sample_rate_hz": sample_rate_hz,
            "encoder_counts_per_rev": encoder_counts_per_rev,
            "angle_noise_std": angle_noise_std,
        },
    }
    return SynthResult(runs=runs, truth=truth, answer=answer)
