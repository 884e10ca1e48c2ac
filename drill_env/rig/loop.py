"""``run-controller``: a controller on a rig, at a fixed period, behind the safety supervisor.

The loop is clocked by the rig's sample clock: the rig streams one READING per control
period (``control_dt * sample_rate_hz`` samples), and each reading is answered by one
COMMAND. Per period: the counts go through the environment's own observation code
(:class:`~drill_env.rig.observer.Observer`), the supervisor checks the lower-disk speed,
the controller is called exactly as the benchmark calls it (``predict(obs, state,
episode_start, deterministic=True)``, :func:`drill_env.agents.evaluation.episodes.run_episode`),
its action becomes a voltage as in the environment's ``step`` and the supervisor clamps
and slew-limits it before it is written.

A run: an open-loop warm-up at the set point's nominal voltage (``warmup`` s, as the
benchmark's episodes start on the open-loop behaviour), then the controller for
``duration`` s. It always ends at 0 V: at the end, on a supervisor trip (watchdog: no
reading for ``watchdog_periods`` periods, as many commands in a row that the rig applied
only after its next reading, or a controller call longer than its period; speed limit), on
Ctrl-C and on any error.

Every run writes into its output folder: ``recording/`` (the measured-data format of
:mod:`drill_env.recordings.dataset`: ``dataset.json`` and one CSV ``t,u,theta_u,theta_l`` at
the rig's sample rate, readable by ``drill-env identify`` and ``drill-env discrepancy`` as
it is), ``controller_log.csv`` (per period: requested and applied voltage, what the
controller saw, call time, reading arrival, whether the command met its deadline), ``events.csv`` (the supervisor's), ``result.json``,
``report.md`` and the figures ``run.png`` and ``timing.png``.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drill_env.rig.protocol import NO_COMMAND, RigInfo, RigIO
from drill_env.rig.supervisor import Supervisor, SupervisorLimits, Trip

__all__ = [
    "LoopResult",
    "RunSettings",
    "call_time",
    "command_applied",
    "requested_voltage",
    "run_loop",
    "write_outputs",
]

# a controller whose call takes more than this share of the period cannot hold the rate
MAX_CALL_SHARE = 0.5


@dataclass(frozen=True)
class RunSettings:
    """What a run does (the command's options)."""

    preset: str  # the design model's preset (brake, no_brake)
    nominal_voltage: float  # [V] the set point
    duration: float  # [s] closed loop
    warmup: float  # [s] open loop at the nominal voltage before
    window: float = 20.0  # [s] the report's steady-state window at the end
    limits: SupervisorLimits = field(default_factory=SupervisorLimits)


@dataclass
class LoopResult:
    """Everything a run recorded."""

    info: RigInfo
    settings: RunSettings
    control_dt: float
    controller: str
    target_speed: float
    regime: str
    ticks: list[np.ndarray] = field(default_factory=list)
    counts_u: list[np.ndarray] = field(default_factory=list)
    counts_l: list[np.ndarray] = field(default_factory=list)
    voltage: list[np.ndarray] = field(default_factory=list)
    log: list[dict[str, Any]] = field(default_factory=list)
    events: list[tuple[float, str, str]] = field(default_factory=list)
    trip: str | None = None  # the one line of a trip or error
    trip_kind: str | None = None
    interrupted: bool = False
    stopped_ok: bool = False
    gaps: int = 0
    control_start_tick: int | None = None

    def samples(self) -> dict[str, np.ndarray]:
        if not self.ticks:
            z = np.zeros(0)
            return {"tick": z.astype(np.int64), "u": z, "theta_u": z, "theta_l": z}
        r = 2.0 * math.pi / self.info.counts_per_rev
        return {
            "tick": np.concatenate(self.ticks),
            "u": np.concatenate(self.voltage),
            "theta_u": np.concatenate(self.counts_u) * r,
            "theta_l": np.concatenate(self.counts_l) * r,
        }


def requested_voltage(action: Any, settings: Any, nominal_voltage: float) -> float:
    """The voltage an action asks for, as the environment's ``step`` maps it
    (``a * action_to_volts``, plus the nominal voltage for a correction action)."""
    from drill_env.envs.config import numeric_action

    a = numeric_action(action, "action").reshape(-1)
    if a.size != 1:
        raise ValueError(f"action: expected one value, got shape {np.shape(action)}")
    u = float(a[0]) * float(settings.action_to_volts)
    if settings.action_offset:
        u += nominal_voltage
    return u


def command_applied(last_applied: int, command_seq: int) -> bool:
    """Whether a READING whose last applied COMMAND is ``last_applied`` (its wire field:
    :data:`~drill_env.rig.protocol.NO_COMMAND` for none) shows the command numbered
    ``command_seq`` applied, or a later one (sequence numbers wrap at 2^32)."""
    if last_applied == NO_COMMAND:
        return False
    return ((int(last_applied) - int(command_seq)) & 0xFFFFFFFF) < 0x80000000


def call_time(controller: Any, observation: np.ndarray, calls: int = 6) -> float:
    """The controller's time per call [s]: the median of ``calls - 1`` calls on ``observation``
    after a first one (which may load or compile what the controller needs), each from a fresh
    start (``state=None``). What it raises is passed on."""
    times = []
    for _ in range(calls):
        c0 = time.perf_counter()
        controller.predict(
            observation, state=None, episode_start=np.ones((1,), dtype=bool), deterministic=True
        )
        times.append(time.perf_counter() - c0)
    return float(np.median(times[1:]))


def run_loop(
    rig: RigIO,
    info: RigInfo,
    env: Any,
    controller: Any,
    name: str,
    run: RunSettings,
    *,
    progress=None,
) -> LoopResult:
    """Run ``controller`` (built for ``env``, a drill-string environment whose settings give
    the observation and the action mapping) on ``rig``; never raises for a trip, an error of
    the controller or Ctrl-C: the rig is at 0 V when it returns and the result says why it
    ended."""
    from drill_env.rig.observer import Observer

    settings = env.unwrapped.settings
    point = settings.parse_options({"nominal_voltage": run.nominal_voltage})["point"]
    dt = settings.control_dt
    n_sub = settings.n_sub
    period = dt / info.time_scale  # [s of wall-clock time]
    res = LoopResult(info, run, dt, name, float(point.target_speed), str(point.regime))
    sup = Supervisor(run.limits, dt)
    obs_chain = Observer(settings, info.counts_per_rev, info.sample_rate_hz)
    obs_chain.set_point(point.target_speed, point.nominal_voltage)
    n_warm = int(round(run.warmup / dt))
    n_ctrl = int(round(run.duration / dt))
    wait = run.limits.watchdog_periods * period
    state = None
    start = np.ones((1,), dtype=bool)
    last_arrival = None
    behind = 0  # periods in a row whose command the rig applied late
    ts = info.sample_period

    def event(t: float, kind: str, text: str) -> None:
        res.events.append((t, kind, text))

    try:
        # can the controller hold the rate? Timed before the rig streams, on the observation of
        # the rig at rest at this set point (a chain of its own: the loop's starts afresh)
        probe = Observer(settings, info.counts_per_rev, info.sample_rate_hz)
        probe.set_point(point.target_speed, point.nominal_voltage)
        zeros = np.zeros(n_sub, dtype=np.int64)
        try:
            took = call_time(controller, probe.update(1, zeros, zeros, point.nominal_voltage))
        except Exception as exc:
            raise Trip("controller", f"controller: {name} raised {type(exc).__name__}: {exc}") from exc
        if took > MAX_CALL_SHARE * period:
            raise Trip(
                "rate",
                f"CONTROLLER: {name} takes {took * 1e3:.2f} ms per call, more than "
                f"{MAX_CALL_SHARE:.0%} of its {period * 1e3:g} ms period (control_dt {dt:g} s at the "
                f"rig's clock x{info.time_scale:g}): it cannot hold the rate; 0 V written",
            )
        # the rig's own timeout is the loop's watchdog twice over: a backstop for a controller's
        # computer that died, never the first to act on a late reading
        rig.start(n_sub, 2 * run.limits.watchdog_periods * dt)
        for k in range(n_warm + n_ctrl):
            reading = rig.read(wait)
            arrival = time.perf_counter()
            if reading is None:
                raise Trip(
                    "watchdog",
                    f"watchdog: no encoder reading for {run.limits.watchdog_periods} control periods "
                    f"({run.limits.watchdog_periods * dt * 1e3:g} ms of rig time); 0 V written, run stopped",
                )
            if reading.timed_out:
                raise Trip("rig_timeout", "rig: its own command timeout set 0 V (commands arrived too late)")
            if res.log and res.log[-1]["command_seq"] >= 0:
                # the rig's side of the deadline: the command answering the last reading must be
                # applied before this one was sent (its block is the period the command is for)
                late = not command_applied(reading.last_command, res.log[-1]["command_seq"])
                res.log[-1]["late_at_rig"] = late
                res.log[-1]["missed_deadline"] = bool(res.log[-1]["missed_deadline"] or late)
                behind = behind + 1 if late else 0
            res.ticks.append(reading.first_tick + np.arange(reading.n))
            res.counts_u.append(reading.counts_upper)
            res.counts_l.append(reading.counts_lower)
            res.voltage.append(reading.voltage)
            if behind >= run.limits.watchdog_periods:
                # the rig ran on old voltages for that long: as if no reading had come (a loop
                # descheduled with readings waiting in its socket never waits for one)
                raise Trip(
                    "watchdog",
                    f"watchdog: the loop fell behind the rig: its commands reached the rig a period late "
                    f"{behind} times in a row ({run.limits.watchdog_periods} allowed: --watchdog-periods); "
                    "0 V written, run stopped",
                )
            t = (reading.first_tick + reading.n - 1) * ts  # the rig time of the last sample
            obs = obs_chain.update(
                reading.first_tick, reading.counts_upper, reading.counts_lower, float(reading.voltage[-1])
            )
            control = k >= n_warm
            sup.check_speed(obs_chain.lower_speed, t)
            call = call_cpu = 0.0
            if control:
                c0, cpu0 = time.perf_counter(), time.thread_time()
                try:
                    action, state = controller.predict(
                        obs, state=state, episode_start=start, deterministic=True
                    )
                except Exception as exc:  # a controller's own error: 0 V, and the run ends
                    raise Trip(
                        "controller", f"controller: {name} raised {type(exc).__name__}: {exc}"
                    ) from exc
                call = time.perf_counter() - c0
                call_cpu = time.thread_time() - cpu0
                start = np.zeros((1,), dtype=bool)
                if call > period:
                    # the CPU time tells a slow controller from a computer that descheduled the loop
                    why = (
                        "the computer ran other work meanwhile"
                        if call_cpu < 0.5 * call
                        else "the controller computed for most of it"
                    )
                    raise Trip(
                        "overrun",
                        f"watchdog: the controller call took {call * 1e3:.1f} ms, longer than its period "
                        f"({period * 1e3:g} ms of wall-clock time; {call_cpu * 1e3:.1f} ms of CPU: {why}); "
                        "0 V written, run stopped",
                    )
                u_req = requested_voltage(action, settings, point.nominal_voltage)
            else:
                u_req = point.nominal_voltage
            u = sup.apply(u_req, t)
            seq = rig.write(u)
            written = time.perf_counter()
            res.log.append(
                {
                    "t": t,
                    "tick": reading.first_tick + reading.n - 1,
                    "phase": "control" if control else "warmup",
                    "u_requested": u_req,
                    "u_applied": u,
                    "lower_speed": obs_chain.lower_speed,
                    "lower_speed_mean": obs_chain.lower_speed_mean,
                    "call_ms": call * 1e3,
                    "call_cpu_ms": call_cpu * 1e3,
                    "arrival_interval_ms": math.nan
                    if last_arrival is None
                    else (arrival - last_arrival) * 1e3,
                    "latency_ms": (written - arrival) * 1e3,
                    "missed_deadline": bool(written - arrival > period),
                    "late_at_rig": False,
                    "reading_seq": reading.seq,
                    "command_seq": -1 if seq is None else int(seq),
                }
            )
            last_arrival = arrival
            if progress is not None:
                progress(k, n_warm + n_ctrl)
    except Trip as trip:
        res.trip, res.trip_kind = str(trip), trip.kind
    except KeyboardInterrupt:
        res.interrupted = True
        res.trip_kind = "interrupted"
    except Exception as exc:  # noqa: BLE001 -- any error: 0 V first, then it is reported
        res.trip, res.trip_kind = f"{type(exc).__name__}: {exc}", "error"
    finally:
        sup.zero()
        res.stopped_ok = rig.stop()
        res.gaps = obs_chain.gaps
        t_end = res.log[-1]["t"] if res.log else 0.0
        event(t_end, "stop", "0 V written, rig stopped" + ("" if res.stopped_ok else " (no STOPPED answer)"))
        if res.trip:
            event(t_end, res.trip_kind or "trip", res.trip)
        res.events.extend(sup.events)
        res.events.sort(key=lambda e: e[0])
    return res


# -- outputs ---------------------------------------------------------------------------------------


def _recording_run(res: LoopResult, name: str):
    from drill_env.recordings.dataset import MeasuredRun

    s = res.samples()
    return MeasuredRun(name, s["tick"] * res.info.sample_period, s["u"], s["theta_u"], s["theta_l"])


def write_recording(res: LoopResult, folder: Path, run_name: str) -> Path | None:
    """Add the run to the dataset ``folder`` (created with its ``dataset.json`` when new); None
    when nothing was recorded."""
    from drill_env.recordings.dataset import write_dataset

    run = _recording_run(res, run_name)
    if run.t.size < 2:
        return None
    # readings lost on the wire leave gaps in the clock: the parts between them are analysed
    split = bool(res.gaps)
    if (folder / "dataset.json").is_file():
        from drill_env.recordings.dataset import add_run, load_dataset

        old = load_dataset(folder)
        if old.preset != res.settings.preset or old.encoder_counts_per_rev != res.info.counts_per_rev:
            raise ValueError(
                f"--record: {folder} holds runs of preset {old.preset!r} at {old.encoder_counts_per_rev} "
                f"counts/rev; this run is {res.settings.preset!r} at {res.info.counts_per_rev}"
            )
        add_run(folder, run, split_at_gaps=split)  # the earlier runs' files stay as they are
    else:
        write_dataset(
            folder,
            [run],
            preset=res.settings.preset,
            encoder_counts_per_rev=res.info.counts_per_rev,
            description="recorded by drill-env run-controller",
            split_at_gaps=split,
        )
    return folder / f"{run_name}.csv"


def timing_metrics(res: LoopResult) -> dict[str, Any]:
    """Loop timing in wall-clock ms: reading interval (its jitter: the standard deviation and
    the largest deviation from the period), reading-to-write latency, controller call time,
    missed deadlines: a period whose command was written later than one period after its
    reading arrived, or was not yet applied when the rig sent the next reading (its
    ``last_command`` field: this sees what the loop's own clock cannot, a reading that waited
    in the socket while the loop was descheduled; ``late_at_rig`` counts these)."""
    period_ms = res.control_dt / res.info.time_scale * 1e3
    iv = np.array([r["arrival_interval_ms"] for r in res.log], dtype=float)
    iv = iv[np.isfinite(iv)]
    lat = np.array([r["latency_ms"] for r in res.log], dtype=float)
    calls = np.array([r["call_ms"] for r in res.log if r["phase"] == "control"], dtype=float)
    out: dict[str, Any] = {"period_ms": period_ms, "time_scale": res.info.time_scale, "periods": len(res.log)}
    if iv.size:
        out.update(
            interval_mean_ms=float(iv.mean()),
            jitter_std_ms=float(iv.std()),
            jitter_max_ms=float(np.max(np.abs(iv - period_ms))),
        )
    if lat.size:
        out.update(latency_median_ms=float(np.median(lat)), latency_max_ms=float(lat.max()))
    if calls.size:
        out.update(call_median_ms=float(np.median(calls)), call_max_ms=float(calls.max()))
    out["missed_deadlines"] = int(sum(bool(r["missed_deadline"]) for r in res.log))
    out["late_at_rig"] = int(sum(bool(r.get("late_at_rig", False)) for r in res.log))
    out["readings_lost"] = int(res.gaps)
    return out


def _figures(res: LoopResult, folder: Path) -> list[Path]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from drill_env.outputs import atomic_file

    paths = []
    t = np.array([r["t"] for r in res.log])
    t0 = res.control_start_tick * res.info.sample_period if res.control_start_tick is not None else 0.0
    fig = Figure(figsize=(9, 6), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    ax1.plot(
        t - t0,
        [r["lower_speed_mean"] for r in res.log],
        color="tab:blue",
        label="lower disk, measured (counts per period)",
    )
    ax1.axhline(res.target_speed, color="black", linestyle="--", label=f"target {res.target_speed:.3g} rad/s")
    ax1.axhline(
        res.settings.limits.speed_limit, color="tab:red", linestyle=":", label="supervisor speed limit"
    )
    ax1.set_ylabel("lower-disk speed [rad/s]")
    ax1.legend(loc="upper right", fontsize=8)
    ax2.plot(
        t - t0, [r["u_requested"] for r in res.log], color="tab:orange", linestyle="--", label="requested"
    )
    ax2.plot(t - t0, [r["u_applied"] for r in res.log], color="tab:green", label="applied (supervisor)")
    ax2.set_ylabel("voltage [V]")
    ax2.set_xlabel(f"time since {res.controller} was switched on [s]")
    ax2.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"{res.controller} on the rig, set point {res.settings.nominal_voltage:g} V ({res.regime})")
    FigureCanvasAgg(fig)
    with atomic_file(folder / "run.png", "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    paths.append(folder / "run.png")

    fig = Figure(figsize=(9, 3.5), layout="constrained")
    ax = fig.subplots(1, 1)
    period_ms = res.control_dt / res.info.time_scale * 1e3
    iv = np.array([r["arrival_interval_ms"] for r in res.log], dtype=float)
    lat = np.array([r["latency_ms"] for r in res.log], dtype=float)
    ax.plot(t - t0, iv, color="tab:blue", label="reading interval")
    ax.plot(t - t0, lat, color="tab:orange", label="reading to write (latency)")
    ax.axhline(period_ms, color="black", linestyle="--", label=f"period {period_ms:g} ms")
    ax.set_xlabel(f"rig time since {res.controller} was switched on [s]")
    ax.set_ylabel("wall-clock time [ms]")
    ax.set_yscale("log")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"loop timing (rig clock x{res.info.time_scale:g})")
    FigureCanvasAgg(fig)
    with atomic_file(folder / "timing.png", "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    paths.append(folder / "timing.png")
    return paths


def write_outputs(
    res: LoopResult,
    folder: Path,
    *,
    record: Path | None,
    run_name: str,
    measured: dict[str, Any],
    figures: bool = True,
) -> dict[str, Any]:
    """Write the recording, the logs, ``result.json``, ``report.md`` and the figures; the result.
    ``measured`` holds the suppression and tracking metrics of the run (computed by the
    benchmark's functions, :func:`drill_env.agents.evaluation.rig_runs.measured_metrics`)."""
    import pandas as pd

    from drill_env.outputs import atomic_file, atomic_write_text

    folder.mkdir(parents=True, exist_ok=True)
    rec_folder = record if record is not None else folder / "recording"
    rec = write_recording(res, rec_folder, run_name)
    with atomic_file(folder / "controller_log.csv", "w", newline="") as f:
        pd.DataFrame(res.log, columns=list(res.log[0]) if res.log else ["t"]).to_csv(
            f, index=False, float_format="%.9g"
        )
    with atomic_file(folder / "events.csv", "w", newline="") as f:
        pd.DataFrame(res.events, columns=["t", "kind", "text"]).to_csv(f, index=False, float_format="%.6f")
    timing = timing_metrics(res)
    sup = {
        **res.settings.limits.as_dict(),
        "clamped_periods": int(
            sum(abs(r["u_requested"]) > res.settings.limits.voltage_limit for r in res.log)
        ),
        "slew_limited_periods": int(
            sum(
                r["u_applied"]
                != max(
                    -res.settings.limits.voltage_limit,
                    min(res.settings.limits.voltage_limit, r["u_requested"]),
                )
                for r in res.log
            )
        ),
    }
    result = {
        "controller": res.controller,
        "preset": res.settings.preset,
        "nominal_voltage": res.settings.nominal_voltage,
        "regime": res.regime,
        "target_speed": res.target_speed,
        "control_dt": res.control_dt,
        "warmup_s": res.settings.warmup,
        "duration_s": res.settings.duration,
        "rig": {
            "sample_rate_hz": res.info.sample_rate_hz,
            "counts_per_rev": res.info.counts_per_rev,
            "voltage_limit": res.info.voltage_limit,
            "time_scale": res.info.time_scale,
        },
        "completed": res.trip is None and not res.interrupted,
        "ended_by": res.trip_kind or "end",
        "trip": res.trip,
        "stopped_ok": res.stopped_ok,
        "recording": None if rec is None else str(rec),
        "measured": measured,
        "timing": timing,
        "supervisor": sup,
    }
    atomic_write_text(folder / "result.json", json.dumps(result, indent=2, default=float) + "\n")
    figs = _figures(res, folder) if figures and res.log else []
    atomic_write_text(folder / "report.md", _report(result, figs))
    return result


def _fmt(v: Any, spec: str = ".4g") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def _report(r: dict[str, Any], figs: list[Path]) -> str:
    m, tm, s = r["measured"], r["timing"], r["supervisor"]
    lines = [
        f"# {r['controller']} on the rig at {r['nominal_voltage']:g} V ({r['preset']}, {r['regime']})",
        "",
        f"Target lower-disk speed {r['target_speed']:.4g} rad/s (design model); warm-up {r['warmup_s']:g} s open loop, "
        f"then {r['duration_s']:g} s closed loop at a {r['control_dt'] * 1e3:g} ms period. Rig: "
        f"{r['rig']['sample_rate_hz']:g} Hz, {r['rig']['counts_per_rev']} counts/rev, +-{r['rig']['voltage_limit']:g} V, "
        f"clock x{r['rig']['time_scale']:g}.",
        "",
        f"**Ended by: {r['ended_by']}**"
        + (f": {r['trip']}" if r["trip"] else "")
        + ". The motor was set to 0 V"
        + ("" if r["stopped_ok"] else " (the rig did not answer STOP)")
        + ".",
        "",
        "## Suppression and tracking (last window, measured)",
        "",
        "By the benchmark's metric functions on the lower-disk speed the encoder measures (counts over each control "
        "period / the period; stuck where no count changed): one count per period is "
        f"{2 * math.pi / r['rig']['counts_per_rev'] / r['control_dt']:.3g} rad/s, the floor of the measured amplitude.",
        "",
        "| metric | value |",
        "|---|---|",
    ]
    for key, unit in (
        ("control_periods", ""),
        ("window_s", "s"),
        ("amplitude", "rad/s"),
        ("open_loop_amplitude", "rad/s (analysis)"),
        ("suppression", ""),
        ("stalled", ""),
        ("stick_fraction", ""),
        ("mean_speed", "rad/s"),
        ("rms_error", "rad/s"),
        ("u_mean_abs", "V"),
        ("u_peak_abs", "V"),
    ):
        if key in m:
            v = m[key]
            lines.append(f"| {key} | {v if isinstance(v, bool) else _fmt(v)} {unit} |")
    lines += [
        "",
        "## Loop timing (wall clock)",
        "",
        "| metric | value |",
        "|---|---|",
    ]
    for key in (
        "period_ms",
        "interval_mean_ms",
        "jitter_std_ms",
        "jitter_max_ms",
        "latency_median_ms",
        "latency_max_ms",
        "call_median_ms",
        "call_max_ms",
        "missed_deadlines",
        "late_at_rig",
        "readings_lost",
    ):
        if key in tm:
            lines.append(f"| {key} | {_fmt(tm[key])} |")
    lines += [
        "",
        "## Supervisor",
        "",
        f"Limits: +-{s['voltage_limit_V']:g} V, {s['slew_limit_V_per_s']:g} V/s, |lower speed| <= "
        f"{s['speed_limit_rad_s']:g} rad/s, watchdog {s['watchdog_periods']} periods. Requests clamped in "
        f"{s['clamped_periods']} periods, slew-limited in {s['slew_limited_periods']}. Events: `events.csv`.",
        "",
        f"Recording (measured-data format): `{r['recording']}`.",
        "",
    ]
    for p in figs:
        lines.append(f"![{p.stem}]({p.name})")
    lines.append("")
    return "\n".join(lines)
