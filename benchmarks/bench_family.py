"""Wall time of the benchmark on the standard plant family, against the same benchmark on the
nominal plant alone, timed in the same run.

Targets (on 2 cores): the quick family grid, ``drill-env benchmark --quick --plants family``
(every controller, both rigs, the quick voltages, seed 0, the 18 plants of
``agents/evaluation/plants.py``), under 3 minutes; the full family grid, ``drill-env benchmark --plants
family --seeds 3`` (every controller, the full voltage grid, 3 seeds), under 30 minutes.

Each case is ``drill-env benchmark`` as a user runs it, in a subprocess: a fresh output
folder, the process pool on every core, the summary and the figures (the quick grid's time
series included), its progress on stderr. Its wall time is measured from outside, start-up included. The baseline is
the same command without ``--plants family`` (the nominal plant only), timed in the same run.
The ratio family / nominal is printed beside the ratio of their runs (rows of
``benchmark.csv``, one per controller, operating point, seed and plant). On a perturbed plant
each operating point also needs an open-loop run for its reference amplitude (on the nominal
plant the bifurcation analysis gives it), which is work without a row of its own.

Exit code 1 when a target is missed (0 when all measured ones are met).

Run::

    python benchmarks/bench_family.py           # the quick grids, about 2.5 minutes
    python benchmarks/bench_family.py --full    # + the full grids with 3 seeds, about 20 minutes
    python benchmarks/bench_family.py --quick   # a smoke test: one controller on one rig, seconds
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

QUICK_TARGET = 180.0  # [s] the quick family grid
FULL_TARGET = 1800.0  # [s] the full family grid, 3 seeds


def run_benchmark(args: list[str], out: Path) -> tuple[float, int]:
    """Wall time [s] of ``drill-env benchmark ARGS --out OUT --fresh`` and the rows it wrote."""
    cmd = [sys.executable, "-m", "drill_env.cli", "benchmark", *args, "--out", str(out), "--fresh"]
    print("$ drill-env benchmark " + " ".join([*args, "--out", out.name, "--fresh"]), flush=True)
    t0 = time.perf_counter()
    # the benchmark's progress (stderr) shows as it runs; its closing lines (stdout) are not needed
    res = subprocess.run(cmd, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"drill-env benchmark exited with {res.returncode}")
    with open(out / "benchmark.csv", newline="") as f:
        rows = sum(1 for _ in csv.DictReader(f))
    print(f"  {rows} runs in {wall:.1f} s", flush=True)
    return wall, rows


def case(name: str, args: list[str], target: float | None, root: Path) -> bool:
    """Time ``args`` on the family and on the nominal plant; print the figures and the verdict."""
    print(f"\n{name}", flush=True)
    nominal, n_nominal = run_benchmark(args, root / f"{name}_nominal")
    family, n_family = run_benchmark([*args, "--plants", "family"], root / f"{name}_family")
    print(
        f"  family / nominal: wall time ratio {family / nominal:.1f}, runs ratio "
        f"{n_family / n_nominal:.1f}; {family / n_family * 1e3:.0f} ms per run on the family, "
        f"{nominal / n_nominal * 1e3:.0f} ms on the nominal plant (start-up included)"
    )
    if target is None:
        print("  target: none (smoke test)")
        return True
    ok = family <= target
    print(
        f"  target: family grid under {target / 60:.0f} min: {family / 60:.1f} min  {'PASS' if ok else 'FAIL'}"
    )
    return ok


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--full", action="store_true", help="also time the full grids with 3 seeds")
    ap.add_argument("--quick", action="store_true", help="smoke test: the LQI on the braked rig")
    a = ap.parse_args(argv)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"cores: {os.cpu_count()}, load average at start: {load:.2f}")
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        if a.quick:
            smoke = ["--quick", "--preset", "brake", "--controllers", "lqi", "--no-timeseries"]
            return 0 if case("smoke", smoke, None, root) else 1
        ok &= case("quick", ["--quick"], QUICK_TARGET, root)
        if a.full:
            ok &= case("full", ["--seeds", "3"], FULL_TARGET, root)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
