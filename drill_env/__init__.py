"""drill-env: the torsional stick-slip rig of Mihajlovic et al. (2004), simulated exactly.

Quick start::

    import drill_env
    res = drill_env.simulate("brake", u=2.0, t_final=300.0)
    res.to_pandas()
"""

from drill_env import _cache

_cache.configure()  # before any compiled function is defined

import drill_env.envs  # noqa: E402, F401  (registers DrillString-v0 and DrillStringNoBrake-v0)
from drill_env.params import (  # noqa: E402
    ModelEffects,
    ParameterError,
    RigParams,
    available_presets,
    load_params,
    resolve_params,
)
from drill_env.result import EventLog, SimulationResult  # noqa: E402
from drill_env.simulator import simulate, simulate_batch  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "ModelEffects",
    "ParameterError",
    "RigParams",
    "EventLog",
    "SimulationResult",
    "available_presets",
    "load_params",
    "resolve_params",
    "simulate",
    "simulate_batch",
]
