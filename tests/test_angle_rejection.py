"""Rejection of friction locked to the lower disk's angle (drill_env.agents.controllers.angle_feedforward), and
designing on a given rig model (``drill-env tune/train --params``)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from drill_env.agents.commands.tune import tune_on_model
from drill_env.agents.controllers.angle_feedforward import (
    LQIAngleFeedforward,
    design,
    feedforward_closed_loop,
    phase_error,
    step_scale,
    voltage_to_lower_speed,
)
from drill_env.agents.controllers.base import ControllerSpec
from drill_env.agents.controllers.gains import load_gains
from drill_env.agents.controllers.linear_model import design_point, equilibrium_observation, sampled_rig
from drill_env.agents.controllers.lqi import LQI
from drill_env.agents.controllers.open_loop import OpenLoop
from drill_env.agents.controllers.tuning import design_points
from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate, make_env
from drill_env.agents.registry import CLASSICAL, build_controller
from drill_env.cli import app
from drill_env.envs.task import nominal_params
from drill_env.params import load_params

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"
DETUNED = DATA / "position_friction_detuned.yaml"
SHORT = EpisodeSettings(duration=60.0, window=10.0, warmup_time=30.0, warmup_jitter=2.0)


def lqi_of(preset: str, control_dt: float = 0.05) -> LQI:
    return LQI(ControllerSpec.default(preset, control_dt), **load_gains()["presets"][preset]["lqi"]["gains"])


# -- the linear analysis is the controller's code -------------------------------------------------


@pytest.mark.parametrize(("preset", "voltage"), [("brake", 0.85), ("brake", 1.5), ("no_brake", 1.2)])
def test_linear_form_reproduces_the_controller_on_the_sampled_rig(preset, voltage):
    # The controller's own update, driven by the sampled linear rig with the lower disk
    # turning at w* (its encoder angle w* k dt + theta0 in the v1 entries), follows the
    # transition matrix of feedforward_closed_loop (W_h = C_h exp(j h theta)) exactly.
    env = make_env(preset, SHORT, 1)
    spec = ControllerSpec.from_env(env)
    ctrl = LQIAngleFeedforward(
        spec, hold_decays=0.0, error_clip=1e6, **load_gains()["presets"][preset]["lqi"]["gains"]
    )
    p = spec.params
    eq = design_point(p, voltage=voltage)
    w = eq.x3
    rig = sampled_rig(p, eq, spec.control_dt, spec.sensors)
    d = ctrl.design(w)
    on = [i for i, t in enumerate(d.adaptation_time) if np.isfinite(t)]
    assert 0 in on  # the first harmonic is adapted here
    M = feedforward_closed_loop(rig, ctrl.lqi, d.gains)
    rng = np.random.default_rng(4)
    n = rig.n
    s = 1e-3 * rng.standard_normal(n)
    s[-1] = 0.0  # the last voltage: the equilibrium's
    C0 = 0.02 * (rng.standard_normal(2) + 1j * rng.standard_normal(2))
    C0[[i for i in range(2) if i not in on]] = 0.0  # a harmonic not adapted stays at 0
    theta0 = 0.7
    y_eq = equilibrium_observation(p, eq)

    def observe(k: int, s: np.ndarray) -> np.ndarray:
        y = np.zeros(len(spec.observation_names))
        y[:8] = y_eq
        y[:6] += rig.H @ s
        th = theta0 + w * k * spec.control_dt
        y[spec.index("lower_angle_sin")], y[spec.index("lower_angle_cos")] = math.sin(th), math.cos(th)
        return y[None, :]

    state = ctrl.initial_state(observe(0, s))
    state[0, 7:11] = [C0[0].real, C0[0].imag, C0[1].real, C0[1].imag]
    W0 = [C0[i] * np.exp(1j * (i + 1) * theta0) for i in on]
    z = np.concatenate([s, [0.0], *[[W.real, W.imag] for W in W0]])
    for k in range(400):
        u, state = ctrl.control(observe(k, s), state)
        s = rig.F @ s + rig.G * (u[0] - eq.u)
        z = M @ z
        np.testing.assert_allclose(s, z[:n], atol=1e-9 + 1e-6 * np.max(np.abs(z[:n])))
    assert np.max(np.abs(z[:n])) > 1e-5  # the comparison was not between zeros


def _design_loops(preset):
    """(LQI, operating point, feedforward design, sampled nominal rig) at every design point
    of the envelope of ``preset``."""
    lqi = lqi_of(preset)
    p = lqi.spec.params
    for eq in design_points(p):
        yield lqi, eq, design(p, eq.x3, lqi), sampled_rig(p, eq, lqi.spec.control_dt, lqi.spec.sensors)


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_feedforward_keeps_the_nominal_loop_stable_over_the_envelope(preset):
    adapted = 0
    for lqi, eq, d, rig in _design_loops(preset):
        assert d.decay_rate > 0, (eq.u, d)
        # decay rate of the exact linear loop, eigenvalues of its matrix computed directly
        rho = np.max(np.abs(np.linalg.eigvals(feedforward_closed_loop(rig, lqi, d.gains))))
        assert rho < 1.0
        assert d.decay_rate == pytest.approx(-math.log(rho) / lqi.spec.control_dt, rel=1e-9)
        if 0.3 < eq.u < 2.8:  # the first harmonic adapts from well above uc1 to 2.7 V
            adapted += int(np.isfinite(d.adaptation_time[0]))
            assert d.noise_ratio <= 1.3 + 1e-12
    assert adapted == 5
    p = lqi.spec.params
    for u in (0.7, 1.0, 1.5):  # where the rig turns near the torsional resonance
        d = design(p, design_point(p, voltage=u).x3, lqi)
        assert d.adaptation_time[0] <= 20.0


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_variable_step_keeps_the_nominal_loop_stable(preset):
    # The variable step scales each g_h by s_h in [0, 1]; frozen at any s the exact linear
    # loop stays stable, and for a slow adaptation decays as averaging predicts: at s / T
    # of the slowest adapted harmonic (T its adaptation time).
    checked = 0
    for lqi, eq, d, rig in _design_loops(preset):
        times = d.adaptation_time[np.isfinite(d.adaptation_time)]
        if times.size == 0:
            continue
        for s in (1e-3, 0.01, 0.1, 0.25, 0.5, 0.75, 1.0):
            M = feedforward_closed_loop(rig, lqi, s * d.gains)
            rho = np.max(np.abs(np.linalg.eigvals(M)))
            assert rho < 1.0, (eq.u, s, rho)
            rate = -math.log(rho) / lqi.spec.control_dt
            assert rate >= 0.5 * min(d.lqi_decay_rate, s / times.max()), (eq.u, s, rate)
            if s <= 0.1:
                assert rate == pytest.approx(s / times.max(), rel=0.05), (eq.u, s)
            checked += 1
    assert checked >= 7 * 7


def test_step_scale_follows_the_harmonic_against_its_noise():
    P = np.array([0.0, 1e-3, 1e-2, 1.0]) * np.exp(0.3j)
    s = step_scale(P, np.full(4, 1e-5), significance=4.0)
    np.testing.assert_allclose(s, [0.0, 1e-6 / 4.1e-5, 1e-4 / 1.4e-4, 1.0 / (1.0 + 4e-5)], rtol=1e-12)
    assert step_scale(np.zeros(1, complex), np.zeros(1))[0] == 0.0  # nothing seen yet: no step
    with pytest.raises(ValueError, match="variable_step"):
        LQIAngleFeedforward(ControllerSpec.default(), variable_step="yes")
    with pytest.raises(ValueError, match="significance"):
        LQIAngleFeedforward(ControllerSpec.default(), variable_step=True, significance=0.0)


def test_gains_file_sets_the_options(tmp_path):
    from drill_env.agents.controllers.gains import classical_controller, gains_path

    data = yaml.safe_load(gains_path().read_text())
    data["presets"]["brake"]["lqi_angle_ff"] = {"options": {"variable_step": True, "significance": 3.0}}
    good = tmp_path / "on.yaml"
    good.write_text(yaml.safe_dump(data))
    ctrl = classical_controller("lqi_angle_ff", ControllerSpec.default(), "brake", good)
    assert ctrl.variable_step and ctrl.significance == 3.0
    assert not classical_controller("lqi_angle_ff", ControllerSpec.default(), "brake").variable_step
    data["presets"]["brake"]["lqi_angle_ff"] = {"options": {"step": True}}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ValueError, match="lqi_angle_ff.options"):
        classical_controller("lqi_angle_ff", ControllerSpec.default(), "brake", bad)


@pytest.mark.parametrize(
    "options, message",
    [
        ({"step": True}, r"lqi_angle_ff\.options: expected a mapping of"),
        ({"variable_step": "yes"}, r"lqi_angle_ff\.options\.variable_step: expected true or false"),
        (
            {"significance": 0.0},
            r"lqi_angle_ff\.options\.significance: 0\.0 is outside the allowed range \(0, inf\)",
        ),
        ({"averaging_times": float("nan")}, r"options\.averaging_times: nan is outside the allowed range"),
    ],
)
def test_benchmark_refuses_bad_feedforward_options_before_any_run(tmp_path, options, message):
    """A bad option in a --gains file is a one-line error naming it (exit 2), before the runs."""
    from drill_env.agents.controllers.gains import gains_path

    data = yaml.safe_load(gains_path().read_text())
    data["presets"]["brake"]["lqi_angle_ff"] = {"options": options}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    res = CliRunner().invoke(
        app, ["benchmark", "--quick", "--controllers", "lqi_angle_ff", "--gains", str(bad), "--out", str(out)]
    )
    assert res.exit_code == 2, res.output
    assert re.search(message, res.output) and "Traceback" not in res.output
    assert not (out / "benchmark.csv").exists()


def test_phase_error_of_a_detuned_rig_is_far_from_ninety_degrees():
    lqi = lqi_of("brake")
    true = nominal_params(load_params(DETUNED))
    for u in (0.7, 1.0, 1.5):
        w = design_point(lqi.spec.params, voltage=u).x3
        err = np.degrees(np.abs(phase_error(lqi.spec.params, true, w, lqi)))
        assert np.all(err < 20.0), (u, err)
        assert np.all(err > 0.01)  # the rig differs: the phase does
    # the response from an added voltage to the lower speed: through the string, largest
    # next to the torsional resonance (1.55 rad/s)
    mags = [abs(voltage_to_lower_speed(lqi.spec.params, w, lqi)[0]) for w in (0.4, 1.5, 5.0)]
    assert mags[1] > mags[0] and mags[1] > mags[2]


# -- on the simulated rig --------------------------------------------------------------------------


@pytest.mark.parametrize("variable_step", [False, True])
@pytest.mark.parametrize("voltage", [0.8, 1.0])
def test_rejects_a_pure_position_friction(voltage, variable_step):
    # a1 = 0.15 at the lower disk, nothing else changed; phase and seed not used in the design
    plant = load_params("brake").replace(lower_position_amp_1=0.15, lower_position_phase_1=-1.9)
    env = make_env("brake", SHORT, 1, params=plant)
    design_env = make_env("brake", SHORT, 1)
    gains = load_gains()["presets"]["brake"]["lqi"]["gains"]
    ctrls = {
        "lqi": build_controller("lqi", design_env, "brake"),
        "lqi_angle_ff": LQIAngleFeedforward(
            ControllerSpec.from_env(design_env), variable_step=variable_step, **gains
        ),
    }
    amps = {
        name: evaluate(ctrl, "brake", voltage, 7, SHORT, env=env, open_loop_amplitude=0.0)
        for name, ctrl in ctrls.items()
    }
    assert amps["lqi"].amplitude > 0.5  # the LQI alone leaves a large forced oscillation
    assert amps["lqi_angle_ff"].amplitude < 0.1 * amps["lqi"].amplitude
    assert amps["lqi_angle_ff"].rms_error < 0.2 * amps["lqi"].rms_error
    assert amps["lqi_angle_ff"].stick_fraction == 0.0


def test_rejects_position_friction_at_the_lowest_slipping_speed():
    # 0.3 V with the brake: the lower disk turns at ~0.3 rad/s, one revolution in ~21 s, four
    # in the benchmark's 90 s run. A once-per-revolution friction (a1 = 0.13, a phase the
    # plant family does not use, a seed not used in the design) forces an oscillation of
    # 0.15 rad/s in open loop, which the LQI alone nearly doubles; the feedforward must cancel
    # it within the run. With a whole turn per adaptation time required, the first harmonic
    # adapted in 40 s here and left more than half of the open-loop amplitude.
    plant = load_params("brake").replace(lower_position_amp_1=0.13, lower_position_phase_1=2.3)
    settings = EpisodeSettings()
    env = make_env("brake", settings, params=plant)
    design_env = make_env("brake", settings)
    ff = build_controller("lqi_angle_ff", design_env, "brake")
    assert ff.design(design_point(ff.spec.params, voltage=0.3).x3).adaptation_time[0] <= 20.0
    reference = evaluate(
        OpenLoop(ControllerSpec.from_env(env)), "brake", 0.3, 6, settings, env=env, open_loop_amplitude=0.0
    )
    ctrls = {"lqi": build_controller("lqi", design_env, "brake"), "lqi_angle_ff": ff}
    res = {
        name: evaluate(ctrl, "brake", 0.3, 6, settings, env=env, open_loop_amplitude=reference.amplitude)
        for name, ctrl in ctrls.items()
    }
    assert res["lqi"].suppression < 0.0
    assert res["lqi_angle_ff"].rms_error < 0.2 * res["lqi"].rms_error
    assert res["lqi_angle_ff"].suppression >= 0.85, res["lqi_angle_ff"]
    assert res["lqi_angle_ff"].stick_fraction == 0.0


def test_observation_versions_give_the_same_rejection():
    # v0 integrates the lower encoder counts, v1 reads the encoder angle: a constant offset
    plant = load_params("brake").replace(lower_position_amp_1=0.15, lower_position_phase_1=0.4)
    amps = []
    for version in (0, 1):
        env = make_env("brake", SHORT, version, params=plant)
        ctrl = build_controller("lqi_angle_ff", make_env("brake", SHORT, version), "brake")
        assert (ctrl._angle is None) == (version == 0)
        amps.append(evaluate(ctrl, "brake", 0.9, 2, SHORT, env=env, open_loop_amplitude=0.0).amplitude)
    assert amps[0] == pytest.approx(amps[1], rel=0.2, abs=0.01)
    assert max(amps) < 0.25  # the LQI alone: 1.4 rad/s; 60 s is 3 adaptation times after the hold


@pytest.mark.parametrize(("voltage", "seed"), [(0.7, 3), (1.5, 4), (3.0, 3)])
def test_no_loss_on_the_nominal_rig(voltage, seed):
    env = make_env("brake", EpisodeSettings())
    res = {
        name: evaluate(
            build_controller(name, env, "brake"), "brake", voltage, seed, EpisodeSettings(), env=env
        )
        for name in ("lqi", "lqi_angle_ff")
    }
    assert res["lqi_angle_ff"].open_loop_amplitude > 0.5  # a cycle is predicted
    assert res["lqi_angle_ff"].suppression >= 0.99
    assert res["lqi_angle_ff"].rms_error <= res["lqi"].rms_error + 0.01
    assert res["lqi_angle_ff"].stick_fraction == 0.0


class _FeedforwardAmplitude:
    """Runs a :class:`LQIAngleFeedforward` and records the RMS over a revolution of its u_ff,
    sqrt(sum_h |C_h|^2 / 2) [V], every control period."""

    def __init__(self, ctrl: LQIAngleFeedforward):
        self.ctrl, self.rms = ctrl, []

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        action, state = self.ctrl.predict(obs, state=state, episode_start=episode_start)
        self.rms.append(math.sqrt(np.sum(state[0, 7:11] ** 2) / 2))
        return action, state


def test_variable_step_stops_learning_the_angle_noise():
    # nominal braked rig, nothing locked to the angle, 3 mrad encoder angle noise; voltage and
    # seed not used in the design
    settings = EpisodeSettings()
    env = make_env("brake", settings, overrides={"sensors": {"angle_noise_std": 3e-3}})
    spec = ControllerSpec.from_env(make_env("brake", settings))
    gains = load_gains()["presets"]["brake"]["lqi"]["gains"]
    rms, res = {}, {}
    window = int(settings.window / spec.control_dt)
    for on in (False, True):
        rec = _FeedforwardAmplitude(LQIAngleFeedforward(spec, variable_step=on, **gains))
        res[on] = evaluate(rec, "brake", 0.85, 11, settings, env=env)
        rms[on] = float(np.sqrt(np.mean(np.square(rec.rms[-window:]))))
    assert rms[False] > 2e-3  # off, the coefficients wander on the noise
    assert rms[True] < 0.6 * rms[False], rms
    assert res[True].suppression >= res[False].suppression - 0.002


def test_registered_on_the_lqi_gains():
    assert "lqi_angle_ff" in CLASSICAL
    env = make_env("brake", SHORT)
    ctrl = build_controller("lqi_angle_ff", env, "brake")
    assert isinstance(ctrl, LQIAngleFeedforward)
    assert ctrl.voltage_scale == load_gains()["presets"]["brake"]["lqi"]["gains"]["voltage_scale"]
    with pytest.raises(ValueError, match="adaptation_time"):
        LQIAngleFeedforward(ControllerSpec.default(), adaptation_time=0.0)
    # open loop on the same plant: the reference the benchmark divides by
    m = evaluate(
        OpenLoop(ControllerSpec.from_env(env)), "brake", 1.0, 0, SHORT, env=env, open_loop_amplitude=0.0
    )
    assert m.amplitude > 1.0


# -- designing on a given model --------------------------------------------------------------------


def write_rig(path: Path, **changes) -> Path:
    data = load_params("brake").to_dict()
    data.update(changes)
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.slow  # two LQI tunings: a minute and a half of CPU
def test_tune_on_model_changes_the_gains_with_the_model(tmp_path):
    committed = load_gains()["presets"]["brake"]["lqi"]["gains"]
    same = write_rig(tmp_path / "same.yaml")
    heavy = write_rig(tmp_path / "heavy.yaml", lower_inertia=0.0326 * 1.2)
    got_same = tune_on_model(load_params(same), str(same), "brake", kinds=("lqi",))
    got_heavy = tune_on_model(load_params(heavy), str(heavy), "brake", kinds=("lqi",))
    g_same = got_same["presets"]["brake"]["lqi"]["gains"]
    g_heavy = got_heavy["presets"]["brake"]["lqi"]["gains"]
    assert g_same["voltage_scale"] == pytest.approx(committed["voltage_scale"], rel=1e-9)
    # deterministic: the same model gives the same gain to 1e-9, J_l +20 % moves it by 1.5 %
    assert abs(g_heavy["voltage_scale"] / committed["voltage_scale"] - 1) > 0.005
    assert got_heavy["design_model"] == {"preset": "brake", "params": str(heavy), "name": "brake"}


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"lower_inertia": -1.0}, "lower_inertia"),
        ({"lower_inertia": float("nan")}, "lower_inertia"),
        ({"stiffness": 0.1}, "stiffness"),
        ({"effects": {"lower_position_amp_1": 1.5}}, "lower_position_amp_1"),
        ({"effects": {"bump": 1.0}}, "bump"),
    ],
)
@pytest.mark.parametrize("command", ["tune", "train"])
def test_params_files_are_validated_like_presets(tmp_path, changes, field, command):
    bad = write_rig(tmp_path / "bad.yaml", **changes)
    args = ["--params", str(bad), "--out", str(tmp_path / "out.yaml")]
    if command == "train":
        args = [
            "--algo",
            "ppo",
            "--config",
            str(ROOT / "configs" / "agents" / "experiments" / "ppo_from_scratch.yaml"),
            "--params",
            str(bad),
        ]
        args += ["--out", str(tmp_path / "out")]
    res = CliRunner().invoke(app, [command, *args])
    assert res.exit_code == 2, res.output
    assert field in res.output and res.output.strip().count("\n") == 0
    assert "Traceback" not in res.output
    assert not (tmp_path / "out.yaml").exists()


def test_params_cli_rejects_missing_files_and_two_presets(tmp_path):
    runner = CliRunner()
    res = runner.invoke(app, ["tune", "--params", str(tmp_path / "none.yaml")])
    assert res.exit_code == 2 and "--params" in res.output
    res = runner.invoke(app, ["tune", "--params", str(DETUNED), "--preset", "brake,no_brake"])
    assert res.exit_code == 2 and "one preset" in res.output
    res = runner.invoke(
        app,
        [
            "train",
            "--algo",
            "ppo",
            "--config",
            str(ROOT / "configs" / "agents" / "experiments" / "ppo_from_scratch.yaml"),
            "--params",
            str(tmp_path),
        ],
    )
    assert res.exit_code == 2 and "--params" in res.output


@pytest.mark.slow
def test_cli_tune_params_writes_gains_designed_on_the_model(tmp_path):
    heavy = write_rig(tmp_path / "heavy.yaml", lower_inertia=0.0326 * 1.2)
    out = tmp_path / "gains.yaml"
    res = CliRunner().invoke(app, ["tune", "--params", str(heavy), "--out", str(out)])
    assert res.exit_code == 0, res.output
    data = yaml.safe_load(out.read_text())
    assert list(data["presets"]) == ["brake"]  # the preset whose friction the file has
    assert data["design_model"]["params"] == str(heavy)
    committed = load_gains()["presets"]["brake"]
    for kind in ("torque_feedback", "lqi"):
        new, old = data["presets"]["brake"][kind]["gains"], committed[kind]["gains"]
        assert any(abs(new[k] / old[k] - 1) > 0.01 for k in old), kind


@pytest.mark.slow
def test_cli_train_params_trains_on_the_model(tmp_path, monkeypatch):
    from drill_env.agents.learning.rl import load_config

    cfg = load_config(ROOT / "configs" / "agents" / "experiments" / "ppo_from_scratch.yaml").to_dict()
    cfg.update(total_timesteps=128, n_envs=2)
    cfg["evaluation"] = {"every_steps": 64, "episodes_per_regime": 1, "seed": 7}
    cfg["env_kwargs"] = {"warmup_time": 2.0, "warmup_jitter": 0.5}
    cfg["hyperparameters"].update(n_steps=32, batch_size=32, n_epochs=1)
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(cfg))
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out" / "ppo"
    args = ["train", "--algo", "ppo", "--config", "tiny.yaml", "--no-progress", "--params", str(DETUNED)]
    res = CliRunner().invoke(app, [*args, "--out", str(out)])
    assert res.exit_code == 0, res.output
    written = yaml.safe_load((out / "config.yaml").read_text())
    assert written["env_kwargs"]["params"] == str(DETUNED.resolve())
    assert written["env_kwargs"]["warmup_time"] == 2.0  # the config's other arguments stay
    # the environment it describes is the model's rig
    import gymnasium as gym

    env = gym.make(written["env_id"], **written["env_kwargs"])
    assert env.unwrapped.settings.params.effects.lower_position_amp_1 == 0.15
