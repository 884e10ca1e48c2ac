"""A numpy-only runner for exported MLP policies (``drill-env export-policy``): no torch, no
stable-baselines3, no Gymnasium, for a rig computer that runs Python and NumPy only.

``policy.npz`` (written beside ``policy.onnx``) holds, as arrays:

* ``scales`` (n_obs,): the observation is ``physical / scales`` (the environment's
  normalisation; ``physical`` in the SI units of the observation table);
* ``w0, b0, w1, b1, ...``: the layers, ``x = x @ w_i + b_i``, with ``activations[i]`` (``tanh``,
  ``relu`` or ``none``) after layer i;
* ``squash`` (0 or 1), ``low``, ``high``: the action is ``clip(x, low, high)`` (PPO) or
  ``low + (tanh(x) + 1)(high - low) / 2`` (SAC);
* ``action_to_volts``, ``action_offset`` (0 or 1) and ``unom_index``: the voltage asked for is
  ``action * action_to_volts``, plus the observed nominal voltage ``physical[unom_index]``
  where ``action_offset`` (the correction action of ``DrillString-v2`` and later);
* ``residual_scale`` (0 for a plain policy): for a residual policy the network is the
  correction, and the voltage is that of ``clip(base + residual_scale * correction, -1, 1)``
  with ``base`` the classical base's action (see :meth:`NumpyPolicy.combine`).

Computed in float32, as the network's own forward pass.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["NumpyPolicy"]

_ACT: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "tanh": np.tanh,
    "relu": lambda x: np.maximum(x, np.float32(0.0)),
    "none": lambda x: x,
}


class NumpyPolicy:
    """An exported policy read from its ``policy.npz``."""

    def __init__(self, path: str | Path):
        with np.load(Path(path), allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        self.scales = data["scales"].astype(np.float32)
        acts = [str(a) for a in data["activations"]]
        self.layers = [
            (data[f"w{i}"].astype(np.float32), data[f"b{i}"].astype(np.float32), _ACT[acts[i]])
            for i in range(len(acts))
        ]
        self.squash = bool(data["squash"])
        self.low = data["low"].astype(np.float32)
        self.high = data["high"].astype(np.float32)
        self.action_to_volts = float(data["action_to_volts"])
        self.action_offset = bool(data["action_offset"])
        self.unom_index = int(data["unom_index"])
        self.residual_scale = float(data["residual_scale"])
        self.n_in = self.layers[0][0].shape[0]

    def action(self, physical: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray:
        """The network's action (n, 1) for physical observations (n_obs,) or (n, n_obs);
        ``extra`` (n, k): entries appended after the scaled observation (a residual policy that
        observes its base: the base's action and feedforward, in action units)."""
        obs = np.asarray(physical, dtype=np.float32)
        x = (obs.reshape(-1, self.scales.size) / self.scales).astype(np.float32)
        if extra is not None:
            x = np.concatenate([x, np.asarray(extra, dtype=np.float32).reshape(len(x), -1)], axis=1)
        if x.shape[1] != self.n_in:
            raise ValueError(f"observation: {x.shape[1]} entries reach the network; it takes {self.n_in}")
        for w, b, act in self.layers:
            x = act(x @ w + b)
        if self.squash:
            x = self.low + np.float32(0.5) * (np.tanh(x) + np.float32(1.0)) * (self.high - self.low)
        else:
            x = np.clip(x, self.low, self.high)
        return x.astype(np.float32)

    def voltage(self, physical: np.ndarray, action: np.ndarray | None = None) -> np.ndarray:
        """The voltage asked for (n,) [V] (before the amplifier's +-5 V): of the network's
        action for a plain policy, or of ``action`` (a residual policy's combined action)."""
        obs = np.asarray(physical, dtype=np.float64).reshape(-1, self.scales.size)
        a = self.action(physical) if action is None else np.asarray(action, dtype=np.float64)
        u = np.asarray(a, dtype=np.float64).reshape(-1) * self.action_to_volts
        if self.action_offset:
            u = u + obs[:, self.unom_index]
        return u

    def combine(self, base_action: np.ndarray, correction: np.ndarray) -> np.ndarray:
        """A residual policy's action: ``clip(base + residual_scale * correction, -1, 1)``, float32."""
        if self.residual_scale <= 0:
            raise ValueError("combine: this policy is not residual (residual_scale 0)")
        a = np.asarray(base_action, dtype=np.float32) + np.float32(self.residual_scale) * np.asarray(
            correction, dtype=np.float32
        )
        return np.clip(a, -1.0, 1.0).astype(np.float32)
