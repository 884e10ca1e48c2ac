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
    truth: Path | None = typer.Option(
        None,
        "--truth",
        help="Take this plant file as the truth instead of the built-in one (rig YAML with effects, "
        "optionally actuator_delay [s] and sensors:; --magnitude is then unused).",
    ),
    controllers: str | None = typer.Option(
        None,
        help="Comma-separated controllers compared before/after (default: "
        "torque_feedback,lqi,lqi_angle_ff,ppo_robust; also sac_robust).",
    ),
    params: Path | None = typer.Option(
        None,
        "--params",
        help="The lab's model of its rig (a rig YAML, e.g. identify's rig.yaml) instead of the "
        "preset's: the before design is built and tuned on it, the discrepancy compares the data "
        "with it, the built-in truth is it with the hidden effect; the recording and compared "
        "voltages come from its own analysis (regimes with a cycle) unless --voltages is given.",
    ),
    quick: bool = typer.Option(
        False, "--quick", help="A smoke run: short recordings and episodes, one seed, a coarse tuning."
    ),
    trust_policies: bool = typer.Option(
        False,
        "--trust-policies",
        help="Load the learned controllers' policy files from outside results/agents/ (a "
        "$DRILL_ENV_AGENTS_DIR folder; loading one can run code it holds) in a run without a "
        "terminal, which otherwise refuses them; also DRILL_ENV_TRUST_POLICIES=1. On a terminal "
        "you are asked.",
    ),
) -> None:
    """Truth plant with a hidden effect -> synth data -> discrepancy -> model.yaml -> retune on it ->
    benchmark on the truth plant, before (nominal design) and after (design on the corrected model).

    With --truth the truth is a plant file (its effects, delay and sensors recorded and simulated).
    Writes OUT/summary.md, results.csv, timeseries_<V>V.png, suppression.png, gains_corrected.yaml,
    truth.yaml, truth_answer.json and the discrepancy report under OUT/discrepancy/.
    """
    import dataclasses

    from drill_env.agents.evaluation.sim_to_real import (
        SIM_TO_REAL_FILES,
        SimToRealConfig,
        parse_voltages,
        quick_config,
        run_sim_to_real,
    )
    from drill_env.outputs import check_command_folder, check_new_folder

    try:
        volts = parse_voltages(voltages) if voltages is not None else None
    except ValueError as exc:
        _fail(str(exc))
    if not 1 <= seeds <= 20:
        _fail(f"--seeds must be an integer from 1 to 20, got {seeds!r}")
    if not 0.01 <= magnitude <= 0.2:
        _fail(f"--magnitude must lie in [0.01, 0.2] (a1 of the lower position friction), got {magnitude!r}")
    if truth is not None:
        from drill_env.params import ParameterError
        from drill_env.plant_file import read_plant_file, without_measurement

        try:
            without_measurement(read_plant_file(truth), "sim-to-real's closed loop")
        except (ParameterError, ValueError) as exc:
            _fail(f"--truth {truth}: {exc}")
    if params is not None:
        from drill_env.params import ParameterError, load_params

        if params.suffix.lower() not in (".yaml", ".yml") or not params.is_file():
            _fail(f"--params: {params} is not a rig YAML file (the preset format)")
        try:
            load_params(params)
        except (ParameterError, ValueError) as exc:
            _fail(f"--params {params}: {exc}")
    ctrl_list = None
    if controllers is not None:
        ctrl_list = tuple(c.strip() for c in controllers.split(",") if c.strip())
    if data is not None and (data.resolve() == out.resolve() or out.resolve() in data.resolve().parents):
        _fail(f"--data {data}: must not be the output folder --out or lie inside it")
    check_command_folder(out, "sim-to-real", "--out", own=SIM_TO_REAL_FILES)
    if data is not None:  # a new dataset, never mixed with the runs of another one
        check_new_folder(data, "--data", what="dataset")
    try:
        extra: dict = {"truth_file": None if truth is None else str(truth)}
        if ctrl_list is not None:
            extra["controllers"] = ctrl_list
        if quick:
            cfg = dataclasses.replace(quick_config(voltages=volts or (1.0,)), magnitude=magnitude, **extra)
        else:
            if volts:
                extra["voltages"] = volts
            cfg = SimToRealConfig(magnitude=magnitude, seeds=tuple(range(seeds)), **extra)
        if params is not None:
            from drill_env.agents.evaluation.sim_to_real import for_rig

            cfg = for_rig(cfg, params, voltages=volts is None)
    except ValueError as exc:
        msg = str(exc)  # the config's field names are the options' names
        _fail(f"--{msg}" if msg.startswith(("voltages:", "seeds:", "controllers:")) else msg)
    from drill_env.agents.commands._trust import vouch_for_policies
    from drill_env.agents.registry import LEARNED, policy_path

    try:
        policies = [policy_path(c, cfg.preset) for c in cfg.controllers if c in LEARNED]
    except ValueError as exc:
        _fail(str(exc))
    if vouch_for_policies(policies, flag=trust_policies, option="agents folder"):
        cfg = dataclasses.replace(cfg, trust_policies=True)
    res = run_sim_to_real(out, cfg, data_dir=data, progress=lambda line: typer.echo(line, err=True))
    typer.echo(f"wrote {len(res.files)} files to {out}; see {out / 'summary.md'}")


def register(app: typer.Typer) -> None:
    app.command(name="sim-to-real")(sim_to_real)
