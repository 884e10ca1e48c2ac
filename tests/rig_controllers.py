"""Controllers that misbehave, for the rig loop's tests (``run-controller tests.rig_controllers:Raising``
with ``tests/`` on the path)."""

from __future__ import annotations

import time

import numpy as np


class Raising:
    """Raises on its fourth call."""

    def __init__(self, spec):  # noqa: ANN001
        self.spec = spec
        self.calls = 0

    def predict(self, observation, state=None, episode_start=None, deterministic=True):  # noqa: ANN001, ANN201
        self.calls += 1
        if self.calls > 3 + 6:  # six calls are the rate check before the run
            raise RuntimeError("sensor value out of range")
        return np.zeros(1, dtype=np.float32), None


class Slow:
    """Takes 0.2 s per call: no period of the rig's can hold it."""

    def __init__(self, spec):  # noqa: ANN001
        self.spec = spec

    def predict(self, observation, state=None, episode_start=None, deterministic=True):  # noqa: ANN001, ANN201
        time.sleep(0.2)
        return np.zeros(1, dtype=np.float32), None


class Overrunning:
    """Fast at first (the rate check passes), then one call of 0.3 s."""

    def __init__(self, spec):  # noqa: ANN001
        self.spec = spec
        self.calls = 0

    def predict(self, observation, state=None, episode_start=None, deterministic=True):  # noqa: ANN001, ANN201
        self.calls += 1
        if self.calls == 6 + 20:
            time.sleep(0.3)
        return np.zeros(1, dtype=np.float32), None
