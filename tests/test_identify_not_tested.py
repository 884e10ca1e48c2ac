"""A base fit refused (T_sl not determined) leaves the structure untested: the verdict says so
(``not_tested``, never ``none``) in the CLI output, report.md and identification.json, with the
run that would determine what the fit lacks."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from drill_env.cli import app
from drill_env.recordings.synth import SynthConfig, make_dataset, write_synthetic

# constant runs far above the stick boundary, recorded after a settle: the lower disk always
# slips fast, so its static level is extrapolated and the base fit is refused
FAST_ONLY = SynthConfig(
    voltages=(2.0, 3.0, 4.5), random_runs=0, duration_s=30.0, pre_roll_s=30.0, sample_rate_hz=250.0
)


def test_a_refused_base_fit_is_not_tested_never_none(tmp_path):
    syn = make_dataset("position_friction_lower", seed=3, config=FAST_ONLY, magnitude=0.15)
    write_synthetic(syn, tmp_path / "data", tmp_path / "answer.json", preset="brake")
    out = tmp_path / "id"
    r = CliRunner().invoke(
        app,
        ["identify", str(tmp_path / "data"), "--out", str(out), "--no-figures", "--no-bifurcation",
         "--known", f"string_stiffness={syn.truth.string_stiffness!r}"],
    )  # fmt: skip
    assert r.exit_code == 1, r.output  # no rig.yaml: the refusal
    assert "structure: not_tested (0 round(s)" in r.output, r.output
    assert "structure: none" not in r.output
    assert "a hidden effect is not ruled out" in r.output
    # what was fitted beside the refused T_sl: one warning line names them all
    beside = [line for line in r.output.splitlines() if "fitted beside a refused parameter" in line]
    assert len(beside) == 1, r.output
    for n in ("motor_constant", "upper_inertia", "lower_inertia", "upper_static_pos"):
        assert n in beside[0] and f"warning: {n} is not identifiable" not in r.output
    assert "the fit was refused (lower_static not determined)" in beside[0]
    assert "stick boundary" in beside[0]
    record = json.loads((out / "identification.json").read_text())
    search = record["structure_search"]
    assert search["verdict"] == "not_tested" and search["tested"] is False and search["rounds"] == []
    assert "lower_static" in search["stopped"] and "stick boundary" in search["stopped"], search["stopped"]
    report = (out / "report.md").read_text()
    assert "**Not tested (verdict `not_tested`)" in report
    assert "the run that determines it" in report


def test_a_refused_fit_marks_no_parameter_identified():
    """What a refused fit fitted beside the parameter it lacks is not identified either: the
    refused T_sl moves the rest (an inertia at -51 % beside one), which their own intervals, holding
    T_sl at its fitted value, do not show. Each says so, with the run that determines the refused
    parameter; the refusal itself still names only T_sl."""
    from drill_env.identify import identify
    from drill_env.identify.identification import REFUSED_METHOD
    from drill_env.recordings.dataset import MeasuredDataset

    syn = make_dataset("position_friction_lower", seed=3, config=FAST_ONLY, magnitude=0.15)
    ds = MeasuredDataset(preset="brake", encoder_counts_per_rev=2000, runs=tuple(syn.runs))
    ident = identify(ds, known={"string_stiffness": syn.truth.string_stiffness}, simulate_heldout=False)
    assert ident.params is None
    assert [p.name for p in ident.blocking] == ["lower_static"]
    lacking = ident.parameters["lower_static"].needs
    assert "stick boundary" in lacking
    beside = [p for p in ident.parameters.values() if p.method == REFUSED_METHOD]
    assert {"motor_constant", "upper_inertia", "lower_inertia"} <= {p.name for p in beside}
    for n, p in ident.parameters.items():
        if n == "string_stiffness":
            assert p.identified and p.method == "fixed by the user"
            continue
        assert not p.identified, (n, p)
    for p in beside:
        assert "the fit was refused (lower_static not determined)" in p.note and p.needs == lacking


# the same fast runs, five of them: two can be held out
FAST_FIVE = SynthConfig(
    voltages=(2.0, 2.5, 3.0, 3.5, 4.5), random_runs=0, duration_s=30.0, pre_roll_s=30.0, sample_rate_hz=250.0
)


def test_a_fit_refused_for_an_extrapolated_static_level_is_tested_where_its_data_reach(tmp_path):
    """Refused only because T_sl is the curve carried below the slowest slip: the fitted model is
    kept beside the refusal and the structure tests run on the held-out runs at the slips the
    data cover. The verdict is theirs (never not_tested); T_sl stays not determined, with the
    run that determines it, and no rig file is written."""
    from drill_env.identify.identification import static_extrapolated
    from drill_env.recordings.dataset import MeasuredDataset
    from drill_env.structure_search import _covered_slips, identify_structure

    syn = make_dataset("position_friction_lower", seed=3, config=FAST_FIVE, magnitude=0.15)
    ds = MeasuredDataset(preset="brake", encoder_counts_per_rev=2000, runs=tuple(syn.runs))
    s = identify_structure(ds, known={"string_stiffness": syn.truth.string_stiffness}, simulate_heldout=False)
    ident = s.identification
    assert ident.params is None and [p.name for p in ident.blocking] == ["lower_static"]
    assert static_extrapolated(ident.fit) and ident.provisional is not None
    assert s.tested and s.verdict != "not_tested" and s.rounds
    assert "lower_static" in s.refused and "stick boundary" in s.refused and s.refused in s.stopped
    assert _covered_slips(ident).min_speed_lower_rad_s == ident.fit.slowest_slip
    if s.verdict == "unexplained":
        assert s.suspect
    for n in ("lower_static", "lower_hump_1", "lower_hump_rate_1"):
        p = ident.parameters[n]
        assert not p.identified and "stick boundary" in p.needs, (n, p)
    record = s.as_dict()
    assert record["tested"] is True and record["refused_fit"] == s.refused


def test_a_fit_refused_for_a_loose_static_level_is_tested_where_its_data_reach():
    """T_sl not determined by a wide interval (not extrapolated): the fitted model is kept beside
    the refusal for the tests at the slips the data cover, which find nothing (no effect hidden);
    the fit stays refused, no rig, and T_sl is not marked identified. (A hidden effect can be what
    leaves T_sl loose: two harmonics of position friction in closed-loop PI runs were not tested
    at all, and are found and fitted so.)"""
    from drill_env.recordings.dataset import MeasuredDataset
    from drill_env.structure_search import identify_structure

    syn = make_dataset("none", seed=3, config=FAST_FIVE)
    ds = MeasuredDataset(preset="brake", encoder_counts_per_rev=2000, runs=tuple(syn.runs))
    s = identify_structure(ds, known={"string_stiffness": syn.truth.string_stiffness}, simulate_heldout=False)
    assert s.identification.params is None and s.identification.provisional is not None
    assert s.tested and s.verdict == "none", s.as_dict()
    assert s.refused and "slips its data cover" in s.refused
    assert not s.identification.parameters["lower_static"].identified
