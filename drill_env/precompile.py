"""Compile every kernel of the package into the on-disk cache, once.

With an empty cache (a fresh install, or after an upgrade: the cache is keyed by the
package's source, see :mod:`drill_env._cache`) the first simulation, the first
``gym.make(...)`` + ``reset()`` and the first vector-env step each compile their kernels.
Processes that start together on an empty cache -- the workers of SB3's
``SubprocVecEnv`` or of the benchmark's process pool -- would each compile the same
kernels at once. :func:`precompile` (``drill-env precompile``) compiles them in this
process, so that every process started afterwards loads them from the cache.
"""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["precompile"]


def precompile(progress: Callable[[str, float], None] | None = None) -> dict[str, float]:
    """Compile (or load from the cache) the simulator, the sensors, the single and the
    vector environments, the analysis (equilibria and limit cycles) and the rig's emulator and
    observer; returns the wall time [s] of each part.

    ``progress(part, seconds)`` is called after each part.
    """
    import gymnasium as gym
    import numpy as np

    import drill_env

    def simulator() -> None:
        drill_env.simulate("brake", 2.0, 0.2)
        drill_env.simulate("brake", [1.0, 2.0], 0.2, control_dt=0.1)
        drill_env.simulate_batch("brake", [1.0, 2.0], 0.2)

    def single_env() -> None:
        env = gym.make("DrillString-v3")
        env.reset(seed=0)
        env.step(np.zeros(1, dtype=np.float32))
        env.close()

    def vector_env() -> None:
        venv = gym.make_vec("DrillString-v3", num_envs=2, vectorization_mode="vector_entry_point")
        venv.reset(seed=0)
        venv.step(np.zeros((2, 1), dtype=np.float32))
        venv.close()

    def analysis() -> None:
        from drill_env.analysis import limit_cycle, slip_equilibrium
        from drill_env.analysis.equilibria import equilibrium_jacobian

        limit_cycle("brake", 2.0, settle=20.0)
        eq = slip_equilibrium("brake", 2.0)
        if eq is not None:
            equilibrium_jacobian("brake", float(eq.x3))

    def rig() -> None:
        from drill_env.envs.config import EnvSettings
        from drill_env.rig.emulator import EmulatedRig, emulated_plant
        from drill_env.rig.observer import Observer

        params, sensors = emulated_plant("brake", None)
        emulated = EmulatedRig(params, sensors)
        counts, _ = emulated.advance(50)
        Observer(EnvSettings(), 2000, 1000.0).update(1, counts[:, 0], counts[:, 1], 0.0)

    times = {}
    for name, part in (
        ("simulator", simulator),
        ("environment", single_env),
        ("vector environment", vector_env),
        ("analysis", analysis),
        ("rig", rig),
    ):
        t0 = time.perf_counter()
        part()
        times[name] = time.perf_counter() - t0
        if progress is not None:
            progress(name, times[name])
    return times
