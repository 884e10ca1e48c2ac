"""Recordings of the rig: the measured-data layer under identification and the discrepancy workflow.

Both :mod:`drill_env.identify` (fit a rig model to a lab's recordings) and
:mod:`drill_env.discrepancy` (find where, and by which missing effect, recordings leave a
model) read measured data through this package, side by side; neither imports the other's
internals.

* :mod:`~drill_env.recordings.dataset` -- the measured-data format: reading and validating a
  dataset folder, writing one;
* :mod:`~drill_env.recordings.split` -- which runs are held out;
* :mod:`~drill_env.recordings.equation_error` -- the filtered equation error of each run and
  its noise floor;
* :mod:`~drill_env.recordings.regression` -- the regression columns of the identified
  parameters in the equation error;
* :mod:`~drill_env.recordings.effects` -- the effect library: each effect the base model
  leaves out, its regression columns and its ``effects:`` entries of a rig file;
* :mod:`~drill_env.recordings.steady_state` -- steady states of constant-voltage runs and the
  friction curves they give;
* :mod:`~drill_env.recordings.compare` -- a model against a recorded run in sensor space
  (short horizons, spectra, steady-state features);
* :mod:`~drill_env.recordings.synth` -- measured-like recordings from a truth model.

Example::

    from drill_env.recordings import load_dataset
    ds = load_dataset("my_rig/")
    [(r.name, r.duration, r.is_constant_voltage) for r in ds.runs]
"""

from drill_env.recordings.dataset import (
    DatasetError,
    MeasuredDataset,
    MeasuredRun,
    load_dataset,
    write_dataset,
)
from drill_env.recordings.effects import CANDIDATES, candidate_names
from drill_env.recordings.split import split_runs
from drill_env.recordings.synth import HIDDEN_EFFECTS, SynthConfig, make_dataset, write_synthetic

__all__ = [
    "CANDIDATES",
    "DatasetError",
    "HIDDEN_EFFECTS",
    "MeasuredDataset",
    "MeasuredRun",
    "SynthConfig",
    "candidate_names",
    "load_dataset",
    "make_dataset",
    "split_runs",
    "write_dataset",
    "write_synthetic",
]
