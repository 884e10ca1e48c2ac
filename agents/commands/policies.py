"""``drill-env policy-cards`` and ``drill-env upgrade-policies``: the trained policy folders
described, and their files brought to the present format."""

from __future__ import annotations

from pathlib import Path

import typer


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def register(app: typer.Typer) -> None:
    @app.command("policy-cards")
    def policy_cards(
        agents_dir: Path = typer.Argument(
            ..., help="A folder of trained policies laid out like results/agents (searched recursively)."
        ),
    ) -> None:
        """Write policy.md beside every trained policy under AGENTS_DIR and AGENTS_DIR/README.md.

        Each card says, from the folder's config.yaml and training_summary.json, how the policy
        started (from scratch, clone of a classical controller, residual on one, distilled from a
        trained policy), the training config it was trained with, how long it trained and what it
        reached; README.md is a table of them. Each folder's learning_curve.png is drawn again
        from its eval.csv and progress.csv (as train draws it).
        """
        from drill_env.agents.learning.cards import policy_folders, write_policy_cards
        from drill_env.outputs import check_tree_files

        if not agents_dir.is_dir():
            _fail(f"AGENTS_DIR: {agents_dir} is not a folder")
        try:
            curves = [f for f in policy_folders(agents_dir) if (f / "eval.csv").is_file()]
            check_tree_files(
                agents_dir,
                [f / "learning_curve.png" for f in curves],
                "policy-cards",
                "AGENTS_DIR",
                accepts=("train",),
            )
            written = write_policy_cards(agents_dir)
        except ValueError as exc:
            _fail(str(exc))
        for path in written:
            typer.echo(f"wrote {path}")
        if curves:
            from drill_env.agents.learning.rl import plot_learning_curve

            for folder in curves:
                try:
                    typer.echo(f"wrote {plot_learning_curve(folder)}")
                except (ValueError, KeyError, OSError) as exc:
                    _fail(f"{folder / 'eval.csv'}: the learning curve cannot be drawn: {exc}")

    @app.command("upgrade-policies")
    def upgrade_policies(
        agents_dir: Path = typer.Argument(
            ..., help="A folder of trained policies laid out like results/agents (searched recursively)."
        ),
        trusted: bool = typer.Option(
            False,
            "--trusted",
            help="Rewrite policies outside results/agents/ too (rewriting unpickles their stored objects).",
        ),
    ) -> None:
        """Bring every policy.zip under AGENTS_DIR to the present format.

        A file without the record of what it was trained on gets it (drill_env.json: algo, env
        id, env kwargs, observation version, training config), made from the config.yaml beside it.

        Objects pickled under a former module path are stored under the present one, and a
        residual policy's file names the policy class that refuses to load without its base
        (stable-baselines3's PPO.load / SAC.load of it raises, naming load_policy). The weights
        and every other entry of the zip stay byte for byte as they were; a file already up to
        date is not touched.
        """
        from drill_env.agents.learning.cards import policy_folders
        from drill_env.agents.learning.policy_info import POLICY_INFO_MEMBER
        from drill_env.agents.learning.rl import check_policy_zip, untrusted_policy_note, upgrade_policy_file

        if not agents_dir.is_dir():
            _fail(f"AGENTS_DIR: {agents_dir} is not a folder")
        folders = policy_folders(agents_dir)
        if not folders:
            _fail(
                f"AGENTS_DIR: no policy folder (policy.zip, config.yaml, training_summary.json) under {agents_dir}"
            )
        from drill_env.outputs import check_tree_files

        # every file it may rewrite, before the first: inside AGENTS_DIR, never through a link
        check_tree_files(
            agents_dir,
            [f / "policy.zip" for f in folders],
            "upgrade-policies",
            "AGENTS_DIR",
            accepts=("train",),
        )
        for folder in folders:  # a zip bomb is refused even when trusted, before any rewrite
            try:
                check_policy_zip(folder / "policy.zip")
            except ValueError as exc:
                _fail(str(exc))
        if not trusted:
            for folder in folders:
                note = untrusted_policy_note(folder / "policy.zip")
                if note is not None:
                    _fail(f"{note} (pass --trusted to rewrite it)")
        for folder in folders:
            try:
                changed = upgrade_policy_file(folder / "policy.zip", trusted=trusted)
            except ValueError as exc:
                _fail(str(exc))
            added = [c for c in changed if c == POLICY_INFO_MEMBER]
            rewritten = [c for c in changed if c != POLICY_INFO_MEMBER]
            parts = ([f"rewrote {', '.join(rewritten)}"] if rewritten else []) + (
                [f"added {POLICY_INFO_MEMBER} (what it was trained on)"] if added else []
            )
            what = "; ".join(parts) if parts else "up to date"
            typer.echo(f"{folder / 'policy.zip'}: {what}")
