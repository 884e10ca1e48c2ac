"""The scenario suite's report: ``runs.csv`` (one row per run), ``scenarios.csv`` (mean score
per controller and scenario, and the suite score), ``summary.md`` and the figures
``scores.png`` (the per-scenario table as a heat map) and ``set_point_steps_<preset>.png``
(the lower-disk speed of the leading controllers through the set-point steps)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.agents.evaluation.scenarios import (
    REFERENCE,
    headroom,
    scenario_table,
    scenario_trajectory,
)
from drill_env.envs.scenarios import SCENARIOS
from drill_env.outputs import atomic_write_text

__all__ = ["write_report", "scores_figure", "set_point_figure"]

N_LEADERS = 3  # controllers drawn beside the open loop in the set-point figure


def _canvas(fig: Any) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)


def scores_figure(runs: Any, out: Path) -> Path:
    """``scores.png``: mean score per controller (rows, best suite score first) and scenario,
    each cell written to three decimals."""
    from matplotlib.figure import Figure

    table = scenario_table(runs)
    values = table.to_numpy(dtype=float)
    fig = Figure(figsize=(1.25 * values.shape[1] + 3.0, 0.42 * values.shape[0] + 1.8))
    _canvas(fig)
    ax = fig.add_subplot()
    im = ax.imshow(np.clip(values, -1.0, 1.0), cmap="RdYlGn", vmin=-1.0, vmax=1.0, aspect="auto")
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            v = values[i, j]
            ax.text(j, i, "-" if not np.isfinite(v) else f"{v:.3f}", ha="center", va="center", fontsize=8)
    ax.set_xticks(
        range(values.shape[1]), [c.replace("_", " ") for c in table.columns], rotation=30, ha="right"
    )
    ax.set_yticks(range(values.shape[0]), list(table.index))
    ax.set_title("scenario suite: mean score over presets and seeds (1 = perfect, 0 = open loop)")
    fig.colorbar(im, ax=ax, label="score [-]")
    fig.tight_layout()
    path = out / "scores.png"
    fig.savefig(path, dpi=110)
    return path


def set_point_figure(
    runs: Any, preset: str, out: Path, *, seed: int = 0, agents_dir: str | None = None
) -> Path | None:
    """``set_point_steps_<preset>.png``: lower-disk speed [rad/s] against time [s] through the
    set-point steps for the open loop and the :data:`N_LEADERS` best controllers by suite score,
    with the target speed; ``None`` if the runs have no set-point steps on ``preset``."""
    from matplotlib.figure import Figure

    from drill_env.agents.registry import controller_style

    sel = runs[(runs["scenario"] == "set_point_steps") & (runs["preset"] == preset)]
    if sel.empty:
        return None
    order = [c for c in scenario_table(runs).index if c != REFERENCE]
    names = [REFERENCE, *order[:N_LEADERS]]
    fig = Figure(figsize=(10.0, 4.8))
    _canvas(fig)
    ax = fig.add_subplot()
    target = None
    for name in names:
        rec = scenario_trajectory(name, "set_point_steps", preset, seed, agents_dir=agents_dir)
        st = controller_style(name)
        lw = 0.8 if name == REFERENCE else 1.3
        ax.plot(rec["t_fast"], rec["lower_speed"], color=st.colour, lw=lw, label=name)
        target = rec
    assert target is not None
    ax.step(target["t"], target["target"], where="pre", color="black", ls="--", lw=1.0, label="target speed")
    ax.set_xlabel("time since switch-on [s]")
    ax.set_ylabel("lower-disk speed x3 [rad/s]")
    volts = " -> ".join(f"{v:g} V" for v in SCENARIOS["set_point_steps"].set_point_voltages(preset))
    ax.set_title(f"set-point steps, {preset} ({volts}), seed {seed}")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    path = out / f"set_point_steps_{preset}.png"
    fig.savefig(path, dpi=110)
    return path


def _markdown(table: Any, digits: int = 3) -> str:
    cols = [str(c) for c in table.columns]
    lines = ["| controller | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for name, row in table.iterrows():
        cells = ["-" if not np.isfinite(v) else f"{v:.{digits}f}" for v in row.to_numpy(dtype=float)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def summary_text(runs: Any, meta: Mapping[str, Any]) -> str:
    """``summary.md``: what ran, the per-scenario table, the headroom and the effort."""
    table = scenario_table(runs)
    head = headroom(runs)
    failed = runs[runs["error"].fillna("") != ""]
    effort = (
        runs[runs["scenario"] == "effort"]
        .groupby("controller")[["energy_ratio", "u_rms", "u_peak_abs", "du_dt_peak", "du_dt_rms"]]
        .mean()
    )
    effort = effort.loc[[c for c in table.index if c in effort.index]]
    lines = [
        "# Scenario suite",
        "",
        f"Command: `{meta.get('command', '')}`",
        "",
        f"Controllers {len(table)}, scenarios {runs['scenario'].nunique()}, presets "
        f"{', '.join(sorted(runs['preset'].unique()))}, seeds {runs['seed'].nunique()}: {len(runs)} runs "
        f"in {meta.get('wall_time_s', float('nan')):.0f} s wall time on {meta.get('workers', 1)} worker(s) "
        f"({runs['wall_time'].sum():.0f} s of run time); code version {meta.get('version', '?')}.",
        "",
        "Score per run: `max(-1, 1 - IAE / IAE_open_loop)` (the `effort` scenario times "
        "`min(1, E_ref / E)`); a controller's scenario score is the mean over presets and seeds, "
        "its suite score the mean of its scenario scores (see `docs/explanation/scenarios.md`).",
        "",
        "## Mean score per scenario (best suite score first)",
        "",
        _markdown(table),
        "",
        "## Headroom: the best controller on each scenario (open loop left out)",
        "",
        "| scenario | best controller | best score |",
        "|---|---|---|",
        *[f"| {s} | {r.best_controller} | {r.best_score:.3f} |" for s, r in head.iterrows()],
        "",
        "## Effort on the `effort` scenario (means over presets and seeds)",
        "",
        "energy_ratio: the motor's work over the equilibrium's; u_rms [V]; u_peak_abs [V]; "
        "du_dt_peak, du_dt_rms [V/s]",
        "",
        _markdown(effort, 2) if not effort.empty else "(not run)",
        "",
    ]
    if not failed.empty:
        lines += [
            "## Failed runs (scored -1)",
            "",
            *[
                f"- {r.controller} {r.scenario} {r.preset} seed {r.seed}: {r.error}"
                for r in failed.itertuples()
            ],
            "",
        ]
    return "\n".join(lines)


def write_report(
    runs: Any, out: Path, meta: Mapping[str, Any], *, presets: Sequence[str], agents_dir: str | None = None
) -> list[Path]:
    """Write the CSVs, ``summary.md`` and the figures into ``out``; returns the paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "runs.csv", out / "scenarios.csv", out / "summary.md"]
    atomic_write_text(paths[0], runs.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(paths[1], scenario_table(runs).to_csv(float_format="%.6g"))
    atomic_write_text(paths[2], summary_text(runs, meta))
    paths.append(scores_figure(runs, out))
    for preset in presets:
        p = set_point_figure(runs, preset, out, agents_dir=agents_dir)
        if p is not None:
            paths.append(p)
    return paths
