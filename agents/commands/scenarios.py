"""``drill-env scenarios``: every controller through the scenario suite (start-up, set-point
steps, changing bit friction, sensing, effort), scored per run, per scenario and overall."""

from __future__ import annotations

import time
from pathlib import Path

import typer

MAX_SEEDS = 1000
MAX_WORKERS = 256


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def _code_version() -> str:
    """The package version and, in a git checkout, the commit (``+dirty`` with changes)."""
    import subprocess

    from drill_env import __version__
    from drill_env.agents._locations import ROOT

    try:
        rev = subprocess.run(
            ["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return __version__
    return f"{__version__} ({rev})" if rev else __version__


# what `drill-env scenarios` writes (a folder of these from before folders had markers is its own)
SCENARIO_FILES = ("runs.csv", "scenarios.csv", "summary.md", "ranking.json", "ranking.md", "*.png")


def register(app: typer.Typer) -> None:
    from drill_env.agents.registry import CONTROLLERS as KNOWN_CONTROLLERS
    from drill_env.envs.scenarios import SCENARIO_NAMES

    @app.command("scenarios")
    def scenarios(
        out: Path = typer.Option(
            ..., help="Directory for runs.csv, scenarios.csv, summary.md and the figures."
        ),
        scenarios: str = typer.Option(
            "all", "--scenarios", help=f"all, or a comma-separated subset of: {', '.join(SCENARIO_NAMES)}."
        ),
        controllers: str | None = typer.Option(
            None, help=f"Comma-separated subset of: {', '.join(KNOWN_CONTROLLERS)} (default: all)."
        ),
        preset: str = typer.Option("all", help="Comma-separated presets: brake, no_brake, or all (both)."),
        seeds: int = typer.Option(3, help=f"Seeds per scenario and preset: 0, 1, ...; 1 to {MAX_SEEDS}."),
        workers: int | None = typer.Option(
            None, help=f"Parallel processes, 1 to {MAX_WORKERS} (default: the number of CPUs)."
        ),
        nominal_ranking: Path | None = typer.Option(
            None,
            help="A nominal benchmark's ranking.json (or its folder, e.g. results/benchmark): the summary "
            "counts how many pairs of its leaders (mean suppression 0.99 or more) the suite resolves.",
        ),
    ) -> None:
        """Run every controller through the scenario suite on the same seeds (paired runs).

        Writes OUT/runs.csv (one row per controller x scenario x preset x seed, the open loop's
        reference runs included), OUT/scenarios.csv (mean score per controller and scenario and
        the suite score), the paired statistics of the suite score and of every scenario's
        (OUT/ranking.json, OUT/ranking.md, OUT/ranking_suite.png), OUT/summary.md, OUT/scores.png
        and OUT/set_point_steps_<preset>.png. Scores: docs/explanation/scenarios.md.
        """
        import os
        import shlex
        import sys

        from drill_env.envs.scenarios import resolve_scenarios
        from drill_env.outputs import check_command_folder, command_folder
        from drill_env.params import PRESETS

        try:
            names = resolve_scenarios(scenarios)
        except ValueError as exc:
            _fail(f"--{exc}")
        ctrls = KNOWN_CONTROLLERS
        if controllers is not None:
            ctrls = tuple(dict.fromkeys(c.strip() for c in controllers.split(",") if c.strip()))
            bad = [c for c in ctrls if c not in KNOWN_CONTROLLERS]
            if bad or not ctrls:
                _fail(f"--controllers: {bad or controllers!r} not among {list(KNOWN_CONTROLLERS)}")
        chosen = [p.strip() for p in preset.split(",") if p.strip()]
        if not chosen or any(p not in ("all", *PRESETS) for p in chosen):
            _fail(f"--preset: {preset!r}; allowed: a comma-separated subset of {['all', *PRESETS]}")
        presets = PRESETS if "all" in chosen else tuple(dict.fromkeys(chosen))
        if not 1 <= seeds <= MAX_SEEDS:
            _fail(f"--seeds: {seeds!r}; allowed: an integer from 1 to {MAX_SEEDS}")
        if workers is not None and not 1 <= workers <= MAX_WORKERS:
            _fail(f"--workers: {workers!r}; allowed: an integer from 1 to {MAX_WORKERS}")
        try:  # a folder of another command's outputs or a dataset is refused before any run
            folder = check_command_folder(out, "scenarios", "--out", own=SCENARIO_FILES)
        except ValueError as exc:
            _fail(str(exc))
        nominal = None
        if nominal_ranking is not None:
            from drill_env.agents.evaluation.scenario_report import read_nominal_ranking

            try:
                nominal = read_nominal_ranking(nominal_ranking)
            except ValueError as exc:
                _fail(str(exc))

        from drill_env.agents.evaluation.scenario_report import write_report
        from drill_env.agents.evaluation.scenarios import SuiteConfig, run_suite

        cfg = SuiteConfig(controllers=ctrls, scenarios=names, presets=presets, seeds=seeds)
        n_workers = workers or os.cpu_count() or 1
        total = len(cfg.jobs())
        typer.echo(
            f"{total} runs: {len(cfg.jobs()) // max(1, len(names) * len(presets) * seeds)} controllers (the open-loop reference among them) x {len(names)} "
            f"scenarios x {len(presets)} presets x {seeds} seeds on {n_workers} worker(s)"
        )
        t0 = time.perf_counter()

        def progress(done: int, total: int, row: dict) -> None:
            if done % 25 == 0 or done == total:
                typer.echo(f"  {done}/{total} runs, {time.perf_counter() - t0:.0f} s")

        with command_folder(folder, "scenarios", "--out", own=SCENARIO_FILES):  # OUT is this run's alone
            runs = run_suite(cfg, workers=n_workers, progress=progress)
            wall = time.perf_counter() - t0
            meta = {
                "command": "drill-env " + shlex.join(sys.argv[1:]) if sys.argv[1:] else "drill-env scenarios",
                "wall_time_s": wall,
                "workers": n_workers,
                "version": _code_version(),
            }
            paths = write_report(runs, folder, meta, presets=presets, nominal=nominal)
        import json

        from drill_env.agents.evaluation.benchmark.ranking import RANKING_FILE
        from drill_env.agents.evaluation.scenarios import scenario_table

        table = scenario_table(runs)
        record = (
            json.loads((folder / RANKING_FILE).read_text(encoding="utf-8"))
            if (folder / RANKING_FILE).is_file()
            else {}
        )
        suite = next((r for r in record.get("rankings", []) if r["key"] == "suite"), None)
        typer.echo(f"suite score ({wall:.0f} s){' [95 % paired interval] ranks' if suite else ''}:")
        rows = {r["controller"]: r for r in suite["scores"]} if suite else {}
        for name, score in table["suite_score"].items():
            r = rows.get(name)
            ci = f"  [{r['low']:.3f}, {r['high']:.3f}]  {r['best_rank']}-{r['worst_rank']}" if r else ""
            typer.echo(f"  {name:<16} {score:7.3f}{ci}")
        for h in record.get("headroom", []):
            typer.echo(
                f"  headroom {h['scenario']:<16} best {h['best_controller']:<16} {h['best_score']:.3f}"
            )
        lead = record.get("nominal_leaders")
        if lead:
            typer.echo(
                f"  the nominal benchmark's {len(lead['controllers'])} leaders (>= {lead['threshold']:g}): "
                f"{lead['resolved']} of {lead['n_pairs']} pairs resolved ({lead['resolved_holm']} with Holm)"
            )
        for p in paths:
            typer.echo(f"wrote {p}")
