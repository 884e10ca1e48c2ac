"""The one rule of the commands for policy files from outside ``results/agents/``.

Loading a stable-baselines3 ``.zip`` unpickles Python objects, which can run any code the
file holds. A command loads such a file only when its user vouched for it: with
``--trust-policies`` (or ``DRILL_ENV_TRUST_POLICIES=1``), or by answering yes on a
terminal. Otherwise it ends with one line ``error: ...`` and exit code 2 before anything in
the file is read.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from pathlib import Path

import typer

__all__ = ["vouch_for_policies"]


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code=2)


def vouch_for_policies(paths: Iterable[str | Path], *, flag: bool, option: str) -> bool:
    """Whether the policy files ``paths`` may be loaded (pass the result as ``trusted=``).

    Every file is checked against the bounded zip size first (a zip bomb is refused even when
    trusted). Files of ``results/agents/`` need nothing; any other needs ``flag``
    (``--trust-policies``), the environment variable, or a yes on a terminal; else the command
    fails naming ``option``, the first file and how to vouch for it.
    """
    from drill_env.agents.learning.rl import (
        TRUST_ENV_VAR,
        check_policy_zip,
        trust_from_environment,
        untrusted_policy_note,
    )

    untrusted: list[str] = []
    for path in paths:
        try:
            check_policy_zip(path)
        except ValueError as exc:
            _fail(f"{option}: {exc}")
        if untrusted_policy_note(path) is not None:
            untrusted.append(str(path))
    if not untrusted or flag or trust_from_environment():
        return True
    head = f"{option}: {untrusted[0]}" + (f" (and {len(untrusted) - 1} more)" if len(untrusted) > 1 else "")
    why = (
        " is not one of the committed policies in results/agents/; loading a policy unpickles "
        "Python objects, which can run arbitrary code"
    )
    how = f"pass --trust-policies (or set {TRUST_ENV_VAR}=1) to load files you made or trust"
    if sys.stdin.isatty() and sys.stderr.isatty():
        typer.secho(f"warning: {head}{why}", fg=typer.colors.YELLOW, err=True)
        if typer.confirm("Load it?", default=False, err=True):
            return True
        _fail(f"{head} not loaded (not confirmed); {how}")
    _fail(f"{head}{why}, and this run has no terminal to ask on: {how}")
    return False  # not reached
