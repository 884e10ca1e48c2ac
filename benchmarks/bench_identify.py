"""Speed of ``drill-env identify`` with the structure search, against the base-only fit (``--no-effects``).

    python benchmarks/bench_identify.py [--seed 0] [--rate 500] [--effect motor_inductance] [--quick]

Records a rig with every parameter x0.35-x3 of the paper's (:func:`drill_env.identify.draw_rig`)
with one library effect hidden on a lab's week of runs (the ``mixed`` protocol of
:mod:`drill_env.recordings.protocols`: a staircase, slow ramps, a PRBS, a closed-loop PI run
and four constant runs, 8 runs x 150 s), then times on one core, in the same run, the
identification with the structure search (:func:`drill_env.structure_search.identify_structure`:
the base fit, the discrepancy tests on the held-out runs, the joint re-fit with each named
effect, until nothing more is named) and the base-only identification (its baseline). Prints
both times, their ratio and what the search found; the target is the structure search under
3 minutes. ``--quick``: 30 s runs, a smoke test of the script (no target). Exit code 1 when
the target is missed.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

TARGET_S = 180.0
FIELDS = {"motor_inductance": {"motor_lag": 0.025}, "string_damping": {"string_damping": 0.004}, "none": {}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=500.0, help="sample rate [Hz]")
    ap.add_argument("--structure", default="brake", choices=("brake", "no_brake"))
    ap.add_argument("--effect", default="motor_inductance", choices=sorted(FIELDS))
    ap.add_argument("--quick", action="store_true", help="30 s runs: a smoke test, no target")
    args = ap.parse_args()
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    except (AttributeError, OSError):
        pass
    print(f"load average at the start: {os.getloadavg()[0]:.2f}", flush=True)
    from drill_env.identify import draw_rig, identify
    from drill_env.recordings.dataset import MeasuredDataset
    from drill_env.recordings.protocols import record_protocol
    from drill_env.structure_search import identify_structure

    rig = draw_rig(args.structure, args.seed, low=0.35, high=3.0)
    duration = 30.0 if args.quick else 150.0
    t = time.perf_counter()
    syn = record_protocol(
        rig.replace(**FIELDS[args.effect]),
        "mixed",
        seed=args.seed,
        duration_s=duration,
        sample_rate_hz=args.rate,
        preset=args.structure,
    )
    ds = MeasuredDataset(preset=args.structure, encoder_counts_per_rev=2000, runs=tuple(syn.runs))
    print(
        f"dataset: {len(syn.runs)} runs x {duration:g} s at {args.rate:g} Hz, rig {rig.name}, hidden: "
        f"{args.effect} {FIELDS[args.effect]}; synth {time.perf_counter() - t:.1f} s",
        flush=True,
    )
    known = {"string_stiffness": rig.string_stiffness}
    t = time.perf_counter()
    base = identify(ds, known=known)
    t_base = time.perf_counter() - t
    print(f"identify --no-effects (base only), one core: {t_base:.1f} s", flush=True)
    t = time.perf_counter()
    search = identify_structure(ds, known=known)
    t_search = time.perf_counter() - t
    found = {n: e.parameters for n, e in search.identification.effects.items()}
    print(
        f"identify with the structure search, one core: {t_search:.1f} s ({len(search.rounds)} round(s); "
        f"verdict {search.verdict}; found {found}; stopped: {search.stopped})",
        flush=True,
    )
    worst = max(
        (abs(search.identification.parameters[n].value / getattr(rig, n) - 1.0), n)
        for n in ("motor_constant", "upper_inertia", "lower_inertia", "upper_static_pos", "upper_viscous_pos")
    )
    worst_base = max(
        (abs(base.parameters[n].value / getattr(rig, n) - 1.0), n)
        for n in ("motor_constant", "upper_inertia", "lower_inertia", "upper_static_pos", "upper_viscous_pos")
    )
    print(
        f"largest error of k_m, J_u, J_l, T_sup, b_up: {worst[0]:.2%} ({worst[1]}); base only {worst_base[0]:.2%} ({worst_base[1]})"
    )
    print(f"ratio structure search / base only: {t_search / t_base:.2f}")
    if args.quick:
        print("quick run: no target")
        return 0
    ok = t_search < TARGET_S
    print(
        f"{'PASS' if ok else 'FAIL'}: identify with the structure search {t_search:.1f} s, target < {TARGET_S:g} s"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
