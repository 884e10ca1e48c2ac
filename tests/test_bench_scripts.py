"""The speed scripts of ``benchmarks/`` run (``--quick``: a smoke test of each, not a timing)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize(
    "script",
    [
        # the training and family smoke tests train and run a benchmark grid: minutes of CPU
        pytest.param("bench_training.py", marks=pytest.mark.slow),
        "bench_vec_env.py",
        "bench_env.py",
        pytest.param("bench_family.py", marks=pytest.mark.slow),
        # two policies exported, then run by three runners on 400 observations: a minute under load
        pytest.param("bench_export.py", marks=pytest.mark.slow),
    ],
)
def test_bench_script_runs_quick(script):
    res = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), "--quick"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=900,
    )
    # exit 1 is a missed speed target (expected on a loaded test machine), not a crash
    assert res.returncode in (0, 1) and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert "ratio" in res.stdout or "target" in res.stdout, res.stdout[-2000:]
