"""``drill-env tune``: tune the classical controllers' gains on the linearised nominal rig."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

if TYPE_CHECKING:
    from drill_env.params import RigParams


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def tune_on_model(
    model: RigParams,
    source: str,
    preset: str,
    control_dt: float = 0.05,
    kinds: Sequence[str] | None = None,
    progress: Callable[[str, str], None] | None = None,
) -> dict[str, Any]:
    """:func:`drill_env.agents.controllers.tuning.tune_all` for one preset, designed on the rig ``model`` (a
    ``RigParams`` read from ``source``) instead of the preset's parameters."""
    from drill_env.agents.controllers.base import ControllerSpec
    from drill_env.agents.controllers.tuning import TUNED_GAINS, tune, tune_all

    data = tune_all(presets=(), control_dt=control_dt)
    data["design_model"] = {"preset": preset, "params": source, "name": model.name}
    spec = ControllerSpec(params=model, control_dt=control_dt)
    data["presets"][preset] = {}
    for kind in kinds or tuple(TUNED_GAINS):
        if progress is not None:
            progress(f"{preset} ({source})", kind)
        data["presets"][preset][kind] = tune(kind, spec).to_dict()
    return data


def register(app: typer.Typer) -> None:
    @app.command("tune")
    def tune(
        out: Path | None = typer.Option(
            None,
            help="YAML file for the tuned gains and the tuning record. Default: a fresh run folder, "
            "runs/tune/controllers_TIME/controllers.yaml (use it with `drill-env benchmark --gains`); "
            "the committed configs/agents/controllers.yaml is regenerated only when named here.",
        ),
        preset: str | None = typer.Option(
            None,
            help="Comma-separated rig preset(s) to tune for (default: brake,no_brake; with --params "
            "one preset, by default the one whose lower-disk friction is closest to the file's).",
        ),
        control_dt: float = typer.Option(0.05, help="Control period of the environment [s]."),
        params: Path | None = typer.Option(
            None,
            "--params",
            help="Design on this rig model instead of the preset's parameters: a rig YAML in the "
            "preset format, e.g. a discrepancy result's model.yaml. The gains are written under the "
            "preset (its operating points and benchmark); effects in the file are not part of the "
            "linearised design model.",
        ),
    ) -> None:
        """Tune PI (upper, lower), torque feedback and LQI by the procedure of drill_env.agents.controllers.tuning.

        Worst-case closed-loop decay rate over 12 slip equilibria spanning the envelope,
        with a 0.05 V bound on the voltage noise from encoder quantisation; writes the
        gains with each design point's decay rate and noise to OUT.
        """
        import yaml

        from drill_env.agents.controllers.tuning import tune_all
        from drill_env.params import available_presets

        model = None
        if params is not None:
            from drill_env.agents.evaluation.plants import Plant
            from drill_env.params import load_params

            if params.suffix not in (".yaml", ".yml") or not params.is_file():
                _fail(f"--params: {params} is not a rig YAML file (the preset format)")
            try:
                model = load_params(params)
            except ValueError as exc:
                _fail(f"--params: {exc}")
            preset = preset if preset is not None else Plant(name="model", params=model).friction_family()
        presets = tuple(
            dict.fromkeys(p.strip() for p in (preset or "brake,no_brake").split(",") if p.strip())
        )
        if not presets:
            _fail(f"--preset: expected one or more of {available_presets()}, got {preset!r}")
        for p in presets:
            if p not in available_presets():
                _fail(f"--preset: {p!r} is not one of {available_presets()}")
        if model is not None and len(presets) != 1:
            _fail(f"--preset: with --params expected one preset to write the gains under, got {preset!r}")
        if not (0 < control_dt <= 1.0):
            _fail(f"--control-dt must lie in (0, 1] s, got {control_dt!r}")
        from drill_env.sensors import SensorConfig

        ts = SensorConfig().sample_period  # the controller acts on whole sensor periods
        if abs(round(control_dt / ts) * ts - control_dt) > 1e-9 * control_dt:
            _fail(
                f"--control-dt {control_dt!r} s must be a whole number of sensor periods ({ts:g} s), "
                f"e.g. {max(1, round(control_dt / ts)) * ts:g}"
            )

        def progress(p: str, kind: str) -> None:
            typer.echo(f"tuning {kind} on {p} ...", err=True)

        from drill_env.outputs import (
            OutputFolderError,
            atomic_write_text,
            check_command_file,
            command_files,
            fresh_run_folder,
        )

        if out is not None and out.is_dir():
            _fail(f"--out {out} is a directory; expected a YAML file path")
        if out is not None:
            check_command_file(out, "tune", "--out")  # before the tuning, not after it
        data = (
            tune_all(presets=presets, control_dt=control_dt, progress=progress)
            if model is None
            else tune_on_model(model, str(params), presets[0], control_dt, progress=progress)
        )
        header = (
            "# Tuned gains of the classical controllers, written by `drill-env tune` (agents/controllers/tuning.py).\n"
            "# Regenerate, never edit by hand: decay rates [1/s], noise [V], gains in SI units.\n"
        )
        text = header + yaml.safe_dump(data, sort_keys=False, width=100)
        run_folder = None
        try:
            if out is None:
                run_folder = fresh_run_folder(Path("runs") / "tune", "controllers")
                out = run_folder / "controllers.yaml"
            with command_files([out], "tune", "--out"):
                atomic_write_text(out, text)
        except OutputFolderError as exc:
            if run_folder is not None:  # the run folder made for this file: not left empty
                with contextlib.suppress(OSError):
                    run_folder.rmdir()
            _fail(f"--out: {exc}" if not str(exc).startswith("--out") else str(exc))
        for p, kinds in data["presets"].items():
            for kind, rec in kinds.items():
                gains = ", ".join(f"{k}={v:.4g}" for k, v in rec["gains"].items())
                typer.echo(
                    f"{p:9s} {kind:16s} {gains:55s} design set {rec['design_set']:16s} "
                    f"alpha {rec['worst_decay_rate']:+.3f} (envelope {rec['envelope_decay_rate']:+.3f}) 1/s, "
                    f"noise {rec['max_noise_v']:.3f} V"
                )
        typer.echo(f"wrote {out}; benchmark with these gains: drill-env benchmark --gains {out} --out DIR")
