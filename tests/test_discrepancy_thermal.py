"""Temperature-dependent friction in the discrepancy workflow: its regressor, its fit, and
that it is told apart from a drift of the friction level, from no effect, and from a change
of the brake's normal force (which only recalibrates)."""

from __future__ import annotations

import numpy as np
import pytest

import drill_env
from drill_env.discrepancy.scoring import DecisionRule
from drill_env.discrepancy.workflow import analyse
from drill_env.recordings.dataset import MeasuredDataset
from drill_env.recordings.effects import CANDIDATES, THERMAL_TIMES_S, thermal_state, thermal_trajectory
from drill_env.recordings.equation_error import RunEquations, estimate_angle_noise
from drill_env.recordings.synth import SynthConfig, make_dataset

NOMINAL = drill_env.load_params("brake")
# four constant voltages and two quasi-random runs of 60 s at 250 Hz (real encoders: no
# added angle noise)
SMALL = SynthConfig(
    voltages=(0.2, 0.7, 2.0, 4.5), random_runs=2, duration_s=60.0, pre_roll_s=40.0, sample_rate_hz=250.0
)
CANDIDATE = next(c for c in CANDIDATES if c.name == "friction_temperature")


def _analyse(effect, seed, *, overrides=None, config=SMALL):
    syn = make_dataset(effect, seed=seed, config=config, truth_overrides=overrides)
    ds = MeasuredDataset(
        preset="brake", encoder_counts_per_rev=config.encoder_counts_per_rev, runs=tuple(syn.runs)
    )
    return analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=40)), syn


def test_thermal_state_from_the_data_follows_the_simulated_one():
    # no pre-roll: the truth's thermal state starts at zero with the recording, as the
    # regressor's does; the regressor takes the power from the nominal friction at the
    # measured speed, the simulator from the heated friction at the true speed
    cfg = SynthConfig(voltages=(3.0,), random_runs=1, duration_s=60.0, pre_roll_s=0.0, sample_rate_hz=250.0)
    tau = 30.0
    syn = make_dataset(
        "none", seed=5, config=cfg, truth_overrides={"friction_heating": 0.05, "thermal_time": tau}
    )
    noise = estimate_angle_noise(syn.runs, 2 * np.pi / cfg.encoder_counts_per_rev)
    for run, volts in zip(syn.runs, (3.0, None), strict=True):
        eq = RunEquations(run, NOMINAL, noise)
        if volts is None:
            continue  # the quasi-random run's voltage record is checked through the fit tests
        truth = drill_env.simulate(syn.truth, volts, 60.0, x0={"theta_u": 0.0}, dt=1.0 / cfg.sample_rate_hz)
        got = thermal_state(eq, tau)
        # stick-slip at 3 V: compare where both have risen (after one time constant)
        late = eq.t_rel > tau
        err = np.max(np.abs(got[late] - truth.thermal_state[late])) / np.max(truth.thermal_state)
        assert err < 0.05, err
        # a wrong time constant is far off
        wrong = thermal_state(eq, 3.0 * tau)
        assert np.max(np.abs(wrong[late] - truth.thermal_state[late])) / np.max(truth.thermal_state) > 0.15


@pytest.mark.parametrize(
    ("coef", "ok"),
    [
        ((0.05, 0.03, 0.02), True),  # preheated 0.5, rise between the lags
        ((-0.04, -0.1, 0.0), True),  # cooling friction, short lag only
        ((0.3, 0.2, -0.4), False),  # the lags pull in opposite directions
        ((0.4, -0.05, -0.05), False),  # the rise opposes the steady change
        ((1.0, 0.3, 0.2), False),  # the friction would reverse at about 1 W
    ],
)
def test_admissibility_of_a_heating_fit(coef, ok):
    par = CANDIDATE.to_parameters(np.array(coef))
    assert par["friction_heating"] == pytest.approx(sum(coef))
    why = CANDIDATE.admissible(par)
    assert (why is None) == ok, why
    if ok:
        lo, hi = THERMAL_TIMES_S
        assert lo <= par["thermal_time"] <= hi
        effects = CANDIDATE.to_model_effects(par)
        assert set(effects) == {"friction_heating", "thermal_time"}
        NOMINAL.replace(**effects)  # a valid rig


@pytest.mark.parametrize("seed", [51, 52, 53])
def test_heating_is_named_with_its_sign_and_size(seed):
    res, syn = _analyse("friction_temperature", seed)
    truth = syn.answer["model_effects"]
    assert res.effect == "friction_temperature", res.decision.reason
    found = res.decision.winner.parameters
    assert np.sign(found["friction_heating"]) == np.sign(truth["friction_heating"])
    assert abs(found["friction_heating"]) == pytest.approx(abs(truth["friction_heating"]), rel=0.5)
    assert res.corrected.effects.friction_heating == pytest.approx(found["friction_heating"])
    assert res.corrected.effects.thermal_time == pytest.approx(found["thermal_time"])


@pytest.mark.parametrize(
    ("effect", "seed"), [("friction_drift", 51), ("friction_drift", 52), ("none", 51), ("none", 52)]
)
def test_drift_and_no_effect_are_not_read_as_heating(effect, seed):
    res, _ = _analyse(effect, seed)
    assert res.effect == effect, res.decision.reason


def test_a_brake_normal_force_change_is_a_recalibration():
    # the normal force scales the static level and both humps of the lower friction alike:
    # 4 % more of it is a parameter change, not an effect
    scale = 1.04
    changes = {n: getattr(NOMINAL, n) * scale for n in ("lower_static", "lower_hump_1", "lower_hump_2")}
    res, syn = _analyse("none", 54, overrides=changes)
    out = res.result_json()
    assert res.effect == "recalibrated", res.decision.reason
    assert out["parameters"] == {}
    assert "lower_static" in out["recalibrated"]
    truth = syn.answer["parameters_at_nominal_string_stiffness"]
    for name, entry in out["recalibrated"].items():
        lo, hi = entry["ci95"]
        assert lo <= truth[name] <= hi, (name, entry, truth[name])
    # the model written has the stronger brake
    assert res.corrected.lower_static == pytest.approx(changes["lower_static"], rel=0.01)


def test_thermal_state_of_a_warm_recording_is_estimated_from_the_run():
    # the truth heated for 40 s before the recording: the simulations of a heated model from
    # measured states start from the lag of the power plus a fitted initial heat
    cfg = SynthConfig(voltages=(3.0,), random_runs=0, duration_s=60.0, pre_roll_s=40.0, sample_rate_hz=250.0)
    heating = {"friction_heating": 0.3, "thermal_time": 80.0}
    syn = make_dataset("none", seed=6, config=cfg, truth_overrides=heating)
    noise = estimate_angle_noise(syn.runs, 2 * np.pi / cfg.encoder_counts_per_rev)
    eq = RunEquations(syn.runs[0], NOMINAL, noise)
    truth = drill_env.simulate(syn.truth, 3.0, 60.0, dt=1.0 / cfg.sample_rate_hz, t0=-40.0)
    true_th = truth.thermal_state[-eq.t_rel.size :]
    got = thermal_trajectory(eq, NOMINAL.replace(**heating))
    assert true_th[0] > 0.2  # warm at the first sample
    err = np.max(np.abs(got - true_th)) / np.max(true_th)
    assert err < 0.1, err
    # starting cold instead is far off at the start
    assert abs(thermal_state(eq, 80.0)[0] - true_th[0]) / np.max(true_th) > 0.3


@pytest.mark.slow
@pytest.mark.parametrize("seed", [61, 74])
def test_heated_model_simulated_from_measured_states_is_named(seed):
    # the whole workflow on full-size data (7 constant-voltage and 3 quasi-random runs of
    # 150 s after a 60 s pre-roll): the corrected model's short horizons start from the
    # thermal state estimated on each run; from a cold contact they were worse than the
    # recalibrated model's on seed 61 and the effect was not named
    syn = make_dataset("friction_temperature", seed=seed)
    ds = MeasuredDataset(preset="brake", encoder_counts_per_rev=2000, runs=tuple(syn.runs))
    res = analyse(ds, simulate_gaps=True, rule=DecisionRule(bootstrap=40))
    assert res.effect == "friction_temperature", res.decision.reason
