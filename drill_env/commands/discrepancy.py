"""``drill-env synth`` and ``drill-env discrepancy``: hidden-effect data and the discrepancy workflow."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import typer


def _fail(message: str) -> NoReturn:
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


@contextmanager
def _stage_progress() -> Iterator[Callable[[str, int, int], None]]:
    """A progress callback ``(stage, i, n)`` drawing one bar per named stage."""
    with _progress() as prog:
        tasks: dict[str, Any] = {}

        def progress(stage: str, i: int, n: int) -> None:
            if stage not in tasks:
                tasks[stage] = prog.add_task(stage, total=n)
            prog.update(tasks[stage], completed=i)

        yield progress


DATASET_FILES = ("dataset.json", "*.csv")  # what synth writes into --out


MAX_SEED = 2**63 - 1  # a seed is written to the answer file and read back as an int64


def synth(
    ctx: typer.Context,
    preset: str = typer.Option("brake", help="Rig preset of the truth model (brake, no_brake)."),
    effect: str | None = typer.Option(
        None,
        help="Hidden effect: none, a library effect (encoder_eccentricity_lower/_upper are reading "
        "errors of an encoder), or external_torque (outside the library); or give --plant.",
    ),
    plant: Path | None = typer.Option(
        None,
        "--plant",
        help="Record this truth plant instead of the preset with a drawn effect: a plant file (rig "
        "YAML with effects, optionally actuator_delay [s], sensors: (whose counts_per_rev and "
        "angle_noise_std replace --counts and --angle-noise) and measurement: (encoder eccentricity, "
        "applied to the recorded angles) and amplifier: (gain, offset_v [V]: the amplifier applies "
        "gain u + offset_v for the recorded u), e.g. a model.yaml of drill-env discrepancy). Its "
        "preset (friction family) is --preset.",
    ),
    magnitude: float | None = typer.Option(
        None,
        help="Magnitude of the effect (its meaning per effect is in the README); default: "
        "drawn log-uniformly from the documented detectable range.",
    ),
    seed: int = typer.Option(0, min=0, help="Seed of everything random (effect phases, runs, noise)."),
    out: Path = typer.Option(..., help="Dataset folder to write (runs + dataset.json)."),
    answer: Path = typer.Option(..., help="File that receives the effect and its parameters (JSON)."),
    angle_noise: float = typer.Option(
        0.0,
        "--angle-noise",
        "--noise",
        help="Gaussian angle noise before quantisation [rad], 0 to 1; 0 is a real encoder (the angle is the "
        "quantised true angle and nothing else). --noise is the older name.",
    ),
    param_error: float = typer.Option(
        0.0,
        "--param-error",
        help="Relative error of every identified parameter of the truth model, drawn uniformly from "
        "[-REL, REL] per dataset from the seed (0-0.3); the drawn values go to --answer only.",
    ),
    counts: int = typer.Option(2000, help="Encoder counts per revolution (1 to 2^26)."),
    rate: float = typer.Option(500.0, help="Sample rate [Hz] (100-10000, the loader's range)."),
    duration: float = typer.Option(
        150.0,
        help="Recorded length of each run [s]: 10 (the loader's shortest) to 3600, and at most a "
        "1 GiB file per run (1342 s at 10 kHz).",
    ),
    voltages: str = typer.Option(
        "0.2,0.5,0.7,1.0,2.0,3.0,4.5", help="Constant-voltage runs [V], comma-separated ('' for none)."
    ),
    random_runs: int = typer.Option(3, help="Quasi-random voltage runs (runs in all: at most 100)."),
    time_jitter: float = typer.Option(
        0.0,
        "--time-jitter",
        help="Time-stamp jitter of the DAQ clock, uniform +-this share of the period (0-0.1): the angles "
        "are read at the jittered instants, which the time stamps record.",
    ),
    fresh: bool = typer.Option(
        False,
        "--fresh",
        help="Replace the dataset already in --out whole (only a folder holding a dataset: dataset.json "
        "and run CSVs); without it --out must be new or empty.",
    ),
    plan: str | None = typer.Option(
        None,
        "--plan",
        help="Record on an identification plan of `drill-env identify --plan` (full, minimum): its "
        "voltages, random-level runs in [-5, 5] V and durations, instead of --voltages/--random-runs/--duration.",
    ),
    params: Path | None = typer.Option(
        None,
        "--params",
        help="Truth rig from a YAML file (the preset format, e.g. an identified rig.yaml) instead of the "
        "preset's parameters; --preset then only names the structure written to dataset.json.",
    ),
) -> None:
    """Make measured-like data from a truth model with one hidden effect (and, with --param-error,
    parameters off by a few percent), or from a truth plant file (--plant)."""
    from drill_env.outputs import (
        check_new_folder,
        check_output_file,
        check_output_folder,
        clear_folder,
        output_lock,
    )
    from drill_env.params import ParameterError
    from drill_env.recordings.synth import (
        HIDDEN_EFFECTS,
        SynthConfig,
        make_dataset,
        make_plant_dataset,
        write_synthetic,
    )

    # the arguments first, then both outputs, all before the runs are simulated
    if seed > MAX_SEED:
        _fail(f"--seed: {seed}; allowed: an integer from 0 to 2**63 - 1 ({MAX_SEED})")
    if plan is not None:
        given = [
            f"--{name.replace('_', '-')}"
            for name in ("voltages", "random_runs", "duration")
            if getattr(ctx.get_parameter_source(name), "name", "DEFAULT") != "DEFAULT"
        ]
        if given:
            _fail(
                f"{', '.join(given)}: cannot be given with --plan (the plan sets the voltages, runs and durations)"
            )
    if (effect is None) == (plant is None):
        _fail(
            "--effect/--plant: give exactly one of them (a hidden effect on the preset, or a truth plant file)"
        )
    if effect is not None and effect not in HIDDEN_EFFECTS:
        _fail(f"effect: unknown effect {effect!r}; allowed: {sorted(HIDDEN_EFFECTS)}")
    truth_file = None
    if plant is not None:
        from drill_env.plant_file import read_plant_file

        if params is not None or plan is not None:
            _fail("--plant: a truth plant file holds its own parameters; leave --params and --plan out")
        try:
            truth_file = read_plant_file(plant)
        except (ValueError, ParameterError) as exc:
            _fail(f"--plant {plant}: {exc}")
        if param_error:
            _fail("--param-error: a truth plant file holds its own parameters; leave --param-error out")
        if "counts_per_rev" in truth_file.sensors:
            counts = truth_file.sensors["counts_per_rev"]
            if counts is None:  # ideal angles: the rig model allows them, a recording does not
                _fail(
                    f"--plant {plant}: sensors.counts_per_rev: null (ideal angles) cannot be recorded: "
                    "a recording holds encoder counts; allowed: an integer from 1 to 2^26"
                )
        angle_noise = float(truth_file.sensors.get("angle_noise_std", angle_noise))
    pieces = [v.strip() for v in voltages.split(",")] if voltages.strip() else []
    if "" in pieces:
        _fail(f"--voltages: an empty entry in {voltages!r}; expected comma-separated numbers ('' for none)")
    try:
        volts = tuple(float(v) for v in pieces)
    except ValueError:
        _fail(f"--voltages: expected comma-separated numbers, got {voltages!r}")
    truth = preset
    if params is not None:
        from drill_env.params import available_presets, load_params

        if params.suffix.lower() not in (".yaml", ".yml"):
            _fail(f"--params {params}: expected a rig YAML file (.yaml or .yml)")
        load_params(params)  # a bad file ends here, naming its field
        if preset not in available_presets():
            _fail(f"--preset: with --params the structure, one of {available_presets()}; got {preset!r}")
        truth = str(params)
    try:
        # SynthConfig's fields by name (all but the preset)
        design: dict[str, Any] = dict(voltages=volts, random_runs=random_runs, duration_s=duration)
        if plan is not None:
            from drill_env.identify.plan import PLANS, synth_config

            if plan not in PLANS:
                _fail(f"--plan: {plan!r}; allowed: {', '.join(PLANS)}")
            design = {k: v for k, v in vars(synth_config(plan, truth)).items() if k != "preset"}
        design.update(
            sample_rate_hz=rate,
            encoder_counts_per_rev=counts,
            angle_noise_std=angle_noise,
            param_error=param_error,
            time_jitter=time_jitter,
        )
        cfg = SynthConfig(preset=truth, **design)
    except (ValueError, ParameterError) as exc:
        _fail(str(exc))
    # a dataset is never mixed with the runs of another one
    stale = check_new_folder(out, "--out", fresh=fresh, replaceable=DATASET_FILES, what="dataset")
    check_output_folder(out, "--out")
    check_output_file(answer, "--answer")
    if out.resolve() in answer.resolve().parents:
        _fail(
            f"--answer {answer}: lies inside the dataset folder --out {out}; keep the answer apart from the data"
        )
    try:
        with output_lock(out, "synth"):  # the dataset folder is this run's alone
            with _progress() as prog:
                task = prog.add_task("simulating runs", total=len(cfg.voltages) + cfg.random_runs)
                if truth_file is not None:
                    res = make_plant_dataset(
                        truth_file.params,
                        seed=seed,
                        config=cfg,
                        delay_s=truth_file.actuator_delay,
                        source=str(plant),
                        measurement=truth_file.measurement,
                        amplifier_gain=truth_file.amplifier_gain,
                        amplifier_offset_v=truth_file.amplifier_offset_v,
                        progress=lambda i, n: prog.update(task, completed=i),
                    )
                else:
                    assert effect is not None  # exactly one of --effect and --plant, checked above
                    res = make_dataset(
                        effect,
                        seed=seed,
                        magnitude=magnitude,
                        config=cfg,
                        progress=lambda i, n: prog.update(task, completed=i),
                    )
            clear_folder(stale)  # --fresh: the former dataset goes whole, once the new one is made
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
    seed: int = typer.Option(0, min=0, help="Seed of the bootstrap."),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures."),
    params: Path | None = typer.Option(
        None,
        "--params",
        help="The nominal model as a rig YAML (e.g. the rig.yaml of `drill-env identify`, its effects "
        "section included: those effects are part of the model, and the tests look for what is still "
        "missing); default: the preset named in dataset.json.",
    ),
    voltage_lag: int = typer.Option(
        0,
        "--voltage-lag",
        help="Samples by which the voltage column lags the angles (negative: leads), -3 to 3: the "
        "motor is taken to have seen u[i + K] at sample i (each run loses |K| samples at one end). "
        "Use the lag the report's *Timing of the voltage column* names; 0 analyses the file as recorded.",
    ),
) -> None:
    """Find where and why measured data disagree with the nominal model; name the missing effect."""
    from drill_env.discrepancy.timing import MAX_VOLTAGE_LAG

    if not -MAX_VOLTAGE_LAG <= voltage_lag <= MAX_VOLTAGE_LAG:
        _fail(
            f"--voltage-lag: {voltage_lag} samples is beyond the re-timing range; allowed: whole samples "
            f"from -{MAX_VOLTAGE_LAG} to {MAX_VOLTAGE_LAG} (a larger offset is not one clock's sampling: "
            "align the files by their time stamps)"
        )
    from drill_env.discrepancy.workflow import run_discrepancy
    from drill_env.outputs import check_command_folder, command_folder
    from drill_env.recordings.dataset import DatasetError

    nominal = None
    if params is not None:
        from drill_env.params import load_params

        if params.suffix.lower() not in (".yaml", ".yml"):
            _fail(f"--params {params}: expected a rig YAML file (.yaml or .yml)")
        nominal = load_params(params)
        from drill_env.recordings.effects import EFFECT_FIELDS, model_effect_names

        outside = model_effect_names(nominal)[1]
        if outside:
            _fail(
                f"--params {params}: switches on {', '.join(outside)}, an effect outside the library; "
                "allowed in the nominal model: the library's effects ("
                + ", ".join(EFFECT_FIELDS)
                + "), which are part of the model compared against"
            )
    check_command_folder(out, "discrepancy", "--out", own=DISCREPANCY_FILES)
    if data_dir.exists() and (
        out.resolve() == data_dir.resolve() or data_dir.resolve() in out.resolve().parents
    ):
        _fail(f"--out {out}: lies in the dataset folder {data_dir}; keep the analysis apart from the data")
    held = [h.strip() for h in heldout.split(",") if h.strip()] if heldout else None
    if held is not None and len(set(held)) != len(held):
        twice = next(h for h in held if held.count(h) > 1)
        _fail(f"--heldout: run {twice!r} is named twice; name each held-out run once")
    try:
        with (
            command_folder(out, "discrepancy", "--out", own=DISCREPANCY_FILES),
            _stage_progress() as progress,
        ):
            res = run_discrepancy(
                data_dir,
                out,
                heldout=held,
                figures=not no_figures,
                seed=seed,
                progress=progress,
                params=nominal,
                voltage_lag=voltage_lag,
            )
    except (DatasetError, ValueError) as exc:
        _fail(str(exc))
    for note in res.validity_warnings:
        typer.secho(f"warning: {note}", fg=typer.colors.YELLOW, err=True)
    typer.echo(res.verdict_line())


def discrepancy_study(
    out: Path | None = typer.Option(
        None,
        help="Output folder of the study. Default: a fresh run folder runs/discrepancy-study/study_TIME; "
        "the committed results/discrepancy is regenerated only when named here.",
    ),
    seeds: int = typer.Option(
        3, help="Seeds per truth and condition (angle noise x parameter error), 1 to 100."
    ),
    sweep_seeds: int = typer.Option(2, help="Seeds per point of the magnitude sweep, 1 to 100."),
    first_seed: int = typer.Option(
        0,
        help="Index of the first seed (0: the committed study; any other start gives datasets it never saw).",
    ),
    workers: int = typer.Option(
        0, help="Processes that share the datasets (0: one per CPU core); the result does not depend on it."
    ),
    backend: str = typer.Option(
        "process", help="process (a local pool of --workers processes) or ray (Ray tasks); same rows."
    ),
    ray_address: str | None = typer.Option(
        None, help="With --backend ray: the Ray cluster's address (default: a local Ray instance)."
    ),
    paper_case_only: bool = typer.Option(False, "--paper-case-only", help="Only the paper's case."),
    skip_paper_case: bool = typer.Option(False, "--skip-paper-case", help="Skip the paper's case."),
    figures_only: bool = typer.Option(
        False,
        "--figures-only",
        help="Draw confusion.png and detection.png of the study in OUT again from its study.json; run nothing.",
    ),
    fresh: bool = typer.Option(
        False,
        "--fresh",
        help="Discard the datasets an interrupted study left in OUT instead of resuming from them "
        "(resumed only when made with the same options by the same drill-env).",
    ),
) -> None:
    """Hidden-effect study under real-rig conditions (confusion matrix, false discoveries and
    alarms, interval coverage, detection vs magnitude) and the paper's case."""
    import os

    if backend not in ("process", "ray"):
        _fail(f"--backend: {backend!r} is not a backend; allowed: process, ray")
    if ray_address is not None and backend != "ray":
        _fail("--ray-address: only with --backend ray")
    if ray_address:  # an address nothing answers at: said within seconds, not after minutes,
        # before the heavy imports (a Ctrl-C in the wait ends a light process at once)
        from drill_env.ray_cluster import check_ray_address

        try:
            check_ray_address(ray_address)
        except ValueError as exc:
            _fail(f"--{str(exc).replace('_', '-', 1)}")
    from drill_env.discrepancy.study import MAX_SEEDS, paper_case, run_study
    from drill_env.outputs import OutputFolderError, check_command_folder, command_folder

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
    if figures_only:
        if out is None or paper_case_only:
            _fail("--figures-only: needs --out, the folder of a finished study (and no --paper-case-only)")
        from drill_env.discrepancy.study import redraw_figures

        check_command_folder(out, "discrepancy-study", "--out", own=STUDY_FILES)
        try:
            with command_folder(out, "discrepancy-study", "--out", own=STUDY_FILES):
                paths = redraw_figures(out)
        except (OutputFolderError, ValueError) as exc:
            _fail(f"--figures-only: {exc}")
        typer.echo("wrote " + ", ".join(str(p) for p in paths))
        return
    if out is not None and out.exists() and not out.is_dir():
        _fail(f"--out {out} exists and is not a folder")
    if out is not None:
        check_command_folder(out, "discrepancy-study", "--out", own=STUDY_FILES)
    if out is None:  # never the committed results unless named
        from drill_env.outputs import fresh_run_folder

        try:
            out = fresh_run_folder(Path("runs") / "discrepancy-study", "study")
        except OutputFolderError as exc:
            _fail(str(exc))
    try:
        # for the whole command, both parts
        with command_folder(out, "discrepancy-study", "--out", own=STUDY_FILES):
            if not paper_case_only:
                import time

                where = (
                    f"Ray tasks ({ray_address or f'a local Ray instance, {workers} CPU(s)'})"
                    if backend == "ray"
                    else f"{workers} worker process(es)"
                )
                typer.echo(f"hidden-effect study: {where}; results in {out}")
                t0 = time.perf_counter()
                import contextlib
                import sys

                # a live bar on a terminal; in a log file a plain line every 5 % of the datasets
                # (a live display holds back everything printed while it runs)
                live = sys.stdout.isatty()
                with _progress() if live else contextlib.nullcontext() as prog:
                    task = (
                        prog.add_task("hidden-effect study (datasets)", total=None)
                        if prog is not None
                        else None
                    )

                    def progress(i: int, n: int) -> None:
                        if prog is not None:  # live
                            prog.update(task, completed=i, total=n)
                        elif i == n or i % max(1, n // 20) == 0:
                            typer.echo(f"{i}/{n} datasets, {time.perf_counter() - t0:.0f} s")

                    try:
                        summary = run_study(
                            out,
                            seeds=seeds,
                            sweep_seeds=sweep_seeds,
                            first_seed=first_seed,
                            workers=workers,
                            progress=progress,
                            backend=backend,
                            ray_address=ray_address,
                            resume=not fresh,
                        )
                    except KeyboardInterrupt:
                        from drill_env.cli import interrupted
                        from drill_env.discrepancy.study import PARTIAL_ROWS

                        interrupted(
                            f"the datasets finished so far are in {out / PARTIAL_ROWS}; the same command "
                            "goes on from them (--fresh discards them)"
                        )
                if summary.get("resumed_datasets"):
                    typer.echo(
                        f"resumed: {summary['resumed_datasets']} datasets kept from the interrupted run"
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


# what `drill-env discrepancy` and `discrepancy-study` write (a folder of these from before
# folders had markers is the command's own)
DISCREPANCY_FILES = (
    "report.md",
    "result.json",
    "model.yaml",
    "model_rejected.yaml",
    "candidates.png",
    "equation_error.png",
    "spectra.png",
    "residual_spectra.png",
    "trajectories.png",
    "bifurcation.png",
)
STUDY_FILES = (
    "study.json",
    "confusion.md",
    "confusion.png",
    "detection.png",
    "study_rows.partial.jsonl",
)


def register(app: typer.Typer) -> None:
    app.command(name="synth")(synth)
    app.command(name="discrepancy")(discrepancy)
    app.command(name="discrepancy-study")(discrepancy_study)
