"""Triangle geometry on vertex arrays: signed areas, edge lengths, diameters, interior angles.

Every function takes vertex coordinates ``x`` ``(num_vertices, gdim)`` (``gdim >= 2``; only
x and y are read) and triangles ``cells`` ``(m, 3)`` of vertex indices.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = [
    "Bool",
    "Float",
    "Int",
    "cell_diameters",
    "edge_lengths",
    "interior_angles",
    "signed_areas",
]

Float = npt.NDArray[np.float64]
"""Real arrays (coordinates, distances, signs)."""
Int = npt.NDArray[np.int32] | npt.NDArray[np.int64]
"""Index arrays (vertices, cells)."""
Bool = npt.NDArray[np.bool_]
"""Flag arrays."""


def readonly(a: npt.NDArray) -> npt.NDArray:
    """``a`` as a contiguous read-only array (tables and samples that callers share)."""
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def rot90(v: Float) -> Float:
    """Vectors ``(n, 2)`` rotated by +90 degrees (the tangent of an outward normal)."""
    return np.column_stack([-v[:, 1], v[:, 0]])


def _corners(x: Float, cells: Int) -> Float:
    """Planar vertex coordinates of each triangle, shape ``(m, 3, 2)``."""
    return x[cells][:, :, :2]


def signed_areas(x: Float, cells: Int) -> Float:
    """Signed areas of triangles, positive for counter-clockwise vertices, shape ``(m,)``."""
    p = _corners(x, cells)
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def edge_lengths(x: Float, cells: Int) -> Float:
    """Edge lengths of triangles, shape ``(m, 3)``: column ``k`` from vertex ``k`` to ``k + 1``."""
    p = _corners(x, cells)
    return np.linalg.norm(np.roll(p, -1, axis=1) - p, axis=2)


def cell_diameters(x: Float, cells: Int) -> Float:
    """Longest edge of each triangle, shape ``(m,)``."""
    return edge_lengths(x, cells).max(axis=1)


def interior_angles(x: Float, cells: Int) -> Float:
    """Interior angle (radians) at each vertex of each triangle, shape ``(m, 3)``.

    Column ``k`` is the angle at vertex ``k``.
    """
    p = _corners(x, cells)
    a = np.roll(p, -1, axis=1) - p  # to the next vertex
    b = np.roll(p, 1, axis=1) - p  # to the previous vertex
    cross = np.abs(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])
    return np.arctan2(cross, (a * b).sum(axis=2))
