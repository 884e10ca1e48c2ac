"""Time series of single benchmark runs: what each controller does, over time, on every plant
of a benchmark.

:func:`timeseries_figures` writes ``timeseries_<preset>_<plant>_<group>.png``: one figure per
plant and controller group (``classical``: open loop, PIs, torque feedback, LQIs; ``learned``:
the trained policies), one row per controller with one run (voltage, seed, the benchmark's
episode settings): the lower-disk speed with its stuck phases shaded, the open-loop run on the
same plant and seed in grey, the target speed (the design model's), and the applied voltage
beside it. Speeds share one scale in a figure, voltages another. Runs go through
:func:`drill_env.agents.evaluation.episodes.run_episode`, the path every benchmark run takes,
with the controller built on the design model and run on the plant.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.agents.evaluation.episodes import EpisodeSettings, make_env, run_episode
from drill_env.agents.evaluation.plants import Plant
from drill_env.agents.registry import CLASSICAL, LEARNED, controller_style
from drill_env.outputs import save_figure

__all__ = ["GROUPS", "run_trace", "timeseries_figures"]

GROUPS = {"classical": CLASSICAL, "learned": LEARNED}  # one figure per plant and group


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
    design_params: Any = None,
    trusted: bool = False,
):
    """One closed-loop episode of ``controller`` (built on the design model ``design_params``,
    default the preset's) on ``plant``, with the 1 kHz true lower-disk samples of the whole
    episode (a ``Trajectory``)."""
    from drill_env.agents.registry import build_controller, observation_version

    version = observation_version(controller, preset, agents_dir)
    design = make_env(preset, episode, version, design_params=design_params)
    env = make_env(
        preset,
        episode,
        version,
        params=plant.rig(preset),
        overrides=plant.env_overrides(),
        design_params=design_params,
    )
    try:
        ctrl = build_controller(
            controller, design, preset, agents_dir=agents_dir, gains_file=gains_file, trusted=trusted
        )
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
    design_params: Any = None,
    progress: Any = None,
    trusted: bool = False,
) -> list[Path]:
    """``timeseries_<preset>_<plant>_<group>.png`` for each plant and controller group (see the
    module docstring). A controller that cannot be built (e.g. no trained policy) is left out
    of its figure; the error is raised only if no figure could be made. ``progress`` receives
    each written path."""
    from matplotlib.patches import Patch

    from drill_env.analysis.plots import AMPLIFIER_LIMIT_V

    episode = episode or EpisodeSettings()
    out = Path(out)
    paths: list[Path] = []
    errors: list[str] = []
    kw = {
        "agents_dir": agents_dir,
        "gains_file": gains_file,
        "design_params": design_params,
        "trusted": trusted,
    }
    for q in plants:
        open_loop = run_trace("open_loop", preset, voltage, seed, episode, q, **kw)
        for group, members in GROUPS.items():
            traces: dict[str, Any] = {}
            for c in (c for c in controllers if c in members and c != "open_loop"):
                try:
                    traces[c] = run_trace(c, preset, voltage, seed, episode, q, **kw)
                except ValueError as exc:
                    errors.append(f"{c}: {exc}")
            if not traces and not (group == "classical" and "open_loop" in controllers):
                continue
            if not traces:  # the open loop alone
                traces["open_loop"] = open_loop
            paths.append(
                _figure(Patch, AMPLIFIER_LIMIT_V, traces, open_loop, q, group, preset, voltage, seed, out)
            )
            if progress is not None:
                progress(paths[-1])
    if errors and not paths:
        raise ValueError("no time series could be made: " + "; ".join(errors))
    return paths


def _figure(Patch, u_limit, traces, open_loop, q: Plant, group, preset, voltage, seed, out: Path) -> Path:
    from matplotlib.lines import Line2D

    from drill_env._figures import subplots

    n = len(traces)
    fig, axes = subplots(
        n,
        2,
        figsize=(12, 1.9 * n + 1.6),
        sharex=True,
        sharey="col",
        squeeze=False,
        gridspec_kw={"width_ratios": [3, 1]},
    )
    t_ol = _switch_on(open_loop)
    stuck_any = False
    for i, (c, tr) in enumerate(traces.items()):
        ax, axu = axes[i]
        t0 = _switch_on(tr)
        col = controller_style(c).colour
        if c != "open_loop":
            ax.plot(open_loop.window_t - t_ol, open_loop.window_lower_speed, color="0.72", lw=0.8)
            axu.plot(open_loop.t - t_ol, open_loop.voltage, color="0.72", lw=0.8)
        for a, b in _spans(tr.window_t - t0, tr.window_lower_stuck.astype(bool)):
            ax.axvspan(a, b, color="tab:red", alpha=0.15, lw=0)
            stuck_any = True
        ax.plot(tr.window_t - t0, tr.window_lower_speed, color=col, lw=1.0)
        w = float(tr.reset_info["target_speed"])
        ax.axhline(w, color="black", lw=0.7, ls=":")
        ax.set_ylabel(f"{c}\nlower-disk speed [rad/s]", fontsize=8)
        ax.grid(alpha=0.3)
        axu.plot(tr.t - t0, tr.voltage, color=col, lw=1.0)
        axu.axhline(u_limit, color="tab:red", lw=0.6, ls="--")
        axu.set_ylabel("voltage u [V]", fontsize=8)
        axu.grid(alpha=0.3)
    axes[-1][0].set_xlabel("time since the controller was switched on [s]")
    axes[-1][1].set_xlabel("time [s]")
    lo = min(-0.2, min(float(np.min(tr.voltage)) for tr in traces.values()) - 0.3)
    axes[0][1].set_ylim(lo, u_limit + 0.4)
    handles = [
        Line2D([], [], color="0.4", lw=1.0, label="controller: lower-disk speed / voltage (colour per row)"),
        Line2D([], [], color="0.72", lw=0.8, label="open loop on the same plant and seed"),
        Line2D([], [], color="black", lw=0.7, ls=":", label="target speed w* (design model)"),
        Line2D([], [], color="tab:red", lw=0.6, ls="--", label=f"amplifier limit {u_limit:g} V"),
    ]
    if stuck_any:
        handles.append(Patch(color="tab:red", alpha=0.15, label="lower disk stuck"))
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=8, frameon=False)
    what = "the design model" if q.is_nominal else (q.description or q.source or q.name)
    fig.suptitle(
        textwrap.fill(
            f"{preset}, plant {q.name} ({what}): {group} controllers at {voltage:g} V, seed {seed}", 110
        ),
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.75 / fig.get_figheight(), 1, 1))
    p = out / f"timeseries_{preset}_{q.name}_{group}.png"
    save_figure(fig, p, dpi=100)
    return p
