"""The command-line reference, generated from the Typer app of ``drill_env.cli``.

sphinx-click does not apply (the app is Typer), so this walks the click command that Typer
builds (``typer.main.get_command``) and writes one section per command: its help text, its
usage line and a table of its arguments and options with their types and defaults. The
page is written to ``_generated/cli.md`` before the sources are read; ``reference/cli.md``
includes it.
"""

from __future__ import annotations

from pathlib import Path


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def command_markdown(group, prog: str = "drill-env") -> str:  # noqa: ANN001 (Typer's click group)
    """One Markdown section per command of ``group``, in the order ``--help`` lists them.

    Typer ships its own copy of click, so the objects are read through click's public
    methods only (``list_commands``, ``collect_usage_pieces``, ``get_help_record``): the page
    shows what ``--help`` shows."""
    ctx = group.context_class(group, info_name=prog)
    lines = [
        "Generated from the command-line app (`drill_env/cli.py`) when the documentation is built;",
        f"`{prog} COMMAND --help` prints the same text.",
        "",
    ]
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        if cmd is None or cmd.hidden:
            continue
        sub = cmd.context_class(cmd, info_name=name, parent=ctx)
        lines += [f"## `{prog} {name}`", ""]
        lines += ["```text", f"{prog} {name} {' '.join(cmd.collect_usage_pieces(sub))}", "```", ""]
        for para in (cmd.help or "").strip().split("\n\n"):
            para = " ".join(para.split())
            if para:
                lines += [para.replace("<", "&lt;"), ""]
        records = [p.get_help_record(sub) for p in cmd.get_params(sub) if p.name != "help"]
        records = [r for r in records if r is not None]
        if records:
            lines += ["| argument or option | what |", "|---|---|"]
            for names, what in records:
                lines.append(f"| `{_cell(names)}` | {_cell(what).replace('<', '&lt;')} |")
            lines.append("")
    return "\n".join(lines)


def write_cli_reference(app) -> None:  # noqa: ANN001 (Sphinx application)
    import typer

    from drill_env.cli import app as typer_app

    group = typer.main.get_command(typer_app)
    out = Path(app.srcdir) / "_generated" / "cli.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    text = command_markdown(group)
    if not out.is_file() or out.read_text() != text:
        out.write_text(text)


def setup(app):  # noqa: ANN001, ANN201
    app.connect("builder-inited", write_cli_reference)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
