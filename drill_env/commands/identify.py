"""``drill-env identify``: every parameter of the rig model from a lab's recordings."""

from __future__ import annotations

from pathlib import Path
from typing import NoReturn

import typer


def _fail(message: str) -> NoReturn:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def identify(
    data_dir: Path | None = typer.Argument(
        None, help="Dataset folder (CSV runs t,u,theta_u,theta_l + dataset.json), as for discrepancy."
    ),
    out: Path | None = typer.Option(
        None, help="Output folder: rig.yaml, identification.json, report.md, figures."
    ),
    structure: str | None = typer.Option(
        None, help="Rig structure: brake or no_brake (default: dataset.json's 'preset')."
    ),
    known: list[str] = typer.Option(
        [],
        "--known",
        help="The one value the data cannot fix: string_stiffness=VALUE [N m/rad] (k = G pi d^4/(32 L)) or "
        "motor_constant=VALUE [N m/V]. Default: the paper's string stiffness, said so in the report.",
    ),
    heldout: str | None = typer.Option(
        None, help="Comma-separated runs held out for validation (default: every third run by voltage)."
    ),
    plan: bool = typer.Option(False, "--plan", help="Print the experiments that identify a rig, and exit."),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures."),
    no_bifurcation: bool = typer.Option(
        False, "--no-bifurcation", help="Skip the identified model's bifurcation diagram."
    ),
    no_effects: bool = typer.Option(
        False,
        "--no-effects",
        help="Fit the base model only: no discrepancy tests, no effect added (the model a lab would "
        "then test with drill-env discrepancy --params rig.yaml).",
    ),
    effects: str | None = typer.Option(
        None,
        "--effects",
        help="Comma-separated library effects the structure search may add (default: every one; "
        "drill-env discrepancy's library, e.g. position_friction_lower,motor_inductance).",
    ),
    rounds: int = typer.Option(3, "--rounds", help="Rounds of discrepancy tests at most (1-5)."),
) -> None:
    """Identify every parameter of the rig model (friction curves, inertias, motor constant, string)
    from constant-voltage and random-level runs; write rig.yaml usable by every command."""
    if plan:
        from drill_env.identify.plan import plan_text

        typer.echo(plan_text())
        return
    if data_dir is None:
        _fail("DATA_DIR: missing; give a dataset folder (or --plan for the experiments to record)")
    if out is None:
        _fail("--out: missing; give the output folder")
    from drill_env.identify.identification import identify as run_identify
    from drill_env.identify.identification import parse_known
    from drill_env.identify.report import write_outputs
    from drill_env.outputs import check_command_folder, command_folder
    from drill_env.params import available_presets
    from drill_env.recordings.dataset import load_dataset

    if structure is not None and structure not in available_presets():
        _fail(f"--structure: {structure!r}; allowed: {', '.join(available_presets())}")
    if no_effects and effects is not None:
        _fail("--effects: cannot be given with --no-effects (the base-only fit searches no effect)")
    if not 1 <= rounds <= 5:
        _fail(f"--rounds: {rounds}; allowed: 1 to 5")
    allowed = None
    if effects is not None:
        from drill_env.structure_search import check_effect_names

        names = [e.strip() for e in effects.split(",") if e.strip()]
        if not names:
            _fail("--effects: empty; give one or more library effects, or --no-effects")
        try:
            allowed = check_effect_names(names)
        except ValueError as exc:
            _fail(f"--{exc}")
    try:
        known_values = parse_known(known)
    except ValueError as exc:
        _fail(f"--{exc}")
    check_command_folder(out, "identify", "--out", own=IDENTIFY_FILES)
    if data_dir.exists() and (
        out.resolve() == data_dir.resolve() or data_dir.resolve() in out.resolve().parents
    ):
        _fail(
            f"--out {out}: lies in the dataset folder {data_dir}; keep the identification apart from the data"
        )
    held = [h.strip() for h in heldout.split(",") if h.strip()] if heldout is not None else None
    if held is not None and len(set(held)) != len(held):
        twice = next(h for h in held if held.count(h) > 1)
        _fail(f"--heldout: run {twice!r} is named twice; name each held-out run once")
    dataset = load_dataset(data_dir)
    from drill_env.commands.discrepancy import _stage_progress

    with command_folder(out, "identify", "--out", own=IDENTIFY_FILES):
        try:
            with _stage_progress() as progress:
                if no_effects:
                    res = run_identify(
                        dataset, structure=structure, known=known_values, heldout=held, progress=progress
                    )
                    search = None
                else:
                    from drill_env.structure_search import identify_structure

                    search = identify_structure(
                        dataset,
                        structure=structure,
                        known=known_values,
                        heldout=held,
                        allowed=allowed,
                        max_rounds=rounds,
                        progress=progress,
                    )
                    res = search.identification
        except ValueError as exc:
            _fail(str(exc))
        typer.echo(
            "drawing the figures and the bifurcation diagram" if not no_figures else "writing the files"
        )
        written = write_outputs(
            res, out, figures=not no_figures, bifurcation=not no_bifurcation, search=search
        )
    if res.scale_assumed:
        typer.secho(f"warning: {res.scale_sentence()}", fg=typer.colors.YELLOW, err=True)
    from drill_env.identify.identification import REFUSED_METHOD, refusal_reason

    beside = [p for p in res.not_identifiable if p.method == REFUSED_METHOD]
    if beside:
        # a refused fit: what was fitted beside the refused parameters shares one reason and one
        # run that fixes it, so one line names them all
        reason = refusal_reason(res.blocking, res.invalid)
        needs = "; ".join(dict.fromkeys(p.needs for p in beside if p.needs))
        typer.secho(
            f"warning: not identified, fitted beside a refused parameter ({reason}): "
            + ", ".join(p.name for p in beside)
            + (f"; the run that identifies them: {needs}" if needs else ""),
            fg=typer.colors.YELLOW,
            err=True,
        )
    for p in res.not_identifiable:
        if p.method == REFUSED_METHOD:
            continue
        typer.secho(
            f"warning: {p.name} is not identifiable from these data"
            + (f" ({p.note})" if p.note else "")
            + f"; the run that identifies it: {p.needs}",
            fg=typer.colors.YELLOW,
            err=True,
        )
    if search is not None:
        typer.echo(f"structure: {search.verdict} ({len(search.rounds)} round(s); stopped: {search.stopped})")
        if not search.tested:
            typer.secho(
                "warning: the structure was not tested (no discrepancy round ran): a hidden effect is not "
                "ruled out",
                fg=typer.colors.YELLOW,
                err=True,
            )
        if search.suspect:
            typer.secho(
                "warning: an unexplained residual remains; suspect parameters: " + ", ".join(search.suspect),
                fg=typer.colors.YELLOW,
                err=True,
            )
    files = ", ".join(k for k in ("rig.yaml", "identification.json", "report.md") if written.get(k))
    typer.echo(f"wrote {files} to {out} ({res.timings.get('total', 0):.0f} s)")
    if res.params is None:
        reason = (
            "the data do not identify "
            + ", ".join(p.name for p in res.blocking)
            + "; record the runs named in report.md (drill-env identify --plan)"
            if res.blocking
            else "the fitted parameters make no valid rig ("
            + (getattr(res, "invalid", "") or "outside the model's range")
            + "); record runs that excite the rig more widely (drill-env identify --plan)"
        )
        typer.secho(f"error: no rig.yaml: {reason}", fg=typer.colors.RED, err=True)
        raise typer.Exit(code=1)


# what `drill-env identify` writes (a folder of these from before folders had markers is its own)
IDENTIFY_FILES = (
    "rig.yaml",
    "identification.json",
    "report.md",
    "friction.png",
    "heldout.png",
    "bifurcation.png",
)


def register(app: typer.Typer) -> None:
    app.command(name="identify")(identify)
