"""The controller commands of ``drill-env``: ``tune``, ``train``, ``benchmark``, ``sim-to-real``.

They build on the core (:mod:`drill_env`) and on :mod:`agents`, so they live here and the
core never imports them: :mod:`drill_env.cli` registers every module of this package, as
it does its own :mod:`drill_env.commands`, by calling its ``register(app)``. Keep heavy
imports inside the command functions so that ``drill-env --help`` stays quick.
"""
