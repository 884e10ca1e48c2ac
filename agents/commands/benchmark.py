"""``drill-env benchmark``: every controller over a grid of operating points and seeds."""

from __future__ import annotations

import math
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import typer

MAX_SEEDS = 1000  # seeds per operating point
MAX_RUNS = 1_000_000  # runs of one benchmark (controllers x voltages x plants x seeds)
MAX_WORKERS = 256

TIMESERIES_VOLTAGE = 1.0  # [V] the rig's operating region, where position friction hurts most


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def _floats(text: str | None, name: str) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        _fail(f"{name} must be a comma-separated list of numbers, got {text!r}")


# what `drill-env benchmark` writes (a folder of these from before folders had markers is its own)
BENCHMARK_FILES = (
    "benchmark.csv",
    "benchmark_config.json",
    "summary.md",
    "provenance.json",
    "ranking.json",
    "ranking.md",
    "*.png",
)


def resumed_count(out: Path) -> int:
    """Complete rows of the benchmark CSV in ``out`` (what an interrupted run keeps)."""
    try:
        data = (out / "benchmark.csv").read_bytes()
    except OSError:
        return 0
    return max(0, data.count(b"\n") - 1)


def _check_run_files(cfg: Any, agents_dir: Path | None, trust_policies: bool) -> Any:  # noqa: ANN401
    """Every file the runs will need (gains, policies), before the first run; the policies
    from outside the project's vouched for (``cfg`` with ``trust_policies`` then)."""
    from drill_env.agents.commands._trust import vouch_for_policies
    from drill_env.agents.learning.policy_info import policy_training_record
    from drill_env.agents.learning.rl import check_policy_zip
    from drill_env.agents.registry import LEARNED, load_gains, policy_path

    policies: list[Path] = []
    try:
        if any(c not in LEARNED for c in cfg.controllers):
            load_gains(cfg.gains_file)
        for c in cfg.controllers:
            if c in LEARNED:
                for p in cfg.presets:
                    path = policy_path(c, p, cfg.agents_dir)
                    check_policy_zip(path)
                    policy_training_record(path)  # what it was trained on, or refused
                    policies.append(path)
    except ValueError as exc:
        if "policy" not in str(exc):
            _fail(f"--gains: {exc}")
        _fail(f"--agents-dir: {exc}" if agents_dir is not None else str(exc))
    option = "--agents-dir" if agents_dir is not None else "agents folder"
    if vouch_for_policies(policies, flag=trust_policies, option=option):
        import dataclasses

        cfg = dataclasses.replace(cfg, trust_policies=True)
    return cfg


def register(app: typer.Typer) -> None:
    from drill_env.agents.registry import CONTROLLERS as KNOWN_CONTROLLERS

    @app.command("benchmark")
    def benchmark(
        out: Path = typer.Option(..., help="Directory for benchmark.csv, summary.md and the figures."),
        preset: str = typer.Option("all", help="Comma-separated presets: brake, no_brake, or all (both)."),
        quick: bool = typer.Option(False, "--quick", help="A handful of voltages per preset and one seed."),
        controllers: str | None = typer.Option(
            None,
            help=f"Comma-separated subset of: {', '.join(KNOWN_CONTROLLERS)} (default: all).",
        ),
        controller: list[str] | None = typer.Option(
            None,
            "--controller",
            help="A controller of your own, scored beside the shipped ones (--controllers): "
            "package.module:Name, path/to/file.py:Name or path/to/policy.zip, optionally LABEL=SPEC "
            "(the name of its rows); repeatable. Name is a class or factory whose result has "
            "predict(obs, state, episode_start, deterministic), see docs/howto/own_controller.md; a "
            "policy zip from outside results/agents/ needs --trust-policies.",
        ),
        voltages: str | None = typer.Option(
            None,
            help="Comma-separated nominal voltages [V] (replace the grid; default: the full or quick grid).",
        ),
        seeds: int | None = typer.Option(
            None,
            help=f"Number of seeds per operating point: seeds 0, 1, ... (default: 5; 1 with --quick); "
            f"1 to {MAX_SEEDS}, and at most {MAX_RUNS:,} runs in all.",
        ),
        duration: float = typer.Option(90.0, help="Closed-loop time per run [s], at most 1e4."),
        window: float = typer.Option(
            20.0, help="Steady-state window at the end of each run [s], at most --duration."
        ),
        warmup: float = typer.Option(
            60.0, help="Open-loop warm-up before the controller is switched on [s], 0 to 1e4."
        ),
        backend: str = typer.Option("process", help="process (local pool), sequential or ray."),
        workers: int | None = typer.Option(
            None, help=f"Parallel workers, 1 to {MAX_WORKERS} (default: the number of CPUs)."
        ),
        ray_address: str | None = typer.Option(
            None, help="Ray cluster address (default: a local Ray instance)."
        ),
        agents_dir: Path | None = typer.Option(
            None,
            help="Trained policies, laid out like results/agents (a policy zip inflates to at most 64 MiB). "
            "Default: $DRILL_ENV_AGENTS_DIR if "
            "set, else results/agents/ of the source tree in a checkout, else the committed "
            "policies installed with the package.",
        ),
        plant: list[str] | None = typer.Option(
            None,
            "--plant",
            help="Run every controller on this plant instead of the nominal model: a plant file (a "
            "rig YAML in the preset format, effects included, optionally with actuator_delay [s] "
            "and a sensors: mapping; docs/guides/plants.md); repeatable; `nominal` is the preset's "
            "own model and runs only when given. Controllers keep their design on the design model "
            "(--design-params, default the preset's); so do the target speed and the regime labels. "
            "Suppression is relative to the open-loop run on the plant. Default: nominal.",
        ),
        plants: str | None = typer.Option(
            None,
            "--plants",
            help="`family`: run on the standard family of plants as well (the nominal rig, each "
            "identified parameter perturbed, each library effect, 10 ms delay, 3 mrad angle noise; "
            "see agents/evaluation/plants.py); or a folder of plant files. summary.md and "
            "robustness_<preset>.png then show each controller's nominal, mean and worst case "
            "across them.",
        ),
        design_params: Path | None = typer.Option(
            None,
            "--design-params",
            help="Design every controller on this model (a rig YAML, effects included, e.g. a "
            "discrepancy model.yaml) instead of the preset's: the LQI's schedule, the feedforwards "
            "(an effect the model names is fed forward), the target speed and the regime labels. "
            "Gains still come from --gains (tune them on the model with `drill-env tune --params`). "
            "One preset only.",
        ),
        gains: Path | None = typer.Option(
            None, help="Tuned gains of the classical controllers (default: configs/agents/controllers.yaml)."
        ),
        fresh: bool = typer.Option(
            False, "--fresh", help="Discard results already in OUT instead of resuming."
        ),
        trust_policies: bool = typer.Option(
            False,
            "--trust-policies",
            help="Load policy files from outside results/agents/ (loading one can run code it holds) "
            "in a run without a terminal, which otherwise refuses them; also "
            "DRILL_ENV_TRUST_POLICIES=1. On a terminal they load with a warning.",
        ),
        timeseries: bool | None = typer.Option(
            None,
            "--timeseries/--no-timeseries",
            help="Also write timeseries_<preset>_<plant>_<group>.png: one run per controller at "
            f"{TIMESERIES_VOLTAGE:g} V (with --design-params: the grid's voltage nearest to it where the "
            "design model turns) on every plant of the benchmark, one figure per plant and "
            "controller group (classical, learned). Default: with --quick.",
        ),
    ) -> None:
        """Run every controller at every operating point and seed; resume an interrupted run.

        Writes OUT/benchmark.csv (one row per controller x operating point x seed),
        OUT/summary.md (a table per regime), OUT/bifurcation_<preset>.png and
        OUT/suppression_<preset>.png.
        """
        from drill_env.params import PRESETS as RIG_PRESETS

        PRESETS = ("all", *RIG_PRESETS)
        names = [x.strip() for x in preset.split(",") if x.strip()]
        for name in names:
            if name not in PRESETS:
                _fail(f"--preset: {name!r} is not one of {list(PRESETS)}")
        if not names:
            _fail(f"--preset: expected one or more of {list(PRESETS)}, got {preset!r}")
        if len(set(names)) != len(names):
            _fail(
                f"--preset: {next(n for n in names if names.count(n) > 1)!r} is given twice; name each preset once"
            )
        if ray_address and backend == "ray":  # an address nothing answers at: said within seconds,
            # before the heavy imports (a Ctrl-C in the wait ends a light process at once)
            from drill_env.ray_cluster import check_ray_address

            try:
                check_ray_address(ray_address)
            except ValueError as exc:
                _fail(f"--{str(exc).replace('_', '-', 1)}")
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        from drill_env.agents.evaluation.benchmark import (
            BACKENDS,
            FULL_SEEDS,
            QUICK_SEEDS,
            BenchmarkConfig,
            run_benchmark,
        )
        from drill_env.agents.evaluation.episodes import EpisodeSettings
        from drill_env.agents.registry import CONTROLLERS

        if backend not in BACKENDS:
            _fail(f"--backend must be one of {list(BACKENDS)}, got {backend!r}")
        if ray_address is not None and backend != "ray":
            _fail(f"--ray-address: only with --backend ray (the {backend} backend runs on this machine)")
        presets = RIG_PRESETS if "all" in names else tuple(dict.fromkeys(names))
        ctrls = CONTROLLERS
        if controllers is not None:
            ctrls = tuple(c.strip() for c in controllers.split(",") if c.strip())
            if len(set(ctrls)) != len(ctrls):
                twice = next(c for c in ctrls if ctrls.count(c) > 1)
                _fail(f"--controllers: {twice!r} is given twice; name each controller once")
        if seeds is not None and not 1 <= seeds <= MAX_SEEDS:
            _fail(f"--seeds: {seeds!r}; allowed: an integer from 1 to {MAX_SEEDS}")
        if workers is not None and not 1 <= workers <= MAX_WORKERS:
            _fail(
                f"--workers: {workers!r}; allowed: an integer from 1 to {MAX_WORKERS} (default: the number of CPUs)"
            )
        from drill_env.agents.evaluation.episodes import MAX_EPISODE_S

        for name, value, low in (
            ("--duration", duration, 0.0),
            ("--window", window, 0.0),
            ("--warmup", warmup, None),
        ):
            if (
                not math.isfinite(value)
                or value > MAX_EPISODE_S
                or (value < 0 if low is None else value <= 0)
            ):
                allowed = f"[0, {MAX_EPISODE_S:g}]" if low is None else f"(0, {MAX_EPISODE_S:g}]"
                _fail(f"--{name.lstrip('-')}: {value!r} s; allowed: {allowed} s")
        from drill_env.agents.evaluation.controller_spec import controller_label

        custom: list[tuple[str, str]] = []
        for item in controller or []:
            try:
                custom.append((controller_label(item), item))
            except ValueError as exc:
                _fail(str(exc))
        seed_list = tuple(range(seeds)) if seeds is not None else (QUICK_SEEDS if quick else FULL_SEEDS)
        vs = _floats(voltages, "--voltages")
        from drill_env.agents.evaluation.plants import FAMILY, NOMINAL, Plant, plants_in, standard_family
        from drill_env.params import ParameterError

        plant_list: list = []
        if plants is not None:
            if plants.strip() == FAMILY:
                plant_list = list(standard_family())
            elif Path(plants).is_dir():
                try:
                    plant_list = plants_in(plants)
                except (ParameterError, ValueError) as exc:
                    _fail(f"--plants {plants}: {exc}")
            else:
                _fail(
                    f"--plants: {plants!r} is not '{FAMILY}' or a folder of plant files (single rigs: --plant PATH)"
                )
        for item in plant or ([] if plant_list else [NOMINAL]):
            if item == NOMINAL and any(q.is_nominal for q in plant_list):
                continue
            if item == FAMILY:
                _fail(f"--plant {item}: use --plants {FAMILY} for the standard family")
            try:
                plant_list.append(Plant() if item == NOMINAL else Plant.from_path(item))
            except (ParameterError, ValueError) as exc:
                _fail(f"--plant {item}: {exc}")
        names = [q.name for q in plant_list]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            _fail(f"--plant: the plant name(s) {dup} appear twice (a plant is named by its file's stem)")
        if design_params is not None:
            if len(presets) != 1:
                _fail(
                    f"--design-params: a design model is one rig; give one --preset (brake or no_brake), got {preset!r}"
                )
            if not design_params.is_file():
                _fail(f"--design-params: {design_params} is not a file (a rig YAML in the preset format)")
            from drill_env.params import load_params

            try:
                load_params(design_params)
            except (ParameterError, ValueError) as exc:
                _fail(f"--design-params: {design_params}: {exc}")
        if gains is not None and not gains.is_file():
            _fail(f"--gains: {gains} is not a file (a YAML written by drill-env tune)")
        from drill_env.envs.config import EnvSettings

        control_dt = EnvSettings().control_dt
        for name, value in (("--duration", duration), ("--window", window)):
            if value < control_dt:
                _fail(f"{name} {value:g} s is shorter than one control period ({control_dt:g} s)")
        try:
            episode = EpisodeSettings(duration=duration, window=window, warmup_time=warmup)
            if vs is not None:
                cfg = BenchmarkConfig(
                    presets=presets,
                    controllers=ctrls,
                    voltages={p: vs for p in presets},
                    seeds=seed_list,
                    episode=episode,
                    agents_dir=None if agents_dir is None else str(agents_dir),
                    gains_file=None if gains is None else str(gains),
                    plants=tuple(plant_list),
                    design_params=None if design_params is None else str(design_params),
                    custom=tuple(custom),
                    trust_policies=trust_policies,
                )
            else:
                cfg = BenchmarkConfig.preset_grid(
                    presets,
                    quick=quick,
                    controllers=ctrls,
                    seeds=seed_list,
                    episode=episode,
                    agents_dir=None if agents_dir is None else str(agents_dir),
                    gains_file=None if gains is None else str(gains),
                    plants=tuple(plant_list),
                    design_params=None if design_params is None else str(design_params),
                    custom=tuple(custom),
                    trust_policies=trust_policies,
                )
        except ValueError as exc:
            _fail(str(exc))
        n_runs = (
            len(cfg.controllers)
            * len(cfg.plants)
            * len(cfg.seeds)
            * sum(len(v) for v in cfg.voltages.values())
        )
        if n_runs > MAX_RUNS:
            _fail(
                f"the grid has {n_runs:,} runs; allowed: at most {MAX_RUNS:,} (fewer seeds, voltages or controllers)"
            )
        # a resume with every run of the grid in OUT runs nothing: it writes the report and the
        # figures again from the rows, and needs (and loads) no policy, gains or agents folder
        # (the time-series figures run the controllers: with them, the files are checked)
        complete = False
        if not fresh and not (timeseries if timeseries is not None else quick):
            from drill_env.agents.evaluation.benchmark import check_resumable, runs_missing

            try:
                complete = check_resumable(cfg, out) is not None and runs_missing(cfg, out) == 0
            except (ValueError, OSError):
                complete = False  # named below, before anything runs
        if complete:
            Console(stderr=True).print(
                f"every run of the grid is in {out}: the report and the figures are made again "
                "from its rows (no controller is run, no policy loaded)",
                highlight=False,
            )
        elif agents_dir is not None and not agents_dir.is_dir():
            _fail(
                f"--agents-dir: {agents_dir} is not a folder (trained policies, laid out like results/agents)"
            )
        else:
            cfg = _check_run_files(cfg, agents_dir, trust_policies)
        from drill_env.outputs import OutputFolderError, check_command_folder, command_folder

        check_command_folder(out, "benchmark", "--out", own=BENCHMARK_FILES)
        if not fresh:
            from drill_env.agents.evaluation.benchmark import check_resumable

            try:
                check_resumable(cfg, out)  # a damaged folder is named before anything runs
            except ValueError as exc:
                _fail(str(exc))

        held = ExitStack()
        try:
            # OUT is this run's alone, resume included
            held.enter_context(command_folder(out, "benchmark", "--out", own=BENCHMARK_FILES))
        except OutputFolderError as exc:
            _fail(str(exc))
        with held:
            n = len(cfg.jobs())
            console = Console(stderr=True)
            if cfg.design_params is not None:
                from drill_env.agents.evaluation.benchmark.grid import describe_regimes, design_regimes

                try:
                    console.print(
                        f"design model {cfg.design_params}: {describe_regimes(design_regimes(cfg.design_model()))}"
                        + ("" if vs is not None else "; the grid's voltages are chosen in them"),
                        highlight=False,
                        soft_wrap=True,
                    )
                except (ValueError, RuntimeError) as exc:
                    console.print(
                        f"design model {cfg.design_params}: regimes not found: {exc}", highlight=False
                    )
            console.print(
                f"benchmark: {len(cfg.controllers)} controllers x "
                + " + ".join(f"{len(cfg.voltages[p])} voltages ({p})" for p in cfg.presets)
                + (
                    f" x {len(cfg.plants)} plants ({', '.join(q.name for q in cfg.plants)})"
                    if len(cfg.plants) > 1
                    else ""
                )
                + f" x {len(cfg.seeds)} seed(s) = {n} runs, backend {backend}; results in {out}"
            )
            columns = (
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
            )
            t0 = time.perf_counter()
            with Progress(*columns, console=console) as prog:
                task = prog.add_task("runs", total=n)

                resumed: list[int] = []

                def on_progress(done: int, total: int, row: dict) -> None:
                    desc = "runs"
                    if not resumed:
                        resumed.append(done)  # the first call: runs found in OUT already
                    if row:
                        desc = f"{row['controller']:>15s} {row['preset']:>8s} {float(row['voltage']):4.2f} V"
                        if row.get("plant", "nominal") != "nominal":
                            desc += f" on {row['plant']}"
                    prog.update(task, completed=done, description=desc)
                    if not console.is_terminal and row and (done == total or done % max(1, total // 20) == 0):
                        # no live bar in a log file: a line every 5 % of the runs
                        console.print(
                            f"{done}/{total} runs, {time.perf_counter() - t0:.0f} s", highlight=False
                        )

                try:
                    csv_path = run_benchmark(
                        cfg,
                        out,
                        backend=backend,
                        workers=workers,
                        ray_address=ray_address,
                        fresh=fresh,
                        progress=on_progress,
                    )
                except ValueError as exc:
                    _fail(str(exc))
                except KeyboardInterrupt:
                    from drill_env.cli import interrupted

                    prog.stop()
                    finished = resumed_count(out)
                    interrupted(
                        f"{finished} finished run(s) are kept in {out / 'benchmark.csv'}; the same command "
                        "resumes with the runs still missing (summary.md and the figures are made at the end)"
                    )
        reused = resumed[0] if resumed else 0
        typer.echo(
            f"{n} runs in {time.perf_counter() - t0:.0f} s"
            + (f" ({reused} resumed from an earlier run in {out}, {n - reused} run now)" if reused else "")
        )
        summary = (out / "summary.md").read_text()
        typer.echo(summary)
        typer.echo(f"wrote {csv_path}, {out / 'summary.md'} and the figures in {out}")
        if timeseries if timeseries is not None else quick:
            from drill_env.agents.evaluation.timeseries import timeseries_figures

            design = cfg.design_model()
            for p in cfg.presets:
                ts_voltage = TIMESERIES_VOLTAGE
                if design is not None and not ts_voltage > design.uc1:
                    # the design model does not turn there: the grid's voltage nearest to it
                    ts_voltage = min(cfg.voltages[p], key=lambda v: abs(v - TIMESERIES_VOLTAGE))
                    if not ts_voltage > design.uc1:
                        typer.echo(
                            f"no time-series figures of {p}: the design model turns at no grid voltage"
                        )
                        continue
                try:
                    made = timeseries_figures(
                        cfg.controllers,
                        p,
                        ts_voltage,
                        cfg.plants,
                        out,
                        episode=cfg.episode,
                        agents_dir=cfg.agents_dir,
                        gains_file=cfg.gains_file,
                        design_params=design,
                        trusted=cfg.trust_policies,
                        progress=lambda path: typer.echo(f"wrote {path}", err=True),
                    )
                except ValueError as exc:
                    _fail(f"--timeseries: {exc}")
                typer.echo(f"wrote {len(made)} time-series figures of {p} in {out}")
        import pandas as pd

        from drill_env.agents.evaluation.benchmark.runs import NOT_MADE

        rows = pd.read_csv(csv_path, keep_default_na=False)
        errors = rows["error"].astype(str)
        not_made = rows[errors.str.startswith(NOT_MADE)]
        for (p, v), group in not_made.groupby(["preset", "voltage"], sort=True):
            typer.secho(
                f"not made: {len(group)} run(s) at {float(v):g} V ({p}): "
                f"{group.iloc[0]['error'][len(NOT_MADE) :]}",
                fg=typer.colors.YELLOW,
                err=True,
            )
        failed = rows[(errors != "") & ~errors.str.startswith(NOT_MADE)]
        if len(failed):
            first = failed.iloc[0]
            typer.secho(
                f"error: {len(failed)} of {len(rows)} runs failed (their metrics are NaN in {csv_path}); "
                f"first: {first['controller']} {first['preset']} {first['voltage']} V seed {first['seed']}: "
                f"{first['error']}",
                fg=typer.colors.RED,
                err=True,
            )
            raise typer.Exit(code=1)
