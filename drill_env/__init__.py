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


def __getattr__(name: str):
    # Lazy: drill_env.envs.sb3 imports Stable-Baselines3 and torch (about 1 s), not needed
    # by `import drill_env`.
    if name == "sb3_vec_env":
        from drill_env.envs.sb3 import sb3_vec_env

        return sb3_vec_env
    if name == "precompile":
        from drill_env.precompile import precompile

        return precompile
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
    "sb3_vec_env",
    "precompile",
]
