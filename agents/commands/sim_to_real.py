"""``drill-env sim-to-real``: from measured data to a better controller, the worked example."""

from __future__ import annotations

from pathlib import Path

import typer


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def sim_to_real(
    out: Path = typer.Option(..., help="Output folder (e.g. results/sim_to_real)."),
    voltages: str | None = typer.Option(
        None,
        help="Nominal voltages of the before/after comparison [V], comma-separated "
        "(default: 0.7,0.85,1.0,1.25,1.5; 1.0 with --quick).",
    ),
    seeds: int = typer.Option(2, help="Seeds per voltage: 0, 1, ... (1-20)."),
    magnitude: float = typer.Option(
        0.12, help="a1 of the truth plant's lower position friction (0.01-0.2, the detectable range)."
    ),
    data: Path | None = typer.Option(
        None, help="Keep the synthetic dataset in this folder (default: a temporary one, removed)."
    ),
    quick: bool = typer.Option(
        False, "--quick", help="A smoke run: short recordings and episodes, one seed, a coarse tuning."
    ),
) -> None:
    """Truth plant with a hidden effect -> synth data -> discrepancy -> model.yaml -> retune on it ->
    benchmark on the truth plant, before (nominal design) and after (design on the corrected model).

    Writes OUT/summary.md, results.csv, timeseries_<V>V.png, suppression.png, gains_corrected.yaml,
    truth.yaml, truth_answer.json and the discrepancy report under OUT/discrepancy/.
    """
    import dataclasses

    from drill_env.agents.evaluation.sim_to_real import (
        SimToRealConfig,
        parse_voltages,
        quick_config,
        run_sim_to_real,
    )
    from drill_env.outputs import check_output_folder

    try:
        volts = parse_voltages(voltages) if voltages is not None else None
    except ValueError as exc:
        _fail(str(exc))
    if not 1 <= seeds <= 20:
        _fail(f"--seeds must be an integer from 1 to 20, got {seeds!r}")
    if not 0.01 <= magnitude <= 0.2:
        _fail(f"--magnitude must lie in [0.01, 0.2] (a1 of the lower position friction), got {magnitude!r}")
    check_output_folder(out, "--out")
    if data is not None:
        check_output_folder(data, "--data")
        if data.resolve() == out.resolve():
            _fail(f"--data {data}: must not be the output folder --out")
    try:
        if quick:
            cfg = dataclasses.replace(quick_config(voltages=volts or (1.0,)), magnitude=magnitude)
        else:
            extra = {"voltages": volts} if volts else {}
            cfg = SimToRealConfig(magnitude=magnitude, seeds=tuple(range(seeds)), **extra)
    except ValueError as exc:
        msg = str(exc)  # the config's field names are the options' names
        _fail(f"--{msg}" if msg.startswith(("voltages:", "seeds:")) else msg)
    res = run_sim_to_real(out, cfg, data_dir=data, progress=lambda line: typer.echo(line, err=True))
    typer.echo(f"wrote {len(res.files)} files to {out}; see {out / 'summary.md'}")


def register(app: typer.Typer) -> None:
    app.command(name="sim-to-real")(sim_to_real)
