"""Command-line interface: ``drill-env COMMAND``.

Each command is a thin shell over the Python API; heavy modules are imported inside
the command so that ``drill-env --help`` stays quick.
"""

from __future__ import annotations

import math
from pathlib import Path

import typer

# Plain help text (no rich markup): units in brackets such as "[s]" stay visible, switches show
# as flags and long values wrap instead of being cut at the terminal width.
app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=None,
    help="drill-env: the torsional stick-slip rig of Mihajlovic et al. (2004).",
)


@app.callback()
def _root() -> None:
    """drill-env: the torsional stick-slip rig of Mihajlovic et al. (2004)."""


RIG_VOLTAGE_LIMIT = 5.0  # [V] the amplifier input range of the rig, Sec. 2.1


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


@app.command()
def simulate(
    preset: str = typer.Option("brake", help="Rig preset (brake, no_brake) or a YAML file."),
    voltage: float = typer.Option(2.0, help="Constant amplifier input voltage u [V]."),
    duration: float = typer.Option(300.0, help="Simulated time [s]."),
    dt: float = typer.Option(0.01, help="Output sample period [s]."),
    out: Path | None = typer.Option(None, help="CSV file to write (t,u,theta_u,...)."),
    no_voltage_limit: bool = typer.Option(
        False, "--no-voltage-limit", help="Lift the rig's +-5 V amplifier limit (analysis only)."
    ),
    summary_window: float = typer.Option(100.0, help="Summary over the last this many seconds."),
) -> None:
    """Simulate the rig at a constant voltage, write a CSV and print a steady-state summary."""
    for name, value in (("--duration", duration), ("--dt", dt), ("--summary-window", summary_window)):
        if not math.isfinite(value) or value <= 0:
            _fail(f"{name} must be a finite number > 0, got {value!r}")
    if not math.isfinite(voltage):
        _fail(f"--voltage must be finite, got {voltage!r}")
    if dt > duration:
        _fail(f"--dt ({dt:g} s) must not exceed --duration ({duration:g} s)")

    from drill_env.metrics import stick_slip_metrics
    from drill_env.params import ParameterError, resolve_params
    from drill_env.simulator import simulate as run_simulation

    try:
        params = resolve_params(preset)
    except ParameterError as exc:
        _fail(str(exc))
    applied = voltage
    if not no_voltage_limit and abs(voltage) > RIG_VOLTAGE_LIMIT:
        applied = math.copysign(RIG_VOLTAGE_LIMIT, voltage)
        typer.secho(
            f"warning: --voltage {voltage:g} V is outside the rig's +-{RIG_VOLTAGE_LIMIT:g} V "
            f"amplifier range; clipped to {applied:g} V (use --no-voltage-limit to lift it)",
            fg=typer.colors.YELLOW,
            err=True,
        )
    res = run_simulation(params, applied, duration, dt=dt)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        df = res.to_pandas()
        df["stick_u"] = df["stick_u"].astype(int)
        df["stick_l"] = df["stick_l"].astype(int)
        df.to_csv(out, index=False, float_format="%.10g")
    win = res.window(min(summary_window, duration))
    m = stick_slip_metrics(win.t, win.x3, win.stick_l)
    stick_u = float(win.stick_u.mean())
    period = (
        f"{m.period:.3f} s ({1 / m.period:.4f} Hz)" if math.isfinite(m.period) else "none (no oscillation)"
    )
    typer.echo(f"rig: {params.name}, u = {applied:g} V, {duration:g} s simulated, status: {res.message}")
    typer.echo(f"last {win.t[-1] - win.t[0]:g} s of the lower-disk speed x3 [rad/s]:")
    typer.echo(f"  mean {m.mean_speed:.5f}  min {m.min_speed:.5f}  max {m.max_speed:.5f}")
    typer.echo(f"  fraction of time stuck: lower disk {m.stick_fraction:.4f}, upper disk {stick_u:.4f}")
    typer.echo(f"  dominant period: {period}")
    typer.echo(f"  switching events: {len(res.events)}")
    if out is not None:
        typer.echo(f"wrote {out} ({res.t.size} rows)")


def _register_commands() -> None:
    import importlib
    import pkgutil

    from drill_env import commands

    for mod in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        importlib.import_module(f"drill_env.commands.{mod.name}").register(app)


_register_commands()


def main() -> None:  # entry point
    app()


if __name__ == "__main__":
    main()
