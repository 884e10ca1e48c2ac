"""Model-discrepancy workflow: where, and by which missing effect, measured data leave the model.

It reads recordings through :mod:`drill_env.recordings` (the dataset format, the equation
error, the effect library, the sensor-space comparison, synthetic recordings); its own parts:

* :mod:`~drill_env.discrepancy.calibrate` -- the recalibration of the identified parameters;
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
* :mod:`~drill_env.discrepancy.timing` -- a voltage column recorded on another clock;
* :mod:`~drill_env.discrepancy.workflow`, :mod:`~drill_env.discrepancy.report` -- the
  command's whole run and its report;
* :mod:`~drill_env.discrepancy.study` -- the hidden-effect study.

The dataset functions (:func:`load_dataset`, :func:`write_dataset`, :func:`make_dataset`, ...)
are :mod:`drill_env.recordings`' own, importable from here as well.
"""

from drill_env.discrepancy.workflow import RESULT_EFFECTS, analyse, run_discrepancy
from drill_env.recordings.dataset import (
    DatasetError,
    MeasuredDataset,
    MeasuredRun,
    load_dataset,
    write_dataset,
)
from drill_env.recordings.effects import CANDIDATES, candidate_names
from drill_env.recordings.synth import HIDDEN_EFFECTS, SynthConfig, make_dataset, write_synthetic

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
