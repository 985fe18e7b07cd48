"""The package's layout keeps its shape: stage subpackages without import circles, no
private names across subpackages, the dimension picked through kits, short functions.

The measures are those of ``layout_metrics.py``; each test also shows on a small synthetic
package that its measure can fail.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from layout_metrics import (
    dimension_branches,
    function_imports,
    import_cycles,
    load,
    long_functions,
    private_cross_imports,
)

MAX_DIMENSION_BRANCHES = 10
"""Branches on the dimension allowed outside the kits (``cells``, the ``*_tri``/``*_tet``
modules and the stages' kit modules): argument checks at the entry points."""

KIT_MODULES = ("kit", "_tri", "_tet", "cells.")
"""Where a branch on the dimension belongs (modules whose name ends or contains these)."""


@pytest.fixture(scope="module")
def modules():
    return load()


def _write(root: Path, files: dict[str, str]) -> Path:
    pkg = root / "pkg"
    for name, text in files.items():
        path = pkg / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return pkg


def test_no_import_circle(modules):
    assert import_cycles(modules) == []


def test_no_private_name_across_subpackages(modules):
    assert private_cross_imports(modules) == []


def test_no_function_over_100_lines(modules):
    assert long_functions(modules) == []


def test_dimension_branches_outside_the_kits(modules):
    counts = dimension_branches(modules)
    outside = {m: n for m, n in counts.items() if not any(k in m for k in KIT_MODULES)}
    assert sum(outside.values()) <= MAX_DIMENSION_BRANCHES, outside


def test_imports_inside_functions_hide_no_circle(modules):
    """Moving every function-level import to module level still gives no circle."""
    for mod in modules.values():
        mod.imports = [(t, n, False) for t, n, _ in mod.imports]
    assert import_cycles(modules) == []
    assert all(not inside for mod in modules.values() for _, _, inside in mod.imports)


def test_the_measures_can_fail(tmp_path):
    pkg = _write(
        tmp_path,
        {
            "__init__.py": "",
            "a/__init__.py": "",
            "a/x.py": "from pkg.b.y import _hidden\n",
            "b/__init__.py": "",
            "b/y.py": (
                "def f():\n    from pkg.a.x import g\n\n"
                "def _hidden(tdim):\n    if tdim == 3:\n        return 1\n" + "    x = 1\n" * 101
            ),
        },
    )
    mods = load(pkg)
    assert import_cycles(mods) == [["pkg.a.x", "pkg.b.y"]]
    assert function_imports(mods) == [("pkg.b.y", "pkg.a.x")]
    assert private_cross_imports(mods) == [("pkg.a.x", "pkg.b.y", "_hidden")]
    assert dimension_branches(mods) == {"pkg.b.y": 1}
    assert long_functions(mods) == [("pkg.b.y", "_hidden", 103)]
