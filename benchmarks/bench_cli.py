"""How long ``drill-env --help`` and every ``drill-env COMMAND --help`` take, against Python itself.

    python benchmarks/bench_cli.py [--repeat 7]

Each command line runs ``--repeat`` times as a fresh process (what a user's shell does), after
one warm-up run of each that fills the operating system's file cache; the median wall time
is printed beside the median of ``python -c pass`` (the floor any Python command pays) and
of ``python -c "import gymnasium"`` (what importing a Gymnasium env package costs), timed
the same way in the same run, and the ratio of each to ``python -c pass``.

Target: every median below 0.5 s (on a quiet machine: the figures are wall times, and the
load average is printed first). A PASS/FAIL line per target.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

TARGET_S = 0.5


def _median_wall(argv: list[str], repeat: int) -> float:
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _commands(cli: list[str]) -> list[str]:
    """The subcommands the top-level help lists."""
    text = subprocess.run([*cli, "--help"], capture_output=True, text=True, check=True).stdout
    names, inside = [], False
    for line in text.splitlines():
        if line.strip().startswith("Commands:"):
            inside = True
            continue
        if inside and line.startswith("  ") and line.strip():
            names.append(line.split()[0])
    return names


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="timed runs per command line (median)")
    args = parser.parse_args()
    if not 1 <= args.repeat <= 1000:
        parser.error(f"--repeat: {args.repeat}; allowed: 1 to 1000")
    script = shutil.which("drill-env", path=str(Path(sys.executable).parent)) or shutil.which("drill-env")
    cli = [script] if script else [sys.executable, "-m", "drill_env"]
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"command: {' '.join(cli)}; median of {args.repeat} runs each")
    floor = _median_wall([sys.executable, "-c", "pass"], args.repeat)
    gym = _median_wall([sys.executable, "-c", "import gymnasium"], args.repeat)
    print(f"{'python -c pass':<36} {floor:7.3f} s   1.0x   (baseline)")
    label = 'python -c "import gymnasium"'
    print(f"{label:<36} {gym:7.3f} s {gym / floor:5.1f}x")
    rows = [("drill-env --help", [*cli, "--help"])]
    rows += [(f"drill-env {c} --help", [*cli, c, "--help"]) for c in _commands(cli)]
    worst = 0.0
    for label, argv in rows:
        t = _median_wall(argv, args.repeat)
        worst = max(worst, t)
        print(f"{label:<36} {t:7.3f} s {t / floor:5.1f}x")
    verdict = "PASS" if worst < TARGET_S else "FAIL"
    print(
        f"slowest help {worst:.3f} s ({worst / floor:.1f}x python -c pass); target < {TARGET_S} s: {verdict}"
    )
    return 0 if verdict == "PASS" else 1


if __name__ == "__main__":
    sys.exit(main())
