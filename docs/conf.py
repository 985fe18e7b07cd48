"""Sphinx configuration of the dolfinx_universal documentation.

Build with ``bash .ci/docs`` (warnings are errors). Two pages are generated at build time
into ``docs/_autogen/`` (git-ignored) by the local extensions in ``docs/_ext/``:

* ``demo_pages``: every ``demos/*.py`` (jupytext light or percent style) as a MyST page,
  comment blocks as Markdown and code as code blocks; nothing is executed.
* ``api_pages``: one autodoc page per public module of the package, and the table of the
  top-level exports.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import dolfinx_universal  # noqa: E402

project = "dolfinx_universal"
author = "dolfinx_universal developers"
copyright = "2026, dolfinx_universal developers"
release = dolfinx_universal.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "demo_pages",
    "api_pages",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "requirements.txt"]
templates_path: list[str] = []

# MyST: $...$ and $$...$$ math, \begin{align} environments, definition lists, anchors.
myst_enable_extensions = ["dollarmath", "amsmath", "deflist", "colon_fence"]
myst_heading_anchors = 3
myst_dmath_double_inline = True

# Docstrings are numpy style.
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_preserve_defaults = True
# The package imports DOLFINx: it must be importable (the venv of .ci/venv has it).
autodoc_mock_imports: list[str] = []

html_theme = "alabaster"
html_title = f"dolfinx_universal {release}"
html_static_path: list[str] = []
html_theme_options = {
    "description": "Universal meshes for DOLFINx",
    "fixed_sidebar": True,
}

# Demo pages: where the demos are, where their pages go.
demo_source_dir = str(ROOT / "demos")
demo_output_dir = "_autogen/demos"
# API pages: the order of the module pages; modules not listed (or added later, like
# ``io``) follow in alphabetical order, listed ones that do not exist are skipped.
api_output_dir = "_autogen/api"
api_modules = [
    "boundaries",
    "background",
    "graded",
    "sizing",
    "classify",
    "conform",
    "checks",
    "curved",
    "jacobian",
    "domain",
    "moving",
    "constraints",
    "quality",
    "validation",
    "io",
    "plotting",
    "cli",
]
