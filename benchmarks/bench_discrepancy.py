"""Speed of the discrepancy workflow: one full run on a 10-run dataset, 150 s per run at 500 Hz.

    python benchmarks/bench_discrepancy.py [--effect position_friction_lower] [--seed 0]

Makes the dataset with the defaults of ``drill-env synth`` (7 constant-voltage runs and
3 quasi-random runs, 150 s at 500 Hz), then times ``drill-env discrepancy`` on it end
to end (loading the CSV files, equation error, candidates, bootstrap, simulations of
the nominal and corrected models, report and figures) on one core. The target is
under 2 minutes.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effect", default="position_friction_lower")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    except (AttributeError, OSError):
        pass
    from drill_env.discrepancy.workflow import run_discrepancy
    from drill_env.recordings.synth import SynthConfig, make_dataset, write_synthetic

    cfg = SynthConfig()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        syn = make_dataset(args.effect, seed=args.seed, config=cfg)
        write_synthetic(syn, tmp / "data", tmp / "answer.json", preset=cfg.preset)
        t_synth = time.perf_counter() - t
        t = time.perf_counter()
        res = run_discrepancy(tmp / "data", tmp / "out")
        t_run = time.perf_counter() - t
    n = len(syn.runs)
    print(
        f"dataset: {n} runs x {cfg.duration_s:g} s at {cfg.sample_rate_hz:g} Hz "
        f"({n * (int(cfg.duration_s * cfg.sample_rate_hz) + 1)} samples); synth + write {t_synth:.1f} s"
    )
    print(
        f"drill-env discrepancy, one core: {t_run:.1f} s "
        f"(equation error {res.timings['equation_error']:.1f} s, calibration {res.timings['calibrate']:.1f} s, decide + bootstrap {res.timings['decide']:.1f} s, "
        f"simulations {res.timings['simulate']:.1f} s); target < 120 s"
    )
    print(res.verdict_line())


if __name__ == "__main__":
    main()
