"""``drill-env bifurcation`` and ``drill-env rig-comparison``: the analysis of Sec. 3 and 4."""

from __future__ import annotations

import json
import math
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import typer


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


MAX_ABS_VOLTAGE = 100.0  # [V] the analysed range (the rig's amplifier limit is 5 V)


def register(app: typer.Typer) -> None:
    @app.command("bifurcation")
    def bifurcation(
        preset: str = typer.Option("brake", help="Rig preset (brake, no_brake) or a YAML file."),
        umax: float = typer.Option(5.0, help="Upper end of the voltage range [V], at most 100."),
        umin: float = typer.Option(0.0, help="Lower end of the voltage range [V], at least -100."),
        out: Path = typer.Option(..., help="Directory for bifurcation.json and the figures."),
        check: bool = typer.Option(
            True, "--check/--no-check", help="Confirm the diagram by brute-force simulation."
        ),
    ) -> None:
        """Bifurcation diagram in the voltage: equilibria, Hopf points, periodic orbits, points A-F.

        Writes OUT/bifurcation.json, the figures fig6_equilibria.png, fig8_bifurcation.png,
        period.png and fig9_limit_cycles.png, and with --check OUT/brute_force_check.json.
        A range beyond the rig's +-5 V, or orbits faster than the speed the brake friction
        was identified up to (12.6 rad/s), gives a warning and bifurcation.json's
        "validity_warnings".
        """
        if not (math.isfinite(umin) and math.isfinite(umax)) or umax <= umin:
            _fail(f"need finite --umin < --umax, got {umin!r}, {umax!r}")
        for name, value in (("--umin", umin), ("--umax", umax)):
            if abs(value) > MAX_ABS_VOLTAGE:
                _fail(
                    f"{name}: {value:g} V; allowed: [-{MAX_ABS_VOLTAGE:g}, {MAX_ABS_VOLTAGE:g}] V "
                    "(the rig's amplifier gives +-5 V; the model is analysed beyond it up to this bound)"
                )
        from rich.console import Console
        from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
        from rich.table import Table

        from drill_env.analysis import bifurcation_diagram, brute_force_check
        from drill_env.analysis.plots import save_figures
        from drill_env.outputs import (
            OutputFolderError,
            atomic_write_text,
            check_command_folder,
            command_folder,
        )
        from drill_env.params import ParameterError, resolve_params, validity_warnings

        try:
            params = resolve_params(preset)
        except (ParameterError, ValueError) as exc:
            _fail(f"--preset {preset}: {exc}")
        check_command_folder(out, "bifurcation", "--out", own=BIFURCATION_FILES)
        console = Console(stderr=True)
        notes = validity_warnings(params.name, voltages=(umin, umax))
        for note in notes:
            console.print(
                f"[yellow]warning: {note}; it is analysed there all the same[/yellow]", highlight=False
            )
        if params.effects.active:
            # a rig file with an effect section (identify, discrepancy): the analysis is that of
            # its base model, as the env's regimes and the benchmark's design grid are
            from drill_env.envs.equilibrium import nominal_params

            note = (
                f"the analysis covers the paper's model only: the effects {list(params.effects.active)} "
                f"of {Path(preset).name} are left out (the env's regimes and the benchmark's grid on "
                "this rig are those of the same base model)"
            )
            console.print(f"[yellow]warning: {note}[/yellow]", highlight=False, soft_wrap=True)
            notes.append(note)
            params = nominal_params(params)
        held = ExitStack()
        try:
            # OUT is this run's alone until it ends
            held.enter_context(command_folder(out, "bifurcation", "--out", own=BIFURCATION_FILES))
        except OutputFolderError as exc:
            _fail(str(exc))
        with held:
            columns = (SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn())
            with Progress(*columns, console=console, transient=False) as prog:
                task = prog.add_task("continuation", total=umax - umin)

                def on_point(c) -> None:
                    prog.update(
                        task,
                        completed=min(max(c.u - umin, 0.0), umax - umin),
                        description=f"continuation: u = {c.u:7.4f} V, amplitude {c.amplitude:7.4f} rad/s",
                    )

                try:
                    diagram = bifurcation_diagram(params, u_max=umax, u_min=umin, on_point=on_point)
                except ValueError as exc:
                    _fail(f"the diagram from {umin:g} to {umax:g} V: {exc}")
                prog.update(task, completed=umax - umin, description="continuation: done")
                result = None
                if check:
                    ctask = prog.add_task("brute-force check", total=1.0)

                    def on_stage(stage: str, frac: float) -> None:
                        prog.update(ctask, completed=frac, description=f"brute-force check: {stage}")

                    result = brute_force_check(diagram, progress=on_stage)
                    prog.update(ctask, completed=1.0, description="brute-force check: done")
            record = diagram.to_dict()
            speed_notes = validity_warnings(params.name, max_speed=_max_speed(record))
            for note in speed_notes:
                console.print(f"[yellow]warning: {note}[/yellow]", highlight=False, soft_wrap=True)
            record["validity_warnings"] = notes + speed_notes
            atomic_write_text(out / "bifurcation.json", json.dumps(record, indent=1, allow_nan=False) + "\n")
            if result is not None:
                result.save_json(out / "brute_force_check.json")
            paths = save_figures(diagram, out, check=result)

        table = Table(title=f"{diagram.preset}, {umin:g} to {umax:g} V")
        for col in ("point", "u [V]", "type"):
            table.add_column(col)
        for name, pt in diagram.points.items():
            table.add_row(name, f"{pt.u:.6f}", pt.type)
        for pt in diagram.other_points:
            table.add_row(f"({pt.name})", f"{pt.u:.6f}", pt.type)
        Console().print(table)
        absent = [k for k in "ABCDEF" if k not in diagram.points]
        if absent:
            typer.echo(f"not in the range: {', '.join(absent)}")
        for br in diagram.branches:
            typer.echo(
                f"branch from the Hopf point at {br.start.u:.4f} V: {len(br.cycles)} orbits, ends: {br.end_reason}"
            )
        chk = diagram.checks()
        if chk["orbits"]:
            typer.echo(
                f"{chk['orbits']} orbits: max |trivial multiplier - 1| = {chk['trivial_multiplier_max_deviation']:.1e}, "
                f"max periodicity residual = {chk['periodicity_max_residual']:.1e}"
            )
        typer.echo(f"diagram computed in {diagram.timings['total']:.2f} s")
        if result is not None:
            typer.echo(result.summary())
        typer.echo(f"wrote {out / 'bifurcation.json'}" + "".join(f", {p.name}" for p in paths))
        if result is not None and not result.passed:
            raise typer.Exit(code=1)

    @app.command("rig-comparison")
    def rig_comparison_cmd(
        preset: str = typer.Option("brake", help="Rig preset; the paper's measurements are with the brake."),
        out: Path | None = typer.Option(None, help="Markdown file to write (a .json beside it)."),
        params: Path | None = typer.Option(
            None,
            "--params",
            help="A rig YAML to compare instead of the preset (effects included, e.g. a discrepancy "
            "model.yaml); with effects the values come from long simulations.",
        ),
    ) -> None:
        """Compare the model's steady states with the measurements quoted in the paper (Sec. 4)."""
        from drill_env.analysis import rig_comparison
        from drill_env.outputs import check_command_file, command_files

        if out is not None:
            if out.suffix.lower() == ".json":
                _fail(f"--out {out}: the Markdown file; its .json goes beside it")
            check_command_file(out, "rig-comparison", "--out")
            check_command_file(out.with_suffix(".json"), "rig-comparison", "--out")
        model: Any = preset
        if params is not None:
            from drill_env.params import ParameterError, load_params

            if params.suffix.lower() not in (".yaml", ".yml"):
                _fail(f"--params {params}: expected a rig YAML file (.yaml or .yml)")
            try:
                model = load_params(params)
            except ParameterError as exc:
                _fail(f"--params {params}: {exc}")
        try:
            comp = rig_comparison(model)
        except ValueError as exc:
            _fail(str(exc))
        text = comp.to_markdown()
        if out is not None:
            with command_files([out, out.with_suffix(".json")], "rig-comparison", "--out"):
                comp.save(out)  # both files, or (a write error) neither new one
        typer.echo(text)
        if out is not None:
            typer.echo(f"wrote {out} and {out.with_suffix('.json')}")


# what `drill-env bifurcation` writes (a folder of these from before folders had markers is its own)
BIFURCATION_FILES = ("bifurcation.json", "brute_force_check.json", "*.png")


def _max_speed(record: dict[str, Any]) -> float:
    """The largest |lower-disk speed| of any equilibrium or orbit in the diagram [rad/s]."""
    speeds = [abs(v) for br in record["branches"] for key in ("x3_min", "x3_max") for v in br.get(key, [])]
    return max(speeds, default=0.0)
