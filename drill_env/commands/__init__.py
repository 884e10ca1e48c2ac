"""Subcommands of ``drill-env`` beyond ``simulate``.

Each module here defines ``register(app)`` that adds its command(s) to the Typer app;
:mod:`drill_env.cli` registers every module of this package. Keep heavy imports
inside the command functions so that ``drill-env --help`` stays quick.
"""
