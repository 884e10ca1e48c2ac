"""Running a controller on a rig: the observer against the environment, the emulated rig against
the simulator, the loop and its supervisor (in process, lockstep with the emulated rig), and
the command line end to end against `drill-env emulate-rig` on loopback."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import drill_env
from drill_env.recordings.dataset import load_dataset
from drill_env.rig.emulator import EmulatedRig, LockstepRig, emulated_plant
from drill_env.rig.loop import RunSettings, run_loop, write_outputs
from drill_env.rig.observer import Observer
from drill_env.rig.supervisor import Supervisor, SupervisorLimits, Trip

ROOT = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
CLI = [sys.executable, "-m", "drill_env"]


# -- observer: the environment's own observation from the counts ---------------------------------


@pytest.mark.parametrize("env_id", ["DrillString-v0", "DrillString-v3"])
def test_observer_gives_the_environments_observation_bit_for_bit(env_id):
    env = gym.make(env_id, start="rest", sensors={"counts_per_rev": 1024})
    obs, info = env.reset(seed=3, options={"nominal_voltage": 1.6})
    base = env.unwrapped
    ob = Observer(base.settings, 1024, 1000.0)
    ob.set_point(info["target_speed"], info["nominal_voltage"])
    rng = np.random.default_rng(5)
    res = 2 * np.pi / 1024
    for k in range(40):
        obs, _, _, _, step = env.step(
            env.action_space.sample() * 0 + rng.uniform(-1, 1, 1).astype(np.float32)
        )
        s = base.last_step_samples()
        cu = np.floor(s["upper_angle"] / res).astype(np.int64)
        cl = np.floor(s["lower_angle"] / res).astype(np.int64)
        first = int(round(s["t"][0] * 1000))
        if k == 0:
            ob.start_episode()
        got = ob.update(first, cu, cl, step["voltage"])
        np.testing.assert_array_equal(got, obs, err_msg=f"step {k}")
    env.close()


# -- the emulated rig: the exact simulator, its encoders -------------------------------------------


def test_emulated_rig_follows_the_simulator_and_its_encoders():
    params, sensors = emulated_plant("no_brake", None)
    rig = EmulatedRig(params, sensors)
    rig.apply(1.2)
    counts, truth = zip(*(rig.advance(m) for m in (1, 7, 992, 1000)), strict=True)
    counts, truth = np.concatenate(counts), np.concatenate(truth)
    ref = drill_env.simulate("no_brake", 1.2, 2.0, dt=0.001)
    np.testing.assert_allclose(truth[:, 2], ref.x3[1:], atol=1e-6)
    np.testing.assert_allclose(truth[:, 4], ref.theta_l[1:], atol=1e-7)
    expect = np.floor(ref.theta_l[1:] * 2000 / (2 * np.pi))
    assert np.mean(counts[:, 1] == expect) > 0.999  # an angle on a count's edge may round either way
    assert rig.apply(7.0) == 5.0  # the amplifier's range


def test_warming_the_emulated_rig_does_not_move_it():
    """emulate-rig loads its compiled code before it announces its port (a cold start answered
    the first HELLOs seconds late); warming runs on a copy of the state."""
    warmed, fresh = (EmulatedRig(*emulated_plant("brake", None)) for _ in range(2))
    for r in (warmed, fresh):
        r.apply(2.0)
    warmed.warm()
    assert warmed.tick == 0
    np.testing.assert_array_equal(warmed.advance(300)[1], fresh.advance(300)[1])


def test_emulated_rig_refuses_what_the_wire_cannot_carry(tmp_path):
    plant = tmp_path / "plant.yaml"
    plant.write_text(
        (ROOT / "configs" / "rig" / "brake.yaml").read_text() + "sensors:\n  speed_noise_std: 0.1\n"
    )
    params, sensors = emulated_plant("brake", plant)
    with pytest.raises(ValueError, match="speed_noise_std"):
        EmulatedRig(params, sensors)


def test_plant_files_delay_reaches_the_counts(tmp_path):
    plant = tmp_path / "plant.yaml"
    plant.write_text((ROOT / "configs" / "rig" / "brake.yaml").read_text() + "actuator_delay: 0.01\n")
    params, sensors = emulated_plant("brake", plant)
    assert sensors.delay_samples == 10
    late, prompt = EmulatedRig(params, sensors), EmulatedRig(*emulated_plant("brake", None))
    for r in (late, prompt):
        r.apply(3.0)
    cl_late = late.advance(500)[0][:, 1]
    cl_prompt = prompt.advance(500)[0][:, 1]
    np.testing.assert_array_equal(cl_late[10:], cl_prompt[:-10])


# -- the supervisor ------------------------------------------------------------------------------


def test_supervisor_clamps_and_slew_limits():
    sup = Supervisor(SupervisorLimits(voltage_limit=4.0, slew_limit=20.0), control_dt=0.05)
    assert sup.apply(3.0, 0.0) == pytest.approx(1.0)  # 20 V/s * 50 ms
    assert sup.apply(3.0, 0.05) == pytest.approx(2.0)
    assert sup.apply(9.0, 0.1) == pytest.approx(3.0)
    assert sup.apply(9.0, 0.15) == pytest.approx(4.0)  # clamped at 4 V
    assert (sup.clamped, sup.slewed) == (2, 3)
    with pytest.raises(Trip, match="speed"):
        sup.check_speed(-13.0, 1.0)
    with pytest.raises(Trip, match="nan"):
        sup.apply(float("nan"), 1.0)


@pytest.mark.parametrize(
    "field, value, words",
    [
        ("voltage_limit", 6.0, r"--voltage-limit: 6.0 is outside the allowed range \(0, 5\] V"),
        ("slew_limit", 0.0, "--slew-limit"),
        ("speed_limit", 1000.0, r"--speed-limit: 1000.0 is outside the allowed range \(0, 100\] rad/s"),
        ("watchdog_periods", 0, "--watchdog-periods"),
    ],
)
def test_supervisor_limits_outside_the_rigs_range(field, value, words):
    with pytest.raises(ValueError, match=words):
        SupervisorLimits(**{field: value})


# -- the loop, lockstep with the emulated rig (no wire, no wall clock) ----------------------------


def _lockstep(
    controller: str,
    voltage: float,
    warmup: float,
    duration: float,
    window: float = 5.0,
    limits: SupervisorLimits | None = None,
    **kw,
):
    from drill_env.agents.evaluation.rig_runs import resolve_controller

    rig = LockstepRig(EmulatedRig(*emulated_plant("brake", None)), **kw)
    # lockstep has no wall clock: announced 1000 times slower than it, the loop's wall-clock
    # checks (a call overrunning its period) never act on how this host schedules the test
    info = dataclasses.replace(rig.hello(), time_scale=1e-3)
    env, ctrl, name = resolve_controller(controller, "brake", info.counts_per_rev, info.sample_rate_hz)
    run = RunSettings("brake", voltage, duration, warmup, window, limits or SupervisorLimits())
    res = run_loop(rig, info, env, ctrl, name, run)
    return rig, res


def test_loop_runs_a_controller_and_records_a_dataset(tmp_path):
    from drill_env.agents.evaluation.rig_runs import measured_metrics

    rig, res = _lockstep("lqi", 2.0, warmup=6.0, duration=6.0)
    assert res.trip is None and rig.stopped and rig.writes[-1] == 0.0
    assert len(res.log) == 240 and sum(r["phase"] == "control" for r in res.log) == 120
    u = np.array([r["u_applied"] for r in res.log])
    assert np.all(np.abs(u) <= 5.0) and np.all(np.abs(np.diff(u)) <= 100.0 * 0.05 + 1e-12)
    result = write_outputs(res, tmp_path, record=None, run_name="lqi_2V", measured=measured_metrics(res))
    ds = load_dataset(tmp_path / "recording")
    run = ds.runs[0]
    assert ds.preset == "brake" and ds.encoder_counts_per_rev == 2000 and run.t.size == 12000
    # the recording is the rig's: its angles are the emulated encoders' counts
    r = 2 * np.pi / 2000
    lower_true = np.concatenate([tr[:, 4] for _, _, tr in rig.truth])
    np.testing.assert_allclose(run.theta_l, np.floor(lower_true / r) * r, atol=1e-9)
    assert result["completed"] and (tmp_path / "report.md").is_file() and (tmp_path / "run.png").is_file()
    log = np.genfromtxt(tmp_path / "controller_log.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert len(log) == 240
    # every command was applied before the rig's next reading: no deadline missed
    assert result["timing"]["missed_deadlines"] == 0 and result["timing"]["late_at_rig"] == 0
    assert list(log["command_seq"]) == list(range(240))


def test_commands_the_rig_applied_late_are_missed_deadlines():
    """A loop a period behind its rig (each command applied only after the next reading was
    sent: what a loop descheduled with readings queued in its socket does) meets every one of
    its own wall-clock checks; the readings' last applied command show every deadline missed."""
    from drill_env.rig.loop import command_applied, timing_metrics

    rig, res = _lockstep(
        "lqi", 2.0, warmup=1.0, duration=2.0, limits=SupervisorLimits(watchdog_periods=100), late_commands=1
    )
    assert res.trip is None
    tm = timing_metrics(res)
    # the last period's command has no next reading to be judged by
    assert tm["late_at_rig"] == tm["missed_deadlines"] == len(res.log) - 1 == 59
    assert not any(r["latency_ms"] > 50.0 for r in res.log)  # the loop's own clock saw nothing
    assert command_applied(5, 5) and command_applied(6, 5) and not command_applied(4, 5)
    assert command_applied(2, 0xFFFFFFF0) and not command_applied(0xFFFFFFF0, 2)  # wrapping
    assert not command_applied(0xFFFFFFFF, 0)  # none applied yet


def test_a_loop_behind_its_rig_for_the_watchdogs_periods_trips_it():
    """As many late commands in a row as --watchdog-periods: the rig ran that long on old
    voltages, as if no reading had come; the watchdog stops the run at 0 V."""
    rig, res = _lockstep("lqi", 2.0, warmup=1.0, duration=2.0, limits=SupervisorLimits(watchdog_periods=4),
                         late_commands=1)  # fmt: skip
    assert res.trip_kind == "watchdog" and res.trip == (
        "watchdog: the loop fell behind the rig: its commands reached the rig a period late 4 times in a row "
        "(4 allowed: --watchdog-periods); 0 V written, run stopped"
    )
    # readings 0..4 recorded: the 5th showed the 4th late command in a row (each command is
    # judged by the reading after its own), and the trip came before it was answered
    assert len(res.ticks) == 5 and len(res.log) == 4 and all(r["late_at_rig"] for r in res.log)
    assert rig.stopped and rig.writes[-1] == 0.0 and rig.rig.voltage == 0.0


def test_a_raising_controller_trips_the_supervisor_at_0_volt():
    sys.path.insert(0, str(TESTS))
    try:
        rig, res = _lockstep("rig_controllers:Raising", 2.0, warmup=1.0, duration=5.0)
    finally:
        sys.path.remove(str(TESTS))
    assert res.trip_kind == "controller" and "sensor value out of range" in res.trip
    assert rig.stopped and rig.writes[-1] == 0.0 and rig.rig.voltage == 0.0
    assert sum(r["phase"] == "control" for r in res.log) == 3


def test_a_rig_that_stops_answering_trips_the_watchdog_and_keeps_the_recording(tmp_path):
    from drill_env.agents.evaluation.rig_runs import measured_metrics

    rig, res = _lockstep("lqi", 2.0, warmup=8.0, duration=20.0, fail_after=260)
    assert res.trip_kind == "watchdog" and res.trip.startswith(
        "watchdog: no encoder reading for 3 control periods"
    )
    assert rig.writes[-1] == 0.0 and rig.stopped
    write_outputs(res, tmp_path, record=tmp_path / "data", run_name="cut", measured=measured_metrics(res))
    assert load_dataset(tmp_path / "data").runs[0].t.size == 260 * 50


# -- the command line on loopback -------------------------------------------------------------------


class Emulator:
    """`drill-env emulate-rig` in a process of its own, on a free port."""

    def __init__(self, tmp_path: Path, *args: str, time_scale: float = 5.0):
        tmp_path.mkdir(parents=True, exist_ok=True)
        self.truth = tmp_path / "truth.csv"
        self.proc = subprocess.Popen(
            [
                *CLI,
                "emulate-rig",
                "--port",
                "0",
                "--time-scale",
                str(time_scale),
                "--truth",
                str(self.truth),
                *args,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        line = self.proc.stdout.readline()
        assert "listening on udp" in line, (
            line,
            self.proc.stderr.read() if self.proc.poll() is not None else "",
        )
        self.address = line.split()[-1]

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(30)

    def truth_voltages(self) -> np.ndarray:
        self.stop()
        data = np.genfromtxt(self.truth, delimiter=",", names=True)
        return np.atleast_1d(data["u"])


def _seconds_driven(truth: Path) -> float:
    """Rig time [s] since the emulator's voltage first left 0 V (0 before)."""
    if not truth.is_file():
        return 0.0
    lines = truth.read_text().splitlines()[1:-1]  # the last line may be half written
    u = np.array([float(line.split(",")[1]) for line in lines])
    on = np.flatnonzero(u != 0.0)
    return 0.0 if on.size == 0 else (len(u) - on[0]) / 1000.0


def run_cli(*args: str, timeout: float = 300, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout, env=env)


# The loopback tests share a two-core machine with other work: the wall-clock periods the loop
# and the emulator must keep (10 ms at the emulator's clock x5) are then sometimes not given to
# them. The supervisor must stop such a run, and it does; these tests check that it said why.
# A run the host's scheduling stopped is repeated (up to ATTEMPTS runs), and the test is
# skipped, with the supervisor's line, only when every run was so stopped.
ATTEMPTS = 3
WATCHDOG = "20"  # control periods: 200 ms of wall-clock time at x5 (the default 3 is 30 ms)


def stopped_by_the_host(result: dict, emulator_alive: bool) -> str | None:
    """The supervisor's line when the run was stopped by this machine's scheduling rather than
    by the loop or the emulator: a controller call whose CPU time was a small part of its wall
    time (descheduled meanwhile), no reading for WATCHDOG periods from a live emulator, or the
    emulator's own command timeout (the loop descheduled for twice that). None otherwise."""
    trip = result["trip"] or ""
    if result["ended_by"] == "overrun" and "the computer ran other work meanwhile" in trip:
        return trip
    if result["ended_by"] in ("watchdog", "rig_timeout") and emulator_alive:
        return trip
    return None


def check_stopped_run(out: Path, result: dict, p: subprocess.CompletedProcess, truth_u: np.ndarray) -> None:
    """A run the supervisor stopped: exit 1 with its one line, 0 V written and the rig at 0 V,
    and every reading received in the recording, in order, without a gap."""
    assert p.returncode == 1, p.stderr
    errors = [line for line in p.stderr.splitlines() if line.startswith("error:")]
    assert errors == [f"error: {result['trip']}"]
    assert truth_u[-1] == 0.0
    log = np.genfromtxt(out / "controller_log.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert np.all(np.diff(np.atleast_1d(log["reading_seq"])) == 1)
    assert "0 V written, rig stopped" in (out / "events.csv").read_text()


@pytest.fixture
def emulator(tmp_path):
    emu = Emulator(tmp_path)
    yield emu
    emu.stop()


def test_run_controller_on_the_emulated_rig(tmp_path):
    reasons = []
    for attempt in range(ATTEMPTS):
        emulator = Emulator(tmp_path / f"a{attempt}")
        out = tmp_path / f"a{attempt}" / "run"
        try:
            p = run_cli(
                "run-controller", "lqi", "--rig", emulator.address, "--voltage", "2", "--warmup", "6",
                "--duration", "5", "--window", "2", "--watchdog-periods", WATCHDOG, "--out", str(out),
            )  # fmt: skip
            alive = emulator.proc.poll() is None
        finally:
            u = emulator.truth_voltages()
        result = json.loads((out / "result.json").read_text())
        assert result["rig"]["time_scale"] == 5.0 and result["timing"]["readings_lost"] == 0
        if result["completed"]:
            break
        reason = stopped_by_the_host(result, alive)
        assert reason is not None, (p.stderr, result["trip"])
        check_stopped_run(out, result, p, u)
        reasons.append(reason)
    else:
        pytest.skip(f"this machine's scheduling stopped all {ATTEMPTS} runs: {reasons}")
    assert p.returncode == 0, (p.stderr, result["trip"])
    assert result["timing"]["periods"] == 220
    # what the loop saw late it reported: the missed deadlines are those of its own log
    log = np.genfromtxt(out / "controller_log.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert result["timing"]["missed_deadlines"] == int(np.sum(log["missed_deadline"]))
    assert result["timing"]["missed_deadlines"] >= int(np.sum(log["late_at_rig"]))
    ds = load_dataset(out / "recording")
    assert ds.runs[0].duration == pytest.approx(11.0, abs=0.002)  # the loader wants 10 s
    assert u[-1] == 0.0  # 0 V at the end


def test_killing_the_emulator_trips_the_watchdog(tmp_path):
    reasons = []
    for attempt in range(ATTEMPTS):
        emu = Emulator(tmp_path / f"a{attempt}", time_scale=5.0)
        out = tmp_path / f"a{attempt}" / "run"
        proc = subprocess.Popen(
            [*CLI, "run-controller", "lqi", "--rig", emu.address, "--voltage", "2", "--warmup", "5",
             "--duration", "60", "--watchdog-periods", WATCHDOG, "--out", str(out)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            # kill it once 12 s of the run are recorded: the truth log shows the rig's time, and
            # the run began where its voltage left 0 V
            if _seconds_driven(emu.truth) > 12.0:
                break
            time.sleep(0.5)
        ended_before = proc.poll() is not None
        emu.proc.kill()
        emu.proc.wait(30)
        _, err = proc.communicate(timeout=120)
        result = json.loads((out / "result.json").read_text())
        if not ended_before:
            break
        # the run stopped before the emulator was killed: only this machine's scheduling may do that
        reason = stopped_by_the_host(result, True)
        assert reason is not None, (err, result["trip"])
        reasons.append(reason)
    else:
        pytest.skip(f"this machine's scheduling stopped all {ATTEMPTS} runs before the kill: {reasons}")
    assert proc.returncode == 1
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert lines == [lines[0]] and lines[0].startswith(
        f"error: watchdog: no encoder reading for {WATCHDOG} control periods"
    )
    assert result["ended_by"] == "watchdog" and not result["stopped_ok"]
    events = (out / "events.csv").read_text()
    assert "0 V written, rig stopped" in events
    assert load_dataset(out / "recording").runs[0].duration >= 10.0


def test_ctrl_c_writes_0_volt_and_exits_130(tmp_path):
    """Ctrl-C (SIGINT) mid-run: 0 V written and STOP answered, one line, exit code 130, and
    the run so far recorded: the recording readable by identify's loader, the report written.
    Started with SIGINT ignored, as a shell script's background job is (`python -m drill_env`
    ran on regardless, the motor driven, until it ran through the entry point's handler)."""
    emu = Emulator(tmp_path)
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [*CLI, "run-controller", "lqi", "--rig", emu.address, "--voltage", "2", "--warmup", "5",
         "--duration", "60", "--watchdog-periods", WATCHDOG, "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None and _seconds_driven(emu.truth) < 12.0:
            time.sleep(0.2)
        ended_before = proc.poll() is not None
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        u = emu.truth_voltages()
    result = json.loads((out / "result.json").read_text())
    if ended_before:  # the supervisor stopped it first: only this machine's scheduling may do that
        reason = stopped_by_the_host(result, True)
        assert reason is not None, (err, result["trip"])
        pytest.skip(f"this machine's scheduling stopped the run before Ctrl-C: {reason}")
    assert proc.returncode == 130, err
    lines = [line for line in err.splitlines() if not line.startswith("run-controller:")]
    assert lines == [f"interrupted (Ctrl-C): 0 V written; the run so far is recorded in {out}"]
    assert result["ended_by"] == "interrupted" and result["stopped_ok"] and not result["completed"]
    assert u[-1] == 0.0
    assert load_dataset(out / "recording").runs[0].duration >= 12.0
    assert (out / "report.md").is_file()


def test_a_loop_that_falls_behind_reports_its_missed_deadlines(tmp_path):
    """run-controller stopped (SIGSTOP) for 0.3 s of wall clock mid-run, 30 periods at x5, as a
    computer that deschedules it: the readings wait in its socket and, running again, it works
    through them. Its own clock sees each reading answered at once; the readings' last applied
    command shows every command of those periods applied after the next reading was sent: the
    report counts them as missed deadlines."""
    reasons = []
    for attempt in range(ATTEMPTS):
        emu = Emulator(tmp_path / f"a{attempt}")
        out = tmp_path / f"a{attempt}" / "run"
        proc = subprocess.Popen(
            [*CLI, "run-controller", "lqi", "--rig", emu.address, "--voltage", "2", "--warmup", "6",
             "--duration", "5", "--window", "2", "--watchdog-periods", "60", "--out", str(out)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 240
            while time.monotonic() < deadline and proc.poll() is None and _seconds_driven(emu.truth) < 3.0:
                time.sleep(0.05)
            stopped_at = _seconds_driven(emu.truth)
            os.kill(proc.pid, signal.SIGSTOP)
            time.sleep(0.3)
            os.kill(proc.pid, signal.SIGCONT)
            _, err = proc.communicate(timeout=120)
            alive = emu.proc.poll() is None
        finally:
            emu.stop()
        result = json.loads((out / "result.json").read_text())
        if result["completed"] and stopped_at < 11.0:
            break
        reason = stopped_by_the_host(result, alive) if not result["completed"] else "ended before the stop"
        assert reason is not None, (err, result["trip"])
        reasons.append(reason)
    else:
        pytest.skip(f"this machine's scheduling stopped all {ATTEMPTS} runs: {reasons}")
    tm = result["timing"]
    log = np.genfromtxt(out / "controller_log.csv", delimiter=",", names=True, dtype=None, encoding=None)
    late = log["late_at_rig"].astype(bool)
    assert tm["late_at_rig"] == int(late.sum()) >= 25  # 30 periods stopped, give or take the edges
    assert tm["missed_deadlines"] >= tm["late_at_rig"]
    # most of them the loop's own clock did not see: it answered the waiting readings at once
    assert np.sum(log["latency_ms"][late] > 10.0) < 0.5 * late.sum()
    assert tm["readings_lost"] == 0 and tm["periods"] == 220


@pytest.mark.parametrize(
    "args, words",
    [
        (["--voltage-limit", "6"], "error: --voltage-limit: 6.0 is outside the allowed range (0, 5] V"),
        (["--speed-limit", "2"], "error: --speed-limit: 2 rad/s is below the set point's target speed"),
        (["--voltage", "7"], "error: --voltage: 7.0; allowed: (0, 5] V"),
    ],
)
def test_bad_limits_are_one_line_and_exit_2(emulator, tmp_path, args, words):
    base = [
        "run-controller",
        "lqi",
        "--rig",
        emulator.address,
        "--voltage",
        "2",
        "--out",
        str(tmp_path / "o"),
    ]
    p = run_cli(*base, *args)
    assert (
        p.returncode == 2 and p.stderr.strip().startswith(words) and len(p.stderr.strip().splitlines()) == 1
    )
    assert np.all(emulator.truth_voltages() == 0.0)  # the motor never ran


@pytest.mark.parametrize(
    "controller, run",
    [("lqi", "lqi_2V"), (str(ROOT / "results" / "agents" / "ppo" / "policy.zip"), "ppo_2V")],
)
def test_a_recorded_run_is_never_replaced(tmp_path, controller, run):
    """A dataset folder that holds a run of the name this one would get: refused in one line
    before the rig is asked anything (the name of a policy file's run is its folder's)."""
    data = tmp_path / "data"
    data.mkdir()
    (data / "dataset.json").write_text('{"preset": "brake", "encoder_counts_per_rev": 2000}')
    (data / f"{run}.csv").write_text("t,u,theta_u,theta_l\n")
    p = run_cli(
        "run-controller", controller, "--rig", "127.0.0.1:9", "--voltage", "2", "--out",
        str(tmp_path / "o"), "--record", str(data),
    )  # fmt: skip
    assert p.returncode == 2
    assert p.stderr.strip() == (
        f"error: --record {data}: already holds a run named {run!r}; give another --run-name (the recorded "
        "run is kept)"
    )
    assert (data / f"{run}.csv").read_text() == "t,u,theta_u,theta_l\n"


def test_an_address_that_does_not_answer(tmp_path):
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))  # bound and silent: no ICMP answer either
    port = s.getsockname()[1]
    try:
        p = run_cli(
            "run-controller", "lqi", "--rig", f"127.0.0.1:{port}", "--voltage", "2", "--out",
            str(tmp_path / "o"), "--connect-timeout", "0.2",
        )  # fmt: skip
    finally:
        s.close()
    assert p.returncode == 2
    assert p.stderr.strip() == (
        f"error: --rig 127.0.0.1:{port}: no answer to HELLO within 0.2 s (3 tries); is the I/O box or "
        "`drill-env emulate-rig` running there?"
    )


def test_a_controller_that_cannot_hold_the_rate(emulator, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(TESTS)}
    p = run_cli(
        "run-controller", "rig_controllers:Slow", "--rig", emulator.address, "--voltage", "2",
        "--out", str(tmp_path / "o"), env=env,
    )  # fmt: skip
    assert p.returncode == 2, p.stderr
    err = [line for line in p.stderr.splitlines() if line.startswith("error")]
    assert len(err) == 1 and "cannot hold the rate" in err[0] and "Slow takes" in err[0]
    assert np.all(emulator.truth_voltages() == 0.0)


@pytest.mark.slow
def test_an_overrunning_controller_trips_the_watchdog(tmp_path):
    """Its 26th call takes 300 ms (30 periods at x5); the call before it may overrun too when
    this machine deschedules the loop: an overrun either way, said so in one line."""
    env = {**os.environ, "PYTHONPATH": str(TESTS)}
    reasons = []
    for attempt in range(ATTEMPTS):
        emulator = Emulator(tmp_path / f"a{attempt}")
        out = tmp_path / f"a{attempt}" / "o"
        try:
            p = run_cli(
                "run-controller", "rig_controllers:Overrunning", "--rig", emulator.address, "--voltage", "2",
                "--warmup", "1", "--duration", "10", "--window", "5", "--watchdog-periods", WATCHDOG,
                "--out", str(out), env=env,
            )  # fmt: skip
            alive = emulator.proc.poll() is None
        finally:
            u = emulator.truth_voltages()
        result = json.loads((out / "result.json").read_text())
        check_stopped_run(out, result, p, u)
        if result["ended_by"] == "overrun":
            break
        reasons.append(stopped_by_the_host(result, alive))
        assert reasons[-1] is not None, result["trip"]
    else:
        pytest.skip(f"this machine's scheduling stopped all {ATTEMPTS} runs before the overrun: {reasons}")
    assert p.stderr.splitlines()[-1].startswith("error: watchdog: the controller call took")
    assert result["trip"].endswith("0 V written, run stopped")
    # the calls before it were timed and logged; the overrun is the 20th call of the run or earlier
    log = np.genfromtxt(out / "controller_log.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert 1 <= np.sum(log["phase"] == "control") <= 19


# -- the same suppression as the benchmark's episode ---------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("controller", ["lqi", "ppo"])
@pytest.mark.parametrize("voltage", [1.0, 2.0])  # the braked rig's Hopf cycle and its stick-slip
def test_the_loop_reaches_the_benchmarks_suppression(controller, voltage):
    """Lockstep with the emulated rig, the loop runs the benchmark's episode (90 s after a warm-up
    of 62 s): the true state's suppression within 0.01 of evaluate()'s, the measured one (the
    encoder's counts per period) within 0.03."""
    from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate
    from drill_env.agents.evaluation.rig_runs import measured_metrics

    rig, res = _lockstep(controller, voltage, warmup=62.0, duration=90.0, window=20.0)
    assert res.trip is None
    t = np.concatenate([f + np.arange(tr.shape[0]) for f, _, tr in rig.truth]) / 1000.0
    x = np.concatenate([tr for _, _, tr in rig.truth])
    from drill_env.agents.evaluation.rig_runs import _score

    w = t > t[-1] - 20.0 + 1e-9
    truth = _score(t[w], x[w, 2], x[w, 5] != 0, "brake", voltage, res.target_speed)
    from drill_env.agents.evaluation.rig_runs import resolve_controller

    env, ctrl, name = resolve_controller(controller, "brake", 2000, 1000.0)
    bench = evaluate(ctrl, "brake", voltage, 0, EpisodeSettings(), name=name, env=env)
    assert abs(truth["suppression"] - bench.suppression) <= 0.01
    assert abs(measured_metrics(res)["suppression"] - bench.suppression) <= 0.03
    assert abs(truth["rms_error"] - bench.rms_error) <= 0.01


@pytest.mark.slow
def test_on_the_wire_lqi_reaches_the_benchmarks_suppression(tmp_path):
    """The same through the emulator on loopback at twice the wall clock (the commands arrive
    a few ms late there, as on a rig)."""
    from drill_env.agents.evaluation.episodes import EpisodeSettings, evaluate
    from drill_env.agents.evaluation.rig_runs import resolve_controller, truth_metrics

    emu = Emulator(tmp_path, time_scale=2.0)
    out = tmp_path / "run"
    try:
        p = run_cli(
            "run-controller", "lqi", "--rig", emu.address, "--voltage", "2", "--warmup", "62", "--out", str(out),
            timeout=900,
        )  # fmt: skip
    finally:
        emu.stop()
    assert p.returncode == 0, p.stderr
    result = json.loads((out / "result.json").read_text())
    log = np.genfromtxt(out / "controller_log.csv", delimiter=",", names=True, dtype=None, encoding=None)
    t_end = float(log["t"][-1])
    truth = truth_metrics(emu.truth, t_end - 20.0, t_end, "brake", 2.0, result["target_speed"])
    env, ctrl, name = resolve_controller("lqi", "brake", 2000, 1000.0)
    bench = evaluate(ctrl, "brake", 2.0, 0, EpisodeSettings(), name=name, env=env)
    assert abs(truth["suppression"] - bench.suppression) <= 0.02
    assert abs(result["measured"]["suppression"] - bench.suppression) <= 0.03


@pytest.mark.slow
def test_recordings_of_the_loop_go_through_identify_and_discrepancy(tmp_path):
    """The round trip: runs recorded by the loop (open loop at three set points and the LQI at
    one, each written by run-controller's own writer into one dataset folder) are identified,
    and the discrepancy workflow reads the same folder against the identified rig."""
    from drill_env.agents.evaluation.rig_runs import measured_metrics
    from drill_env.params import load_params

    data = tmp_path / "data"
    for controller, voltage in (("open_loop", 0.8), ("open_loop", 1.5), ("open_loop", 2.5), ("lqi", 2.0)):
        _, res = _lockstep(controller, voltage, warmup=25.0, duration=5.0)
        assert res.trip is None
        name = f"{controller}_{voltage:g}V"
        write_outputs(
            res, tmp_path / name, record=data, run_name=name, measured=measured_metrics(res), figures=False
        )
    assert len(load_dataset(data).runs) == 4
    p = run_cli(
        "identify", str(data), "--out", str(tmp_path / "id"), "--no-figures", "--no-bifurcation", timeout=1800
    )
    assert p.returncode == 0, p.stderr
    rig = load_params(tmp_path / "id" / "rig.yaml")
    truth = load_params("brake")
    assert rig.upper_inertia == pytest.approx(truth.upper_inertia, rel=0.1)
    assert rig.lower_inertia == pytest.approx(truth.lower_inertia, rel=0.1)
    p = run_cli(
        "discrepancy", str(data), "--out", str(tmp_path / "disc"), "--no-figures",
        "--params", str(tmp_path / "id" / "rig.yaml"), timeout=1800,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert json.loads((tmp_path / "disc" / "result.json").read_text())


def test_a_recording_with_lost_readings_loads_as_its_parts_and_earlier_runs_stay(tmp_path):
    """Readings lost on the wire leave gaps in the recording's clock: the run is written with
    ``split_at_gaps`` so that identify and discrepancy read it as it is (the parts between the
    gaps as runs); a run added later leaves the earlier runs' files byte for byte."""
    from types import SimpleNamespace

    from drill_env.recordings.dataset import load_dataset
    from drill_env.rig.loop import write_recording

    def fake(gap: bool):
        ticks = np.arange(30_000)
        if gap:  # 50 readings lost at 15 s
            ticks = np.concatenate([ticks[:15_000], ticks[15_050:]])
        counts = (ticks * 0.5).astype(np.int64)
        res = SimpleNamespace(
            info=SimpleNamespace(sample_period=0.001, counts_per_rev=2000),
            settings=SimpleNamespace(preset="brake"),
            gaps=1 if gap else 0,
        )
        res.samples = lambda: {
            "tick": ticks,
            "u": np.full(ticks.size, 1.0),
            "theta_u": counts * 2 * np.pi / 2000,
            "theta_l": (counts - 40) * 2 * np.pi / 2000,
        }
        return res

    write_recording(fake(False), tmp_path / "rec", "lqi_1V")
    first = (tmp_path / "rec" / "lqi_1V.csv").read_bytes()
    assert "split_at_gaps" not in (tmp_path / "rec" / "dataset.json").read_text()
    write_recording(fake(True), tmp_path / "rec", "lqi_2V")
    assert (tmp_path / "rec" / "lqi_1V.csv").read_bytes() == first
    ds = load_dataset(tmp_path / "rec")
    assert sorted(r.name for r in ds.runs) == ["lqi_1V", "lqi_2V@1", "lqi_2V@2"]
    with pytest.raises(Exception, match="already holds a run named 'lqi_2V'"):
        write_recording(fake(True), tmp_path / "rec", "lqi_2V")
