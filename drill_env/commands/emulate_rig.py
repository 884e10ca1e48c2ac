"""``drill-env emulate-rig``: the exact simulator behind the rig's wire protocol."""

from __future__ import annotations

import math
from pathlib import Path

import typer


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def register(app: typer.Typer) -> None:
    @app.command("emulate-rig")
    def emulate_rig(
        preset: str = typer.Option("brake", help="The plant: a preset (brake, no_brake) or a rig YAML."),
        plant: Path | None = typer.Option(
            None, help="A plant file (parameters, effects, actuator_delay, sensors); replaces --preset."
        ),
        host: str = typer.Option("127.0.0.1", help="Address to listen on (0.0.0.0: every interface)."),
        port: int = typer.Option(50450, help="UDP port, 0 to 65535 (0: any free port, printed)."),
        time_scale: float = typer.Option(
            1.0,
            help="Rig seconds per wall-clock second, in [0.1, 50]. Tests only: a real rig runs at 1; "
            "run-controller reads it from the rig and scales its periods.",
        ),
        seed: int = typer.Option(0, min=0, help="Seed of the encoders' angle noise (if the plant has any)."),
        truth: Path | None = typer.Option(
            None, help="CSV to write the true state into at every sensor tick (what no rig can record)."
        ),
    ) -> None:
        """Serve an emulated rig on a UDP port until Ctrl-C: the exact simulator paced to the wall
        clock, at rest and 0 V when it starts, speaking the protocol of docs/reference/rig_protocol.md."""
        from drill_env.rig.emulator import MAX_TIME_SCALE

        if not 0 <= port <= 65535:
            _fail(f"--port: {port}; allowed: 0 to 65535")
        if not (math.isfinite(time_scale) and 0.1 <= time_scale <= MAX_TIME_SCALE):
            _fail(f"--time-scale: {time_scale!r}; allowed: [0.1, {MAX_TIME_SCALE:g}]")
        if truth is not None:
            from drill_env.outputs import check_command_file

            check_command_file(truth, "emulate-rig", "--truth")
        from drill_env.params import ParameterError
        from drill_env.rig.emulator import EmulatedRig, emulated_plant, serve

        try:
            params, sensors = emulated_plant(preset, plant)
            rig = EmulatedRig(params, sensors, seed=seed)
        except (ParameterError, ValueError) as exc:
            _fail(str(exc))
        try:
            serve(
                rig, host, port, time_scale=time_scale, truth=truth, announce=lambda s: typer.echo(s, nl=True)
            )
        except OSError as exc:
            _fail(f"--host {host} --port {port}: {exc.strerror or exc}")
        typer.echo(f"emulate-rig: stopped at t = {rig.tick * sensors.sample_period:.3f} s (0 V)")
