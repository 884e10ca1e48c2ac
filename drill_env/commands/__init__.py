"""Subcommands of ``drill-env`` beyond ``simulate`` that need nothing but the core:
``bifurcation``, ``rig-comparison``, ``synth``, ``discrepancy``, ``discrepancy-study``,
``precompile``. The controller commands (``tune``, ``train``, ``benchmark``) live in
:mod:`drill_env.agents.commands`, above the core they build on.

Each module here defines ``register(app)`` that adds its command(s) to the Typer app;
:mod:`drill_env.cli` registers every module of this package. Keep heavy imports
inside the command functions so that ``drill-env --help`` stays quick.
"""
