"""drill-env: the torsional stick-slip rig of Mihajlovic et al. (2004), simulated exactly.

Quick start::

    import drill_env
    res = drill_env.simulate("brake", u=2.0, t_final=300.0)
    res.to_pandas()
"""

from typing import TYPE_CHECKING

import drill_env.envs  # noqa: F401  (registers the environments when Gymnasium is imported)

if TYPE_CHECKING:  # the lazy names below, for type checkers and editors
    from drill_env.envs.sb3 import sb3_vec_env
    from drill_env.params import (
        ModelEffects,
        ParameterError,
        RigParams,
        available_presets,
        load_params,
        resolve_params,
    )
    from drill_env.precompile import precompile
    from drill_env.result import EventLog, SimulationResult
    from drill_env.simulator import simulate, simulate_batch

__version__ = "0.2.0"

# The public names, imported on first use (PEP 562): ``import drill_env`` and the command line's
# ``--help`` load neither numba nor SciPy nor torch until a name that needs them is used.
_LAZY = {
    "ModelEffects": "drill_env.params",
    "ParameterError": "drill_env.params",
    "RigParams": "drill_env.params",
    "available_presets": "drill_env.params",
    "load_params": "drill_env.params",
    "resolve_params": "drill_env.params",
    "EventLog": "drill_env.result",
    "SimulationResult": "drill_env.result",
    "simulate": "drill_env.simulator",
    "simulate_batch": "drill_env.simulator",
    "sb3_vec_env": "drill_env.envs.sb3",
    "precompile": "drill_env.precompile",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


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
