"""Where the project's files are, found from the core package ``drill_env``: this package is
its ``agents`` sub-package (the project's ``agents/`` folder, which ``drill_env/agents`` links
to in a checkout), so its own path says nothing about the layout around it."""

from __future__ import annotations

from pathlib import Path

import drill_env

# the drill_env package folder; in an installed wheel its _configs/ and _results/ hold the
# copies of the project's configs/ and committed policies (pyproject.toml, force-include)
PACKAGE_DIR = Path(drill_env.__file__).resolve().parent
# the folder holding it: the project's root (configs/, results/, pyproject.toml) in a checkout
ROOT = PACKAGE_DIR.parent


def shown_path(path: str | Path) -> str:
    """``path`` as reports print it: relative to the project root when it lies inside it (an
    absolute path into the checkout), else as given."""
    p = Path(path)
    if p.is_absolute():
        try:
            return p.resolve().relative_to(ROOT.resolve()).as_posix()
        except ValueError:
            return str(p)
    return p.as_posix()
