"""Drawing of the rig for ``render_mode="rgb_array"`` and ``"human"`` (matplotlib, imported
only when a frame is first drawn).

Left: the two disks seen from above with a mark at their angle (the upper disk larger, as
on the rig), the string between them, the voltage bar of the amplifier; the lower disk
turns red while it sticks. Right: the last 10 s of the speeds (true: lines; measured:
dots) and the target speed.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["RigRenderer"]

_WIDTH, _HEIGHT, _DPI = 640, 320, 80


class RigRenderer:
    """One matplotlib figure, redrawn in place for every frame."""

    def __init__(self, mode: str, fps: int = 20):
        if mode not in ("rgb_array", "human"):
            raise ValueError(f"mode: {mode!r} is not one of ['rgb_array', 'human']")
        self.mode = mode
        self.fps = fps
        import matplotlib

        if mode == "rgb_array":
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            self.fig = Figure(figsize=(_WIDTH / _DPI, _HEIGHT / _DPI), dpi=_DPI)
            self._agg: Any = FigureCanvasAgg(self.fig)  # the canvas rgb_array reads its pixels from
            self._plt = None
        else:
            import matplotlib.pyplot as plt

            self._plt = plt
            self._agg = None
            plt.ion()
            self.fig = plt.figure(figsize=(_WIDTH / _DPI, _HEIGHT / _DPI), dpi=_DPI)
        self._matplotlib = matplotlib
        self._build()

    def _build(self) -> None:
        from matplotlib.patches import Circle, Rectangle

        fig = self.fig
        self.ax_rig = fig.add_axes((0.01, 0.04, 0.34, 0.92))
        ax = self.ax_rig
        ax.set_xlim(-1.3, 1.3)
        ax.set_ylim(-2.6, 2.6)
        ax.set_aspect("equal")
        ax.axis("off")
        ax.plot([0, 0], [1.2, -1.2], color="0.5", lw=1.5, zorder=0)  # the string
        self.upper = Circle((0, 1.45), 0.8, fc="0.85", ec="0.2", lw=1.5)
        self.lower = Circle((0, -1.6), 0.6, fc="#d9c27a", ec="0.2", lw=1.5)  # brass disk
        ax.add_patch(self.upper)
        ax.add_patch(self.lower)
        (self.mark_u,) = ax.plot([], [], color="k", lw=2.5)
        (self.mark_l,) = ax.plot([], [], color="k", lw=2.5)
        ax.add_patch(Rectangle((1.05, -1.0), 0.15, 2.0, fc="none", ec="0.3", lw=1))
        self.vbar = Rectangle((1.05, 0.0), 0.15, 0.0, fc="tab:blue")
        ax.add_patch(self.vbar)
        self.text = ax.text(-1.25, 2.45, "", fontsize=8, va="top", family="monospace")
        self.ax_tr = fig.add_axes((0.44, 0.15, 0.54, 0.78))
        axt = self.ax_tr
        axt.set_xlabel("time [s]", fontsize=8)
        axt.set_ylabel("speed [rad/s]", fontsize=8)
        axt.tick_params(labelsize=7)
        axt.grid(alpha=0.3)
        (self.l_target,) = axt.plot([], [], color="k", ls="--", lw=1, label="target")
        (self.l_up,) = axt.plot([], [], color="tab:blue", lw=1.2, label="upper")
        (self.l_lo,) = axt.plot([], [], color="tab:red", lw=1.2, label="lower (bit)")
        (self.m_up,) = axt.plot([], [], ".", color="tab:blue", ms=2.5)
        (self.m_lo,) = axt.plot([], [], ".", color="tab:red", ms=2.5)
        axt.legend(loc="upper left", fontsize=7, ncol=3, frameon=False)

    @staticmethod
    def _mark(center: tuple[float, float], radius: float, angle: float) -> tuple[list[float], list[float]]:
        cx, cy = center
        return [cx, cx + radius * math.cos(angle)], [cy, cy + radius * math.sin(angle)]

    def draw(self, state: dict[str, Any]) -> np.ndarray | None:
        """Draw one frame; returns an (H, W, 3) uint8 array in rgb_array mode."""
        # Disks seen from above, angles counter-clockwise from the x axis.
        self.mark_u.set_data(*self._mark(self.upper.center, self.upper.radius, state["upper_angle"]))
        self.mark_l.set_data(*self._mark(self.lower.center, self.lower.radius, state["lower_angle"]))
        self.lower.set_facecolor("#e05050" if state["lower_stuck"] else "#d9c27a")
        v = float(state["voltage"])
        self.vbar.set_y(min(0.0, v / 5.0))
        self.vbar.set_height(abs(v) / 5.0)
        regime = state.get("regime") or ""
        self.text.set_text(f"{state.get('params_name', '')} {regime}\nu = {v:+.2f} V")
        h = state["history"]
        if h.shape[0]:
            t = h[:, 0]
            self.l_up.set_data(t, h[:, 1])
            self.l_lo.set_data(t, h[:, 2])
            self.m_up.set_data(t, h[:, 3])
            self.m_lo.set_data(t, h[:, 4])
            self.l_target.set_data(t, h[:, 5])
            t1 = max(10.0, float(t[-1]))
            self.ax_tr.set_xlim(t1 - 10.0, t1)
            finite = h[:, 1:6][np.isfinite(h[:, 1:6])]
            lo = min(0.0, float(finite.min())) if finite.size else 0.0
            hi = max(1.0, float(finite.max())) if finite.size else 1.0
            pad = 0.08 * (hi - lo)
            self.ax_tr.set_ylim(lo - pad, hi + pad)
        if self.mode == "rgb_array":
            self._agg.draw()
            buf = np.asarray(self._agg.buffer_rgba())
            return buf[:, :, :3].copy()
        self.fig.canvas.draw_idle()
        assert self._plt is not None  # human mode
        self._plt.pause(1.0 / self.fps)
        return None

    def close(self) -> None:
        if self._plt is not None:
            self._plt.close(self.fig)  # the renderer is dropped after this (DrillStringEnv.close)
