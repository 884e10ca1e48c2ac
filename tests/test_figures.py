"""The figures say what they show: a legend entry for every line and marker style, the
rig's limits where a diagram reaches them, labels clear of the data, every benchmark
marker at its run's voltage."""

from __future__ import annotations

import json
import math

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from doc_sources import doc_sources

from drill_env._figures import renderer as figure_renderer
from drill_env.analysis import bifurcation_diagram
from drill_env.analysis.plots import (
    AMPLIFIER_LIMIT_V,
    IDENTIFIED_SPEED_RAD_S,
    Label,
    place_labels,
    plot_bifurcation,
    plot_equilibria,
    plot_period,
)
from drill_env.analysis.sweep import SweepRun


@pytest.fixture(scope="module")
def brake():
    return bifurcation_diagram("brake", u_max=5.0)


@pytest.fixture(scope="module")
def no_brake():
    return bifurcation_diagram("no_brake", u_max=2.5)


class _Check:
    """Stand-in for a brute-force check: runs on the diagram's own curves (where the real
    simulations land), every way of starting one."""

    def __init__(self, diagram, n: int = 40):
        self.runs = []
        kinds = ("small", "large", "forward", "backward")
        for i, u in enumerate(np.linspace(diagram.u_min, diagram.u_max, n + 2)[1:-1]):
            cycles = diagram.stable_cycles_at(u)
            if cycles:
                lo, hi = cycles[0].x3_min, cycles[0].x3_max
            else:
                from drill_env.analysis.equilibria import equilibria

                lo = hi = float(equilibria(diagram.params, u)[0].x3)
            self.runs.append(
                SweepRun(
                    u=float(u),
                    kind=kinds[i % 4],
                    x3_min=lo,
                    x3_max=hi,
                    x3_mean=lo,
                    period=math.nan,
                    stick_fraction=0.0,
                )
            )


def _vertical_at(ax, x: float) -> bool:
    return any(
        len(line.get_xdata()) == 2 and np.allclose(np.asarray(line.get_xdata(), float), x)
        for line in ax.get_lines()
    )


def _horizontal_at(ax, y: float) -> bool:
    return any(
        len(line.get_ydata()) == 2 and np.allclose(np.asarray(line.get_ydata(), float), y)
        for line in ax.get_lines()
    )


def _legend_texts(ax) -> list[str]:
    """The entries of the legend of ``ax``, or of its figure's (a figure of its own has one
    legend, below its axes)."""
    legends = [ax.get_legend()] if ax.get_legend() else list(ax.figure.legends)
    return [t.get_text() for leg in legends for t in leg.get_texts()]


def test_the_limits_are_those_of_the_rest_of_the_package():
    from drill_env.agents.evaluation.episodes import IDENTIFIED_SPEED
    from drill_env.envs.task import VOLTAGE_LIMIT

    assert AMPLIFIER_LIMIT_V == VOLTAGE_LIMIT
    assert IDENTIFIED_SPEED_RAD_S == IDENTIFIED_SPEED


def test_the_brake_diagram_draws_the_amplifier_limit_and_the_identified_range(brake):
    ax = plot_bifurcation(brake, check=_Check(brake))
    # the stable cycle of the braked rig reaches 18.7 rad/s at 5 V: past the identified 12.6
    assert max(c.x3_max for s in brake.periodic_segments for c in s.cycles) > 12.6
    assert _vertical_at(ax, 5.0) and _horizontal_at(ax, 12.6)
    assert ax.get_xlim()[1] > 5.0  # the limit's line is not under the frame
    texts = _legend_texts(ax)
    assert any("amplifier limit 5 V" in t for t in texts)
    assert any("12.6 rad/s" in t for t in texts)
    # every line style drawn and every way a simulation was started is in the legend
    for entry in (
        "equilibrium, stable",
        "equilibrium, unstable",
        "started near the equilibrium",
        "started with the lower disk at rest",
        "sweep of u upwards",
        "sweep of u downwards",
    ):
        assert entry in texts, entry
    assert any(t.startswith("periodic orbit") and t.endswith("stable") for t in texts)
    assert any("A: start of motion" in t and "D: stick-slip begins" in t for t in texts)
    assert "E: stick-slip ends" not in " ".join(texts)  # E lies beyond 5 V with the brake
    plt.close(ax.figure)

    a, b = plot_equilibria(brake)
    # the equilibrium speed stays below 12.6 rad/s up to 5 V: only the voltage limit there
    assert _vertical_at(a, 5.0) and _vertical_at(b, 5.0) and not _horizontal_at(b, 12.6)
    plt.close(a.figure)
    ax = plot_period(brake)
    assert _vertical_at(ax, 5.0)
    plt.close(ax.figure)


def test_a_diagram_short_of_the_limits_does_not_draw_them(no_brake):
    ax = plot_bifurcation(no_brake)
    assert not _vertical_at(ax, 5.0) and not _horizontal_at(ax, 12.6)
    assert ax.get_xlim() == (0.0, 2.5)
    assert ax.get_xlabel() == "u = amplifier input [V]" and "[rad/s]" in ax.get_ylabel()
    plt.close(ax.figure)


def test_the_extended_brake_diagram_draws_both_limits_and_shades_the_model_only_range():
    d = bifurcation_diagram("brake", u_max=16.0)
    fig_ax = plot_bifurcation(d)
    assert _vertical_at(fig_ax, AMPLIFIER_LIMIT_V) and _horizontal_at(fig_ax, 12.6)
    assert any("beyond: model only" in t for t in _legend_texts(fig_ax))
    from matplotlib.patches import Rectangle

    spans = [p for p in fig_ax.patches if isinstance(p, Rectangle)]
    assert any(np.isclose(p.get_x(), 5.0) and np.isclose(p.get_x() + p.get_width(), 16.0) for p in spans)
    plt.close(fig_ax.figure)


def _boxes(ax):
    r = figure_renderer(ax.figure)
    return [t.get_window_extent(r) for t in ax.texts]


def test_labels_cover_no_marker_and_no_other_label(no_brake):
    ax = plot_bifurcation(no_brake, check=_Check(no_brake))
    ax.figure.canvas.draw()
    boxes = _boxes(ax)
    names = {t.get_text() for t in ax.texts}
    assert {"A", "B", "C", "D", "E", "F", "e1", "e2", "e3", "e4", "p1", "p2", "p3", "p4"} <= names
    centres = []
    for line in ax.get_lines():
        if line.get_marker() not in ("None", "", " ", None):
            centres.append(ax.transData.transform(np.column_stack(line.get_data()).astype(float)))
    centres = np.concatenate(centres)
    for t, b in zip(ax.texts, boxes, strict=True):
        inside = (
            (centres[:, 0] > b.x0) & (centres[:, 0] < b.x1) & (centres[:, 1] > b.y0) & (centres[:, 1] < b.y1)
        )
        assert not inside.any(), f"label {t.get_text()!r} covers a marker"
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            assert not boxes[i].overlaps(boxes[j]), (ax.texts[i].get_text(), ax.texts[j].get_text())
    ax_box = ax.get_window_extent()
    assert all(
        ax_box.x0 <= b.x0 and b.x1 <= ax_box.x1 and ax_box.y0 <= b.y0 and b.y1 <= ax_box.y1 for b in boxes
    )
    plt.close(ax.figure)


def test_place_labels_moves_a_label_off_the_line_it_names():
    fig, ax = plt.subplots(figsize=(4, 3))
    x = np.linspace(0, 1, 200)
    ax.plot(x, x, "-")  # the naive up-right offset sits on this line's continuation
    ax.plot(x[::10], x[::10] + 0.05, "o")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    fig.canvas.draw()
    (txt,) = place_labels(ax, [Label("p1", 0.5, 0.5)])
    fig.canvas.draw()
    b = txt.get_window_extent()
    pts = ax.transData.transform(
        np.column_stack([np.concatenate([x, x[::10]]), np.concatenate([x, x[::10] + 0.05])])
    )
    assert not ((pts[:, 0] > b.x0) & (pts[:, 0] < b.x1) & (pts[:, 1] > b.y0) & (pts[:, 1] < b.y1)).any()
    plt.close(fig)


# -- benchmark figures ---------------------------------------------------------------------------


def _frame(preset: str, voltages, controllers=("open_loop", "lqi", "pi_lower")) -> pd.DataFrame:
    rows = []
    for c in controllers:
        for k, u in enumerate(voltages):
            for seed in (0, 1):
                amp = 0.0 if c == "lqi" else 2.0 + 0.1 * k
                lo = 0.5 * u
                hi = lo + amp
                if c == "pi_lower" and u >= 2.0:  # far beyond the diagram's scale
                    lo, hi = -60.0 - k, 60.0 + k
                ol = 2.0 + 0.1 * k if u > 0.7 else 0.0
                rows.append(
                    {
                        "controller": c,
                        "preset": preset,
                        "plant": "nominal",
                        "voltage": u,
                        "seed": seed,
                        "regime": "stick_slip" if u > 0.7 else "equilibrium",
                        "x3_min": lo,
                        "x3_max": hi,
                        "open_loop_amplitude": ol,
                        "suppression": (1.0 - (hi - lo) / ol) if ol > 0 else math.nan,
                        "stick_fraction": 0.0,
                        "rms_error": 0.01 * (k + 1),
                        "error": "",
                    }
                )
    return pd.DataFrame(rows)


def test_benchmark_markers_sit_at_their_runs_voltage_and_off_scale_runs_are_noted(brake):
    from drill_env.agents.evaluation.benchmark import _MARKERS, draw_bifurcation_figure
    from drill_env.agents.evaluation.robustness import COLORS

    volts = (0.3, 0.55, 1.0, 2.0, 5.0)
    df = _frame("brake", volts)
    fig = draw_bifurcation_figure(df, "brake", diagram=brake)
    panels = {ax.get_title().split("\n")[0]: ax for ax in fig.axes if ax.axison}
    assert set(panels) == {"open_loop", "lqi", "pi_lower"}
    for c, ax in panels.items():
        assert _vertical_at(ax, 5.0) and _horizontal_at(ax, 12.6), c
        xs = np.concatenate(
            [
                np.asarray(line.get_xdata(), float)
                for line in ax.get_lines()
                if line.get_color() == COLORS[c] and line.get_marker() == _MARKERS[c]
            ]
        )
        assert xs.size and set(np.round(xs, 12)) <= set(volts), c  # no horizontal dodge
        for coll in ax.collections:  # the bars between min and max
            for path in coll.get_paths():
                if len(path.vertices) == 2 and np.isclose(path.vertices[0, 0], path.vertices[1, 0]):
                    assert np.round(path.vertices[0, 0], 12) in volts
    ax = panels["pi_lower"]
    y_lo, y_hi = ax.get_ylim()
    title = ax.get_title()
    # 2 V and 5 V, two seeds each: beyond the scale, written in the margin, not drawn across
    assert "4 runs off scale (2-5 V)" in title and "x3 -64.0 to 64.0 rad/s" in title
    edges = [line for line in ax.get_lines() if not line.get_clip_on()]  # on the frame
    assert {float(y) for line in edges for y in line.get_ydata()} == {y_lo, y_hi}
    for coll in ax.collections:
        for path in coll.get_paths():
            assert np.ptp(path.vertices[:, 1]) < y_hi - y_lo  # no bar across the whole panel
    assert "off scale" not in panels["lqi"].get_title()
    plt.close(fig)


def test_suppression_markers_sit_at_their_voltage_and_floored_values_are_readable():
    from drill_env.agents.evaluation.benchmark import FLOOR_BAND, Y_FLOOR, _draw_suppression

    volts = (0.55, 0.7, 1.0, 2.0, 5.0)
    df = _frame("no_brake", volts)
    fig, ax = plt.subplots()
    _draw_suppression(ax, df, "no_brake", ["open_loop", "lqi", "pi_lower"])
    with_cycle = {u for u in volts if u > 0.7}
    for line in ax.get_lines():
        if line.get_marker() not in ("None", "", " ", None) and len(line.get_xdata()) > 2:
            assert set(np.round(np.asarray(line.get_xdata(), float), 12)) <= with_cycle
    texts = [t for t in ax.texts if t.get_text()]
    # pi_lower at 2 V and 5 V: suppression 1 - 124 / 2.5 etc. below the floor, each written once
    assert len(texts) == 2
    assert all(t.get_text().startswith("-") and float(t.get_text()) < Y_FLOOR for t in texts)
    assert all(t.xy[1] < Y_FLOOR for t in texts)  # in the band under the floor, clear of lines
    assert ax.get_ylim()[0] == pytest.approx(Y_FLOOR - FLOOR_BAND)
    assert _vertical_at(ax, 5.0)  # where the amplifier leaves no headroom
    plt.close(fig)


def test_robustness_and_plant_figures_run_on_a_small_frame(tmp_path):
    from drill_env.agents.evaluation.benchmark import _plants_figure
    from drill_env.agents.evaluation.robustness import robustness_figure

    a = _frame("brake", (0.5, 1.0, 2.0))
    b = a.assign(plant="km_x1.05", rms_error=a["rms_error"] * 2)
    df = pd.concat([a, b], ignore_index=True)
    p = robustness_figure(df, "brake", tmp_path)
    q = _plants_figure(df, "brake", tmp_path, ["km_x1.05"])
    assert p.stat().st_size > 20_000 and q.stat().st_size > 10_000


def test_the_library_never_sets_the_matplotlib_backend():
    """No ``matplotlib.use`` in the package (a notebook's inline plots would stop after any call
    that saves a figure); the figures it saves are drawn with the object-oriented API. The
    backend of the whole test run is checked after every test (conftest.py)."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    calls = []
    for folder in ("drill_env", "agents", "benchmarks"):
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if (
                    isinstance(node, ast.Call)
                    and isinstance(node.func, ast.Attribute)
                    and node.func.attr == "use"
                ):
                    owner = node.func.value
                    if isinstance(owner, ast.Name) and owner.id in {"matplotlib", "mpl"}:
                        calls.append(f"{path.relative_to(root)}:{node.lineno}")
    assert calls == []


def test_a_saved_figure_leaves_pyplot_alone(tmp_path, no_brake):
    """Saving the paper's figures opens no pyplot figure (none to close, none shown)."""
    from drill_env.analysis.plots import save_figures

    diagram = no_brake
    before = plt.get_fignums()
    paths = save_figures(diagram, tmp_path)
    assert plt.get_fignums() == before
    assert [p.name for p in paths] == [
        "fig6_equilibria.png",
        "fig8_bifurcation.png",
        "period.png",
        "fig9_limit_cycles.png",
    ]
    assert all(p.stat().st_size > 10_000 for p in paths)


# -- legible at the docs' width ---------------------------------------------------------------


@pytest.fixture
def saved_figures(monkeypatch):
    """Every matplotlib figure saved while the test runs (saved as usual)."""
    from matplotlib.figure import Figure

    figures = []
    original = Figure.savefig

    def record(self, *args, **kwargs):
        figures.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", record)
    return figures


def test_the_size_rule_catches_wide_figures_small_text_and_overlapping_ticks():
    from drill_env._figures import legibility_problems, shown_points, subplots

    fig, ax = subplots(figsize=(17, 4))  # the old benchmark grid's width
    ax.plot([0, 1], [0, 1])
    problems = legibility_problems(fig)
    assert "width 17 in > 10 in" in problems
    assert any("shows at 4.4 pt < 8 pt" in p for p in problems)  # 10 pt * 724 / (96 * 17)
    assert shown_points(fig, 10.0) == pytest.approx(10 * 724 / (96 * 17))
    fig, ax = subplots(figsize=(4, 3))
    ax.set_xticks([0, 0.005, 0.01, 0.015, 0.02], ["a long label", "another long label", "x", "y", "z"])
    ax.set_xlim(0, 0.02)
    for t in ax.get_xticklabels() + ax.get_yticklabels():
        t.set_fontsize(9)
    assert legibility_problems(fig) == ["x tick labels 'a long label' and 'another long label' overlap"]
    fig, ax = subplots(figsize=(8, 3))
    ax.tick_params(labelsize=9)
    assert legibility_problems(fig) == []


@pytest.mark.parametrize("n_controllers", [3, 13])
def test_the_benchmark_figures_are_legible_at_the_docs_width(tmp_path, brake, saved_figures, n_controllers):
    from drill_env._figures import legibility_problems
    from drill_env.agents.evaluation.benchmark import figures as bf
    from drill_env.agents.evaluation.benchmark.ranking import benchmark_rankings, ranking_figure
    from drill_env.agents.evaluation.robustness import ordered_controllers, robustness_figure
    from drill_env.agents.registry import CONTROLLERS

    ctrls = ("open_loop", "lqi", "pi_lower") if n_controllers == 3 else CONTROLLERS
    assert len(ctrls) == n_controllers
    volts = (0.3, 0.55, 1.0, 2.0, 5.0)
    df = _frame("brake", volts, ctrls)
    fam = pd.concat(
        [df, df.assign(plant="km_x1.05", suppression=df["suppression"] - 0.01)], ignore_index=True
    )
    fig = bf.draw_bifurcation_figure(df, "brake", diagram=brake)
    assert legibility_problems(fig) == []
    names = ordered_controllers(df["controller"])
    bf._suppression_figure(df, "brake", tmp_path, "nominal", names)
    bf._plants_figure(fam, "brake", tmp_path, ["km_x1.05"])
    bf.worst_case_figure(fam, "brake", tmp_path)
    robustness_figure(fam, "brake", tmp_path)
    for key, title, st in benchmark_rankings(df):
        ranking_figure(st, title, tmp_path / f"ranking_{key}.png")
    assert len(saved_figures) >= 5
    for f in saved_figures:
        assert legibility_problems(f) == [], f.get_suptitle() or f.axes[0].get_title()
    plt.close("all")


def test_the_suite_figures_are_legible_at_the_docs_width(tmp_path, saved_figures):
    from drill_env._figures import legibility_problems
    from drill_env.agents.evaluation.benchmark.ranking import ranking_figure
    from drill_env.agents.evaluation.scenario_report import scores_figure, suite_rankings
    from drill_env.agents.registry import CONTROLLERS
    from drill_env.envs.scenarios import SCENARIO_NAMES

    rng = np.random.default_rng(0)
    runs = pd.DataFrame(
        [
            {"controller": c, "scenario": s, "preset": p, "seed": k, "score": rng.uniform(-1, 1), "error": ""}
            for c in CONTROLLERS
            for s in SCENARIO_NAMES
            for p in ("brake", "no_brake")
            for k in range(2)
        ]
    )
    scores_figure(runs, tmp_path)
    key, title, st = suite_rankings(runs)[0]
    ranking_figure(st, title, tmp_path / f"ranking_{key}.png")
    assert len(saved_figures) == 2
    for f in saved_figures:
        assert legibility_problems(f) == []


@pytest.mark.parametrize("gains", [(-2e4, 3e5), (-50.0, 2e2), (0.5, 1e9)])
def test_the_gain_axis_decades_stay_apart(gains):
    from drill_env._figures import legibility_problems, subplots
    from drill_env.discrepancy.report import _decade_ticks

    fig, ax = subplots(figsize=(7, 3))
    ax.barh(["a", "b", "c"], [gains[0], 1.0, gains[1]])
    ax.set_xscale("symlog", linthresh=1.0)
    _decade_ticks(ax.xaxis, ax.get_xlim())
    ax.tick_params(labelsize=9)
    ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
    assert 0.0 in ticks and max(ticks) >= 10 ** np.floor(np.log10(gains[1]))  # the largest decade kept
    assert len(ticks) <= 7
    assert legibility_problems(fig) == []


def test_the_discrepancy_reports_gain_and_equation_error_figures_are_legible(tmp_path, saved_figures):
    from drill_env._figures import legibility_problems
    from drill_env.discrepancy.report import _figures
    from drill_env.discrepancy.scoring import DecisionRule
    from drill_env.discrepancy.workflow import analyse
    from drill_env.recordings.dataset import MeasuredDataset
    from drill_env.recordings.synth import SynthConfig, make_dataset

    cfg = SynthConfig(
        voltages=(0.2, 0.5, 1.0, 2.0, 3.0),
        random_runs=3,
        duration_s=40.0,
        pre_roll_s=20.0,
        angle_noise_std=0.0,
    )  # ten runs as the identification plan's, labelled like its (varying -5-5 V)
    syn = make_dataset("position_friction_lower", seed=5, magnitude=0.12, config=cfg)
    ds = MeasuredDataset(
        preset="brake", encoder_counts_per_rev=cfg.encoder_counts_per_rev, runs=tuple(syn.runs)
    )
    res = analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=20))
    names = [name for name, _ in _figures(res, tmp_path)]
    assert {"candidates.png", "equation_error.png"} <= set(names)  # held-out spectra: the sim-to-real test
    assert len(saved_figures) == len(names)
    for fig in saved_figures:  # every figure of the report
        assert legibility_problems(fig) == [], fig.get_suptitle() or fig.axes[0].get_title()


# -- every figure the docs show: legible at the width they are drawn -----------------------


@pytest.mark.parametrize("kind", ["fig6", "fig8", "period", "fig9"])
def test_the_bifurcation_figures_are_legible_at_the_docs_width(
    kind, brake, no_brake, saved_figures, tmp_path
):
    from drill_env._figures import legibility_problems, offscreen
    from drill_env.analysis.plots import save_figures

    for diagram in (brake, no_brake):
        with offscreen():
            ax = diagram.plot(kind, **({"check": _Check(diagram)} if kind == "fig8" else {}))
        fig = (ax[0] if isinstance(ax, np.ndarray | list | tuple) else ax).figure
        assert legibility_problems(fig) == [], (diagram.preset, kind)
        if kind == "fig6":
            assert len(fig.legends) == 1 and not any(a.get_legend() for a in fig.axes)  # one legend
        if kind == "fig9":  # the projections' units, the legend in the grid's fourth cell
            assert [a.get_xlabel() for a in ax] == [
                "x1 = twist [rad]",
                "x1 = twist [rad]",
                "x2 = upper speed [rad/s]",
            ]
            assert ax.legend_axes.get_legend() is not None and not ax.legend_axes.axison
    save_figures(no_brake, tmp_path)  # what `drill-env bifurcation` writes
    assert len(saved_figures) == 4
    for f in saved_figures:
        assert legibility_problems(f) == [], f.get_suptitle() or f.axes[0].get_title()


def test_the_extended_diagram_with_its_enlarged_view_is_legible():
    from drill_env._figures import legibility_problems, offscreen

    diagram = bifurcation_diagram("brake", u_max=16.0)
    with offscreen():
        ax = diagram.plot("fig8")
    assert ax.child_axes  # the enlarged view of the start of motion
    assert legibility_problems(ax.figure) == []


def test_the_sim_to_real_suppression_figure_is_legible_on_the_committed_results(tmp_path, saved_figures):
    from pathlib import Path

    from drill_env._figures import legibility_problems
    from drill_env.agents.evaluation.sim_to_real import SimToRealConfig, _suppression_figure

    df = pd.read_csv(Path(__file__).parents[1] / "results" / "sim_to_real" / "results.csv")
    ctrls = tuple(c for c in dict.fromkeys(df["controller"]) if c != "open_loop")
    assert len(ctrls) >= 3
    cfg = SimToRealConfig(controllers=ctrls, seeds=tuple(sorted(set(df["seed"]))))
    _suppression_figure(df, cfg, tmp_path)
    (fig,) = saved_figures
    assert legibility_problems(fig) == []
    assert len(fig.legends) == 1
    assert [ax.get_title(loc="left") for ax in fig.axes[::2]] == list(ctrls)  # a row per controller


@pytest.mark.slow
def test_the_sim_to_real_figures_are_legible(tmp_path, saved_figures):
    from typer.testing import CliRunner

    from drill_env._figures import legibility_problems
    from drill_env.cli import app

    r = CliRunner().invoke(app, ["sim-to-real", "--quick", "--out", str(tmp_path / "s2r")])
    assert r.exit_code == 0, r.output
    names = {p.name for p in (tmp_path / "s2r").rglob("*.png")}
    assert {"suppression.png", "spectra.png", "residual_spectra.png"} <= names
    assert any(n.startswith("timeseries_") for n in names)
    assert len(saved_figures) >= len(names)
    for f in saved_figures:
        assert legibility_problems(f) == [], f.get_suptitle() or f.axes[0].get_title()


@pytest.mark.slow
def test_the_identification_reports_figures_are_legible(tmp_path, saved_figures):
    from typer.testing import CliRunner

    from drill_env._figures import legibility_problems
    from drill_env.cli import app
    from drill_env.identify import ExperimentPlan, draw_rig, synth_config
    from drill_env.params import IDENTIFIED_PARAMETERS
    from drill_env.recordings.synth import make_dataset, write_synthetic

    plan = ExperimentPlan(
        "small", (0.1, 0.3, 0.8, 2.0, 4.0), 2, (-5.0, 5.0), (0.5, 2.0), 40.0, 30.0, (250.0, 1000.0)
    )
    rig = draw_rig("brake", 7)
    cfg = synth_config(plan, "brake", sample_rate_hz=500.0, angle_noise_std=0.0)
    res = make_dataset(
        "none", seed=7, config=cfg, truth_overrides={n: float(getattr(rig, n)) for n in IDENTIFIED_PARAMETERS}
    )
    write_synthetic(res, tmp_path / "data", tmp_path / "answer.json", preset="brake")
    out = tmp_path / "id"
    args = ["identify", str(tmp_path / "data"), "--out", str(out), "--no-effects"]
    r = CliRunner().invoke(app, [*args, "--known", f"string_stiffness={rig.string_stiffness!r}"])
    assert r.exit_code == 0, r.output
    assert {p.name for p in out.glob("*.png")} == {"friction.png", "heldout.png", "bifurcation.png"}
    assert len(saved_figures) == 3
    for f in saved_figures:
        assert legibility_problems(f) == [], f.axes[0].get_title()
        assert len(f.legends) + sum(a.get_legend() is not None for a in f.axes) >= 1


def test_a_resume_with_every_run_present_redraws_without_the_policies(tmp_path):
    """The records of recipes not kept (results/robust_rl/distilled_brake) name an agents folder
    that is not in the checkout: their figures are redrawn from the rows all the same, and a
    resume with a run missing still needs the folder."""
    import shutil
    from pathlib import Path

    from typer.testing import CliRunner

    from drill_env.cli import app

    src = Path(__file__).parents[1] / "results" / "robust_rl" / "distilled_brake"
    out = tmp_path / "distilled_brake"
    shutil.copytree(src, out)
    for png in out.glob("*.png"):
        png.unlink()
    args = ["benchmark", "--quick", "--preset", "brake", "--plants", "family", "--controllers", "ppo_robust"]
    args += ["--agents-dir", str(tmp_path / "not_here"), "--seeds", "3", "--no-timeseries", "--out", str(out)]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    assert "no policy loaded" in r.output
    assert {"bifurcation_brake.png", "suppression_brake.png", "suppression_brake_plants.png"} <= {
        p.name for p in out.glob("*.png")
    }
    record = json.loads((out / "benchmark_config.json").read_text())
    assert record["policies"] == json.loads((src / "benchmark_config.json").read_text())["policies"]
    lines = (out / "benchmark.csv").read_text().splitlines(keepends=True)
    (out / "benchmark.csv").write_text("".join(lines[:-1]))  # one run missing: it must run
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 2
    assert "--agents-dir" in r.output and "is not a folder" in r.output


# -- the committed figures the docs and the README show ------------------------------------

_ROOT = __import__("pathlib").Path(__file__).parents[1]
_IMAGE = __import__("re").compile(r"!\[[^\]]*\]\(([^)\s]+\.png)\)")
_INCLUDE = __import__("re").compile(r"\{include\}\s*\.\./_generated/results/(\S+\.md)")


def _png_size(path) -> tuple[int, float | None]:
    """(width [px], dpi or None) from a PNG's header and its pHYs chunk."""
    import struct

    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path}: not a PNG"
    width = struct.unpack(">I", data[16:20])[0]
    pos = 8
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos : pos + 8])
        if kind == b"pHYs":
            x, _, unit = struct.unpack(">IIB", data[pos + 8 : pos + 17])
            return width, x * 0.0254 if unit == 1 else None
        if kind in (b"IDAT", b"IEND"):
            break
        pos += 12 + length
    return width, None


def shown_figures() -> dict:
    """Every PNG under results/ that a docs page or the README shows: the images of
    docs/**/*.md, of README.md, of the renderers in docs/_ext, and of the result reports
    (results/**/*.md) the docs pages include, each with where it is shown."""
    import re

    shown: dict = {}

    def add(target: str, base, where: str) -> None:
        if "://" in target:
            return
        path = (base / target).resolve()
        if _ROOT / "results" in path.parents:
            shown.setdefault(path, where)

    included: set[str] = set()
    for page in doc_sources(readme=False):
        text = page.read_text(encoding="utf-8")
        for target in _IMAGE.findall(text):
            add(target, page.parent, str(page.relative_to(_ROOT)))
        included |= set(_INCLUDE.findall(text))
    for target in _IMAGE.findall((_ROOT / "README.md").read_text(encoding="utf-8")):
        add(target, _ROOT, "README.md")
    for ext in sorted((_ROOT / "docs" / "_ext").glob("*.py")):
        for target in re.findall(r"results/[\w./-]+\.png", ext.read_text(encoding="utf-8")):
            add(target, _ROOT, str(ext.relative_to(_ROOT)))
    for md in sorted((_ROOT / "results").rglob("*.md")):
        name = "_".join(md.relative_to(_ROOT / "results").with_suffix("").parts) + ".md"
        if name in included:
            for target in _IMAGE.findall(md.read_text(encoding="utf-8")):
                add(target, md.parent, f"{md.relative_to(_ROOT)} (included by the docs)")
    return shown


# Shown figures whose code draws them 8 in wide but whose committed files are older, each with
# the command of results/README.md that redraws them (a figure leaves this list when redrawn).
AWAITING_REDRAW: dict[str, str] = {}


def test_every_figure_the_docs_show_fits_the_docs_width():
    """A committed figure the docs or the README show is at most MAX_WIDTH_IN wide at the dpi
    it was saved with (its text then legible at the column's 724 px; the figure functions'
    tests check the text itself)."""
    from drill_env._figures import MAX_WIDTH_IN

    shown = shown_figures()
    assert len(shown) >= 30  # the results pages' figures, the README's and the reports'
    assert _ROOT / "results" / "bifurcation" / "no_brake" / "fig8_bifurcation.png" in shown
    assert _ROOT / "results" / "discrepancy" / "detection.png" in shown  # via a report the docs include
    assert {_ROOT / p for p in AWAITING_REDRAW} <= set(shown)
    problems = []
    for path, where in sorted(shown.items()):
        if path.relative_to(_ROOT).as_posix() in AWAITING_REDRAW:
            continue
        if not path.is_file():
            problems.append(f"{path.relative_to(_ROOT)} (shown in {where}) is missing")
            continue
        width, dpi = _png_size(path)
        if dpi is None:
            problems.append(f"{path.relative_to(_ROOT)}: no resolution recorded (pHYs)")
        elif width > MAX_WIDTH_IN * dpi + 0.5:
            problems.append(
                f"{path.relative_to(_ROOT)} (shown in {where}): {width} px at {dpi:.0f} dpi = "
                f"{width / dpi:.2f} in > {MAX_WIDTH_IN:g} in"
            )
    assert problems == []


def test_the_width_scan_reads_a_figures_size_and_catches_a_wide_one(tmp_path):
    from drill_env._figures import MAX_WIDTH_IN, subplots

    for width_in, dpi in ((8.0, 110), (12.0, 130)):
        fig, _ = subplots(figsize=(width_in, 3))
        fig.savefig(tmp_path / "f.png", dpi=dpi)
        width, got = _png_size(tmp_path / "f.png")
        assert got == pytest.approx(dpi, abs=0.05) and width == round(width_in * dpi)
        assert (width > MAX_WIDTH_IN * got + 0.5) == (width_in > MAX_WIDTH_IN)


def test_policy_cards_redraws_each_learning_curve_legibly(tmp_path, saved_figures):
    import shutil

    from typer.testing import CliRunner

    from drill_env._figures import legibility_problems
    from drill_env.cli import app

    for name in ("ppo", "sac_robust_no_brake"):
        shutil.copytree(_ROOT / "results" / "agents" / name, tmp_path / name)
        (tmp_path / name / "learning_curve.png").unlink()
    r = CliRunner().invoke(app, ["policy-cards", str(tmp_path)])
    assert r.exit_code == 0, r.output
    for name in ("ppo", "sac_robust_no_brake"):
        assert (tmp_path / name / "learning_curve.png").stat().st_size > 10_000
    assert len(saved_figures) == 2
    for f in saved_figures:
        assert legibility_problems(f) == [], f.axes[0].get_title()
        assert [a.get_xlabel() for a in f.axes] == ["environment steps"] * 2


def test_the_discrepancy_study_figures_are_redrawn_legibly_from_study_json(tmp_path, saved_figures):
    import shutil

    from typer.testing import CliRunner

    from drill_env._figures import legibility_problems
    from drill_env.cli import app

    out = tmp_path / "study"
    out.mkdir()
    shutil.copy(_ROOT / "results" / "discrepancy" / "unseen_seeds" / "study.json", out / "study.json")
    r = CliRunner().invoke(app, ["discrepancy-study", "--figures-only", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert {p.name for p in out.glob("*.png")} == {"confusion.png", "detection.png"}
    assert len(saved_figures) == 2
    for f in saved_figures:
        assert legibility_problems(f) == [], f.axes[0].get_title()
    r = CliRunner().invoke(app, ["discrepancy-study", "--figures-only", "--out", str(tmp_path / "none")])
    assert r.exit_code == 2 and "no study.json" in r.output


def test_identifys_bifurcation_figure_of_a_rig_with_an_effect_is_its_base_models(tmp_path):
    """A rig identified with an effect (its rig.yaml carries it) gets the bifurcation figure of
    its base model, said so -- as `drill-env bifurcation` treats the same rig file -- not a
    missing figure; the points are the base model's (the paper's braked rig: A 0.116 V, B 0.583 V)."""
    from types import SimpleNamespace

    from drill_env import load_params
    from drill_env.identify.report import _bifurcation_figure

    p = load_params("brake", lower_position_amp_1=0.1)
    out = _bifurcation_figure(SimpleNamespace(states=[], structure="brake"), p, tmp_path / "bifurcation.png")
    assert "error" not in out, out
    assert out["effects_left_out"] == ["lower_position_amp_1"]
    assert out["points"]["A"] == pytest.approx(0.1164, abs=2e-3)
    assert out["points"]["B"] == pytest.approx(0.583, abs=2e-3)
    width, dpi = _png_size(tmp_path / "bifurcation.png")
    assert width <= 10 * dpi
