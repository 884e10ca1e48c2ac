"""``drill-env synth`` and ``drill-env discrepancy``: hidden-effect data and the discrepancy workflow."""

from __future__ import annotations

from pathlib import Path

import typer


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def _progress():
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        transient=True,
    )


def synth(
    preset: str = typer.Option("brake", help="Rig preset of the truth model (brake, no_brake)."),
    effect: str | None = typer.Option(
        None, help="Hidden effect: none, a library effect, or external_torque (or give --plant)."
    ),
    plant: Path | None = typer.Option(
        None,
        "--plant",
        help="Record this truth plant instead of the preset with a drawn effect: a plant file (rig "
        "YAML with effects, optionally actuator_delay [s] and sensors:, whose counts_per_rev and "
        "angle_noise_std replace --counts and --angle-noise). Its preset (friction family) is --preset.",
    ),
    magnitude: float | None = typer.Option(
        None,
        help="Magnitude of the effect (its meaning per effect is in the README); default: "
        "drawn log-uniformly from the documented detectable range.",
    ),
    seed: int = typer.Option(0, help="Seed of everything random (effect phases, runs, noise)."),
    out: Path = typer.Option(..., help="Dataset folder to write (runs + dataset.json)."),
    answer: Path = typer.Option(..., help="File that receives the effect and its parameters (JSON)."),
    angle_noise: float = typer.Option(
        0.0,
        "--angle-noise",
        "--noise",
        help="Gaussian angle noise before quantisation [rad]; 0 is a real encoder (the angle is the "
        "quantised true angle and nothing else). --noise is the older name.",
    ),
    param_error: float = typer.Option(
        0.0,
        "--param-error",
        help="Relative error of every identified parameter of the truth model, drawn uniformly from "
        "[-REL, REL] per dataset from the seed (0-0.3); the drawn values go to --answer only.",
    ),
    counts: int = typer.Option(2000, help="Encoder counts per revolution."),
    rate: float = typer.Option(500.0, help="Sample rate [Hz] (100-10000)."),
    duration: float = typer.Option(150.0, help="Recorded length of each run [s]."),
    voltages: str = typer.Option(
        "0.2,0.5,0.7,1.0,2.0,3.0,4.5", help="Constant-voltage runs [V], comma-separated ('' for none)."
    ),
    random_runs: int = typer.Option(3, help="Quasi-random voltage runs."),
) -> None:
    """Make measured-like data from a truth model with one hidden effect (and, with --param-error,
    parameters off by a few percent), or from a truth plant file (--plant)."""
    from drill_env.discrepancy.synth import SynthConfig, make_dataset, make_plant_dataset, write_synthetic
    from drill_env.outputs import check_output_file, check_output_folder, output_lock
    from drill_env.params import ParameterError

    # both outputs are checked before the runs are simulated
    check_output_folder(out, "--out")
    check_output_file(answer, "--answer")
    if out.resolve() in answer.resolve().parents:
        _fail(
            f"--answer {answer}: lies inside the dataset folder --out {out}; keep the answer apart from the data"
        )

    if (effect is None) == (plant is None):
        _fail(
            "--effect/--plant: give exactly one of them (a hidden effect on the preset, or a truth plant file)"
        )
    truth_file = None
    if plant is not None:
        from drill_env.plant_file import read_plant_file

        try:
            truth_file = read_plant_file(plant)
        except (ValueError, ParameterError) as exc:
            _fail(f"--plant {plant}: {exc}")
        if param_error:
            _fail("--param-error: a truth plant file holds its own parameters; leave --param-error out")
        counts = int(truth_file.sensors.get("counts_per_rev", counts))
        angle_noise = float(truth_file.sensors.get("angle_noise_std", angle_noise))
    try:
        volts = tuple(float(v) for v in voltages.split(",") if v.strip())
    except ValueError:
        _fail(f"--voltages: expected comma-separated numbers, got {voltages!r}")
    try:
        cfg = SynthConfig(
            preset=preset,
            voltages=volts,
            random_runs=random_runs,
            duration_s=duration,
            sample_rate_hz=rate,
            encoder_counts_per_rev=counts,
            angle_noise_std=angle_noise,
            param_error=param_error,
        )
        with output_lock(out, "synth"):  # the dataset folder is this run's alone
            with _progress() as prog:
                task = prog.add_task("simulating runs", total=len(volts) + random_runs)
                if truth_file is not None:
                    res = make_plant_dataset(
                        truth_file.params,
                        seed=seed,
                        config=cfg,
                        delay_s=truth_file.actuator_delay,
                        source=str(plant),
                        progress=lambda i, n: prog.update(task, completed=i),
                    )
                else:
                    res = make_dataset(
                        effect,
                        seed=seed,
                        magnitude=magnitude,
                        config=cfg,
                        progress=lambda i, n: prog.update(task, completed=i),
                    )
            write_synthetic(res, out, answer, preset=preset)
    except (ValueError, ParameterError) as exc:
        _fail(str(exc))
    typer.echo(f"wrote {len(res.runs)} runs to {out}; the answer is in {answer}")


def discrepancy(
    data_dir: Path = typer.Argument(..., help="Dataset folder (CSV runs + dataset.json)."),
    out: Path = typer.Option(..., help="Output folder: report.md, result.json, figures, model.yaml."),
    heldout: str | None = typer.Option(
        None, help="Comma-separated run names to hold out (default: every third run by voltage)."
    ),
    seed: int = typer.Option(0, help="Seed of the bootstrap."),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures."),
) -> None:
    """Find where and why measured data disagree with the nominal model; name the missing effect."""
    from drill_env.discrepancy.dataset import DatasetError
    from drill_env.discrepancy.workflow import run_discrepancy
    from drill_env.outputs import check_output_folder

    check_output_folder(out, "--out")
    held = [h.strip() for h in heldout.split(",") if h.strip()] if heldout else None
    try:
        with _progress() as prog:
            tasks: dict[str, int] = {}

            def progress(stage: str, i: int, n: int) -> None:
                if stage not in tasks:
                    tasks[stage] = prog.add_task(stage, total=n)
                prog.update(tasks[stage], completed=i)

            res = run_discrepancy(
                data_dir, out, heldout=held, figures=not no_figures, seed=seed, progress=progress
            )
    except (DatasetError, ValueError) as exc:
        _fail(str(exc))
    for note in res.validity_warnings:
        typer.secho(f"warning: {note}", fg=typer.colors.YELLOW, err=True)
    typer.echo(res.verdict_line())


def discrepancy_study(
    out: Path = typer.Option(Path("results/discrepancy"), help="Output folder of the study."),
    seeds: int = typer.Option(3, help="Seeds per truth and condition (angle noise x parameter error)."),
    sweep_seeds: int = typer.Option(2, help="Seeds per point of the magnitude sweep."),
    first_seed: int = typer.Option(
        0,
        help="Index of the first seed (0: the committed study; any other start gives datasets it never saw).",
    ),
    workers: int = typer.Option(
        0, help="Processes that share the datasets (0: one per CPU core); the result does not depend on it."
    ),
    paper_case_only: bool = typer.Option(False, "--paper-case-only", help="Only the paper's case."),
    skip_paper_case: bool = typer.Option(False, "--skip-paper-case", help="Skip the paper's case."),
) -> None:
    """Hidden-effect study under real-rig conditions (confusion matrix, false discoveries and
    alarms, interval coverage, detection vs magnitude) and the paper's case."""
    import os

    from drill_env.discrepancy.study import MAX_SEEDS, paper_case, run_study
    from drill_env.outputs import OutputFolderError, output_lock

    # every argument is checked before anything is written: OUT may hold committed results
    for name, value in (("--seeds", seeds), ("--sweep-seeds", sweep_seeds)):
        if not 1 <= value <= MAX_SEEDS:
            _fail(f"{name} must be an integer from 1 to {MAX_SEEDS}, got {value!r}")
    if not 0 <= first_seed <= MAX_SEEDS - max(seeds, sweep_seeds):
        _fail(
            f"--first-seed must be an integer from 0 to {MAX_SEEDS - max(seeds, sweep_seeds)} with these "
            f"--seeds/--sweep-seeds (first seed + seeds <= {MAX_SEEDS}), got {first_seed!r}"
        )
    if not 0 <= workers <= 256:
        _fail(f"--workers must be an integer from 0 (one per CPU core) to 256, got {workers!r}")
    workers = workers or (os.cpu_count() or 1)
    if paper_case_only and skip_paper_case:
        _fail("--paper-case-only and --skip-paper-case together leave nothing to do; give at most one")
    if out.exists() and not out.is_dir():
        _fail(f"--out {out} exists and is not a folder")
    try:
        with output_lock(out, "discrepancy-study"):  # for the whole command, both parts
            if not paper_case_only:
                import time

                typer.echo(f"hidden-effect study: {workers} worker process(es); results in {out}")
                t0 = time.perf_counter()
                import contextlib
                import sys

                # a live bar on a terminal; in a log file a plain line every 5 % of the datasets
                # (a live display holds back everything printed while it runs)
                live = sys.stdout.isatty()
                with _progress() if live else contextlib.nullcontext() as prog:
                    task = prog.add_task("hidden-effect study (datasets)", total=None) if live else None

                    def progress(i: int, n: int) -> None:
                        if live:
                            prog.update(task, completed=i, total=n)
                        elif i == n or i % max(1, n // 20) == 0:
                            typer.echo(f"{i}/{n} datasets, {time.perf_counter() - t0:.0f} s")

                    summary = run_study(
                        out,
                        seeds=seeds,
                        sweep_seeds=sweep_seeds,
                        first_seed=first_seed,
                        workers=workers,
                        progress=progress,
                    )
                typer.echo(
                    f"accuracy {summary['accuracy']:.1%} over {summary['n_datasets']} datasets; "
                    f"false discoveries {summary['false_discoveries']}; false alarms "
                    f"{summary['false_alarms']} of {summary['datasets_without_effect']}; parameters inside "
                    f"their 95 % intervals {summary['coverage_per_parameter']:.1%}; see {out / 'confusion.md'}"
                )
            if not skip_paper_case:
                typer.echo(
                    "the paper's case: simulating the data, analysing, holding the models against the rig"
                )
                case = paper_case(out / "paper_case")
                typer.echo(
                    f"paper's case: {case['verdict']} (confidence {case['confidence']:.2f}); see "
                    f"{out / 'paper_case' / 'paper_case.md'}"
                )
    except OutputFolderError as exc:
        _fail(str(exc))


def register(app: typer.Typer) -> None:
    app.command(name="synth")(synth)
    app.command(name="discrepancy")(discrepancy)
    app.command(name="discrepancy-study")(discrepancy_study)
