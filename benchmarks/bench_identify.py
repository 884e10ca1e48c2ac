"""Speed of ``drill-env identify``: 10 runs x 150 s, against ``drill-env discrepancy`` on the same data.

    python benchmarks/bench_identify.py [--seed 0] [--rate 500] [--quick]

Makes a dataset on the full identification plan (``drill-env identify --plan``: 7
constant-voltage runs and 3 random-level runs, 150 s each) of a rig with every parameter
x0.5-x2 of the paper's (:func:`drill_env.identify.draw_rig`), then times, on one core and
in the same run, ``drill-env identify`` end to end (loading the CSV files, both passes of
the equation error, the joint fit, the held-out simulations, rig.yaml, identification.json,
report.md with its figures and the bifurcation diagram) and ``drill-env discrepancy`` on
the same folder (its baseline). Prints both times and their ratio; the target is
identify under 2 minutes. ``--quick``: 30 s runs, a smoke test of the script (no target).
Exit code 1 when the target is missed.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

TARGET_S = 120.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=500.0, help="sample rate [Hz]")
    ap.add_argument("--structure", default="brake", choices=("brake", "no_brake"))
    ap.add_argument("--quick", action="store_true", help="30 s runs: a smoke test, no target")
    args = ap.parse_args()
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    except (AttributeError, OSError):
        pass
    print(f"load average at the start: {os.getloadavg()[0]:.2f}", flush=True)
    from drill_env.discrepancy.workflow import run_discrepancy
    from drill_env.identify import draw_rig, identify, synth_config
    from drill_env.identify.report import write_outputs
    from drill_env.params import IDENTIFIED_PARAMETERS
    from drill_env.recordings.dataset import load_dataset
    from drill_env.recordings.synth import make_dataset, write_synthetic

    rig = draw_rig(args.structure, args.seed)
    overrides = {"duration_s": 30.0, "pre_roll_s": 30.0} if args.quick else {}
    cfg = synth_config("full", args.structure, sample_rate_hz=args.rate, angle_noise_std=0.0, **overrides)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        syn = make_dataset(
            "none",
            seed=args.seed,
            config=cfg,
            truth_overrides={n: getattr(rig, n) for n in IDENTIFIED_PARAMETERS},
        )
        write_synthetic(syn, tmp / "data", tmp / "answer.json", preset=args.structure)
        t_synth = time.perf_counter() - t
        n = len(syn.runs)
        print(
            f"dataset: {n} runs x {cfg.duration_s:g} s at {cfg.sample_rate_hz:g} Hz, rig {rig.name}; "
            f"synth + write {t_synth:.1f} s",
            flush=True,
        )
        t = time.perf_counter()
        ident = identify(load_dataset(tmp / "data"), known={"string_stiffness": rig.string_stiffness})
        write_outputs(ident, tmp / "identified")
        t_identify = time.perf_counter() - t
        print(
            f"drill-env identify, one core: {t_identify:.1f} s (equation error and fit, pass 1 "
            f"{ident.timings['pass_1']:.1f} s, pass 2 {ident.timings['pass_2']:.1f} s; held-out simulations "
            f"{ident.timings.get('heldout', 0.0):.1f} s; files, figures and bifurcation diagram "
            f"{t_identify - ident.timings['total']:.1f} s)",
            flush=True,
        )
        t = time.perf_counter()
        res = run_discrepancy(tmp / "data", tmp / "discrepancy")
        t_disc = time.perf_counter() - t
        print(f"drill-env discrepancy on the same data, one core: {t_disc:.1f} s ({res.verdict_line()})")
    ratio = t_identify / t_disc
    print(f"ratio identify / discrepancy: {ratio:.2f}")
    if args.quick:
        print("quick run: no target")
        return 0
    ok = t_identify < TARGET_S
    print(f"{'PASS' if ok else 'FAIL'}: identify {t_identify:.1f} s, target < {TARGET_S:g} s")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
