"""The controllers: SB3's predict protocol, every controller in both environments, the PI's
anti-windup at the 5 V limit, the linear design model, the tuning and the evaluation path."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import drill_env  # noqa: F401  (registers the environments)
from drill_env.agents.controllers.base import Controller, ControllerSpec
from drill_env.agents.controllers.linear_model import (
    design_point,
    equilibrium_observation,
    linearise,
    sampled_rig,
)
from drill_env.agents.controllers.lqi import LQI
from drill_env.agents.controllers.open_loop import OpenLoop
from drill_env.agents.controllers.pi import LowerSpeedPI, UpperSpeedPI
from drill_env.agents.controllers.torque_feedback import TorqueFeedback
from drill_env.agents.controllers.tuning import (
    TUNED_GAINS,
    closed_loop,
    controller_matrices,
    design_points,
    evaluate_design,
    make_controller,
    tune,
)
from drill_env.agents.evaluation.episodes import (
    EpisodeSettings,
    env_id_of,
    evaluate,
    make_env,
    run_episode,
    suppression,
)
from drill_env.agents.registry import (
    CLASSICAL,
    CONTROLLERS,
    build_controller,
    default_agents_dir,
    load_gains,
    observation_version,
)
from drill_env.analysis import critical_friction_slope
from drill_env.friction import lower_friction_curve

PRESETS = ("brake", "no_brake")
SHORT = EpisodeSettings(duration=4.0, window=2.0, warmup_time=3.0, warmup_jitter=1.0)


@pytest.fixture(scope="module")
def spec_brake() -> ControllerSpec:
    return ControllerSpec.default("brake")


def obs_at(spec: ControllerSpec, voltage: float, **changes: float) -> np.ndarray:
    """The observation (as the env returns it) at the nominal equilibrium, with changes in SI units."""
    y = equilibrium_observation(spec.params, design_point(spec.params, voltage=voltage))
    for name, value in changes.items():
        y[spec.index(name)] = value
    return spec.to_observation(y)


# -- every controller in both environments ------------------------------------------------------


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("name", CONTROLLERS)
def test_every_controller_runs_in_both_envs(preset, name):
    # each on the observation version it reads (a learned policy: the one it was trained on)
    env = gym.make(env_id_of(preset, observation_version(name, preset)))
    ctrl = build_controller(name, env, preset)
    traj = run_episode(env, ctrl, seed=3, n_steps=60, options={"nominal_voltage": 1.0})
    assert traj.t.size == 60 and traj.sim_status == 0
    assert np.all(np.isfinite(traj.voltage)) and np.all(np.abs(traj.voltage) <= 5.0)
    assert np.all(np.isfinite(traj.true_state))


@pytest.mark.parametrize("preset", PRESETS)
def test_observation_versions_run_the_same_episode(preset):
    # v1 only observes more: a classical controller (reading the v0 entries every version
    # starts with) drives the same rig through the same episode on v0 and v1
    runs = []
    for version in (0, 1):
        env = gym.make(env_id_of(preset, version))
        ctrl = build_controller("lqi", env, preset)
        runs.append(run_episode(env, ctrl, seed=5, n_steps=80, options={"nominal_voltage": 2.0}))
    np.testing.assert_array_equal(runs[0].voltage, runs[1].voltage)
    np.testing.assert_array_equal(runs[0].true_state, runs[1].true_state)
    np.testing.assert_array_equal(runs[0].reward, runs[1].reward)


def test_v0_policies_stay_evaluable():
    # the version-0 policies (results/agents/v0) run on the v0 envs, chosen from the policy
    v0_dir = default_agents_dir() / "v0"
    for algo in ("ppo", "sac"):  # the policies kept in v0/
        for preset in PRESETS:
            assert observation_version(algo, preset, v0_dir) == 0
            env = gym.make(env_id_of(preset, 0))
            ctrl = build_controller(algo, env, preset, agents_dir=v0_dir)
            traj = run_episode(env, ctrl, seed=1, n_steps=20, options={"nominal_voltage": 2.0})
            assert traj.sim_status == 0 and np.all(np.isfinite(traj.voltage))
            with pytest.raises(ValueError, match="observation_space"):
                build_controller(algo, gym.make(env_id_of(preset, 1)), preset, agents_dir=v0_dir)


def test_controllers_follow_sb3_predict_protocol(spec_brake):
    ctrl = make_controller(
        "torque_feedback", spec_brake, load_gains()["presets"]["brake"]["torque_feedback"]["gains"]
    )
    obs = obs_at(spec_brake, 2.0, upper_speed_mean=3.0, twist=2.1)
    a1, s1 = ctrl.predict(obs)
    assert a1.shape == (1,) and a1.dtype == np.float32 and s1.shape == (1, ctrl.state_size)
    batch = np.stack([obs, obs_at(spec_brake, 1.0), obs])
    a, s = ctrl.predict(batch, state=None, episode_start=np.ones(3, bool), deterministic=True)
    assert a.shape == (3, 1) and s.shape == (3, ctrl.state_size)
    assert a[0, 0] == a1[0] and a[2, 0] == a1[0]
    # rows evolve independently; episode_start restarts only its row
    a2, s2 = ctrl.predict(batch, state=s, episode_start=np.array([False, False, True]))
    assert np.array_equal(s2[2], s[2]) and not np.array_equal(s2[0], s[0])
    with pytest.raises(ValueError, match="observation"):
        ctrl.predict(np.zeros(5, np.float32))
    with pytest.raises(ValueError, match="state"):
        ctrl.predict(batch, state=np.zeros((2, ctrl.state_size)))


def test_open_loop_applies_the_nominal_voltage(spec_brake):
    a, _ = OpenLoop(spec_brake).predict(obs_at(spec_brake, 1.7, lower_speed=0.0, twist=5.0))
    assert a[0] * 5.0 == pytest.approx(1.7, abs=1e-6)


def test_spec_scaling_is_consistent_across_env_configurations():
    """Physical units and volts actions: the controller applies the same voltages."""
    volts = []
    for kwargs in ({}, {"normalize_observation": False, "action_mode": "voltage"}):
        env = gym.make("DrillString-v0", **kwargs)
        spec = ControllerSpec.from_env(env)
        ctrl = LQI(spec, voltage_scale=0.06)
        traj = run_episode(env, ctrl, seed=1, n_steps=40, options={"nominal_voltage": 2.0})
        volts.append(traj.voltage)
    np.testing.assert_allclose(volts[0], volts[1], atol=2e-5)


# -- PI anti-windup at the limit ---------------------------------------------------------------


@pytest.mark.parametrize("cls", [UpperSpeedPI, LowerSpeedPI])
def test_pi_anti_windup_at_the_voltage_limit(spec_brake, cls):
    kp, ki = 0.5, 2.0
    disk = "upper_speed_mean" if cls is UpperSpeedPI else "lower_speed_mean"
    w = design_point(spec_brake.params, voltage=2.0).x3
    stalled = obs_at(spec_brake, 2.0, **{disk: w - 3.0})  # far too slow: the PI saturates at +5 V
    ahead = obs_at(spec_brake, 2.0, **{disk: w + 0.5})  # then too fast

    def hold_then_release(ctrl):
        state = None
        for k in range(400):  # 20 s, at the limit after the integral has built up
            a, state = ctrl.predict(stalled, state=state)
            if k >= 100:
                assert a[0] * 5.0 == pytest.approx(5.0)
        z_held = state[0, 0]
        a, state = ctrl.predict(ahead, state=state)
        return z_held, a[0] * 5.0

    z, u_after = hold_then_release(cls(spec_brake, kp, ki))
    # Back-calculation holds the integrator where the integral part alone sits at the limit
    # (Tt = Ti): u_nom + ki z -> 5 V, so one step of negative error leaves the limit.
    assert 2.0 + ki * z == pytest.approx(5.0, abs=0.05)
    assert u_after < 5.0 - 0.1
    # Without anti-windup the integral winds up and the output stays stuck at the limit.
    z_wound, u_wound = hold_then_release(cls(spec_brake, kp, ki, anti_windup=False))
    assert z_wound > 5 * z and u_wound == pytest.approx(5.0)


def test_pi_in_closed_loop_never_requests_beyond_the_limit():
    env = gym.make("DrillString-v0")
    ctrl = build_controller("pi_lower", env, "brake")
    traj = run_episode(env, ctrl, seed=0, n_steps=400, options={"nominal_voltage": 4.5})
    assert np.all(np.abs(traj.voltage_requested) <= 5.0 + 1e-6)


def test_gain_validation_names_the_field(spec_brake):
    with pytest.raises(ValueError, match="kp"):
        UpperSpeedPI(spec_brake, -1.0, 1.0)
    with pytest.raises(ValueError, match="z_imp"):
        TorqueFeedback(spec_brake, 0.1, 1.0, 0.0)
    with pytest.raises(ValueError, match="voltage_scale"):
        LQI(spec_brake, voltage_scale=math.inf)
    with pytest.raises(ValueError, match="kind"):
        make_controller("pid", spec_brake, {})


# -- controllers at rest at the equilibrium, and their linearisation ---------------------------


@pytest.mark.parametrize("kind", list(TUNED_GAINS))
def test_controllers_hold_the_nominal_equilibrium(spec_brake, kind):
    ctrl = make_controller(kind, spec_brake, load_gains()["presets"]["brake"][kind]["gains"])
    for u in (0.4, 2.0, 4.9):
        obs = obs_at(spec_brake, u)
        a, s = ctrl.predict(obs)
        a2, s2 = ctrl.predict(obs, state=s)
        assert a[0] * 5.0 == pytest.approx(u, abs=1e-5) and a2[0] * 5.0 == pytest.approx(u, abs=1e-5)
        nd = getattr(ctrl, "n_dynamic_states", ctrl.state_size)
        np.testing.assert_allclose(s2[:, :nd], s[:, :nd], atol=1e-9)


def test_torque_feedback_starts_from_the_nominal_string_torque(spec_brake):
    ctrl = TorqueFeedback(spec_brake, 0.1, 1.0, 0.05)
    w = design_point(spec_brake.params, voltage=2.0).x3
    _, s = ctrl.predict(obs_at(spec_brake, 2.0))
    assert s[0, 1] == pytest.approx(float(lower_friction_curve(spec_brake.params, w)))
    # a torque rise lowers the top drive's speed set point by dT / z_imp: less voltage
    a0, _ = ctrl.predict(obs_at(spec_brake, 2.0))
    a1, _ = ctrl.predict(obs_at(spec_brake, 2.0, twist=obs_at(spec_brake, 2.0)[2] * 2.0 + 0.1))
    assert a1[0] < a0[0]


def test_probed_pi_matrices_are_the_pi_law(spec_brake):
    kp, ki = 0.7, 1.3
    eq = design_point(spec_brake.params, voltage=1.0)
    Ac, Bc, Cc, Dc = controller_matrices(UpperSpeedPI(spec_brake, kp, ki), eq)
    dt = spec_brake.control_dt
    np.testing.assert_allclose(Ac, [[1.0]], atol=1e-8)
    np.testing.assert_allclose(Bc, [[0, 0, 0, 0, -dt, 0]], atol=1e-8)
    np.testing.assert_allclose(Cc, [ki], atol=1e-7)
    np.testing.assert_allclose(Dc, [0, 0, 0, 0, -kp, 0], atol=1e-7)


def test_sampled_rig_has_the_continuous_eigenvalues(brake):
    for u in (0.3, 1.0, 3.0):
        eq = design_point(brake, voltage=u)
        A, _ = linearise(brake, eq)
        rig = sampled_rig(brake, eq, 0.05)
        # sensor filter poles are fast and the step-mean / last-voltage states are 0 poles,
        # so the slowest mode of the sampled model is the rig's
        assert rig.open_loop_decay_rate() == pytest.approx(-np.max(np.linalg.eigvals(A).real), rel=1e-6)
        assert (rig.open_loop_decay_rate() > 0) == eq.stable
    with pytest.raises(ValueError, match="voltage"):
        design_point(brake, voltage=0.05)


def test_open_loop_closed_loop_is_the_rig(spec_brake):
    eq = design_point(spec_brake.params, voltage=1.0)
    rig = sampled_rig(spec_brake.params, eq, spec_brake.control_dt)
    A, *_ = closed_loop(rig, controller_matrices(OpenLoop(spec_brake), eq))
    np.testing.assert_allclose(A, rig.F, atol=1e-12)


# -- the tuning's claims --------------------------------------------------------------------------


@pytest.mark.parametrize("preset", ["brake", "no_brake"])
def test_speed_pis_cannot_damp_the_negative_slope_points(preset):
    """Whatever the gains, a speed PI leaves the equilibrium at the steepest negative friction
    slope unstable; torque feedback and the LQI, as tuned, damp every design point."""
    spec = ControllerSpec.default(preset)
    d_crit = critical_friction_slope(spec.params)
    eqs = design_points(spec.params)
    worst = min(eqs, key=lambda e: e.friction_slope)
    assert worst.friction_slope < d_crit
    rig = sampled_rig(spec.params, worst, spec.control_dt)
    for kind in ("pi_upper", "pi_lower"):
        for kp in np.geomspace(0.01, 10.0, 7):
            for ki in np.geomspace(0.01, 30.0, 7):
                res = evaluate_design(make_controller(kind, spec, {"kp": kp, "ki": ki}), [rig])
                assert res[0].decay_rate < 0.0, (kind, kp, ki)
    gains = load_gains()["presets"][preset]
    for kind in ("torque_feedback", "lqi"):
        rec = gains[kind]
        assert rec["design_set"] == "envelope" and rec["envelope_decay_rate"] > 0.0
        assert rec["max_noise_v"] <= 0.05 + 1e-6
        res = evaluate_design(make_controller(kind, spec, rec["gains"]), [rig])
        assert res[0].decay_rate > 0.0


# the LQI's tuning searches its weights over simulated episodes (about 14 s of CPU): slow run
@pytest.mark.parametrize("kind", ["pi_upper", pytest.param("lqi", marks=pytest.mark.slow)])
def test_committed_gains_are_reproduced_by_the_procedure(spec_brake, kind):
    committed = load_gains()["presets"]["brake"]
    fresh = tune(kind, spec_brake)
    for name, value in committed[kind]["gains"].items():
        assert fresh.gains[name] == pytest.approx(value, rel=1e-3), (kind, name)


@pytest.mark.slow
def test_all_committed_gains_are_reproduced():
    from drill_env.agents.controllers.tuning import tune_all

    fresh = tune_all()
    committed = load_gains()
    for preset, kinds in committed["presets"].items():
        for kind, rec in kinds.items():
            for name, value in rec["gains"].items():
                assert fresh["presets"][preset][kind]["gains"][name] == pytest.approx(value, rel=1e-3)


# -- evaluation ----------------------------------------------------------------------------------


def test_suppression_hand_computed():
    assert suppression(1.0, 4.0) == pytest.approx(0.75)
    assert suppression(0.0, 2.5) == 1.0
    assert suppression(5.0, 2.5) == pytest.approx(-1.0)
    assert math.isnan(suppression(0.3, 0.0))  # no predicted cycle: undefined
    with pytest.raises(ValueError, match="amplitude"):
        suppression(-1.0, 2.0)
    with pytest.raises(ValueError, match="open_loop_amplitude"):
        suppression(1.0, math.nan)


def test_metrics_of_a_hand_computed_run(spec_brake):
    """A constant voltage below uc1 keeps the rig stuck at rest: every metric is known."""

    class Zero(Controller):
        name = "zero"

        def control(self, y, state):
            return np.zeros(y.shape[0]), state

    m = evaluate(Zero(spec_brake), "brake", 0.2, 0, SHORT)
    w = design_point(spec_brake.params, voltage=0.2).x3
    assert m.amplitude == 0.0 and m.mean_speed == 0.0 and m.stick_fraction == 1.0
    assert m.rms_error == pytest.approx(w, rel=1e-9)
    assert m.u_mean_abs == 0.0 and m.u_peak_abs == 0.0 and m.u_limit_fraction == 0.0
    assert m.open_loop_amplitude == 0.0 and math.isnan(m.suppression)


@pytest.mark.parametrize(
    ("preset", "voltage"), [("brake", 1.0), ("brake", 2.0), ("no_brake", 1.0), ("no_brake", 1.5)]
)
def test_open_loop_suppression_is_zero_where_a_cycle_is_predicted(preset, voltage):
    env = make_env(preset, EpisodeSettings())
    m = evaluate(OpenLoop(ControllerSpec.from_env(env)), preset, voltage, 0, EpisodeSettings(), env=env)
    assert m.open_loop_amplitude > 0.5
    assert abs(m.suppression) < 0.01
    assert m.x3_max == pytest.approx(m.open_loop_amplitude + m.x3_min, rel=0.01)


def test_same_seed_same_start_for_every_controller():
    env = make_env("brake", SHORT)
    starts = []
    for name in CLASSICAL:
        ctrl = build_controller(name, env, "brake")
        traj = run_episode(env, ctrl, seed=11, n_steps=1, options={"nominal_voltage": 2.0})
        starts.append(traj.reset_info["true_state"])
    for s in starts[1:]:
        np.testing.assert_array_equal(s, starts[0])
    a = evaluate(build_controller("lqi", env, "brake"), "brake", 2.0, 5, SHORT, env=env)
    b = evaluate(build_controller("lqi", env, "brake"), "brake", 2.0, 5, SHORT)
    assert a.amplitude == b.amplitude and a.episode_return == b.episode_return


def test_episode_settings_validate():
    with pytest.raises(ValueError, match="window"):
        EpisodeSettings(duration=10.0, window=20.0)
    with pytest.raises(ValueError, match="duration"):
        EpisodeSettings(duration=-1.0)
    with pytest.raises(ValueError, match="env_kwargs"):
        EpisodeSettings(env_kwargs={"warmup_time": 3.0})
    with pytest.raises(ValueError, match="voltage"):
        evaluate(OpenLoop(ControllerSpec.default()), "brake", 7.0, 0, SHORT)
    with pytest.raises(ValueError, match="preset"):
        make_env("icy", SHORT)


def test_a_missing_no_brake_policy_is_an_error_not_the_braked_rigs(tmp_path):
    import shutil

    from drill_env.agents.registry import default_agents_dir, policy_path

    (tmp_path / "ppo_lqi_clone").mkdir()
    shutil.copy(
        default_agents_dir() / "ppo_lqi_clone" / "policy.zip", tmp_path / "ppo_lqi_clone" / "policy.zip"
    )
    assert policy_path("ppo_lqi_clone", "brake", tmp_path) == tmp_path / "ppo_lqi_clone" / "policy.zip"
    with pytest.raises(ValueError, match=r"preset 'no_brake' at .*ppo_lqi_clone_no_brake/policy.zip"):
        policy_path("ppo_lqi_clone", "no_brake", tmp_path)


@pytest.mark.parametrize(
    "name",
    [
        "ppo",
        "sac",
        "ppo_no_brake",
        "sac_no_brake",
        "ppo_lqi_clone",
        "ppo_lqi_clone_no_brake",
        "v0/ppo",
        "v0/sac",
    ],
)
def test_the_numpy_forward_pass_is_sb3s_deterministic_predict(name):
    from drill_env.agents.learning.rl import load_policy

    policy = load_policy(Path(__file__).resolve().parents[1] / "results" / "agents" / name / "policy.zip")
    assert policy._actor is not None  # the committed policies take the fast path
    space = policy.model.observation_space
    obs = (
        np.random.default_rng(7).uniform(space.low, space.high, size=(300, space.shape[0])).astype(np.float32)
    )
    for o in obs:
        fast, state = policy.predict(o)
        ref, _ = policy.model.predict(o, deterministic=True)
        assert state is None and fast.shape == ref.shape and fast.dtype == ref.dtype
        np.testing.assert_allclose(fast, ref, rtol=0, atol=5e-5)  # float32 sums in another order
    batch, _ = policy.predict(obs)
    np.testing.assert_allclose(batch, policy.model.predict(obs, deterministic=True)[0], rtol=0, atol=1e-4)


class _NoTopLevelAgents:
    """An import hook refusing a top-level ``agents`` (another distribution's, say)."""

    def find_spec(self, name, path=None, target=None):
        if name == "agents" or name.startswith("agents."):
            raise ImportError(f"{name}: a top-level agents must not be imported")
        return None


def test_a_policy_saved_under_the_former_package_name_loads_under_the_present_one(monkeypatch):
    import sys

    from stable_baselines3.common.utils import LinearSchedule

    from drill_env.agents.learning.rl import load_config, load_policy, renamed_objects

    # the braked ppo_robust as committed before its retraining (results/agents/ppo_robust until
    # the lqi_angle_ff change): it pickled its learning-rate schedule as agents.rl.LinearSchedule
    folder = Path(__file__).resolve().parent / "data" / "former_package_name" / "ppo_robust"
    assert set(renamed_objects(folder / "policy.zip")) == {"learning_rate", "lr_schedule"}
    monkeypatch.setattr(sys, "meta_path", [_NoTopLevelAgents(), *sys.meta_path])
    modules = {m for m in sys.modules if m == "agents" or m.startswith("agents.")}
    policy = load_policy(folder / "policy.zip", trusted=True)  # a file of this repository
    model = getattr(policy, "policy", policy).model  # a residual policy's learned part
    assert {m for m in sys.modules if m == "agents" or m.startswith("agents.")} == modules
    # the schedules are those of the training config, under drill_env.agents.learning.rl
    hp = load_config(folder / "config.yaml").hyperparameters
    assert hp["learning_rate"] == "lin_3.0e-4"
    assert isinstance(model.learning_rate, LinearSchedule) and model.learning_rate.start == 3.0e-4
    assert (model.learning_rate.end, model.learning_rate.end_fraction) == (0.0, 1.0)
    for progress in (1.0, 0.25):
        assert model.lr_schedule(progress) == pytest.approx(3.0e-4 * progress, rel=1e-12)
        assert model.clip_range(progress) == hp["clip_range"]


class _FormerLinearSchedule:
    """The project's own schedule before stable-baselines3's replaced it (state: ``value``)."""

    def __init__(self, value):
        self.value = value


@pytest.mark.parametrize(
    "former_module", ["agents.rl", "drill_env.agents.rl", "drill_env.agents.learning.rl"]
)
def test_renamed_objects_maps_former_module_paths_only(tmp_path, former_module):
    import base64
    import json
    import pickle
    import zipfile

    from stable_baselines3.common.utils import LinearSchedule

    from drill_env.agents.learning.rl import linear_schedule, renamed_objects

    # protocol 0 names a class as text ("c<module>\n<name>\n"): the former path written in
    former = pickle.dumps(_FormerLinearSchedule(0.5), protocol=0)
    assert b"test_agents\n_FormerLinearSchedule" in former
    former = former.replace(
        b"test_agents\n_FormerLinearSchedule", f"{former_module}\nLinearSchedule".encode()
    )
    current = pickle.dumps(linear_schedule(0.5), protocol=0)
    assert b"stable_baselines3.common.utils\nLinearSchedule" in current
    data = {
        "clip_range": {":type:": "<class 'x'>", ":serialized:": base64.b64encode(former).decode()},
        "learning_rate": {":serialized:": base64.b64encode(current).decode()},
        "gamma": 0.99,
    }
    path = tmp_path / "policy.zip"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("data", json.dumps(data))
    objects = renamed_objects(path)
    assert list(objects) == ["clip_range"]
    schedule = objects["clip_range"]
    assert type(schedule) is LinearSchedule and (schedule.start, schedule.end, schedule.end_fraction) == (
        0.5,
        0,
        1,
    )
    for progress in (1.0, 0.5, 0.1, 0.0):
        assert schedule(progress) == pytest.approx(0.5 * progress, rel=1e-15, abs=0)
    # not a model: nothing to rename, stable-baselines3 names what is wrong
    (tmp_path / "bad.zip").write_bytes(b"not a zip")
    assert renamed_objects(tmp_path / "bad.zip") == {}


@pytest.mark.parametrize(
    "name", ["ppo_lqi_clone", "ppo_robust", "ppo_lqi_clone_no_brake", "ppo_robust_no_brake"]
)
def test_committed_policies_saved_before_the_split_load_with_their_schedules(name):
    from stable_baselines3.common.utils import LinearSchedule

    from drill_env.agents.learning.rl import load_config, load_policy, renamed_objects

    folder = Path(__file__).resolve().parents[1] / "results" / "agents" / name
    # saved under the former module paths, rewritten under the present ones by
    # `drill-env upgrade-policies results/agents` (results/README.md; tests/test_policy_files.py)
    assert renamed_objects(folder / "policy.zip") == {}
    policy = load_policy(folder / "policy.zip")
    model = getattr(policy, "policy", policy).model
    hp = load_config(folder / "config.yaml").hyperparameters
    start = float(str(hp["learning_rate"]).removeprefix("lin_"))
    assert isinstance(model.learning_rate, LinearSchedule) and model.learning_rate.start == start
    assert model.lr_schedule(0.25) == pytest.approx(0.25 * start, rel=1e-12)


def test_a_policy_the_numpy_pass_does_not_cover_runs_through_sb3():
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO

    from drill_env.agents.learning.rl import SB3Policy

    env = gym.make("DrillString-v1")
    model = PPO("MlpPolicy", env, policy_kwargs={"activation_fn": torch.nn.ELU}, n_steps=64, device="cpu")
    policy = SB3Policy(model, "ppo")
    assert policy._actor is None
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(policy.predict(obs)[0], model.predict(obs, deterministic=True)[0])
    env.close()
