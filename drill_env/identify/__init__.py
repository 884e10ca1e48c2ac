"""Identify every parameter of the rig model from a lab's recordings ("bring your own rig").

It reads recordings through :mod:`drill_env.recordings` (the dataset, the equation error and
its regression columns, the steady states, the sensor-space comparison); its own parts:

* :mod:`~drill_env.identify.dynamics` -- the period of the torsional cycles;
* :mod:`~drill_env.identify.joint` -- the joint fit of every parameter on the filtered
  equation error (:mod:`drill_env.recordings.equation_error`) with its intervals;
* :mod:`~drill_env.identify.identification` -- the whole identification (:func:`identify`);
* :mod:`~drill_env.identify.plan` -- the experiments that identify a rig;
* :mod:`~drill_env.identify.report` -- rig.yaml, identification.json, report.md, figures;
* :mod:`~drill_env.identify.rigs` -- rigs other than the paper's, for tests and examples.

Example::

    from drill_env.recordings import load_dataset
    from drill_env.identify import identify
    res = identify(load_dataset("my_rig/"), known={"string_stiffness": 0.081})
    res.params.to_yaml("rig.yaml"); res.parameters["lower_inertia"].ci95
"""

from drill_env.identify.identification import (
    EXCITED_PARAMETERS,
    SCALE_PARAMETERS,
    Identification,
    ParameterResult,
    identify,
    parse_known,
)
from drill_env.identify.plan import PLANS, ExperimentPlan, plan_text, synth_config
from drill_env.identify.rigs import draw_rig

__all__ = [
    "EXCITED_PARAMETERS",
    "ExperimentPlan",
    "Identification",
    "PLANS",
    "ParameterResult",
    "SCALE_PARAMETERS",
    "draw_rig",
    "identify",
    "parse_known",
    "plan_text",
    "synth_config",
]
