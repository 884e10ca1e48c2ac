"""Time series of single benchmark runs: what a controller does, over time, on the nominal rig
and on a plant it was not designed for.

:func:`timeseries_figures` writes ``timeseries_<preset>_<controller>.png`` per controller:
one run (voltage, seed, the benchmark's episode settings) on each plant side by side, the
lower- and upper-disk speeds with the lower disk's stuck phases shaded, the open-loop run on
the same plant and seed in grey, and the applied voltage below. Runs go through
:func:`drill_env.agents.evaluation.episodes.run_episode`, the path every benchmark run takes.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.agents.evaluation.episodes import EpisodeSettings, make_env, run_episode
from drill_env.agents.evaluation.plants import Plant
from drill_env.agents.registry import controller_style

__all__ = ["run_trace", "timeseries_figures"]


def run_trace(
    controller: str,
    preset: str,
    voltage: float,
    seed: int,
    episode: EpisodeSettings,
    plant: Plant,
    *,
    agents_dir: str | None = None,
    gains_file: str | None = None,
):
    """One closed-loop episode of ``controller`` (designed on the nominal model) on ``plant``,
    with the 1 kHz true lower-disk samples of the whole episode (a ``Trajectory``)."""
    from drill_env.agents.registry import build_controller, observation_version

    version = observation_version(controller, preset, agents_dir)
    design = make_env(preset, episode, version)
    env = make_env(preset, episode, version, params=plant.rig(preset), overrides=plant.env_overrides())
    try:
        ctrl = build_controller(controller, design, preset, agents_dir=agents_dir, gains_file=gains_file)
        n = episode.n_steps(env.unwrapped.control_dt)
        return run_episode(
            env, ctrl, seed=seed, n_steps=n, options={"nominal_voltage": float(voltage)}, window_steps=n
        )
    finally:
        env.close()
        design.close()


def _switch_on(tr) -> float:
    """The time [s] the controller was switched on (the episode's first control period)."""
    dt = float(tr.t[1] - tr.t[0]) if tr.t.size > 1 else 0.0
    return float(tr.t[0]) - dt if tr.t.size else 0.0


def _spans(t: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """Intervals of ``t`` where ``mask`` holds."""
    if not mask.any():
        return []
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m))
    return [(float(t[a]), float(t[b - 1])) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def timeseries_figures(
    controllers: Sequence[str],
    preset: str,
    voltage: float,
    plants: Sequence[Plant],
    out: str | Path,
    *,
    seed: int = 0,
    episode: EpisodeSettings | None = None,
    agents_dir: str | None = None,
    gains_file: str | None = None,
) -> list[Path]:
    """``timeseries_<preset>_<controller>.png`` for each controller (see the module docstring).
    A controller that cannot be built (e.g. no trained policy) is skipped with its reason in
    the returned list's place: the error is raised only if no figure could be made."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    from drill_env.analysis.plots import AMPLIFIER_LIMIT_V, IDENTIFIED_SPEED_RAD_S

    episode = episode or EpisodeSettings()
    out = Path(out)
    open_loop: dict[str, Any] = {}
    paths: list[Path] = []
    errors: list[str] = []
    for c in controllers:
        try:
            traces = [
                run_trace(c, preset, voltage, seed, episode, q, agents_dir=agents_dir, gains_file=gains_file)
                for q in plants
            ]
        except ValueError as exc:
            errors.append(f"{c}: {exc}")
            continue
        for q in plants:
            if q.name not in open_loop:
                open_loop[q.name] = (
                    traces[list(plants).index(q)]
                    if c == "open_loop"
                    else run_trace("open_loop", preset, voltage, seed, episode, q)
                )
        fig, axes = plt.subplots(
            2,
            len(plants),
            figsize=(6.5 * len(plants), 6),
            sharex=True,
            squeeze=False,
            gridspec_kw={"height_ratios": [2.2, 1]},
        )
        stuck_any = False
        for j, (q, tr) in enumerate(zip(plants, traces, strict=True)):
            ax, axu = axes[0][j], axes[1][j]
            t0 = _switch_on(tr)
            ol = open_loop[q.name]
            t_ol = _switch_on(ol)
            reference = c != "open_loop"  # the open-loop run drawn under the controller's
            if reference:
                ax.plot(
                    ol.window_t - t_ol,
                    ol.window_lower_speed,
                    color="0.7",
                    lw=0.8,
                    label="open loop: lower disk",
                )
            for a, b in _spans(tr.window_t - t0, tr.window_lower_stuck.astype(bool)):
                ax.axvspan(a, b, color="tab:red", alpha=0.15, lw=0)
            col = controller_style(c).colour
            ax.plot(tr.window_t - t0, tr.window_lower_speed, color=col, lw=1.0, label=f"{c}: lower disk x3")
            ax.plot(
                tr.t - t0,
                tr.true_state[:, 1],
                color=col,
                lw=0.8,
                ls="--",
                alpha=0.8,
                label=f"{c}: upper disk x2",
            )
            w = float(tr.reset_info["target_speed"])
            ax.axhline(w, color="black", lw=0.6, ls=":", label=f"target w* = {w:.2f} rad/s")
            ax.set_ylabel("disk speed [rad/s]")
            if IDENTIFIED_SPEED_RAD_S.get(preset, np.inf) < ax.get_ylim()[1]:
                w_id = IDENTIFIED_SPEED_RAD_S[preset]
                ax.axhline(
                    w_id, color="tab:brown", lw=0.8, ls=":", label=f"friction identified up to {w_id:g} rad/s"
                )
            what = "nominal model (the design model)" if q.is_nominal else (q.description or q.name)
            ax.set_title(textwrap.fill(f"plant {q.name}: {what}", 80), fontsize=9)
            ax.grid(alpha=0.3)
            stuck_any = stuck_any or bool(tr.window_lower_stuck.any())
            if reference:
                axu.plot(ol.t - t_ol, ol.voltage, color="0.7", lw=0.8, label="open loop")
            axu.plot(tr.t - t0, tr.voltage, color=col, lw=1.0, label=c)
            axu.axhline(
                AMPLIFIER_LIMIT_V,
                color="tab:red",
                lw=0.6,
                ls="--",
                label=f"amplifier limits +-{AMPLIFIER_LIMIT_V:g} V",
            )
            axu.axhline(-AMPLIFIER_LIMIT_V, color="tab:red", lw=0.6, ls="--")  # seen when u goes there
            axu.set_ylim(min(-0.2, float(np.min(tr.voltage)) - 0.4), 5.4)
            axu.set_ylabel("applied voltage u [V]")
            axu.set_xlabel("time since the controller was switched on [s]")
            axu.grid(alpha=0.3)
        # one legend for all panels, below them, so that it covers no trace
        handles, labels = [], []
        for a in (axes[0][0], axes[1][0]):
            for h, lab in zip(*a.get_legend_handles_labels(), strict=True):
                if lab not in labels:
                    handles.append(h)
                    labels.append(
                        lab if a is axes[0][0] or lab.startswith("amplifier") else f"{lab}: voltage"
                    )
        for a in axes[0][1:]:  # the identified range may be reached on another plant only
            for h, lab in zip(*a.get_legend_handles_labels(), strict=True):
                if lab not in labels:
                    handles.append(h)
                    labels.append(lab)
        if stuck_any:
            handles.append(Patch(color="tab:red", alpha=0.15))
            labels.append(f"{c}: lower disk stuck")
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
        fig.suptitle(
            f"{preset}: {c} at {voltage:g} V (seed {seed}) on each plant"
            + (", against the open loop on the same plant (grey)" if c != "open_loop" else ""),
            fontsize=10,
        )
        fig.tight_layout(rect=(0, (0.25 + 0.18 * -(-len(handles) // 4)) / fig.get_figheight(), 1, 1))
        p = out / f"timeseries_{preset}_{c}.png"
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)
    if errors and not paths:
        raise ValueError("no time series could be made: " + "; ".join(errors))
    return paths
