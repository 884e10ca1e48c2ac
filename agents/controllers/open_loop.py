"""Open loop: the constant nominal voltage of the operating point (the paper's experiments)."""

from __future__ import annotations

import numpy as np

from drill_env.agents.controllers.base import Controller, ControllerSpec

__all__ = ["OpenLoop"]


class OpenLoop(Controller):
    """Applies the operating point's nominal voltage (observation ``nominal_voltage``) and
    ignores every measurement: the rig as in Sec. 4 of the paper, the reference against
    which suppression is measured."""

    name = "open_loop"
    state_size = 0

    def __init__(self, spec: ControllerSpec):
        super().__init__(spec)

    def control(self, y: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return y[:, self._i_unom].copy(), state
