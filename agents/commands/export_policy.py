"""``drill-env export-policy``: a trained policy as ONNX and as a numpy-only network."""

from __future__ import annotations

from pathlib import Path

import typer


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def register(app: typer.Typer) -> None:
    @app.command("export-policy")
    def export_policy(
        policy: str = typer.Argument(
            ..., help="A learned benchmark controller (ppo, sac, ppo_robust, ...) or a policy.zip."
        ),
        out: Path = typer.Option(..., help="Folder to write policy.onnx, policy.npz and policy.json into."),
        format: str = typer.Option(
            "onnx", "--format", help="Export format: onnx (with policy.npz for the numpy runner)."
        ),
        preset: str = typer.Option(
            "brake", help="The preset whose committed policy a controller name means."
        ),
        agents_dir: Path | None = typer.Option(None, help="Folder of trained policies (as for benchmark)."),
        trust_policies: bool = typer.Option(
            False, "--trust-policies", help="Load a policy file from anywhere."
        ),
    ) -> None:
        """Export a trained MLP policy with its observation and action scaling inside: policy.onnx
        (input: the physical observation; outputs: the action and the voltage it asks for),
        policy.npz for drill_env.rig.numpy_policy, and policy.json describing both. A residual
        policy exports its correction (policy.json says how its classical base combines with it)."""
        if format != "onnx":
            _fail(f"--format: {format!r}; allowed: onnx")
        from drill_env.outputs import check_command_folder, command_folder

        own = ("policy.onnx", "policy.npz", "policy.json")  # a folder of these from before markers
        check_command_folder(out, "export-policy", "--out", own=own)
        from drill_env.agents.registry import LEARNED

        try:
            import onnx  # noqa: F401
        except ImportError:
            _fail(
                '--format onnx: the onnx package is not installed; pip install -c constraints.txt -e ".[rig]"'
            )
        from drill_env.agents.evaluation.rig_runs import resolve_controller
        from drill_env.agents.learning.export import export_policy as run_export

        if policy not in LEARNED and not policy.endswith(".zip"):
            _fail(
                f"POLICY: {policy!r} is neither a learned controller ({', '.join(LEARNED)}) nor a .zip file"
            )
        try:
            env, pol, _ = resolve_controller(
                policy, preset, 2000, 1000.0, agents_dir=agents_dir, trusted=trust_policies
            )
            env = env  # the environment of the policy's version (its scales and action mapping)
            with command_folder(out, "export-policy", "--out", own=own):
                paths = run_export(pol, env, out)
        except ValueError as exc:
            _fail(str(exc))
        for p in paths.values():
            typer.echo(f"wrote {p}")
