"""``drill-env tune``: tune the classical controllers' gains on the linearised nominal rig."""

from __future__ import annotations

from pathlib import Path

import typer


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def register(app: typer.Typer) -> None:
    @app.command("tune")
    def tune(
        out: Path | None = typer.Option(
            None,
            help="YAML file for the tuned gains and the tuning record. Default: a fresh run folder, "
            "runs/tune/controllers_TIME/controllers.yaml (use it with `drill-env benchmark --gains`); "
            "the committed configs/agents/controllers.yaml is regenerated only when named here.",
        ),
        preset: str = typer.Option("brake,no_brake", help="Comma-separated rig preset(s) to tune for."),
        control_dt: float = typer.Option(0.05, help="Control period of the environment [s]."),
    ) -> None:
        """Tune PI (upper, lower), torque feedback and LQI by the procedure of agents.tuning.

        Worst-case closed-loop decay rate over 12 slip equilibria spanning the envelope,
        with a 0.05 V bound on the voltage noise from encoder quantisation; writes the
        gains with each design point's decay rate and noise to OUT.
        """
        import yaml

        from agents.tuning import tune_all
        from drill_env.params import available_presets

        presets = tuple(dict.fromkeys(p.strip() for p in preset.split(",") if p.strip()))
        if not presets:
            _fail(f"--preset: expected one or more of {available_presets()}, got {preset!r}")
        for p in presets:
            if p not in available_presets():
                _fail(f"--preset: {p!r} is not one of {available_presets()}")
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

        from drill_env.outputs import OutputFolderError, atomic_write_text, fresh_run_folder

        if out is not None and out.is_dir():
            _fail(f"--out {out} is a directory; expected a YAML file path")
        if out is not None:
            from drill_env.outputs import check_output_file

            check_output_file(out, "--out")  # before the tuning, not after it
        data = tune_all(presets=presets, control_dt=control_dt, progress=progress)
        try:
            if out is None:
                out = fresh_run_folder(Path("runs") / "tune", "controllers") / "controllers.yaml"
            out.parent.mkdir(parents=True, exist_ok=True)
        except (OutputFolderError, OSError) as exc:
            _fail(f"--out: {exc}")
        header = (
            "# Tuned gains of the classical controllers, written by `drill-env tune` (agents/tuning.py).\n"
            "# Regenerate, never edit by hand: decay rates [1/s], noise [V], gains in SI units.\n"
        )
        atomic_write_text(out, header + yaml.safe_dump(data, sort_keys=False, width=100))
        for p, kinds in data["presets"].items():
            for kind, rec in kinds.items():
                gains = ", ".join(f"{k}={v:.4g}" for k, v in rec["gains"].items())
                typer.echo(
                    f"{p:9s} {kind:16s} {gains:55s} design set {rec['design_set']:16s} "
                    f"alpha {rec['worst_decay_rate']:+.3f} (envelope {rec['envelope_decay_rate']:+.3f}) 1/s, "
                    f"noise {rec['max_noise_v']:.3f} V"
                )
        typer.echo(f"wrote {out}; benchmark with these gains: drill-env benchmark --gains {out} --out DIR")
