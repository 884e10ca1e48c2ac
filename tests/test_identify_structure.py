"""Identification that includes the structure: library effects fitted jointly with every base
parameter, the rounds of discrepancy tests, what cannot be trusted, and the command's options.

Truth rigs have every parameter x0.35-x3 of the paper's (:func:`drill_env.identify.draw_rig`),
recorded on protocols other than the identification plan
(:mod:`drill_env.recordings.protocols`) or on a short plan; the seeds are not those the
identification was developed on.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from drill_env.cli import app
from drill_env.identify import EXCITED_PARAMETERS, ExperimentPlan, draw_rig, identify, synth_config
from drill_env.params import IDENTIFIED_PARAMETERS
from drill_env.recordings.dataset import MeasuredDataset, MeasuredRun
from drill_env.recordings.protocols import PROTOCOLS, protocol_runs, record_protocol
from drill_env.recordings.synth import make_dataset

SMALL = ExperimentPlan(
    "small", (0.1, 0.3, 0.8, 2.0, 4.0), 2, (-5.0, 5.0), (0.5, 2.0), 40.0, 30.0, (250.0, 1000.0)
)


def _truth(rig):
    return {n: float(getattr(rig, n)) for n in IDENTIFIED_PARAMETERS}


def _dataset(runs, structure: str, counts: int) -> MeasuredDataset:
    return MeasuredDataset(preset=structure, encoder_counts_per_rev=counts, runs=tuple(runs))


def test_position_friction_fitted_jointly_with_every_base_parameter():
    """The joint fit with the effect: the base parameters the base-only fit got wrong come back,
    the effect's own parameters inside their intervals."""
    rig = draw_rig("brake", 31, low=0.35, high=3.0)
    cfg = synth_config(SMALL, "brake", sample_rate_hz=400.0, angle_noise_std=0.0, encoder_counts_per_rev=4096)
    res = make_dataset(
        "position_friction_lower", seed=31, magnitude=0.12, config=cfg, truth_overrides=_truth(rig)
    )
    ds = _dataset(res.runs, "brake", 4096)
    known = {"string_stiffness": rig.string_stiffness}
    base = identify(ds, known=known, simulate_heldout=False)
    joint = identify(ds, known=known, simulate_heldout=False, effects={"position_friction_lower": None})
    # the base-only fit absorbs the effect into the lower static friction
    base_err = abs(base.parameters["lower_static"].value / rig.lower_static - 1.0)
    for n in EXCITED_PARAMETERS:
        assert joint.parameters[n].value == pytest.approx(getattr(rig, n), rel=0.03), n
    assert abs(joint.parameters["lower_static"].value / rig.lower_static - 1.0) < base_err
    eff = joint.effects["position_friction_lower"]
    truth = res.answer["model_effects"]
    for k, v in truth.items():
        lo, hi = eff.ci95[k]
        assert lo <= eff.parameters[k] <= hi and math.isfinite(hi - lo), (k, eff.ci95[k])
        if "phase" in k:
            if truth[k.replace("phase", "amp")] > 0.02:
                err = (eff.parameters[k] - v + math.pi) % (2 * math.pi) - math.pi
                assert abs(err) < 0.05, (k, v, eff.parameters[k])
        elif v > 0.02:
            assert eff.parameters[k] == pytest.approx(v, rel=0.03), (k, v, eff.parameters[k])
    # one model: the plant with the effect, which the rig file holds
    assert joint.params is not None
    assert joint.params.effects.lower_position_amp_1 == pytest.approx(eff.parameters["lower_position_amp_1"])
    assert joint.fit.residual_variance < base.fit.residual_variance / 10


def _search_on_protocol(structure, seed, protocol, hidden, rate, counts):
    """A rig x0.35-x3 of the paper's (``seed``) with the ``hidden`` fields, recorded on a lab
    protocol, and the structure search on it (the string stiffness given)."""
    from drill_env.structure_search import identify_structure

    rig = draw_rig(structure, seed, low=0.35, high=3.0)
    res = record_protocol(
        rig.replace(**hidden), protocol, seed=seed, sample_rate_hz=rate, encoder_counts_per_rev=counts,
        preset=structure,
    )  # fmt: skip
    s = identify_structure(
        _dataset(res.runs, structure, counts), known={"string_stiffness": rig.string_stiffness},
        simulate_heldout=False,
    )  # fmt: skip
    return rig, s


POSITION_CASES = [
    # the lower disk's, on a rig whose friction curve has the paper's slow Stribeck term (rate
    # 0.14 s/rad), which the modulation scales too, recorded on a staircase at 1024 counts
    (
        "brake", 600, "staircase", 250.0, 1024, "position_friction_lower",
        {"lower_position_amp_1": 0.12, "lower_position_phase_1": 1.3405, "lower_position_amp_2": 0.05,
         "lower_position_phase_2": 0.0339},
    ),
    # the upper disk's, on a lab's week of runs
    (
        "brake", 616, "mixed", 250.0, 4096, "position_friction_upper",
        {"upper_position_amp_1": 0.12, "upper_position_phase_1": 2.4920, "upper_position_amp_2": 0.05,
         "upper_position_phase_2": 5.4365},
    ),
]  # fmt: skip


@pytest.mark.parametrize("structure,seed,protocol,rate,counts,effect,hidden", POSITION_CASES)
def test_two_harmonics_of_position_friction_are_found_and_fitted(
    structure, seed, protocol, rate, counts, effect, hidden
):
    """Fitted as columns beside an unscaled friction curve, the lower modulation settled on a hump
    pair of opposite signs with T_sl 22 % off; its phases, fitted against the floored readings, half
    a count off. Fitted as the product it is (a Gauss-Newton step) against the middle of each
    count, the search names the effect, every excited parameter it marks identified is within
    3 %, the effect's amplitudes within 3 %, the residual is at the noise floor, and nothing is
    called suspect (the effect named again by the tests on the base model is explained)."""

    rig, s = _search_on_protocol(structure, seed, protocol, hidden, rate, counts)
    assert s.effects == [effect], s.as_dict()
    assert s.suspect == [], s.as_dict()
    ident = s.identification
    assert ident.parameters["lower_static"].identified
    for n in EXCITED_PARAMETERS:
        if ident.parameters[n].identified:
            assert ident.parameters[n].value == pytest.approx(getattr(rig, n), rel=0.03), n
    eff = ident.effects[effect]
    for k, v in hidden.items():
        lo, hi = eff.ci95[k]
        # one case of four parameters: the truth within 1.5 times its 95 % half-width (the
        # intervals' coverage is the study's, test_study_on_lab_protocols)
        assert abs(eff.parameters[k] - v) <= 1.5 * 0.5 * (hi - lo), (k, v, eff.parameters[k], eff.ci95[k])
        if "amp" in k:
            assert eff.parameters[k] == pytest.approx(v, rel=0.03), k
    assert ident.fit.residual_variance < 1.5


def test_a_motor_lag_is_profiled_from_a_start_two_times_off():
    rig = draw_rig("no_brake", 32, low=0.35, high=3.0)
    cfg = synth_config(SMALL, "no_brake", sample_rate_hz=500.0, angle_noise_std=0.0)
    res = make_dataset("motor_inductance", seed=32, magnitude=0.02, config=cfg, truth_overrides=_truth(rig))
    ds = _dataset(res.runs, "no_brake", 2000)
    # started a factor 2 off: the profile finds it
    joint = identify(
        ds,
        known={"string_stiffness": rig.string_stiffness},
        simulate_heldout=False,
        effects={"motor_inductance": 0.04},
    )
    eff = joint.effects["motor_inductance"]
    lo, hi = eff.ci95["motor_lag"]
    assert lo < eff.parameters["motor_lag"] < hi and hi / lo < 1.5, eff
    assert eff.parameters["motor_lag"] == pytest.approx(0.02, rel=0.05)
    for n in ("motor_constant", "upper_inertia", "lower_inertia", "upper_static_pos", "upper_viscous_pos"):
        assert joint.parameters[n].value == pytest.approx(getattr(rig, n), rel=0.03), n
    assert joint.params is not None and joint.params.effects.motor_lag == pytest.approx(
        eff.parameters["motor_lag"]
    )


def test_protocols_make_valid_recordings():
    rng = np.random.default_rng(3)
    for name in PROTOCOLS:
        runs = protocol_runs(name, 60.0, rng)
        assert runs, name
        for r in runs:
            if r.kind == "program":
                assert max(abs(v) for v in r.levels) <= 5.0
    rig = draw_rig("brake", 33, low=0.35, high=3.0)
    res = record_protocol(
        rig, "closed_loop_pi", seed=33, duration_s=20.0, sample_rate_hz=250.0, encoder_counts_per_rev=1024
    )
    assert len(res.runs) == 2
    for run in res.runs:
        assert np.all(np.abs(run.u) <= 5.0) and np.ptp(run.u) > 0.1  # the PI moves the voltage
        assert run.t.size == int(round(20.0 * 250.0)) + 1


@pytest.mark.parametrize(
    "args, message",
    [
        (["--no-effects", "--effects", "string_damping"], "--effects: cannot be given with --no-effects"),
        (["--effects", "string_damping,backlash"], "--effects: unknown effect(s) 'backlash'; allowed:"),
        (["--effects", ","], "--effects: empty"),
        (["--rounds", "0"], "--rounds: 0; allowed: 1 to 5"),
    ],
)
def test_bad_structure_options_are_one_line_errors(tmp_path, args, message):
    r = CliRunner().invoke(app, ["identify", str(tmp_path / "data"), "--out", str(tmp_path / "o"), *args])
    assert r.exit_code == 2, r.output
    assert message in r.output and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1


def _offset_gain_runs(runs: list[MeasuredRun], offset: float, gain: float) -> list[MeasuredRun]:
    """The runs as a rig whose amplifier applies gain x u + offset records them: the voltage
    column is what was asked for, (u_applied - offset) / gain."""
    return [
        MeasuredRun(name=r.name, t=r.t, u=(r.u - offset) / gain, theta_u=r.theta_u, theta_l=r.theta_l)
        for r in runs
    ]


@pytest.mark.slow
def test_amplifier_offset_and_gain_fold_into_the_upper_friction_and_the_motor_constant(tmp_path):
    """An amplifier offset is a constant torque k_m u0: the upper friction levels absorb it
    exactly (T_sup - k_m u0, T_sun + k_m u0); a gain error scales k_m. The structure search
    must say none or recalibrated, never unexplained, and never name an effect."""
    from drill_env.structure_search import identify_structure

    rig = draw_rig("brake", 34, low=0.35, high=3.0)
    cfg = synth_config(
        SMALL, "brake", sample_rate_hz=500.0, angle_noise_std=0.0, level_min_v=-4.5, level_max_v=4.5
    )
    res = make_dataset("none", seed=34, config=cfg, truth_overrides=_truth(rig))
    offset, gain = 0.02, 1.03
    ds = _dataset(_offset_gain_runs(res.runs, offset, gain), "brake", 2000)
    s = identify_structure(ds, known={"string_stiffness": rig.string_stiffness}, simulate_heldout=False)
    assert s.verdict in ("none", "recalibrated"), [r.as_dict() for r in s.rounds]
    p = s.identification.parameters
    km = rig.motor_constant
    assert p["motor_constant"].value == pytest.approx(km * gain, rel=0.01)
    assert p["upper_static_pos"].value == pytest.approx(rig.upper_static_pos - km * offset, rel=0.03)
    assert p["upper_static_neg"].value == pytest.approx(rig.upper_static_neg + km * offset, rel=0.03)


@pytest.mark.slow
@pytest.mark.parametrize("amplifier", [{"offset_v": 0.05}, {"gain": 1.05}], ids=["offset", "gain"])
def test_cli_amplifier_errors_are_none_or_recalibrated_never_unexplained(tmp_path, amplifier):
    """A plant file's amplifier with only an offset (+0.05 V) or only a gain error (x1.05):
    synth --plant records the asked-for voltage; identify folds the offset into the upper
    friction levels and the gain into k_m, and neither identify's structure search nor
    discrepancy on the identified rig says unexplained or names an effect."""
    import json

    import yaml

    rig = draw_rig("brake", 34, low=0.35, high=3.0)
    plant = {k: v for k, v in rig.to_dict().items() if k not in ("name", "description")}
    plant["amplifier"] = amplifier
    (tmp_path / "plant.yaml").write_text(yaml.safe_dump(plant, sort_keys=False))
    data, ident_dir = tmp_path / "data", tmp_path / "id"
    r = CliRunner().invoke(
        app,
        ["synth", "--plant", str(tmp_path / "plant.yaml"), "--out", str(data), "--answer",
         str(tmp_path / "answer.json"), "--voltages", "0.3,0.8,2,4", "--random-runs", "2",
         "--duration", "40", "--seed", "3"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    answer = json.loads((tmp_path / "answer.json").read_text())
    assert answer["amplifier"] == {"gain": 1.0, "offset_v": 0.0, **amplifier}
    r = CliRunner().invoke(
        app,
        ["identify", str(data), "--out", str(ident_dir), "--no-figures",
         "--known", f"string_stiffness={rig.string_stiffness!r}"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    ident = json.loads((ident_dir / "identification.json").read_text())
    assert ident["structure_search"]["verdict"] in ("none", "recalibrated"), ident["structure_search"]
    assert not ident["effects"]
    p = ident["parameters"]
    gain, offset = amplifier.get("gain", 1.0), amplifier.get("offset_v", 0.0)
    km = rig.motor_constant
    # within the 3 % for an excited parameter (the folded values are exact: a gain scales
    # k_m, an offset is a constant torque k_m u0 the positive-side level absorbs)
    assert p["motor_constant"]["value"] == pytest.approx(km * gain, rel=0.03)
    assert p["upper_static_pos"]["value"] == pytest.approx(rig.upper_static_pos - km * offset, rel=0.03)
    assert p["upper_viscous_pos"]["value"] == pytest.approx(rig.upper_viscous_pos, rel=0.03)
    r = CliRunner().invoke(
        app,
        ["discrepancy", str(data), "--params", str(ident_dir / "rig.yaml"), "--out",
         str(tmp_path / "disc"), "--no-figures"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "disc" / "result.json").read_text())
    assert res["effect"] in ("none", "recalibrated"), res["effect"]
    assert "verdict: unexplained" not in r.output


@pytest.mark.slow
def test_cli_finds_the_effect_and_writes_one_model(tmp_path):
    """drill-env identify on data with a hidden library effect: the rounds in the report, the
    effect in rig.yaml, which every entry point reads."""
    from drill_env.params import load_params
    from drill_env.recordings.synth import write_synthetic

    rig = draw_rig("brake", 36, low=0.35, high=3.0)
    cfg = synth_config(SMALL, "brake", sample_rate_hz=500.0, angle_noise_std=0.0)
    res = make_dataset("string_damping", seed=36, magnitude=0.006, config=cfg, truth_overrides=_truth(rig))
    write_synthetic(res, tmp_path / "data", tmp_path / "answer.json", preset="brake")
    out = tmp_path / "id"
    r = CliRunner().invoke(
        app,
        ["identify", str(tmp_path / "data"), "--out", str(out), "--no-figures",
         "--known", f"string_stiffness={rig.string_stiffness!r}"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "structure: string_damping" in r.output
    import json

    ident = json.loads((out / "identification.json").read_text())
    rounds = ident["structure_search"]["rounds"]
    assert rounds[0]["added"] == ["string_damping"] and rounds[0]["gap_after"] < rounds[0]["gap_before"]
    lo, hi = ident["effects"]["string_damping"]["ci95"]["string_damping"]
    assert lo < ident["effects"]["string_damping"]["parameters"]["string_damping"] < hi
    report = (out / "report.md").read_text()
    assert "## Structure: the effects the data need" in report and "| 1 | base |" in report
    params = load_params(out / "rig.yaml")
    assert params.effects.string_damping == pytest.approx(0.006, rel=0.1)
    import gymnasium as gym

    import drill_env  # noqa: F401 (registers the envs)

    env = gym.make("DrillString-v3", params=str(out / "rig.yaml"))
    env.reset(seed=0)
    assert env.unwrapped.settings.params.effects.string_damping == params.effects.string_damping
    env.close()
    sim = CliRunner().invoke(
        app, ["simulate", "--preset", str(out / "rig.yaml"), "--voltage", "2", "--duration", "5"]
    )
    assert sim.exit_code == 0, sim.output
    base = CliRunner().invoke(
        app,
        ["identify", str(tmp_path / "data"), "--out", str(tmp_path / "b"), "--no-figures", "--no-effects"],
    )
    assert base.exit_code == 0 and "effects" not in load_params(tmp_path / "b" / "rig.yaml").to_dict()


def _plan_from_advice(advice: list[str], voltages: tuple[float, ...], uc1: float) -> ExperimentPlan:
    """The runs a lab records on reading the refusal: its own words, run by run."""
    text = " ".join(advice)
    v = set(voltages)
    random_runs = 0
    level = (0.0, 5.0)
    if "random-level runs" in text:
        random_runs = 2
    if "negative voltage" in text:
        level = (-5.0, 5.0)
        random_runs = max(random_runs, 1)
    if "just above the stick boundary" in text:
        v |= {round(1.1 * uc1, 3), round(1.3 * uc1, 3)}
    if "three or more positive voltages above the stick boundary" in text:
        v |= {round(f * uc1, 3) for f in (1.5, 2.5, 4.0) if f * uc1 <= 5.0}
    if "up to 5 V" in text:
        v |= {5.0}
    if "across the cycles" in text:
        v |= {round(f * uc1, 3) for f in (1.2, 2.0, 3.0) if f * uc1 <= 5.0}
    return ExperimentPlan(
        "advised", tuple(sorted(v)), random_runs, level, (0.5, 2.0), 40.0, 30.0, (250.0, 1000.0)
    )


@pytest.mark.slow
def test_the_refusals_advice_identifies_the_rig():
    """Three constant runs after a settle: refused, with the runs that would fix the rest.
    Recording what the refusal asks for identifies the rig; what it leaves out is never
    marked identified."""
    rig = draw_rig("brake", 37, low=0.35, high=3.0)
    u = rig.uc1
    first = (round(1.1 * u, 3), round(1.2 * u, 3), round(1.3 * u, 3))  # slip equilibria
    plan = ExperimentPlan("settled", first, 0, (0.0, 5.0), (0.5, 2.0), 40.0, 60.0, (250.0, 1000.0))
    known = {"string_stiffness": rig.string_stiffness}
    res = make_dataset(
        "none", seed=37, config=synth_config(plan, "brake", angle_noise_std=0.0), truth_overrides=_truth(rig)
    )
    refused = identify(_dataset(res.runs, "brake", 2000), known=known, simulate_heldout=False)
    for n in ("motor_constant", "upper_inertia", "lower_inertia", "upper_static_pos", "upper_viscous_pos"):
        p = refused.parameters[n]  # a value far off is never marked identified
        assert not p.identified or p.value == pytest.approx(getattr(rig, n), rel=0.25), (n, p)
    assert refused.params is None
    for p in refused.not_identifiable:
        assert not p.identified and p.needs
    advised = _plan_from_advice([p.needs for p in refused.not_identifiable], first, u)
    res2 = make_dataset(
        "none",
        seed=38,
        config=synth_config(advised, "brake", angle_noise_std=0.0),
        truth_overrides=_truth(rig),
    )
    ident = identify(_dataset(res2.runs, "brake", 2000), known=known, simulate_heldout=False)
    assert ident.params is not None, [(p.name, p.needs) for p in ident.blocking]
    for n in ("motor_constant", "upper_inertia", "lower_inertia", "upper_static_pos", "upper_viscous_pos"):
        assert ident.parameters[n].identified
        assert ident.parameters[n].value == pytest.approx(getattr(rig, n), rel=0.03), n


# the study: rigs x0.35-x3 of the paper's, on protocols other than the plan, with one library
# effect hidden, none, or one outside the library (seeds 40-47: not used in development)
STUDY = [
    ("brake", 40, "mixed", {"motor_lag": 0.02}, "motor_inductance", 1000.0, 1024),
    ("no_brake", 41, "staircase", {"string_damping": 0.005}, "string_damping", 250.0, 4096),
    ("brake", 42, "prbs", {}, None, 500.0, 2048),
    ("no_brake", 43, "mixed", {}, None, 1000.0, 1024),
    ("brake", 44, "slow_ramp", {"friction_lag": 0.1}, "friction_memory", 500.0, 2000),
    (
        "brake",
        45,
        "mixed",
        {"disturbance_amp": 0.02, "disturbance_freq": 1.3, "disturbance_phase": 0.4},
        "outside",
        500.0,
        2000,
    ),
    # two harmonics of position friction (seeds 46-47: run once, after the product fit was made)
    (
        "brake", 46, "staircase",
        {"lower_position_amp_1": 0.1, "lower_position_phase_1": 0.7, "lower_position_amp_2": 0.04,
         "lower_position_phase_2": 3.9},
        "position_friction_lower", 250.0, 1024,
    ),
    (
        "no_brake", 47, "prbs",
        {"upper_position_amp_1": 0.1, "upper_position_phase_1": 4.1, "upper_position_amp_2": 0.04,
         "upper_position_phase_2": 2.2},
        "position_friction_upper", 1000.0, 2048,
    ),
]  # fmt: skip


@pytest.mark.slow
def test_study_on_lab_protocols():

    inside = total = 0
    missed = []
    for structure, seed, protocol, fields_, effect, rate, counts in STUDY:
        rig, s = _search_on_protocol(structure, seed, protocol, fields_, rate, counts)
        ident = s.identification
        case = f"{structure}-{seed}-{protocol}"
        errors = {
            n: ident.parameters[n].value / float(getattr(rig, n)) - 1.0
            for n in EXCITED_PARAMETERS
            if ident.parameters[n].identified
        }
        worst = max(errors, key=lambda n: abs(errors[n])) if errors else None
        print(
            f"{case} hidden {effect}: verdict {s.verdict}; largest excited error "
            + (f"{errors[worst]:+.2%} ({worst})" if worst else "-")
        )
        if effect is None:
            assert s.verdict in ("none", "recalibrated"), (case, s.as_dict())  # no false discovery
        elif effect == "outside":
            assert s.verdict == "unexplained" and s.suspect, (case, s.as_dict())
            continue
        else:
            assert s.effects == [effect], (case, s.as_dict())
        for n, p in ident.parameters.items():
            if n == "string_stiffness" or not p.identified:
                continue
            t = float(getattr(rig, n))
            if n in EXCITED_PARAMETERS:
                assert p.value == pytest.approx(t, rel=0.03), (case, n, p.value, t)
            total += 1
            if p.ci95[0] <= t <= p.ci95[1]:
                inside += 1
            else:
                missed.append(f"{case}:{n}")
        for e in ident.effects.values():
            for k, (lo, hi) in e.ci95.items():
                if k in fields_:
                    total += 1
                    inside += lo <= fields_[k] <= hi
                    if not lo <= fields_[k] <= hi:
                        missed.append(f"{case}:{k}")
    print(f"truths inside their 95 % intervals: {inside}/{total} = {inside / total:.1%}; outside: {missed}")
    assert inside >= 0.9 * total, (inside, total, missed)


def test_an_effect_the_model_could_not_take_leaves_the_residual_unexplained():
    """The tests name an effect, but the re-fit with it is not physical (or fails): the model the
    search returns has no effect, so its verdict is unexplained, never the effect's name; a name
    the user did not allow (--effects) is reported as named."""
    from types import SimpleNamespace

    from drill_env.structure_search import Round, StructureSearch

    def search(**kw) -> StructureSearch:
        rnd = Round(1, [], "string_damping", 1.0, "", ["string_damping"], [], 5.0, **kw)
        ident = SimpleNamespace(effects={})
        return StructureSearch(identification=ident, base=ident, rounds=[rnd], allowed=(), stopped="")

    assert search().verdict == "unexplained"
    assert search(refused=["string_damping"]).verdict == "string_damping"
    none = StructureSearch(
        identification=SimpleNamespace(effects={}),
        base=None,
        rounds=[Round(1, [], "none", 0.9, "", [], [], 1.0)],
        allowed=(),
        stopped="",
    )
    assert none.verdict == "none"
