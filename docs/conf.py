"""Sphinx configuration of the dolfinx_universal documentation.

Build with ``bash .ci/docs`` (warnings are errors). Two pages are generated at build time
into ``docs/_autogen/`` (git-ignored) by the local extensions in ``docs/_ext/``:

* ``demo_pages``: every ``demos/*.py`` (jupytext light or percent style) as a MyST page,
  comment blocks as Markdown and code as code blocks; nothing is executed.
* ``api_pages``: one autodoc page per subpackage of the package (every public module of
  it, found by ``pkgutil.walk_packages``), and the table of the top-level exports.

The theme is pydata-sphinx-theme; math is rendered by a MathJax copy bundled with
``sphinx-mathjax-offline``, so the pages need no network. The figures under
``docs/figures/`` are committed and made by ``docs/make_figures.py``.
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
    "sphinx-mathjax-offline",  # MathJax served from _static/mathjax: no network needed
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

html_theme = "pydata_sphinx_theme"
html_title = f"dolfinx_universal {release}"
html_short_title = "dolfinx_universal"
html_static_path: list[str] = []
html_theme_options = {
    "logo": {"text": "dolfinx_universal"},
    "navbar_align": "left",
    "show_toc_level": 2,
    "navigation_with_keys": False,
    # The page's table of contents, except where the API table needs the width.
    "secondary_sidebar_items": {"**": ["page-toc"], "api": []},
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
# The section navigation only where a page has children (demos, API); elsewhere the text
# takes the width.
html_sidebars = {
    page: [] for page in ("index", "install", "method", "mpi", "gallery", "measurements")
}

# The contents of the start page (its toctree, included by index.md): the pages present,
# in this order, so that a page written later (measurements.md, from the benchmarks'
# results) joins once it is there.
CONTENTS = ["install", "method", "time_dependent", "mpi", "demos", "gallery", "measurements", "api"]
_contents = DOCS / "_autogen" / "contents.inc"
_text = (
    "```{toctree}\n:maxdepth: 2\n:caption: Contents\n\n"
    + "".join(f"{page}\n" for page in CONTENTS if (DOCS / f"{page}.md").exists())
    + "```\n"
)
if not _contents.exists() or _contents.read_text(encoding="utf-8") != _text:
    _contents.parent.mkdir(parents=True, exist_ok=True)
    _contents.write_text(_text, encoding="utf-8")

# Demo pages: where the demos are, where their pages go.
demo_source_dir = str(ROOT / "demos")
demo_output_dir = "_autogen/demos"
# The demos' figures (quick runs, made by docs/make_figures.py), shown on their pages.
demo_figures_dir = "figures/demos"
# API pages: one page per subpackage (its modules found by pkgutil.walk_packages), in the
# order of the pipeline; subpackages and top-level modules not listed follow in alphabetical
# order, listed ones that do not exist are skipped.
api_output_dir = "_autogen/api"
api_modules = [
    "boundaries",
    "backgrounds",
    "sizing",
    "conforming",
    "curved",
    "meshing",
    "moving",
    "io",
    "cli",
    "plotting",
    "cells",
    "core",
]
