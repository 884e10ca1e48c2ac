"""Speed of the bifurcation analysis: the whole diagram of each preset, on one core.

    python benchmarks/bench_bifurcation.py [--repeat 3] [--check] [--cold] [--json FILE]

For each case (``no_brake`` over 0-2.5 V, ``brake`` over 0-5 V) it times
:func:`drill_env.analysis.bifurcation_diagram` (equilibria, Hopf points, continuation of
the periodic orbits from every Hopf point, location of the points A-F). The first call in
the process includes loading the compiled kernels (numba's on-disk cache, or compiling
them if the cache is empty); the later calls are the steady cost. ``--cold`` points numba
at an empty cache directory, so that the first call includes compiling every kernel.
With ``--check`` the brute-force simulation check is timed as well. Target: each
diagram under 30 s.
"""

from __future__ import annotations

import os
import sys
import tempfile

if "--cold" in sys.argv:  # must precede the first import of numba
    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="numba-cold-")

# One core: numba's parallel layer and the BLAS behind NumPy run single-threaded.
for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

CASES = (("no_brake", 0.0, 2.5), ("brake", 0.0, 5.0))
TARGET_S = 30.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per case after the first")
    ap.add_argument("--check", action="store_true", help="also time the brute-force simulation check")
    ap.add_argument("--cold", action="store_true", help="compile the kernels afresh (empty numba cache)")
    ap.add_argument("--json", default=None, help="write the timings to this file")
    args = ap.parse_args()

    t0 = time.perf_counter()
    from drill_env.analysis import bifurcation_diagram, brute_force_check

    import_s = time.perf_counter() - t0
    rows = []
    for preset, u_min, u_max in CASES:
        times = []
        d = None
        for _ in range(1 + args.repeat):
            t = time.perf_counter()
            d = bifurcation_diagram(preset, u_max=u_max, u_min=u_min)
            times.append(time.perf_counter() - t)
        orbits = sum(len(b.cycles) for b in d.branches)
        flows = sum(b.flow_evaluations for b in d.branches)
        row = {
            "case": f"{preset} {u_min:g}-{u_max:g} V",
            "first_s": times[0],
            "steady_s": min(times[1:]) if args.repeat else times[0],
            "points": {k: round(v.u, 6) for k, v in d.points.items()},
            "orbits": orbits,
            "shooting_integrations": flows,
        }
        if args.check:
            t = time.perf_counter()
            check = brute_force_check(d)
            row["check_s"] = time.perf_counter() - t
            row["check_passed"] = check.passed
        rows.append(row)

    cache = "empty numba cache: first calls include compilation" if args.cold else "numba cache as found"
    print(
        f"bifurcation diagram benchmark ({platform.processor() or platform.machine()}, one thread, {cache})"
    )
    print(f"import of drill_env.analysis: {import_s:.2f} s")
    head = f"{'case':<20} {'first call [s]':>15} {'steady [s]':>11} {'orbits':>7} {'integrations':>13}"
    if args.check:
        head += f" {'check [s]':>10}"
    print(head)
    for r in rows:
        line = f"{r['case']:<20} {r['first_s']:>15.3f} {r['steady_s']:>11.3f} {r['orbits']:>7d} {r['shooting_integrations']:>13d}"
        if args.check:
            line += f" {r['check_s']:>10.2f}" + ("" if r["check_passed"] else " FAILED")
        print(line)
    for r in rows:
        print(f"  {r['case']}: points {r['points']}")
    worst = max(r["first_s"] for r in rows)
    verdict = "met" if worst < TARGET_S else "NOT met"
    print(
        f"target: each diagram under {TARGET_S:g} s on one core: {verdict} (slowest first call {worst:.2f} s)"
    )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"import_s": import_s, "cases": rows, "target_s": TARGET_S}, fh, indent=1)


if __name__ == "__main__":
    main()
