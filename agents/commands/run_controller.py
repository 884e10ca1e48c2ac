"""``drill-env run-controller``: a controller on a rig (or the emulator) behind the supervisor."""

from __future__ import annotations

import math
from pathlib import Path

import typer


def _fail(message: str, rig=None) -> None:  # noqa: ANN001
    if rig is not None:
        rig.stop()  # 0 V before anything else
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def register(app: typer.Typer) -> None:
    @app.command("run-controller")
    def run_controller(
        controller: str = typer.Argument(
            ..., help="A benchmark controller (lqi, ppo, ...), a policy file (.zip) or module:Class."
        ),
        rig: str = typer.Option(
            ..., "--rig", help="The rig's address HOST:PORT (its I/O box or emulate-rig)."
        ),
        voltage: float = typer.Option(..., help="Set point: the nominal voltage [V], in (0, 5]."),
        out: Path = typer.Option(
            ..., help="Output folder: recording/, logs, result.json, report.md, figures."
        ),
        preset: str = typer.Option("brake", help="The design model the controller and set point come from."),
        duration: float = typer.Option(90.0, help="Closed-loop time [s], in (0, 1e4]."),
        warmup: float = typer.Option(
            60.0,
            help="Open loop at the nominal voltage before the controller is switched on [s], in [0, 1e4].",
        ),
        window: float = typer.Option(20.0, help="The report's steady-state window at the end [s]."),
        voltage_limit: float = typer.Option(5.0, help="Supervisor: |voltage| clamp [V], in (0, 5]."),
        slew_limit: float | None = typer.Option(
            None, help="Supervisor: voltage slew limit [V/s], in (0, 1e4] (default 100 V/s)."
        ),
        speed_limit: float | None = typer.Option(
            None,
            help="Supervisor: |lower-disk speed| limit [rad/s], in (0, 100] (default: the brake model's "
            "identified range, 12.6 rad/s).",
        ),
        watchdog_periods: int = typer.Option(
            3, help="Supervisor: control periods without a reading, 1 to 100."
        ),
        record: Path | None = typer.Option(
            None, help="Dataset folder to add the recording to (default: OUT/recording); created when new."
        ),
        run_name: str | None = typer.Option(
            None, help="The recording's run name (default: CONTROLLER_VOLTAGE V)."
        ),
        agents_dir: Path | None = typer.Option(None, help="Folder of trained policies (as for benchmark)."),
        trust_policies: bool = typer.Option(
            False, "--trust-policies", help="Load a policy file from anywhere."
        ),
        no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures."),
        connect_timeout: float = typer.Option(
            1.0, help="Seconds to wait for the rig's HELLO answer (3 tries)."
        ),
    ) -> None:
        """Run a controller on a rig at the environment's control period behind the safety supervisor
        (+-5 V clamp, slew limit, speed limit, watchdog; 0 V on any stop), and record the run in the
        measured-data format with the controller's log and a report.

        The run: WARMUP s open loop at the nominal voltage, then the controller for DURATION s.
        Exit 0 when it completed, 1 when the supervisor stopped it, 2 for bad input, 130 on Ctrl-C;
        in every case the motor is at 0 V and what was recorded is written.
        """
        import re

        from drill_env.agents.evaluation.episodes import MAX_EPISODE_S
        from drill_env.rig.supervisor import DEFAULT_SLEW_LIMIT, DEFAULT_SPEED_LIMIT, SupervisorLimits

        slew_limit = DEFAULT_SLEW_LIMIT if slew_limit is None else slew_limit
        speed_limit = DEFAULT_SPEED_LIMIT if speed_limit is None else speed_limit

        if not (math.isfinite(voltage) and 0 < voltage <= 5.0):
            _fail(f"--voltage: {voltage!r}; allowed: (0, 5] V")
        for name, value, lo_open in (
            ("--duration", duration, True),
            ("--warmup", warmup, False),
            ("--window", window, True),
        ):
            if not (
                math.isfinite(value) and (value > 0 if lo_open else value >= 0) and value <= MAX_EPISODE_S
            ):
                _fail(f"{name}: {value!r}; allowed: {'(' if lo_open else '['}0, {MAX_EPISODE_S:g}] s")
        if window > duration:
            _fail(f"--window ({window:g} s) must not exceed --duration ({duration:g} s)")
        if not (math.isfinite(connect_timeout) and 0 < connect_timeout <= 60):
            _fail(f"--connect-timeout: {connect_timeout!r}; allowed: (0, 60] s")
        try:
            limits = SupervisorLimits(voltage_limit, slew_limit, speed_limit, watchdog_periods)
        except ValueError as exc:
            _fail(str(exc))
        if controller.endswith(".zip"):
            # a policy file is most often FOLDER/policy.zip: the folder names it (as its label)
            p = Path(controller)
            stem = p.parent.name if p.stem == "policy" and p.parent.name not in ("", ".") else p.stem
        else:
            stem = controller
        name = run_name or f"{re.sub(r'[^A-Za-z0-9_.-]+', '_', stem)}_{voltage:g}V"
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
            _fail(f"--run-name: {name!r}; allowed: letters, digits, _ . -")
        from drill_env.outputs import check_command_folder, check_output_folder, command_folder

        # a folder of these from before folders had markers is this command's own
        own = ("controller_log.csv", "events.csv", "result.json", "report.md", "run.png", "timing.png")
        check_command_folder(out, "run-controller", "--out", own=own)
        if record is not None:
            check_output_folder(record, "--record")
            if (record / f"{name}.csv").exists():  # never replace a recorded run
                _fail(
                    f"--record {record}: already holds a run named {name!r}; give another --run-name "
                    "(the recorded run is kept)"
                )
        from drill_env.params import available_presets
        from drill_env.rig.udp import UdpRig, parse_address

        if preset not in available_presets():
            _fail(f"--preset: {preset!r}; allowed: {', '.join(available_presets())}")
        try:
            host, port = parse_address(rig)
        except ValueError as exc:
            _fail(str(exc))
        from drill_env.rig.udp import RigNotAnswering

        try:
            io = UdpRig(host, port)
            info = io.hello(timeout=connect_timeout)
        except RigNotAnswering as exc:
            _fail(str(exc))
        # from here on every exit writes 0 V first
        if info.voltage_limit < limits.voltage_limit:
            _fail(
                f"--voltage-limit: {voltage_limit:g} V is beyond the rig's amplifier range +-{info.voltage_limit:g} V",
                io,
            )
        from drill_env.agents.evaluation.rig_runs import measured_metrics, resolve_controller
        from drill_env.rig.loop import RunSettings, run_loop, write_outputs

        trusted = False
        if controller.endswith(".zip"):
            from drill_env.agents.commands._trust import vouch_for_policies

            trusted = vouch_for_policies([controller], flag=trust_policies, option="CONTROLLER")
        try:
            env, ctrl, label = resolve_controller(
                controller, preset, info.counts_per_rev, info.sample_rate_hz, agents_dir=agents_dir,
                trusted=trusted,
            )  # fmt: skip
        except ValueError as exc:
            _fail(str(exc), io)
        settings = env.unwrapped.settings
        try:
            point = settings.parse_options({"nominal_voltage": voltage})["point"]
        except ValueError as exc:
            _fail(f"--voltage: {exc}", io)
        if point.target_speed > limits.speed_limit:
            _fail(
                f"--speed-limit: {speed_limit:g} rad/s is below the set point's target speed "
                f"{point.target_speed:.4g} rad/s (at {voltage:g} V); raise it or lower --voltage",
                io,
            )
        run = RunSettings(preset, voltage, duration, warmup, window, limits)
        typer.echo(
            f"run-controller: {label} on {host}:{port} ({info.sample_rate_hz:g} Hz, {info.counts_per_rev} counts/rev, "
            f"clock x{info.time_scale:g}); {warmup:g} s open loop at {voltage:g} V, then {duration:g} s closed loop",
            err=True,
        )
        res = run_loop(io, info, env, ctrl, label, run)
        io.close()
        with command_folder(out, "run-controller", "--out", own=own):
            result = write_outputs(
                res, out, record=record, run_name=name, measured=measured_metrics(res), figures=not no_figures
            )
        m = result["measured"]
        if "suppression" in m:
            typer.echo(
                f"measured over the last {m['window_s']:g} s: suppression {m['suppression']:.4g}, "
                f"rms error {m['rms_error']:.4g} rad/s, stalled {m['stalled']}"
            )
        tm = result["timing"]
        typer.echo(
            f"loop: {tm['periods']} periods, jitter {tm.get('jitter_std_ms', float('nan')):.3g} ms (std), "
            f"{tm['missed_deadlines']} missed deadlines, {tm['readings_lost']} readings lost"
        )
        typer.echo(f"wrote {out} (recording: {result['recording']})")
        if res.interrupted:
            from drill_env.cli import interrupted

            interrupted(f"0 V written; the run so far is recorded in {out}")
        if res.trip_kind == "rate":  # bad input: the controller cannot hold the rig's rate
            typer.secho(f"error: {res.trip}", fg=typer.colors.RED, err=True)
            raise typer.Exit(code=2)
        if res.trip is not None:
            typer.secho(f"error: {res.trip}", fg=typer.colors.RED, err=True)
            raise typer.Exit(code=1)
