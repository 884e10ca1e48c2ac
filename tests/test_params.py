"""Rig parameters: presets equal to the paper's tables, validation that names the field."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import yaml

import drill_env
from drill_env import ModelEffects, ParameterError, RigParams, load_params, resolve_params
from drill_env import _layout as L

# The paper's identified values, eq. (11), (13), (15) (common to both presets).
COMMON = {
    "motor_constant": 3.5693,  # km, eq. (11)
    "upper_inertia": 0.4765,  # Ju, eq. (11)
    "upper_static_pos": 0.3216,  # Tsup, eq. (13)
    "upper_static_neg": 0.3026,  # Tsun, eq. (13)
    "upper_viscous_pos": 1.9667,  # bup, eq. (13)
    "upper_viscous_neg": 2.0,  # bun, eq. (13)
    "lower_inertia": 0.0326,  # Jl, eq. (15)
    "string_stiffness": 0.078,  # ktheta, eq. (15)
}
# Lower-disk friction without the brake, eq. (16), and with it, eq. (17).
NO_BRAKE = {
    "lower_static": 0.01663,
    "lower_viscous": 0.00459,
    "lower_hump_1": 0.7016,
    "lower_hump_2": -0.7173,
    "lower_hump_rate_1": 2.0427,
    "lower_hump_rate_2": 1.9205,
}
BRAKE = {
    "lower_static": 0.0940,
    "lower_viscous": 0.0042,
    "lower_hump_1": 0.0826,
    "lower_hump_2": -0.2910,
    "lower_hump_rate_1": 6.3598,
    "lower_hump_rate_2": 0.0786,
}


@pytest.mark.parametrize(("name", "lower"), [("brake", BRAKE), ("no_brake", NO_BRAKE)])
def test_presets_hold_the_paper_values(name, lower):
    p = load_params(name)
    assert p.name == name
    for key, value in {**COMMON, **lower}.items():
        assert getattr(p, key) == value, key
    assert p.effects == ModelEffects()  # the paper's model: no extra effects
    assert p.effects.active == ()


def test_available_presets():
    assert {"brake", "no_brake"} <= set(drill_env.available_presets())


def test_preset_list_is_the_shipped_rig_files():
    # the one list every command and benchmark iterates: exactly the files shipped, each loads
    assert sorted(drill_env.params.PRESETS) == drill_env.available_presets()
    for name in drill_env.params.PRESETS:
        assert load_params(name).name == name


def test_uc1_is_point_a(brake, no_brake):
    # Point A, uc1 = (Tsup + Tsl)/km, from the tabulated values.
    assert brake.uc1 == pytest.approx((0.3216 + 0.0940) / 3.5693, rel=1e-15)
    assert no_brake.uc1 == pytest.approx((0.3216 + 0.01663) / 3.5693, rel=1e-15)
    # Lower end of the stick range (25).
    assert brake.uc1_neg == pytest.approx(-(0.3026 + 0.0940) / 3.5693, rel=1e-15)
    # The lower disk hangs on a string of stiffness ktheta: period 2 pi sqrt(Jl/ktheta) ~ 4 s.
    assert 2 * math.pi / brake.resonance_rad_s == pytest.approx(2 * math.pi * math.sqrt(0.0326 / 0.078))


def test_params_are_immutable(brake):
    with pytest.raises(dataclasses.FrozenInstanceError):
        brake.upper_inertia = 1.0  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        brake.effects.string_damping = 1.0  # type: ignore[misc]


def test_replace_returns_a_validated_copy(brake):
    q = brake.replace(lower_static=0.05, string_damping=0.001)
    assert q.lower_static == 0.05
    assert q.effects.string_damping == 0.001
    assert brake.lower_static == 0.0940  # the original is untouched
    assert brake.effects.string_damping == 0.0
    assert load_params("brake", lower_static=0.05) == q.replace(string_damping=0.0)
    assert q.replace(**{"effects.string_damping": 0.002}).effects.string_damping == 0.002


@pytest.mark.parametrize("field", ["upper_inertia", "lower_inertia", "string_stiffness", "motor_constant"])
@pytest.mark.parametrize("value", [0.0, -1e-3])
def test_nonpositive_inertia_or_stiffness_names_the_field(brake, field, value):
    with pytest.raises(ParameterError, match=field):
        brake.replace(**{field: value})


@pytest.mark.parametrize("field", ["upper_inertia", "lower_static", "lower_hump_2", "upper_viscous_neg"])
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_nonfinite_value_names_the_field(brake, field, value):
    with pytest.raises(ParameterError, match=f"{field}.*finite"):
        brake.replace(**{field: value})


@pytest.mark.parametrize("value", ["0.5", None, True, [1.0]])
def test_non_number_names_the_field(brake, value):
    with pytest.raises(ParameterError, match="lower_viscous"):
        brake.replace(lower_viscous=value)


def test_negative_friction_level_is_rejected(brake):
    with pytest.raises(ParameterError, match="upper_static_pos"):
        brake.replace(upper_static_pos=-0.1)
    with pytest.raises(ParameterError, match="lower_hump_rate_1"):
        brake.replace(lower_hump_rate_1=-1.0)


def test_unknown_override_names_the_key(brake):
    with pytest.raises(ParameterError, match="'upper_inertai'"):
        brake.replace(upper_inertai=0.5)
    with pytest.raises(ParameterError, match="'bogus'"):
        load_params("brake", bogus=1.0)


def test_direct_construction_is_validated():
    kw = {**COMMON, **BRAKE}
    assert RigParams(**kw).lower_static == 0.0940
    with pytest.raises(ParameterError, match="string_stiffness"):
        RigParams(**{**kw, "string_stiffness": -0.078})
    with pytest.raises(ParameterError, match="effects"):
        RigParams(**kw, effects={"string_damping": 0.1})  # type: ignore[arg-type]


def test_nondissipative_lower_friction_is_rejected(brake):
    # Eq. (4): the slip friction must stay positive; T2 = -5 N m drives it below zero.
    with pytest.raises(ParameterError, match="lower_hump"):
        brake.replace(lower_hump_2=-5.0)


def test_effect_validation_names_the_effect(brake):
    with pytest.raises(ParameterError, match="effects.string_damping"):
        brake.replace(string_damping=-0.01)
    with pytest.raises(ParameterError, match="effects.motor_lag.*finite"):
        brake.replace(motor_lag=math.nan)
    with pytest.raises(ParameterError, match="lower_position_amp"):
        brake.replace(lower_position_amp_1=0.6, lower_position_amp_2=-0.5)


def test_user_yaml_round_trip(tmp_path, brake):
    path = tmp_path / "my_rig.yaml"
    q = brake.replace(lower_static=0.08, name="my_rig")
    q.to_yaml(path)
    assert load_params(path) == q
    assert resolve_params(str(path)) == q
    assert load_params(path, upper_inertia=0.5).upper_inertia == 0.5


def test_user_yaml_with_unknown_key_names_key_and_file(tmp_path, brake):
    data = brake.to_dict()
    data["lower_statik"] = 0.1
    path = tmp_path / "typo.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ParameterError, match=r"typo\.yaml.*lower_statik"):
        load_params(path)


def test_user_yaml_with_missing_or_bad_value(tmp_path, brake):
    data = brake.to_dict()
    del data["lower_inertia"]
    path = tmp_path / "missing.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ParameterError, match="lower_inertia"):
        load_params(path)
    data = brake.to_dict()
    data["string_stiffness"] = 0.0
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ParameterError, match="string_stiffness"):
        load_params(path)
    data = brake.to_dict()
    data["effects"] = {"string_dampin": 0.1}
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ParameterError, match="string_dampin"):
        load_params(path)
    path.write_text("- just\n- a list\n")
    with pytest.raises(ParameterError, match="mapping"):
        load_params(path)


def test_unknown_preset_and_missing_file(tmp_path):
    with pytest.raises(ParameterError, match="'brakes'.*available"):
        load_params("brakes")
    with pytest.raises(ParameterError, match="no such file"):
        load_params(tmp_path / "absent.yaml")
    with pytest.raises(ParameterError, match="params"):
        resolve_params(3.0)  # type: ignore[arg-type]


def test_resolve_params_accepts_object_name_and_path(brake):
    assert resolve_params(brake) is brake
    assert resolve_params("brake") == brake
    assert resolve_params(brake, lower_static=0.05).lower_static == 0.05


def test_flat_vector_layout(brake):
    q = brake.replace(string_damping=0.01, motor_lag=0.02, friction_lag=0.03, disturbance_amp=0.04)
    v = q.as_array()
    assert v.shape == (L.NP,)
    expected = {
        L.KM: q.motor_constant,
        L.JU: q.upper_inertia,
        L.TSUP: q.upper_static_pos,
        L.TSUN: q.upper_static_neg,
        L.BUP: q.upper_viscous_pos,
        L.BUN: q.upper_viscous_neg,
        L.JL: q.lower_inertia,
        L.KTH: q.string_stiffness,
        L.TSL: q.lower_static,
        L.BL: q.lower_viscous,
        L.T1: q.lower_hump_1,
        L.T2: q.lower_hump_2,
        L.BETA1: q.lower_hump_rate_1,
        L.BETA2: q.lower_hump_rate_2,
        L.BTH: 0.01,
        L.TAU_M: 0.02,
        L.TAU_F: 0.03,
        L.DIST_A: 0.04,
        L.ANY_EFFECT: 1.0,
    }
    for index, value in expected.items():
        assert v[index] == value, index
    assert brake.as_array()[L.ANY_EFFECT] == 0.0
    assert np.all(np.isfinite(v))
