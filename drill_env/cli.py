"""Command-line interface: ``drill-env COMMAND``.

Each command is a thin shell over the Python API; heavy modules are imported inside
the command so that ``drill-env --help`` stays quick.

Bad input ends a command with one line ``error: ...`` on stderr and exit code 2, never
a traceback: each command checks its options, and the errors the library raises for bad
input (:data:`EXPECTED_ERRORS` below: a rig or config file, a measured dataset, an
output path) are caught once, around every command, by :class:`_Commands`. Any other
exception is a bug and keeps its traceback. Work that ran and failed exits with code 1.
"""

from __future__ import annotations

import math
from pathlib import Path

import typer
from typer.core import TyperGroup

# At most this many output samples from `drill-env simulate` (about 0.6 GB in memory and
# 1.5 GB of CSV); a larger request is refused before it starts, naming --dt and --duration.
MAX_SIMULATE_ROWS = 10_000_000


def _expected_errors() -> tuple[type[BaseException], ...]:
    """The library's errors for bad input: shown as one line, never as a traceback.

    Only modules already imported can have raised one: none is imported here (importing
    the discrepancy package would cost a second on every error and every Ctrl-C)."""
    import sys

    found: list[type[BaseException]] = [OSError]
    for module, names in (
        ("drill_env.recordings.dataset", ("DatasetError",)),
        ("drill_env.outputs", ("OutputFolderError",)),
        ("drill_env.params", ("ParameterError",)),
        ("drill_env.simulator", ("InputFunctionError", "OutputSizeError")),
    ):
        mod = sys.modules.get(module)
        if mod is not None:
            found += [getattr(mod, n) for n in names]
    return tuple(found)


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        return f"{exc.filename}: {exc.strerror}"
    text = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return text or type(exc).__name__


INTERRUPTED_EXIT = 130  # the shell's code for a command ended by Ctrl-C (128 + SIGINT)


class _Commands(TyperGroup):
    """Every command runs inside one handler for the expected error types and for Ctrl-C."""

    def invoke(self, ctx):  # noqa: ANN001, ANN201 (click's signature)
        _one_line_warnings()
        try:
            return super().invoke(ctx)
        except (typer.Exit, typer.Abort, typer.BadParameter.__mro__[2]):  # click's own: passed on
            raise
        except _expected_errors() as exc:  # evaluated only when an exception propagates
            _fail(_one_line(exc))
        except KeyboardInterrupt:
            interrupted(
                "every file written so far is complete (each is replaced whole); nothing else was written"
            )


def _one_line_warnings() -> None:
    """Warnings of a category marked ``one_line`` (e.g. a regime the rig does not have) are
    shown as one ``warning: ...`` line, without Python's source line; the others as usual."""
    import warnings

    previous = warnings.showwarning
    if getattr(previous, "_one_line", False):
        return

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001, ANN202
        if getattr(category, "one_line", False):
            typer.secho(f"warning: {message}", fg=typer.colors.YELLOW, err=True)
        else:
            previous(message, category, filename, lineno, file, line)

    show._one_line = True  # type: ignore[attr-defined]
    warnings.showwarning = show


def interrupted(kept: str) -> None:
    """End a command stopped by Ctrl-C: one line saying what is kept, exit code 130."""
    typer.secho(f"interrupted (Ctrl-C): {kept}", fg=typer.colors.YELLOW, err=True)
    raise typer.Exit(code=INTERRUPTED_EXIT)


# Plain help text (no rich markup): units in brackets such as "[s]" stay visible, switches show
# as flags and long values wrap instead of being cut at the terminal width.
app = typer.Typer(
    cls=_Commands,
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=None,
    help="drill-env: the torsional stick-slip rig of Mihajlovic et al. (2004).",
)


def _print_version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            typer.echo(f"drill-env {version('drill-env')}")
        except PackageNotFoundError:  # run from a source tree that was never installed
            _fail("--version: drill-env is not installed (no package metadata); pip install -e .")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """drill-env: the torsional stick-slip rig of Mihajlovic et al. (2004)."""


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def _warn(message: str) -> None:
    typer.secho(f"warning: {message}", fg=typer.colors.YELLOW, err=True)


@app.command()
def simulate(
    preset: str = typer.Option("brake", help="Rig preset (brake, no_brake) or a YAML file."),
    voltage: float = typer.Option(2.0, help="Constant amplifier input voltage u [V]."),
    duration: float = typer.Option(300.0, help="Simulated time [s], at most 1e7 (longer: split the run)."),
    dt: float = typer.Option(
        0.01, help="Output sample period [s], at least 1e-9; at most 1e7 output samples in all."
    ),
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
    from drill_env.simulator import MAX_DURATION_S, MIN_DT

    if duration > MAX_DURATION_S:
        _fail(f"--duration: {duration:g} s; allowed: at most {MAX_DURATION_S:g} s (split a longer run)")
    if dt < MIN_DT:
        _fail(f"--dt: {dt:g} s is below the clock's resolution; allowed: at least {MIN_DT:g} s")
    if summary_window > MAX_DURATION_S:
        _fail(f"--summary-window: {summary_window:g} s; allowed: at most {MAX_DURATION_S:g} s")
    if dt > duration:
        _fail(f"--dt ({dt:g} s) must not exceed --duration ({duration:g} s)")
    rows = math.floor(duration / dt * (1 + 1e-12) + 1e-9) + 1
    if rows > MAX_SIMULATE_ROWS:
        _fail(
            f"--duration {duration:g} s at --dt {dt:g} s makes {rows:.4g} output samples (about "
            f"{rows * 58 / 2**30:.3g} GiB in memory, {rows * 150 / 2**30:.3g} GiB of CSV); the limit is "
            f"{MAX_SIMULATE_ROWS:.0e}: raise --dt to at least {duration / (MAX_SIMULATE_ROWS - 1):.3g} s "
            "or shorten --duration"
        )

    from drill_env.metrics import stick_slip_metrics
    from drill_env.outputs import atomic_file, check_command_file, command_files
    from drill_env.params import RIG_VOLTAGE_LIMIT, resolve_params, validity_warnings
    from drill_env.simulator import simulate as run_simulation

    params = resolve_params(preset)
    if out is not None:
        check_command_file(out, "simulate", "--out")  # before the run, not after it
    applied = voltage
    if not no_voltage_limit and abs(voltage) > RIG_VOLTAGE_LIMIT:
        applied = math.copysign(RIG_VOLTAGE_LIMIT, voltage)
        _warn(
            f"--voltage {voltage:g} V is outside the rig's +-{RIG_VOLTAGE_LIMIT:g} V "
            f"amplifier range; clipped to {applied:g} V (use --no-voltage-limit to lift it)"
        )
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a failed run is reported below
        try:
            res = run_simulation(params, applied, duration, dt=dt)
        except KeyboardInterrupt:
            interrupted("the simulation was stopped; nothing written")
    if res.status != 0:
        typer.secho(
            f"error: the simulation at u = {applied:g} V failed: {res.message.rstrip('.')} (status {res.status}); "
            "nothing written",
            fg=typer.colors.RED,
            err=True,
        )
        raise typer.Exit(code=1)
    notes = validity_warnings(params.name, voltages=(applied, applied), max_speed=float(abs(res.x3).max()))
    for note in notes:
        _warn(note)
    if out is not None:
        df = res.to_pandas()
        df["stick_u"] = df["stick_u"].astype(int)
        df["stick_l"] = df["stick_l"].astype(int)
        with command_files([out], "simulate", "--out"), atomic_file(out, "w", newline="") as f:
            df.to_csv(f, index=False, float_format="%.10g")
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
    typer.echo(f"  switching events: {len(res.events) if res.events is not None else 0}")
    if out is not None:
        typer.echo(f"wrote {out} ({res.t.size} rows)")


# Packages whose every module defines ``register(app)`` adding its command(s): the core's
# own commands, then those of the controller package built on it (``drill_env.agents``, the
# project's ``agents/`` folder, shipped in the same distribution; skipped when absent). Named
# here, never imported by the core: the dependency runs from ``drill_env.agents.commands`` to
# this app. Other packages add commands through the ``drill_env.commands`` entry-point group
# (each a ``register``).
COMMAND_PACKAGES = ("drill_env.commands", "drill_env.agents.commands")
ENTRY_POINT_GROUP = "drill_env.commands"


def _register_commands() -> None:
    import importlib
    import pkgutil
    from importlib.metadata import entry_points

    for package_name in COMMAND_PACKAGES:
        try:
            package = importlib.import_module(package_name)
        except ModuleNotFoundError as exc:
            if exc.name is not None and package_name.startswith(exc.name):
                continue  # that package is not installed: its commands are not offered
            raise
        for mod in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
            if mod.name.startswith("_"):
                continue  # a helper of the commands (e.g. _trust), not a command
            importlib.import_module(f"{package_name}.{mod.name}").register(app)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        ep.load()(app)


_register_commands()


def main(prog_name: str | None = None) -> None:  # entry point (``drill-env``, ``python -m drill_env``)
    """Run the command; a Ctrl-C at any moment ends it with exit code 130, also one that
    arrived where Python cannot raise it (a finaliser, a cleanup: "Exception ignored"), and
    also in a process started with SIGINT ignored (a shell script's background job)."""
    import signal

    seen: list[int] = []

    def on_sigint(signum: int, frame: object) -> None:
        seen.append(signum)
        raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGINT, on_sigint)
    except ValueError:  # not the main thread: leave Python's handler
        pass
    try:
        app(prog_name=prog_name) if prog_name is not None else app()
    except SystemExit as exc:
        if seen and exc.code in (0, None):
            typer.secho(
                "interrupted (Ctrl-C): the command was stopped while it finished; every file written is "
                "complete (each is replaced whole)",
                fg=typer.colors.YELLOW,
                err=True,
            )
            _exit_now(INTERRUPTED_EXIT)
        if exc.code == INTERRUPTED_EXIT:
            _exit_now(INTERRUPTED_EXIT)
        raise
    except KeyboardInterrupt:  # one that escaped a command's own handling (e.g. while it started)
        typer.secho(
            "interrupted (Ctrl-C): the command was stopped; every file written is complete (each is "
            "replaced whole)",
            fg=typer.colors.YELLOW,
            err=True,
        )
        _exit_now(INTERRUPTED_EXIT)


def _exit_now(code: int) -> None:
    """End the process at once after a Ctrl-C: the exit handlers run (pools, clusters, temporary
    folders), the output is flushed, and the interpreter's teardown is skipped -- freeing the
    compiled kernels' machine code alone takes seconds on a loaded machine. Every file the
    command wrote was closed (and replaced whole) before it got here."""
    import atexit
    import os
    import sys

    try:
        atexit._run_exitfuncs()
    except BaseException:  # noqa: BLE001 (a second Ctrl-C in a handler: end anyway)
        pass
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except BaseException:  # noqa: BLE001
            pass
    os._exit(code)


if __name__ == "__main__":
    main()
