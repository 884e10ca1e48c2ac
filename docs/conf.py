"""Sphinx configuration of the drill-env documentation (furo, MyST Markdown, sphinx-gallery).

Built by ``make docs`` (``sphinx-build -W --keep-going``: every warning fails the build).
Nothing is fetched from the network: no intersphinx, no remote images. Pages generated
at build time (the command-line reference, the environment page, the results' tables)
are written to ``_generated/`` by the extensions of ``_ext/``; the tutorials of
``tutorials_src/`` are run by sphinx-gallery into ``tutorials/``.
"""

from __future__ import annotations

import os
import re
import sys
import warnings
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(DOCS / "_ext"))
# The tutorials and autodoc import the checkout's package, never an older installed copy.
os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
os.environ.setdefault("MPLBACKEND", "Agg")

import drill_env  # noqa: E402

project = "drill-env"
author = "drill-env developers"
copyright = "drill-env developers"  # noqa: A001
release = drill_env.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx_gallery.gen_gallery",
    "cli_reference",
    "env_page",
    "results_pages",
    "headlines",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = [
    "_build",
    "_generated",  # included by the pages that show them, never pages of their own
    "tutorials_src/README.txt",
    "tutorials_src/runs",  # what the tutorials write while they run
    "tutorials/*.ipynb",
    "tutorials/*.py",
    "tutorials/*.codeobj.json",
    "tutorials/*.md5",
    "tutorials/*.zip",
]
templates_path: list[str] = []

# MyST: $...$ maths, definition lists, anchors for the headings of ## and ### level.
myst_enable_extensions = ["dollarmath", "deflist", "colon_fence", "attrs_inline"]
myst_heading_anchors = 3
suppress_warnings = [
    # The results' reports repeat headings ("stable equilibrium" under every plant).
    "myst.duplicate_def",
]

# -- autodoc -------------------------------------------------------------------------
autodoc_member_order = "bysource"
autodoc_typehints = "description"
# types go into the parameters the docstring documents; without this, autodoc appends a second
# "Parameters" list with every parameter the docstring already describes
autodoc_typehints_description_target = "documented_params"
autodoc_default_options = {"show-inheritance": False}
autodoc_mock_imports: list[str] = []
napoleon_google_docstring = True
napoleon_numpy_docstring = True
# simulate() lists its keyword-only settings under "Options:"
napoleon_custom_sections = [("Options", "params_style")]
autosummary_generate = False


# |u| in a docstring is an absolute value, not a reStructuredText substitution.
ABSOLUTE_VALUE = re.compile(r"(?<![\\`|])\|([A-Za-z_][\w.]*)\|(?![`|])")


def _docstrings(app, what, name, obj, options, lines):  # noqa: ANN001, ANN201
    """Docstrings are written for readers of the code, in reStructuredText with two habits
    autodoc is told about: the env class's docstring is Markdown (Gymnasium's sections and
    tables), shown rendered on the environment page, so autodoc links there; and ``|u|``
    means an absolute value."""
    if name == "drill_env.envs.drill_string.DrillStringEnv":
        lines[:] = [
            "The Gymnasium environment of the rig: see :doc:`/reference/environment` for its",
            "spaces, rewards, episodes and arguments.",
        ]
        return
    lines[:] = [ABSOLUTE_VALUE.sub(r"\\|\1\\|", line) for line in lines]


# -- sphinx-gallery: the tutorials are plain scripts, run at every build ------------
sphinx_gallery_conf = {
    "examples_dirs": "tutorials_src",
    "gallery_dirs": "tutorials",
    "filename_pattern": r"\.py$",  # run every tutorial (they cannot rot)
    "ignore_pattern": r"__init__\.py",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "show_memory": False,
    "write_computation_times": False,  # its pages load scripts from a CDN; the build log has the times
    "show_signature": False,
    "remove_config_comments": True,
    "abort_on_example_error": False,  # report every failing tutorial, then fail (-W)
    "only_warn_on_example_error": False,
    "plot_gallery": "True",
    "capture_repr": ("_repr_html_", "__repr__"),
    "matplotlib_animations": False,
    "image_scrapers": ("matplotlib",),
    "reset_modules": ("matplotlib",),
}

# -- HTML ------------------------------------------------------------------------------
html_theme = "furo"
html_title = f"drill-env {release}"
html_static_path: list[str] = []
html_copy_source = False
html_show_sourcelink = False
html_theme_options = {
    "navigation_with_keys": True,
}

# Warnings of third-party packages while the tutorials run are not the site's warnings.
warnings.filterwarnings("ignore", category=DeprecationWarning)


def setup(app):  # noqa: ANN001, ANN201
    app.connect("autodoc-process-docstring", _docstrings)
