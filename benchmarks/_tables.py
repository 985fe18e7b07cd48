"""Fixed-width text tables shared by the gmsh comparisons (``conform_vs_gmsh.py``,
``conform_vs_gmsh_3d.py``): right-aligned columns of a given width, one space apart."""

from __future__ import annotations

from collections.abc import Sequence

WIDTH = 9
"""Default column width (characters)."""


def columns(cells: Sequence[object], width: int = WIDTH) -> str:
    """One line: every cell right-aligned in ``width`` characters, one space apart."""
    return " ".join(f"{c:>{width}}" for c in cells)


def header(
    head: Sequence[str], units: Sequence[str] | None = None, width: int = WIDTH
) -> list[str]:
    """The column names, their units (if given) and a rule as wide as the columns."""
    lines = [columns(head, width)]
    if units is not None:
        lines.append(columns(units, width))
    return lines + ["-" * (len(head) * (width + 1) - 1)]
