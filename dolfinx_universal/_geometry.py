"""Triangle geometry on vertex arrays (signed areas, edge lengths, diameters, interior angles),
the array types, and the small input checks and planar vector helpers the modules share.

Every function takes vertex coordinates ``x`` ``(num_vertices, gdim)`` (``gdim >= 2``; only
x and y are read) and triangles ``cells`` ``(m, 3)`` of vertex indices.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = [
    "Bool",
    "Float",
    "Int",
    "all_rows",
    "any_rows",
    "as_points",
    "cell_diameters",
    "cross2",
    "edge_lengths",
    "interior_angles",
    "lagrange_element",
    "norm2",
    "positive",
    "signed_areas",
]

Float = npt.NDArray[np.float64]
"""Real arrays (coordinates, distances, signs)."""
Int = npt.NDArray[np.signedinteger[Any]]
"""Index arrays (vertices, cells; int32 from DOLFINx, int64 or intp from numpy)."""
Bool = npt.NDArray[np.bool_]
"""Flag arrays."""


def as_points(x: npt.ArrayLike, name: str = "x", dim: int = 2) -> Float:
    """``x`` as a contiguous float64 array ``(n, dim)``, checked finite.

    ``dim = 2`` (planar boundaries): ``(n, 2)`` or ``(n, 3)``, of which the first two columns
    are kept. ``dim = 3`` (surfaces): exactly ``(n, 3)``.
    """
    a = np.asarray(x, dtype=np.float64)
    if dim == 3:
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f"{name} must have shape (n, 3), got {a.shape}")
        a = np.ascontiguousarray(a)
    elif a.ndim != 2 or a.shape[1] not in (2, 3):
        raise ValueError(f"{name} must have shape (n, 2) or (n, 3), got {a.shape}")
    else:
        a = np.ascontiguousarray(a[:, :2])
    if not np.isfinite(a).all():  # (one reduction over the array; rows only to report)
        i = int(np.argmax(~np.isfinite(a).all(axis=1)))
        kind = "NaN" if np.isnan(a[i]).any() else "inf"
        raise ValueError(f"{name} contains {kind} at index {i} ({name}={a[i].tolist()})")
    return a


def positive(value: float, name: str) -> float:
    """``value`` as a float, checked positive and finite (``name`` for the error)."""
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value}")
    return value


def any_rows(a: Bool) -> Bool:
    """``a.any(axis=1)`` of a boolean ``(m, k)`` array, by columns (a reduction along a
    short axis is slow in numpy)."""
    out = a[:, 0].copy()
    for k in range(1, a.shape[1]):
        out |= a[:, k]
    return out


def all_rows(a: Bool) -> Bool:
    """``a.all(axis=1)`` of a boolean ``(m, k)`` array, by columns (see :func:`any_rows`)."""
    out = a[:, 0].copy()
    for k in range(1, a.shape[1]):
        out &= a[:, k]
    return out


def norm2(v: Float) -> Float:
    """Euclidean norms of planar vectors ``(..., 2)``."""
    return np.sqrt(v[..., 0] ** 2 + v[..., 1] ** 2)


def cross2(u: Float, v: Float) -> Float:
    """The planar cross product ``u_x v_y - u_y v_x`` of vectors ``(..., 2)``."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


@lru_cache(maxsize=32)
def lagrange_element(cell: str, degree: int, variant: Any = None) -> Any:
    """The basix Lagrange element of ``cell`` (``"triangle"``, ``"tetrahedron"``) of degree
    ``degree``: GLL-warped (the variant of DOLFINx's curved coordinate maps) unless another
    ``basix.LagrangeVariant`` is given. Built once per argument set."""
    import basix

    if variant is None:
        variant = basix.LagrangeVariant.gll_warped
    return basix.create_element(basix.ElementFamily.P, basix.CellType[cell], int(degree), variant)


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
