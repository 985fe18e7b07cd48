"""Point location in simplices: is Gamma inside the background (the containment check)."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.core.arrays import Bool, Float, Int
from dolfinx_universal.core.collective import Problem

__all__ = [
    "CONTAINMENT_SAMPLES",
    "CellLocator",
    "cells_near_points",
    "containment_problems",
    "containment_samples",
    "missing_samples_problems",
    "points_in_cells",
    "samples_in_stars",
]


def _inside(x: Float, cells: Int, p: Float, tol: float) -> Bool:
    """Whether each point ``p[i]`` lies in the simplex ``cells[i]``: its barycentric
    coordinates all at least ``-tol`` (relative: on a facet up to rounding is inside)."""
    lam = cell_kernels(x.shape[1]).barycentric(x, cells, p)
    d = lam.shape[1]
    rest = 1.0 - lam[:, 0]
    for k in range(1, d):
        rest = rest - lam[:, k]
    return (lam >= -tol).all(axis=1) & (rest >= -tol)


def points_in_cells(x: Float, cells: Int, points: Float, size: float, tol: float = 1e-12) -> Bool:
    """Whether each point lies in one of ``cells`` (of diameter at most ``size``), ``(n,)``.

    :meth:`CellLocator.contains` for many cells and few points, without the locator: on a
    grid of bins of side ``size`` (and 1 %), each point is listed at the bin of its own and
    at the bins one step lower along any axes (``2^d`` keys a point); the low corner of a
    cell's bounding box lies in one of them when the cell contains the point. The cells are
    paired with the points listed at their low corner's bin, the pairs whose point is in
    the box get the barycentric test.

    Parameters
    ----------
    x
        Vertex coordinates ``(num_vertices, d)``.
    cells
        Simplices ``(m, d + 1)``.
    points
        The points ``(n, d)``.
    size
        At least the diameter of every cell.
    tol
        As in :meth:`CellLocator.contains`.
    """
    n, d = points.shape
    found = np.zeros(n, dtype=bool)
    if n == 0 or len(cells) == 0:
        return found
    g = 1.01 * max(float(size), 1e-300)
    origin = points.min(axis=0) - 2.0 * g
    pij = np.floor((points - origin) / g).astype(np.int64)  # >= 2
    dims = pij.max(axis=0) + 2
    strides = np.cumprod(np.concatenate([[1], dims[:0:-1]]))[::-1]
    offsets = np.array(list(np.ndindex(*([2] * d))), dtype=np.int64)
    keys = ((pij[:, None, :] - offsets[None]) @ strides).ravel()  # bins >= 1: no aliasing
    order = np.argsort(keys, kind="stable")
    keys, owner = keys[order], order // len(offsets)
    q = x[cells]  # column by column: reductions along a short axis are slow in numpy
    lo, hi = q[:, 0].copy(), q[:, 0].copy()
    for k in range(1, cells.shape[1]):
        np.minimum(lo, q[:, k], out=lo)
        np.maximum(hi, q[:, k], out=hi)
    # the low corner lowered by 0.5 % of a bin: a point in the cell up to rounding is at
    # most 1 / 1.01 + 0.005 bins above it; clipped into the grid (a clipped cell may get
    # pairs it cannot hold, rejected by the box test)
    i0 = np.floor((lo - origin) / g - 0.005).astype(np.int64)
    ckey = np.clip(i0, 0, dims - 1) @ strides
    start = np.searchsorted(keys, ckey, side="left")
    num = np.searchsorted(keys, ckey, side="right") - start
    c = np.repeat(np.arange(len(cells)), num)
    pt = owner[np.repeat(start, num) + np.arange(len(c)) - np.repeat(np.cumsum(num) - num, num)]
    p = points[pt]
    slack = 1e-9 * g
    lo, hi = lo[c] - slack, hi[c] + slack
    box = (p[:, 0] >= lo[:, 0]) & (p[:, 0] <= hi[:, 0])
    for k in range(1, d):
        box &= (p[:, k] >= lo[:, k]) & (p[:, k] <= hi[:, k])
    c, pt = c[box], pt[box]
    found[pt[_inside(x, cells[c], points[pt], tol)]] = True
    return found


def samples_in_stars(
    x: Float,
    near_vertex: Bool,
    v2c_offsets: Int,
    v2c: Int,
    cells: Int,
    points: Float,
    size: float,
    tol: float = 1e-12,
) -> tuple[Bool, Bool]:
    """Which points lie in a cell at their nearest flagged vertex; which are left to search.

    A cell containing a point has its vertices within its diameter (at most ``size``) of
    it, all flagged when ``near_vertex`` flags every vertex of such cells: a point farther
    than ``size`` from every flagged vertex is in no cell. The others are tested against
    the cells around their nearest flagged vertex (on lattices and Delaunay meshes almost
    always one of them holds the point); those left get the exhaustive search
    (:func:`cells_near_points`, :func:`points_in_cells`).

    Parameters
    ----------
    x
        Vertex coordinates ``(num_vertices, d)``.
    near_vertex
        The flagged vertices ``(num_vertices,)``.
    v2c_offsets, v2c
        Vertex -> cell adjacency list.
    cells
        Cell -> vertex connectivity ``(num_cells, d + 1)``.
    points
        The points ``(n, d)``.
    size
        At least the diameter of every cell with all vertices flagged.
    tol
        As in :meth:`CellLocator.contains`.

    Returns
    -------
    found
        Points in a cell at their nearest flagged vertex ``(n,)``.
    left
        Points within ``size`` of a flagged vertex but not found ``(n,)``.
    """
    from scipy.spatial import cKDTree

    n = len(points)
    v = np.flatnonzero(near_vertex)
    found = np.zeros(n, dtype=bool)
    if len(v) == 0 or n == 0:
        return found, found.copy()
    tree = cKDTree(x[v], balanced_tree=False, compact_nodes=False)  # built for one query
    dist, i = tree.query(points, distance_upper_bound=1.01 * max(float(size), 1e-300))
    close = np.isfinite(dist)
    pid, vid = np.flatnonzero(close), v[i[close]]
    start = v2c_offsets[vid]
    num = v2c_offsets[vid + 1] - start
    pt = np.repeat(pid, num)
    c = v2c[np.repeat(start, num) + np.arange(len(pt)) - np.repeat(np.cumsum(num) - num, num)]
    found[pt[_inside(x, cells[c], points[pt], tol)]] = True
    return found, close & ~found


class CellLocator:
    """Which cells (triangles or tetrahedra) contain given points: bins about a cell wide
    over the cells' bounding boxes, hashed sparsely (only the bins that cells touch are
    stored), built once for a fixed mesh (process-local, owned and ghost cells).

    Parameters
    ----------
    x
        Vertex coordinates ``(num_vertices, d)``.
    cells
        Simplices as vertex indices ``(num_cells, d + 1)``.
    """

    def __init__(self, x: Float, cells: Int) -> None:
        self.x, self.cells = x, cells
        d = x.shape[1]
        corners = x[cells]  # (m, d + 1, d)
        lo, hi = corners.min(axis=1), corners.max(axis=1)
        m = len(cells)
        self.origin = lo.min(axis=0) if m else np.zeros(d)
        extent = (hi - lo).max(axis=1) if m else np.ones(1)
        # bins about the size of a typical cell (twice that for tetrahedra): each cell spans
        # a few bins
        scale = cell_kernels(d).locator_bin
        self.g = g = scale * float(max(np.median(extent), 1e-300)) if m else 1.0
        i0 = np.floor((lo - self.origin) / g).astype(np.int64)
        i1 = np.floor((hi - self.origin) / g).astype(np.int64)
        self.shape = (i1.max(axis=0) + 1) if m else np.ones(d, dtype=np.int64)
        self.strides = np.cumprod(np.concatenate([[1], self.shape[:0:-1]]))[::-1]
        n = i1 - i0 + 1  # bins per axis of each cell
        count = n.prod(axis=1)
        cell = np.repeat(np.arange(m), count)
        k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
        key = np.zeros(len(cell), dtype=np.int64)
        for axis in range(d - 1, -1, -1):  # the bins of each cell's box, last axis fastest
            key += (i0[cell, axis] + k % n[cell, axis]) * self.strides[axis]
            k = k // n[cell, axis]
        order = np.argsort(key, kind="stable")
        self.bin_cells = cell[order].astype(np.int32)
        key = key[order]
        starts = np.flatnonzero(np.diff(key, prepend=-1))  # the first entry of each bin
        self.keys = key[starts]
        self.offsets = np.append(starts, len(key)).astype(np.int64)

    def contains(self, points: Float, allowed: Bool | None = None, tol: float = 1e-12) -> Bool:
        """Whether each point lies in a cell (among the ``allowed`` ones), ``(n,)``.

        A point counts as inside when its barycentric coordinates are all at least
        ``-tol`` (relative: on a facet up to rounding is inside).
        """
        n, d = points.shape
        if len(self.keys) == 0:  # no cell on this rank
            return np.zeros(n, dtype=bool)
        ij = np.floor((points - self.origin) / self.g).astype(np.int64)
        ok = (ij >= 0).all(axis=1) & (ij < self.shape).all(axis=1)
        key = np.where(ok, ij @ self.strides, -1)
        slot = np.minimum(np.searchsorted(self.keys, key), len(self.keys) - 1)
        ok &= self.keys[slot] == key
        start, stop = self.offsets[slot], self.offsets[slot + 1]
        num = np.where(ok, stop - start, 0)
        pt = np.repeat(np.arange(n), num)
        c = self.bin_cells[
            np.repeat(start, num) + np.arange(int(num.sum())) - np.repeat(np.cumsum(num) - num, num)
        ]
        if allowed is not None:
            keep = allowed[c]
            pt, c = pt[keep], c[keep]
        inside = _inside(self.x, self.cells[c], points[pt], tol)
        found = np.zeros(n, dtype=bool)
        found[pt[inside]] = True
        return found


CONTAINMENT_SAMPLES = 2048
"""Most samples of Gamma the containment check locates: all the dense samples of the
Gamma_h checks (a quarter / half of the mesh size apart) up to this many, else every
``k``-th of them. Locating 2048 points costs about 2 ms (1.3 ms for 512)."""


def containment_samples(points: Float) -> Float:
    """Every ``k``-th of the ordered samples ``points (n, gdim)`` of Gamma, at most about
    :data:`CONTAINMENT_SAMPLES` of them: the points :func:`containment_problems` locates."""
    return points[:: max(1, -(-len(points) // CONTAINMENT_SAMPLES))]


def cells_near_points(
    x: Float, cells: Int, near_vertex: Bool, points: Float, size: float
) -> npt.NDArray[np.intp]:
    """Rows of ``cells`` that may contain one of ``points``: a superset, cheap to find.

    A cell containing a point ``p`` has all its vertices within its diameter of ``p``, at
    most ``size``: on a grid of bins of side ``size`` (and 1 % more, for points on a facet
    up to rounding), each vertex's bin is next to ``p``'s along every axis. The vertices
    flagged ``near_vertex`` in the bins next to the points' bins are marked, and the cells
    with all vertices marked are returned. A :class:`CellLocator` of these few cells then
    answers exactly what one of all ``cells`` would.

    Parameters
    ----------
    x
        Vertex coordinates ``(num_vertices, d)``.
    cells
        Cells as vertex indices ``(m, d + 1)``.
    near_vertex
        Vertices that may belong to a cell containing a point ``(num_vertices,)`` (a cell
        with an unflagged vertex is left out).
    points
        The points ``(n, d)``.
    size
        At least the diameter of every cell with all vertices flagged.
    """
    v = np.flatnonzero(near_vertex)
    if len(v) == 0 or len(points) == 0 or len(cells) == 0:
        return np.zeros(0, dtype=np.intp)
    d = x.shape[1]
    g = 1.01 * max(float(size), 1e-300)
    origin = points.min(axis=0) - 2.0 * g
    pij = np.floor((points - origin) / g).astype(np.int64)  # >= 2 on every axis
    dims = pij.max(axis=0) + 3
    strides = np.cumprod(np.concatenate([[1], dims[:0:-1]]))[::-1]
    offsets = np.stack(np.meshgrid(*([np.arange(-1, 2)] * d), indexing="ij"), -1).reshape(-1, d)
    keys = np.sort(((pij[:, None, :] + offsets[None]) @ strides).ravel())
    vij = np.floor((x[v] - origin) / g).astype(np.int64)
    ok = (vij >= 0).all(axis=1) & (vij < dims).all(axis=1)
    vkey = vij @ strides
    slot = np.minimum(np.searchsorted(keys, vkey), len(keys) - 1)
    mark = np.zeros(len(near_vertex), dtype=bool)
    mark[v[ok & (keys[slot] == vkey)]] = True
    inside = mark[cells[:, 0]]
    for k in range(1, cells.shape[1]):
        inside &= mark[cells[:, k]]
    return np.flatnonzero(inside)


def containment_problems(
    locator: CellLocator, pts: Float, cells: npt.NDArray[np.int32], comm: MPI.Comm
) -> list[Problem]:
    """Points of Gamma that lie in none of ``cells`` of the background (collective).

    Parameters
    ----------
    locator
        A :class:`CellLocator` of all local background cells, built once and reused (the
        search is restricted to ``cells``).
    pts
        Samples of Gamma (the same on every rank, :func:`containment_samples`) ``(n, gdim)``.
    cells
        Background cells to search (those near Gamma) ``(m,)``.
    comm
        Communicator of the mesh.

    Returns
    -------
    The problem on rank 0 when samples of Gamma are in no cell of any rank, else empty.
    """
    allowed = np.zeros(len(locator.cells), dtype=bool)
    allowed[cells] = True
    return missing_samples_problems(comm, pts, locator.contains(pts, allowed))


def missing_samples_problems(comm: MPI.Comm, pts: Float, found: Bool) -> list[Problem]:
    """The problem (on rank 0) of the samples ``pts`` of Gamma that no rank ``found`` in its
    cells, else empty (collective)."""
    found = found.astype(np.int32)
    found = comm.allreduce(found, op=MPI.SUM) if comm.size > 1 else found
    missing = pts[found == 0]
    if len(missing) and comm.rank == 0:
        return [
            Problem(
                "the immersed boundary leaves the background mesh near {where}: enlarge the "
                "background so that it contains the domain's boundary",
                missing,
                len(missing),
                refinable=False,
            )
        ]
    return []
