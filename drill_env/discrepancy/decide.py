"""The names the discrepancy workflow's decision was first published under.

The decision is split along its parts: :mod:`~drill_env.discrepancy.scoring` (per-run
statistics, held-out scores, the false-discovery step), :mod:`~drill_env.discrepancy.spectral_lines`
(line scan and signature), :mod:`~drill_env.discrepancy.parameter_selection` (which parameters
moved and their intervals) and :mod:`~drill_env.discrepancy.verdict` (the rule and the
bootstrap). This module re-exports their public names so that ``from
drill_env.discrepancy.decide import ...`` keeps working.
"""

from drill_env.discrepancy.parameter_selection import (
    admissible_fits,
    final_parameters,
    first_calibration,
    jackknife_var,
    marginal_sd,
    moved_fit,
    recalibrated_equations,
    selection_sd,
)
from drill_env.discrepancy.scoring import (
    CalibrationSetup,
    CandidateScore,
    DecisionRule,
    JointFit,
    RunStatistics,
    run_statistics,
)
from drill_env.discrepancy.spectral_lines import LineScan, LineSignature, line_scan, line_signature
from drill_env.discrepancy.verdict import (
    NOT_AN_EFFECT,
    Decision,
    decide,
    demote,
    second_effect,
    sensor_worse,
)
from drill_env.recordings.split import split_runs

__all__ = [
    "DecisionRule",
    "RunStatistics",
    "run_statistics",
    "CandidateScore",
    "CalibrationSetup",
    "Decision",
    "JointFit",
    "NOT_AN_EFFECT",
    "decide",
    "LineSignature",
    "line_signature",
    "demote",
    "final_parameters",
    "first_calibration",
    "second_effect",
    "sensor_worse",
    "line_scan",
    "LineScan",
    "recalibrated_equations",
    "split_runs",
    "admissible_fits",
    "jackknife_var",
    "marginal_sd",
    "moved_fit",
    "selection_sd",
]
