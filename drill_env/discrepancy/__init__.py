"""Model-discrepancy workflow: where, and by which missing effect, measured data leave the model.

* :mod:`~drill_env.discrepancy.dataset` -- the measured-data format, loader and writer;
* :mod:`~drill_env.discrepancy.synth` -- measured-like data from a truth model with one
  hidden effect;
* :mod:`~drill_env.discrepancy.equation_error` -- the filtered equation error and its
  noise floor;
* :mod:`~drill_env.discrepancy.effects` -- the candidate library: physical effects and the
  encoders' eccentricity (a measurement effect, :mod:`drill_env.measurement`);
* :mod:`~drill_env.discrepancy.scoring` -- per-run statistics, joint fits, held-out scores
  and the false-discovery step;
* :mod:`~drill_env.discrepancy.spectral_lines` -- lines common to the runs and what they
  are locked to;
* :mod:`~drill_env.discrepancy.parameter_selection` -- which parameters moved, and their
  intervals;
* :mod:`~drill_env.discrepancy.verdict` -- the decision rule, the bootstrap, a second effect
  (:mod:`~drill_env.discrepancy.decide` re-exports the public names);
* :mod:`~drill_env.discrepancy.sensor_effects` -- an unexplained rotation-locked line as an
  encoder's reading error (eccentricity) beside position friction;
* :mod:`~drill_env.discrepancy.compare` -- sensor-space comparison by simulation;
* :mod:`~drill_env.discrepancy.workflow`, :mod:`~drill_env.discrepancy.report` -- the
  command's whole run and its report;
* :mod:`~drill_env.discrepancy.study` -- the hidden-effect study.
"""

from drill_env.discrepancy.dataset import (
    DatasetError,
    MeasuredDataset,
    MeasuredRun,
    load_dataset,
    write_dataset,
)
from drill_env.discrepancy.effects import CANDIDATES, candidate_names
from drill_env.discrepancy.synth import HIDDEN_EFFECTS, SynthConfig, make_dataset, write_synthetic
from drill_env.discrepancy.workflow import RESULT_EFFECTS, analyse, run_discrepancy

__all__ = [
    "CANDIDATES",
    "DatasetError",
    "HIDDEN_EFFECTS",
    "MeasuredDataset",
    "MeasuredRun",
    "RESULT_EFFECTS",
    "SynthConfig",
    "analyse",
    "candidate_names",
    "load_dataset",
    "make_dataset",
    "run_discrepancy",
    "write_dataset",
    "write_synthetic",
]
