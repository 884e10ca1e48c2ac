"""Observations from the rig's encoder counts, by the environment's own code.

The environment builds its observation in compiled code (:mod:`drill_env.envs._core`): each
sensor sample goes through :func:`drill_env.sensors.sensor_sample` (encoder reading,
backward difference, Butterworth low-pass), and at the end of a control period
:func:`drill_env.envs._core._write_obs` writes the observation from that chain's state and
the period's count differences. :class:`Observer` calls exactly those two functions on the
counts a rig reports, with the environment's configuration vectors (its observation version,
scales and bounds; its filter), so a controller sees on the rig what it saw in training,
to the bit for the same counts. Only what happens before the counts (delay, noise: the
physics of the rig) is left out of the chain here.

A count ``c`` enters the chain as the angle ``(c + 1/2) r`` (``r = 2 pi / counts_per_rev``),
which the chain's floor quantisation returns as exactly ``c r``, the reading the simulated
encoder gives for the same count.
"""

from __future__ import annotations

import math
from typing import Any

import numba as nb
import numpy as np

from drill_env._numba import JIT
from drill_env.envs._core import (
    EP_INT_QL0,
    EP_INT_TARGET,
    EP_INT_TICK0,
    EP_MEAN_L,
    EP_MEAN_U,
    EP_TARGET,
    EP_TICK,
    EP_TICK0,
    EP_U,
    EP_UNOM,
    NEP,
    NOUT,
    O_INT_CLIPPED,
    OB_LOWER_ERR_INT,
    _write_obs,
)
from drill_env.sensors import C_TS, S_QL, S_QU, SensorConfig, sensor_reset, sensor_sample, state_size

__all__ = ["Observer"]


@nb.njit(**JIT)
def _observe(ecfg, scfg, sst, ep, theta_u, theta_l, noise, y, obs, out):
    """Run the sensor chain over one control period's samples and write the observation
    (as ``_core._rig_step`` does after integrating the period)."""
    n = theta_u.shape[0]
    qu0 = sst[S_QU]
    ql0 = sst[S_QL]
    for k in range(n):
        sensor_sample(scfg, sst, theta_u[k], theta_l[k], noise, k)
    span = n * scfg[C_TS]
    ep[EP_MEAN_U] = (sst[S_QU] - qu0) / span
    ep[EP_MEAN_L] = (sst[S_QL] - ql0) / span
    _write_obs(y, ep, ecfg, scfg, sst, obs, out)


class Observer:
    """The observation of environment settings ``settings`` (an
    :class:`~drill_env.envs.config.EnvSettings`) from a rig's counts.

    ``counts_per_rev`` and ``sample_rate_hz`` are the rig's; the filter is the
    environment's (``settings.sensors``); no noise or delay is added (the rig has its own).
    """

    def __init__(self, settings: Any, counts_per_rev: int, sample_rate_hz: float):
        base = settings.sensors
        self.sensors = SensorConfig(
            counts_per_rev=int(counts_per_rev),
            sample_rate_hz=float(sample_rate_hz),
            cutoff_rad_s=base.cutoff_rad_s,
            filter_order=base.filter_order,
        )
        self.n_sub = int(settings.n_sub)
        self.ecfg = np.array(settings.ecfg, dtype=np.float64)
        self.scfg = self.sensors.as_array()
        self.sst = np.zeros(state_size(0))
        self.ep = np.zeros(NEP)
        self.obs = np.zeros(settings.n_obs, dtype=np.float32)
        self.out = np.zeros(NOUT)
        self._y = np.zeros(1)
        self._noise = np.zeros((max(self.n_sub, 1), 4))
        self.res = 2.0 * math.pi / counts_per_rev
        self.ts = self.sensors.sample_period
        self.last_counts: tuple[int, int] | None = None
        self.next_tick: int | None = None
        self.gaps = 0  # readings lost (the chain restarted across them)

    def _angles(self, counts: Any) -> np.ndarray:
        return (np.asarray(counts, dtype=np.float64) + 0.5) * self.res

    def set_point(self, target_speed: float, nominal_voltage: float) -> None:
        """The target speed [rad/s] and nominal voltage [V] the observation shows."""
        self.ep[EP_TARGET] = target_speed
        self.ep[EP_UNOM] = nominal_voltage

    def start_episode(self) -> np.ndarray:
        """The controller is switched on now: time and the integrated speed error start here.
        Returns the observation as the environment shows it at that instant (its integrated
        speed error, entry 12 of version 1, is 0 there: ``_write_obs`` gives 0 / scale)."""
        self.ep[EP_TICK0] = self.ep[EP_TICK]
        self.ep[EP_INT_TICK0] = self.ep[EP_TICK]
        self.ep[EP_INT_QL0] = self.sst[S_QL]
        self.ep[EP_INT_TARGET] = self.ep[EP_TARGET]
        if self.obs.size > OB_LOWER_ERR_INT:
            self.obs[OB_LOWER_ERR_INT] = 0.0
            self.out[O_INT_CLIPPED] = 0.0
        return self.obs.copy()

    def update(
        self, first_tick: int, counts_upper: np.ndarray, counts_lower: np.ndarray, voltage: float
    ) -> np.ndarray:
        """The observation after a block of samples (ticks ``first_tick ..``); ``voltage`` [V]
        is the voltage applied at its end. A gap since the last block (lost readings) restarts
        the chain on the mean speeds across it, and is counted in :attr:`gaps`."""
        cu = np.asarray(counts_upper, dtype=np.int64)
        cl = np.asarray(counts_lower, dtype=np.int64)
        n = cu.size
        if self.last_counts is None or first_tick != self.next_tick:
            if self.last_counts is None or self.next_tick is None:
                vu = vl = 0.0
            else:
                self.gaps += 1
                span = (first_tick - self.next_tick + 1) * self.ts
                vu = (cu[0] - self.last_counts[0]) * self.res / span
                vl = (cl[0] - self.last_counts[1]) * self.res / span
            th = self._angles([cu[0], cl[0]])
            sensor_reset(self.scfg, self.sst, th[0] - vu * self.ts, th[1] - vl * self.ts, vu, vl)
            if self.last_counts is None:
                self.ep[EP_INT_QL0] = self.sst[S_QL]
        if self._noise.shape[0] < n:
            self._noise = np.zeros((n, 4))
        self.ep[EP_TICK] = first_tick + n - 1  # the tick of the block's last sample (now)
        self.ep[EP_U] = voltage
        self.ep[EP_INT_TARGET] = self.ep[EP_TARGET]
        _observe(
            self.ecfg, self.scfg, self.sst, self.ep, self._angles(cu), self._angles(cl),
            self._noise, self._y, self.obs, self.out,
        )  # fmt: skip
        self.last_counts = (int(cu[-1]), int(cl[-1]))
        self.next_tick = first_tick + n
        return self.obs.copy()

    @property
    def lower_speed(self) -> float:
        """The filtered lower-disk speed estimate now [rad/s] (observation entry 0, in SI)."""
        from drill_env.sensors import S_VL

        return float(self.sst[S_VL])

    @property
    def lower_speed_mean(self) -> float:
        """The lower counts over the last block / its duration [rad/s]."""
        return float(self.ep[EP_MEAN_L])
