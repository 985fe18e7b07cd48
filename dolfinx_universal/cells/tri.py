"""Triangle geometry on vertex arrays: signed areas, edge lengths, diameters, interior angles.

Every function takes vertex coordinates ``x`` ``(num_vertices, gdim)`` (``gdim >= 2``; only
x and y are read) and triangles ``cells`` ``(m, 3)`` of vertex indices.
"""

from __future__ import annotations

import numpy as np

from dolfinx_universal.core.arrays import Float, Int

__all__ = [
    "barycentric",
    "cell_diameters",
    "edge_lengths",
    "interior_angles",
    "signed_areas",
    "triangle_measures",
]


def _corner_columns(x: Float, cells: Int) -> list[tuple[Float, Float]]:
    """The corners of triangles as coordinate columns: ``p[k] = (x_k, y_k)``, each ``(m,)``,
    gathered from the columns of ``x``: the arithmetic on these contiguous arrays takes
    about half the time it takes on an ``(m, 3, 2)`` gather."""
    cells = np.asarray(cells)
    xs, ys = x[:, 0], x[:, 1]
    cols = [np.ascontiguousarray(cells[:, k]) for k in range(3)]
    return [(xs[c], ys[c]) for c in cols]


def _edges(p: list[tuple[Float, Float]]) -> list[tuple[Float, Float]]:
    """Edge vectors ``p[k + 1] - p[k]`` of corners :func:`_corner_columns`, ``k = 0, 1, 2``."""
    return [(p[(k + 1) % 3][0] - p[k][0], p[(k + 1) % 3][1] - p[k][1]) for k in range(3)]


def _signed_areas(p: list[tuple[Float, Float]]) -> Float:
    """Signed areas ``(m,)`` of corners :func:`_corner_columns`."""
    (x0, y0), (x1, y1), (x2, y2) = p
    d1x, d1y, d2x, d2y = x1 - x0, y1 - y0, x2 - x0, y2 - y0
    return 0.5 * (d1x * d2y - d1y * d2x)


def _lengths(e: list[tuple[Float, Float]]) -> Float:
    """Lengths ``(m, 3)`` of edge vectors :func:`_edges`."""
    return np.column_stack([np.sqrt(ex * ex + ey * ey) for ex, ey in e])


def _angles(p: list[tuple[Float, Float]], e: list[tuple[Float, Float]]) -> Float:
    """Interior angles ``(m, 3)`` of corners ``p`` with edge vectors ``e`` (:func:`_edges`):
    at vertex ``k`` between ``a = e_k`` and ``b = p_(k-1) - p_k`` (computed, not ``-e_(k-1)``:
    the signed zeros of a collapsed edge give the angles 0 as before)."""
    out = []
    for k in range(3):
        ax, ay = e[k]
        bx, by = p[k - 1][0] - p[k][0], p[k - 1][1] - p[k][1]
        dot = ax * bx + ay * by
        dot += 0.0  # -0 -> +0: the value numpy's sum over the axis gave (it starts at +0)
        out.append(np.arctan2(np.abs(ax * by - ay * bx), dot))
    return np.column_stack(out)


def signed_areas(x: Float, cells: Int) -> Float:
    """Signed areas of triangles, positive for counter-clockwise vertices, shape ``(m,)``."""
    return _signed_areas(_corner_columns(x, cells))


def edge_lengths(x: Float, cells: Int) -> Float:
    """Edge lengths of triangles, shape ``(m, 3)``: column ``k`` from vertex ``k`` to ``k + 1``."""
    return _lengths(_edges(_corner_columns(x, cells)))


def cell_diameters(x: Float, cells: Int) -> Float:
    """Longest edge of each triangle, shape ``(m,)``."""
    e = _edges(_corner_columns(x, cells))
    sq = [ex * ex + ey * ey for ex, ey in e]
    return np.sqrt(np.maximum(np.maximum(sq[0], sq[1]), sq[2]))


def interior_angles(x: Float, cells: Int) -> Float:
    """Interior angle (radians) at each vertex of each triangle, shape ``(m, 3)``.

    Column ``k`` is the angle at vertex ``k``.
    """
    p = _corner_columns(x, cells)
    return _angles(p, _edges(p))


def triangle_measures(x: Float, cells: Int) -> tuple[Float, Float, Float]:
    """Interior angles ``(m, 3)``, edge lengths ``(m, 3)`` and signed areas ``(m,)`` of
    triangles, from one gather of the corners (the values of :func:`interior_angles`,
    :func:`edge_lengths` and :func:`signed_areas`)."""
    p = _corner_columns(x, cells)
    e = _edges(p)
    return _angles(p, e), _lengths(e), _signed_areas(p)


def barycentric(x: Float, cells: Int, p: Float) -> Float:
    """Barycentric coordinates of vertices 1 and 2 of triangles ``cells[i]`` at points
    ``p[i]`` ``(m, 2)`` (inf or nan where a triangle is degenerate)."""
    a = x[cells[:, 0]]
    b, e = x[cells[:, 1]] - a, x[cells[:, 2]] - a
    q = p - a
    det = b[:, 0] * e[:, 1] - e[:, 0] * b[:, 1]
    l1 = q[:, 0] * e[:, 1] - e[:, 0] * q[:, 1]
    l2 = b[:, 0] * q[:, 1] - q[:, 0] * b[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.column_stack([l1 / det, l2 / det])
