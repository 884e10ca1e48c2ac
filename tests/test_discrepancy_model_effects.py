"""The discrepancy workflow on a nominal model that holds library effects (a rig.yaml of
``drill-env identify`` with its effects section): those effects are part of the model it
compares against, the tests look for what is still missing."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from drill_env.cli import app
from drill_env.discrepancy.verdict import DecisionRule
from drill_env.discrepancy.workflow import analyse
from drill_env.params import ModelEffects, load_params
from drill_env.recordings.dataset import MeasuredDataset
from drill_env.recordings.effects import EFFECT_FIELDS, with_model_effects
from drill_env.recordings.equation_error import RunEquations, estimate_angle_noise
from drill_env.recordings.synth import SynthConfig, make_dataset

SMALL = SynthConfig(
    voltages=(0.2, 0.7, 2.0, 4.5), random_runs=2, duration_s=60.0, pre_roll_s=40.0, sample_rate_hz=250.0
)


def _dataset(effect, seed, second=None):
    syn = make_dataset(effect, seed=seed, config=SMALL, second_effect=second)
    ds = MeasuredDataset(
        preset="brake", encoder_counts_per_rev=SMALL.encoder_counts_per_rev, runs=tuple(syn.runs)
    )
    return ds, syn.truth


def _only(truth, effect):
    """The truth with only ``effect``'s fields of its effects switched on."""
    keep = {k: getattr(truth.effects, k) for k in EFFECT_FIELDS[effect]}
    return dataclasses.replace(truth, effects=ModelEffects(**keep))


def _ss_per_window(ds, params, scale=1.0):
    noise = estimate_angle_noise(ds.runs, ds.encoder_step)
    ss = n = 0.0
    for r in ds.runs:
        eq = with_model_effects(RunEquations(r, params, noise))
        for w in (eq.upper, eq.lower):
            ss += float(np.sum(w.z**2))
            n += len(w)
    return ss / n


@pytest.mark.parametrize("effect", list(EFFECT_FIELDS))
def test_the_models_own_effect_leaves_the_residual_at_the_noise_floor(effect):
    """The truth's equation error with its effect taken out is at the noise floor (per window
    z^2 about 1), far below the base model's; the same effect at twice its size (a wrong sign
    or scale of the columns) is not."""
    ds, truth = _dataset(effect, 21)
    base = dataclasses.replace(truth, effects=ModelEffects())
    with_effect = _ss_per_window(ds, truth)
    assert with_effect < 1.3, (effect, with_effect)
    assert _ss_per_window(ds, base) > 20.0 * with_effect
    doubled = {}
    for k in EFFECT_FIELDS[effect]:
        v = getattr(truth.effects, k)
        doubled[k] = (
            2.0 * v if ("amp" in k or k in ("string_damping", "friction_drift", "friction_heating")) else v
        )
    if effect in ("motor_inductance", "friction_memory"):  # a lag: twice its time constant
        key = EFFECT_FIELDS[effect][0]
        doubled[key] = 2.0 * getattr(truth.effects, key)
    wrong = dataclasses.replace(truth, effects=dataclasses.replace(truth.effects, **doubled))
    assert _ss_per_window(ds, wrong) > 3.0 * with_effect, effect


@pytest.mark.parametrize(
    ("effect", "second", "expected"),
    [("motor_inductance", None, "none"), ("position_friction_lower", "string_damping", "string_damping")],
)
def test_an_effect_in_the_model_is_not_named_again(effect, second, expected):
    """Data with the model's effect alone: verdict none; with a second one beside it: the
    second is named, never the one the model holds."""
    ds, truth = _dataset(effect, 21, second)
    res = analyse(ds, simulate_gaps=False, rule=DecisionRule(bootstrap=40), params=_only(truth, effect))
    assert res.effect == expected, res.decision.reason
    assert effect not in res.effects


def test_discrepancy_refuses_a_rig_with_an_effect_outside_the_library(tmp_path):
    data = load_params("brake").to_dict()
    data.setdefault("effects", {}).update(disturbance_amp=0.01, disturbance_freq=3.0)
    rig = tmp_path / "rig.yaml"
    rig.write_text(yaml.safe_dump(data))
    r = CliRunner().invoke(
        app, ["discrepancy", str(tmp_path / "none"), "--params", str(rig), "--out", str(tmp_path / "o")]
    )
    assert r.exit_code == 2, r.output
    assert "disturbance_amp" in r.output and "outside the library" in r.output and "Traceback" not in r.output
