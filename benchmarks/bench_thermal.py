"""Friction heating costs nothing where it is off: trajectories and wall times of runs without it.

    python benchmarks/bench_thermal.py --save before.npz      # on the code before a change
    python benchmarks/bench_thermal.py --compare before.npz   # on the code after it

Simulates a fixed set of braked-rig runs without friction heating (the paper's model at
0.5, 2.0 and 4.0 V, and with a motor lag, a frictional lag and a friction drift at 2.0 V),
100 s each, sampled every 0.01 s, and prints the median wall time of each over
``--repeat`` runs (after warming up numba). ``--save`` writes the trajectories (all state
components the kernel had, the modes and the step statistics); ``--compare`` checks that
this code reproduces them bit for bit and prints the wall times of both. A last row
times a run with friction heating on, for scale.

Targets (with ``--compare``): every trajectory bit-identical; the summed median wall time
of the cases no more than 5 % above the reference's (wall times: run both on a quiet
machine; the load average is printed first).
"""

from __future__ import annotations

import os
import sys

for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drill_env.params import load_params  # noqa: E402
from drill_env.simulator import simulate  # noqa: E402

DURATION_S = 100.0
CASES = (
    ("paper_0.5V", {}, 0.5),
    ("paper_2.0V", {}, 2.0),
    ("paper_4.0V", {}, 4.0),
    ("motor_lag_2.0V", {"motor_lag": 0.01}, 2.0),
    ("friction_lag_2.0V", {"friction_lag": 0.1}, 2.0),
    ("friction_drift_2.0V", {"friction_drift": 1e-3}, 2.0),
)
HEATED = ("friction_heating_2.0V", {"friction_heating": 0.05, "thermal_time": 60.0}, 2.0)


def _run(effects: dict[str, float], volts: float):
    params = load_params("brake", **effects)
    return simulate(params, volts, DURATION_S, dt=0.01)


def _arrays(res) -> dict[str, np.ndarray]:
    return {
        "t": res.t,
        "x1": res.x1,
        "x2": res.x2,
        "x3": res.x3,
        "theta_l": res.theta_l,
        "motor_torque": res.motor_torque,
        "mode_u": res.mode_u,
        "mode_l": res.mode_l,
        "final_state": np.asarray(res.final_state)[:6],
        "steps": np.atleast_1d(res.stats["steps"]),
        "rhs": np.atleast_1d(res.stats["rhs_evaluations"]),
        "events": np.atleast_1d(res.stats["events"]),
    }


def _time(effects, volts, repeat: int) -> float:
    _run(effects, volts)  # warm-up (compilation)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        _run(effects, volts)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="timed runs per case (median)")
    group = ap.add_mutually_exclusive_group()
    group.add_argument("--save", type=Path, help="write the trajectories and wall times here (.npz)")
    group.add_argument("--compare", type=Path, help="compare with trajectories written by --save")
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error(f"--repeat: expected an integer >= 1, got {args.repeat}")
    ref = dict(np.load(args.compare)) if args.compare else None
    if hasattr(os, "getloadavg"):
        print(f"load average at start: {os.getloadavg()[0]:.2f}")
    out: dict[str, np.ndarray] = {}
    identical = True
    total = total_before = 0.0
    print(f"{'case':24s} {'wall [ms]':>10s} {'before [ms]':>12s}  trajectory")
    for name, effects, volts in CASES:
        arrays = _arrays(_run(effects, volts))
        wall = _time(effects, volts, args.repeat)
        for key, value in arrays.items():
            out[f"{name}/{key}"] = value
        out[f"{name}/wall"] = np.array(wall)
        verdict = ""
        before = ""
        if ref is not None:
            same = all(np.array_equal(ref[f"{name}/{k}"], v) for k, v in arrays.items())
            identical &= same
            verdict = "bit-identical" if same else "DIFFERENT"
            before = f"{1e3 * float(ref[f'{name}/wall']):12.1f}"
            total += wall
            total_before += float(ref[f"{name}/wall"])
        print(f"{name:24s} {1e3 * wall:10.1f} {before:>12s}  {verdict}")
    try:
        wall = _time(HEATED[1], HEATED[2], args.repeat)
        print(f"{HEATED[0]:24s} {1e3 * wall:10.1f} {'':>12s}  (with the effect)")
    except Exception as exc:  # the code before the effect existed cannot run it
        print(f"{HEATED[0]:24s} not available here ({type(exc).__name__})")
    if args.save:
        np.savez(args.save, **out)
    if ref is None:
        return 0
    slower = total > 1.05 * total_before
    print(f"bit-identical trajectories: {'PASS' if identical else 'FAIL'}")
    print(
        f"summed wall time {1e3 * total:.1f} ms against {1e3 * total_before:.1f} ms before "
        f"(ratio {total / total_before:.3f}, target <= 1.05): {'FAIL' if slower else 'PASS'}"
    )
    return 1 if (slower or not identical) else 0


if __name__ == "__main__":
    raise SystemExit(main())
