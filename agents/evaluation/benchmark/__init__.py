"""The controller benchmark: every controller over a grid of operating points and seeds.

Each run is one call of :func:`drill_env.agents.evaluation.episodes.evaluate` (the one evaluation path) with a
key (controller, preset, voltage, seed); all controllers see the same initial states and
sensor noise at the same key. Runs execute

* ``backend="process"`` (default): in a local pool of worker processes;
* ``backend="sequential"``: in this process;
* ``backend="ray"``: as Ray tasks, on a local Ray instance or a cluster (``address``; the
  package must be importable on every node), with ``pip install drill-env[ray]``;

each finished run is appended to ``DIR/benchmark.csv`` at once, so an interrupted
benchmark resumes where it stopped: runs whose key is already in the CSV (without an
error) are skipped. ``DIR/benchmark_config.json`` records the episode settings; resuming
with different ones is refused. One benchmark at a time writes into ``DIR``: it holds
``DIR/.drill-env.lock`` for the whole run (see :mod:`drill_env.outputs`), and a second one
started on the same folder stops at once with an error naming the first.

At the end the CSV is rewritten in grid order and the report is made from it:
``summary.md`` (a table per preset and regime, and the suppression at every voltage),
``bifurcation_<preset>.png`` (the bifurcation diagram of the analysis with each
controller's steady min/max of x3) and ``suppression_<preset>.png``.

The package, by what it does: :mod:`~drill_env.agents.evaluation.benchmark.grid` (the grid and its runs),
:mod:`~drill_env.agents.evaluation.benchmark.runs` (one run, in whichever process), :mod:`~drill_env.agents.evaluation.benchmark.store`
(the results file and resuming), :mod:`~drill_env.agents.evaluation.benchmark.backends` (the three ways to run
a grid), :mod:`~drill_env.agents.evaluation.benchmark.report` (``summary.md``) and
:mod:`~drill_env.agents.evaluation.benchmark.figures`. Everything is importable from ``drill_env.agents.evaluation.benchmark``.
"""

from __future__ import annotations

from drill_env.agents.evaluation.benchmark.backends import BACKENDS, run_benchmark
from drill_env.agents.evaluation.benchmark.figures import _MARKERS as _MARKERS
from drill_env.agents.evaluation.benchmark.figures import (
    FLOOR_BAND,
    Y_FLOOR,
    bifurcation_figure,
    draw_bifurcation_figure,
)
from drill_env.agents.evaluation.benchmark.figures import _draw_suppression as _draw_suppression
from drill_env.agents.evaluation.benchmark.figures import _plants_figure as _plants_figure
from drill_env.agents.evaluation.benchmark.grid import (
    FULL_GRID,
    FULL_SEEDS,
    QUICK_GRID,
    QUICK_SEEDS,
    BenchmarkConfig,
    Job,
)
from drill_env.agents.evaluation.benchmark.report import (
    REGIME_TITLES,
    REPORT_FIGURES,
    SEPARATE_PLANT_FIGURES,
    summary_tables,
    write_report,
)
from drill_env.agents.evaluation.benchmark.runs import OPEN_LOOP_FLOOR, run_job
from drill_env.agents.evaluation.benchmark.store import (
    COLUMNS,
    KEY,
    check_resumable,
    load_results,
    runs_missing,
)
from drill_env.agents.evaluation.plants import NOMINAL, Plant

__all__ = [
    "BACKENDS",
    "COLUMNS",
    "FLOOR_BAND",
    "FULL_GRID",
    "FULL_SEEDS",
    "KEY",
    "NOMINAL",
    "OPEN_LOOP_FLOOR",
    "QUICK_GRID",
    "QUICK_SEEDS",
    "REGIME_TITLES",
    "REPORT_FIGURES",
    "SEPARATE_PLANT_FIGURES",
    "Y_FLOOR",
    "BenchmarkConfig",
    "Job",
    "Plant",
    "bifurcation_figure",
    "check_resumable",
    "runs_missing",
    "draw_bifurcation_figure",
    "load_results",
    "run_benchmark",
    "run_job",
    "summary_tables",
    "write_report",
]
