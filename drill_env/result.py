"""Result objects of the simulator: sampled trajectories and the switching-event log."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from drill_env import _layout as L
from drill_env.kernel import (
    ST_EVENTS,
    ST_REJECTED,
    ST_RHS,
    ST_STEPS,
    STATUS_MESSAGES,
)

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd


__all__ = ["EventLog", "SimulationResult", "CSV_COLUMNS", "MODE_NAMES"]

CSV_COLUMNS = ("t", "u", "theta_u", "theta_l", "x1", "x2", "x3", "stick_u", "stick_l")
MODE_NAMES = {-1: "slip-", 0: "stick", 1: "slip+"}
DISK_NAMES = {0: "upper", 1: "lower"}


@dataclass(frozen=True)
class EventLog:
    """Switching events in time order: which disk went from which mode to which."""

    t: np.ndarray  # [s]
    disk: np.ndarray  # 0 = upper, 1 = lower
    mode_before: np.ndarray  # -1 slip-, 0 stick, +1 slip+
    mode_after: np.ndarray
    state: np.ndarray  # kernel state at the event, (n, 6): x1, x2, x3, theta_l, Tm, w

    def __len__(self) -> int:
        return int(self.t.size)

    def kinds(self) -> list[str]:
        return [
            f"{DISK_NAMES[int(d)]} {MODE_NAMES[int(a)]}->{MODE_NAMES[int(b)]}"
            for d, a, b in zip(self.disk, self.mode_before, self.mode_after, strict=True)
        ]

    def to_pandas(self) -> pd.DataFrame:
        import pandas as pd

        return pd.DataFrame(
            {
                "t": self.t,
                "disk": [DISK_NAMES[int(d)] for d in self.disk],
                "mode_before": [MODE_NAMES[int(m)] for m in self.mode_before],
                "mode_after": [MODE_NAMES[int(m)] for m in self.mode_after],
                "x1": self.state[:, L.X1],
                "x2": self.state[:, L.X2],
                "x3": self.state[:, L.X3],
                "theta_l": self.state[:, L.THL],
            }
        )


@dataclass(frozen=True)
class SimulationResult:
    """Trajectory of the rig sampled every ``dt`` from the dense solution.

    Arrays have shape (n,) for one rig, or (n_rigs, n) from :func:`simulate_batch`.
    ``x1 = theta_u - theta_l`` (string twist) [rad], ``x2``/``x3`` upper/lower disk
    speeds [rad/s], angles [rad], ``u`` the applied voltage [V], ``stick_*`` True
    while a disk is stuck (its speed is then exactly 0). ``thermal_state`` [W] is the
    lagged power of the lower friction (effect ``friction_heating``; zero without it).
    """

    t: np.ndarray
    u: np.ndarray
    theta_u: np.ndarray
    theta_l: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    x3: np.ndarray
    stick_u: np.ndarray
    stick_l: np.ndarray
    mode_u: np.ndarray
    mode_l: np.ndarray
    motor_torque: np.ndarray
    events: EventLog | None
    params: Any
    status: int
    stats: dict[str, Any]
    final_state: np.ndarray = field(repr=False)
    final_modes: np.ndarray = field(repr=False)
    u_requested: np.ndarray | None = field(default=None, repr=False)
    thermal_state: np.ndarray | None = field(default=None, repr=False)

    @classmethod
    def from_kernel(
        cls, *, params, t, Y, M, U, events, stats, status, final_state, final_modes, u_requested
    ) -> SimulationResult:
        # Views when the kernel wrote column-major samples (simulate); copies otherwise.
        col = np.ascontiguousarray
        x1 = col(Y[..., L.X1])
        thl = col(Y[..., L.THL])
        mode_u = col(M[..., 0], dtype=np.int8)
        mode_l = col(M[..., 1], dtype=np.int8)
        st = np.atleast_2d(stats)
        return cls(
            t=t,
            u=U,
            theta_u=x1 + thl,
            theta_l=thl,
            x1=x1,
            x2=col(Y[..., L.X2]),
            x3=col(Y[..., L.X3]),
            stick_u=mode_u == 0,
            stick_l=mode_l == 0,
            mode_u=mode_u,
            mode_l=mode_l,
            motor_torque=col(Y[..., L.TM]),
            events=events,
            params=params,
            status=status,
            stats={
                "steps": st[:, ST_STEPS].astype(int).squeeze(),
                "rejected": st[:, ST_REJECTED].astype(int).squeeze(),
                "rhs_evaluations": st[:, ST_RHS].astype(int).squeeze(),
                "events": st[:, ST_EVENTS].astype(int).squeeze(),
            },
            final_state=final_state,
            final_modes=final_modes,
            u_requested=u_requested,
            thermal_state=col(Y[..., L.TH]),
        )

    # -- names from the rig -------------------------------------------------------------
    @property
    def twist(self) -> np.ndarray:
        return self.x1

    @property
    def upper_speed(self) -> np.ndarray:
        return self.x2

    @property
    def lower_speed(self) -> np.ndarray:
        return self.x3

    @property
    def success(self) -> bool:
        return self.status == 0

    @property
    def message(self) -> str:
        return STATUS_MESSAGES[self.status]

    @property
    def clipped(self) -> np.ndarray | None:
        """True where the requested voltage exceeded the limit (None without a limit)."""
        if self.u_requested is None:
            return None
        return self.u_requested != self.u

    def to_pandas(self) -> pd.DataFrame:
        """One row per sample, columns as in the CSV written by the CLI."""
        import pandas as pd

        if self.t.ndim != 1 or self.x1.ndim != 1:
            raise ValueError("to_pandas: a batched result has a rig axis; index one rig first")
        return pd.DataFrame({c: getattr(self, c) for c in CSV_COLUMNS})

    def rig(self, i: int) -> SimulationResult:
        """One rig of a batched result."""
        if self.x1.ndim != 2:
            raise ValueError("rig: this result holds one rig")
        sl = lambda a: a[i]  # noqa: E731
        return SimulationResult(
            t=self.t,
            u=sl(self.u),
            theta_u=sl(self.theta_u),
            theta_l=sl(self.theta_l),
            x1=sl(self.x1),
            x2=sl(self.x2),
            x3=sl(self.x3),
            stick_u=sl(self.stick_u),
            stick_l=sl(self.stick_l),
            mode_u=sl(self.mode_u),
            mode_l=sl(self.mode_l),
            motor_torque=sl(self.motor_torque),
            events=None,
            params=self.params[i] if isinstance(self.params, list) else self.params,
            status=int(self.status),
            stats={k: np.atleast_1d(v)[i] for k, v in self.stats.items()},
            final_state=self.final_state[i],
            final_modes=self.final_modes[i],
            thermal_state=None if self.thermal_state is None else sl(self.thermal_state),
        )

    def window(self, last: float) -> SimulationResult:
        """The samples of the last ``last`` seconds (one rig)."""
        keep = self.t >= self.t[-1] - last - 1e-9
        return _slice(self, keep)

    def plot(self, ax=None):
        """Lower- and upper-disk speeds and the twist against time (matplotlib)."""
        from drill_env._figures import user_subplots

        if ax is None:
            _, ax = user_subplots(3, 1, sharex=True, figsize=(8, 6))
        ax[0].plot(self.t, self.x3, lw=1)
        ax[0].set_ylabel("x3 = lower speed [rad/s]")
        ax[1].plot(self.t, self.x2, lw=1)
        ax[1].set_ylabel("x2 = upper speed [rad/s]")
        ax[2].plot(self.t, self.x1, lw=1)
        ax[2].set_ylabel("x1 = twist [rad]")
        ax[2].set_xlabel("t [s]")
        return ax


def _slice(res: SimulationResult, keep: np.ndarray) -> SimulationResult:
    fields_1d = (
        "u",
        "theta_u",
        "theta_l",
        "x1",
        "x2",
        "x3",
        "stick_u",
        "stick_l",
        "mode_u",
        "mode_l",
        "motor_torque",
    )
    kw = {f: getattr(res, f)[..., keep] for f in fields_1d}
    return SimulationResult(
        t=res.t[keep],
        events=res.events,
        params=res.params,
        status=res.status,
        stats=res.stats,
        final_state=res.final_state,
        final_modes=res.final_modes,
        u_requested=None if res.u_requested is None else res.u_requested[keep],
        thermal_state=None if res.thermal_state is None else res.thermal_state[..., keep],
        **kw,
    )
