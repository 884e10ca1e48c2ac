"""The figures say what they show: a legend entry for every line and marker style, the
rig's limits where a diagram reaches them, labels clear of the data, every benchmark
marker at its run's voltage."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

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
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg else []


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
    assert {"candidates.png", "equation_error.png"} <= set(names)
    for fig in saved_figures[: names.index("equation_error.png") + 1]:
        assert legibility_problems(fig) == [], fig.axes[0].get_title()
