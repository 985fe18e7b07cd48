"""The sign and distance grid of planar boundaries: points classified in O(1) away from Gamma."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from dolfinx_universal.core.arrays import Bool, Float, Int, norm2

__all__ = ["GRID_CELLS", "SignGrid", "chords", "crossing_sign"]


GRID_CELLS = 1024
"""Cells of the sign and distance grid along the longer side of the boundary's box."""


def chords(p: Float) -> Float:
    """Edge lengths of the closed polyline ``p (m, 2)``, shape ``(m,)``."""
    return norm2(np.roll(p, -1, axis=0) - p)


def crossing_sign(p: Float, loops: Sequence[Float]) -> Float:
    """Even-odd ray-casting test: -1 for points of ``p (m, 2)`` enclosed by the polylines."""
    a = np.concatenate(loops)
    b = np.concatenate([np.roll(q, -1, axis=0) for q in loops])
    out = np.empty(len(p))
    for c in range(0, len(p), 64):
        px, py = p[c : c + 64, :1], p[c : c + 64, 1:]
        cut = (a[:, 1] > py) != (b[:, 1] > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = a[:, 0] + (py - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        out[c : c + 64] = np.where((cut & (px < xc)).sum(axis=1) % 2 == 1, -1.0, 1.0)
    return out


class SignGrid:
    """Uniform grid over a boundary's bounding box, to classify points in O(1).

    Cells within one cell of a dense sample of Gamma are *marked* (code 0); every other cell
    lies in a connected region free of Gamma, whose sign (code -1 or +1) is that of one
    representative centre by ray casting against the dense polyline (exact: the centre is
    more than a cell away from Gamma, the polyline within a tiny fraction of a cell).
    ``lb`` is a lower bound of the distance from the cell to Gamma; the distance of a point
    of the cell is at most ``lb + 3 sqrt(2) h`` (``h`` the cell size: the nearest marked cell
    is within ``lb + sqrt(2) h`` of the point, and a sample within ``2 sqrt(2) h`` of every
    point of a marked cell).
    """

    def __init__(self, loops_at: Callable[[float], list[Float]], bbox: Float) -> None:
        lo, hi = bbox
        self.h = h = float(max((hi - lo).max(), 1e-300)) / GRID_CELLS
        loops = loops_at(h / 3)  # every point of Gamma is within h/6 of a sample
        pts = np.concatenate(loops)
        self.box = bbox
        self.origin = lo - 3 * h
        self.shape = np.ceil((hi - lo) / h).astype(np.intp) + 7
        ij = np.floor((pts - self.origin) / h).astype(np.intp)
        marked = np.zeros(tuple(self.shape), dtype=bool)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                marked[ij[:, 0] + di, ij[:, 1] + dj] = True
        free = ~marked
        label, nlabel = ndimage.label(free)
        first = np.searchsorted(np.maximum.accumulate(label.ravel()), np.arange(1, nlabel + 1))
        centres = self.origin + (np.column_stack(np.unravel_index(first, label.shape)) + 0.5) * h
        rep = np.concatenate([[0.0], crossing_sign(centres, loops)]).astype(np.int8)
        self.code = rep[label]
        lb = (ndimage.distance_transform_edt(free) - np.sqrt(2.0)) * h
        self.lb = (np.maximum(lb, 0.0) * (1 - 1e-6)).astype(np.float32)
        self.tree = cKDTree(pts)
        self.spacing = max(float(chords(q).max()) for q in loops)

    def cells(self, x: Float) -> tuple[Bool, Int]:
        """Mask of the points in the grid, and their flat cell indices (0 outside)."""
        u = (x - self.origin) * (1.0 / self.h)
        u0, u1 = u[:, 0], u[:, 1]  # by columns: an all() along a short axis is slow
        inside = (u0 >= 0) & (u1 >= 0) & (u0 < self.shape[0]) & (u1 < self.shape[1])
        with np.errstate(invalid="ignore"):
            k = u[:, 0].astype(np.intp) * self.shape[1] + u[:, 1].astype(np.intp)
        return inside, np.where(inside, k, 0)

    def sign_code(self, x: Float) -> Float:
        """-1 or +1 where the sign is known, 0 where it must be computed exactly."""
        inside, k = self.cells(x)
        return np.where(inside, self.code.ravel()[k], 1).astype(np.float64)

    def lower_bound(self, x: Float, cells: tuple[Bool, Int] | None = None) -> Float:
        """Lower bound of the distance to Gamma, shape ``(n,)`` (``cells``: :meth:`cells` of
        ``x``, if known)."""
        inside, k = self.cells(x) if cells is None else cells
        out = self.lb.ravel()[k].astype(np.float64)
        xo = x[~inside]
        out[~inside] = norm2(np.maximum(np.maximum(self.box[0] - xo, xo - self.box[1]), 0.0))
        return out
