"""Validity checks of a conforming mesh: classification, containment, Gamma_h, output, quality."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.cells.tet import (
    EDGES,
    _soa_corners,
    _soa_cross,
    _soa_det6,
    _soa_dihedral,
    _soa_dot,
    _soa_sq,
    _soa_sub,
)
from dolfinx_universal.conforming.classify import conditioning_angle, proximal_vertex
from dolfinx_universal.core.arrays import Bool, Float, Int
from dolfinx_universal.core.collective import MeshingError, Problem, collective_call, where

if TYPE_CHECKING:
    from dolfinx_universal.boundaries.curves import Boundary
    from dolfinx_universal.conforming.snap import PositiveFacets
    from dolfinx_universal.sizing.fields import CurveSamples

__all__ = [
    "TOPOLOGY_MESSAGES",
    "CellLocator",
    "TopologyMessages",
    "CONTAINMENT_SAMPLES",
    "cells_near_points",
    "classification_problems",
    "containment_problems",
    "conforming_problems",
    "gamma_h_topology",
    "low_quality_cells",
    "missing_samples_problems",
    "points_in_cells",
    "require_kept",
    "samples_in_stars",
    "tet_measures",
]


def require_kept(comm: MPI.Comm, kept_owned: Bool, boundary: Boundary) -> None:
    """Raise unless some rank keeps a cell, i.e. some background vertex lies inside (collective).

    Parameters
    ----------
    comm
        Communicator of the mesh.
    kept_owned
        Kept flags of this rank's owned cells ``(num_owned_cells,)``.
    boundary
        The domain (sampled for the places of the error).

    Raises
    ------
    MeshingError
        On every rank, when no rank keeps a cell.
    """
    if comm.allreduce(int(np.count_nonzero(kept_owned))) == 0:
        raise MeshingError(
            "no background vertex lies inside the domain: the domain is outside the "
            "background mesh or smaller than its triangles; move or refine the background",
            collective_call(comm, "sampling the boundary", boundary.sample, 64),
        )


def classification_problems(
    xp: Float,
    s: Float,
    phi: Float,
    edges: PositiveFacets,
    c2v: Int,
    c2f: Int,
    f2c_offsets: Int,
    f2c: Int,
    num_owned_vertices: int,
    x0: Float | None = None,
) -> tuple[list[Problem], float]:
    """Local problems with the classification: the conditions of the method.

    Parameters
    ----------
    xp, s, phi
        Perturbed vertex positions ``(num_vertices, 2)``, final signs and signed distances
        ``(num_vertices,)``.
    edges
        Positive edges and incidence counts (:func:`~dolfinx_universal.conforming.snap.gamma_h`).
    c2v, c2f
        Cell -> vertex and cell -> facet connectivity of the background ``(num_cells, 3)``.
    f2c_offsets, f2c
        Facet -> cell adjacency list (offsets ``(num_facets + 1,)`` and cells).
    num_owned_vertices
        Number of owned vertices (the first ones).
    x0
        Unperturbed background positions (tetrahedra: the conditioning test is a property
        of the background cells); ``xp`` if None.

    Returns
    -------
    problems
        This rank's problems.
    theta_max
        The largest conditioning angle (radians, 0 without positively cut cells).
    """
    pc_owned, w = edges.cells, edges.w
    kernels = cell_kernels(c2v.shape[1] - 1)
    tdim, cells, facet = kernels.tdim, kernels.plural, kernels.facet_name
    problems = []
    theta_max = 0.0
    if len(pc_owned):
        if tdim == 2:
            u, v = edges.u, edges.v
            theta = conditioning_angle(xp, phi, u, v, w)
            bad = theta >= np.pi / 2 - 1e-12
            places = xp[proximal_vertex(xp, phi, u[bad], v[bad], w[bad])] if bad.any() else xp[:0]
            text = (
                "conditioning angle of 90 degrees or more in {count} positively cut "
                "triangles near {where}: use a background mesh that is acute near the "
                "boundary (e.g. equilateral or graded_mesh)"
            )
        else:
            from dolfinx_universal.conforming.checks_tet import (
                conditioning_dihedral,  # (gamma_tet imports this module)
            )

            # a property of the background cells: their unperturbed positions
            theta = conditioning_dihedral(x0 if x0 is not None else xp, edges.facets, w)
            bad = theta > np.pi / 2 + 1e-9  # right angles (BCC) allowed up to rounding
            places = xp[edges.facets[bad]].mean(axis=1)
            text = (
                "dihedral angle above 90 degrees at the positive face of {count} positively "
                "cut tetrahedra near {where}: use a background mesh that is non-obtuse near "
                "the boundary (e.g. a15_mesh or bcc_mesh)"
            )
        theta_max = float(theta.max())
        if bad.any():
            problems.append(Problem(text, places, int(bad.sum())))

        # The positive facet is the facet opposite the inside vertex.
        def centre(rows: npt.NDArray[np.intp]) -> Float:
            return xp[edges.facets[rows]].mean(axis=1)

        k = np.argmin(s[c2v[pc_owned]], axis=1)
        f = c2f[pc_owned, k]
        off = f2c_offsets
        ncell = off[f + 1] - off[f]
        lone = ncell == 1
        if lone.any():
            problems.append(
                Problem(
                    "the domain reaches the boundary of the background mesh near {where}: "
                    "enlarge the background",
                    centre(np.flatnonzero(lone)),
                    int(lone.sum()),
                    refinable=False,
                )
            )
        two = np.flatnonzero(ncell == 2)
        c0, c1 = f2c[off[f[two]]], f2c[off[f[two]] + 1]
        other = np.where(c0 == pc_owned[two], c1, c0)
        shared = two[edges.kept[other]]
        if len(shared):
            problems.append(
                Problem(
                    f"Gamma crosses both {cells} beside the positive {facet} near {{where}} (a "
                    "thin part of the domain or of its exterior): the background is too "
                    "coarse there, refine near it",
                    centre(shared),
                    len(shared),
                )
            )
    nvo = num_owned_vertices
    count, in_kept = edges.count[:nvo], edges.in_kept[:nvo]
    # Triangles: two positive edges at every vertex of Gamma_h (closed simple curves); the
    # surface of positive faces (tetrahedra) is checked by gamma_tet.surface_topology.
    chain = (count > 0) & (count != 2) if tdim == 2 else np.zeros(nvo, dtype=bool)
    lost = in_kept & (s[:nvo] > 0) & (count == 0)
    for bad, text in (
        (
            chain,
            "Gamma_h (the union of positive edges) is not a set of closed simple curves at "
            "vertices {where}: the background is too coarse for the boundary's curvature "
            "or for the gap between its parts there; refine near them",
        ),
        (
            lost,
            f"vertices outside the domain at {{where}} belong to kept {cells} but to no "
            f"positive {facet}, so they would not be snapped: Gamma is under-resolved there; "
            "refine the background near them",
        ),
    ):
        if bad.any():
            problems.append(Problem(text, xp[:nvo][bad], int(bad.sum())))
    return problems, theta_max


def _inside(x: Float, cells: Int, p: Float, tol: float) -> Bool:
    """Whether each point ``p[i]`` lies in the simplex ``cells[i]``: its barycentric
    coordinates all at least ``-tol`` (relative: on a facet up to rounding is inside)."""
    d = x.shape[1]
    if d == 2:
        a = x[cells[:, 0]]
        b, e = x[cells[:, 1]] - a, x[cells[:, 2]] - a
        q = p - a
        det = b[:, 0] * e[:, 1] - e[:, 0] * b[:, 1]
        l1 = q[:, 0] * e[:, 1] - e[:, 0] * q[:, 1]
        l2 = b[:, 0] * q[:, 1] - q[:, 0] * b[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = np.column_stack([l1 / det, l2 / det])
    else:  # Cramer's rule on coordinate columns (np.linalg on (k, 3, 3) is slower)
        xt = [x[:, i] for i in range(3)]
        av = [xt[i][cells[:, 0]] for i in range(3)]
        e1, e2, e3 = ([xt[i][cells[:, k]] - av[i] for i in range(3)] for k in (1, 2, 3))
        pa = [p[:, i] - av[i] for i in range(3)]
        n1, n2, n3 = _soa_cross(e2, e3), _soa_cross(e3, e1), _soa_cross(e1, e2)
        det = _soa_dot(e1, n1)
        ok_det = np.abs(det) > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = np.column_stack([_soa_dot(pa, n) / det for n in (n1, n2, n3)])
        lam[~ok_det] = -np.inf
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
        # bins about the size of a typical cell (twice that in 3D): each cell spans a few
        # bins (at most 2 per axis in 3D, where 3 per axis would mean up to 27 entries)
        scale = 1.0 if d == 2 else 2.0
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


class TetMeasures(NamedTuple):
    """What the output checks measure of the moved tetrahedra, computed once
    (:func:`tet_measures`) for :func:`conforming_problems` and :func:`low_quality_cells`."""

    cells: Int
    """The moved cells ``(m, 4)``."""
    volume0: Float
    """Signed volumes in the background ``(m,)``."""
    volume: Float
    """Signed volumes of the images ``(m,)``."""
    diameter0: Float
    """Longest edges in the background ``(m,)``."""
    angles: Float
    """Dihedral angles (radians) of the images ``(m, 6)``."""


def tet_measures(x: Float, y: Float, moved: Bool, cells: Int) -> TetMeasures:
    """Volumes, diameters and dihedral angles of the moved tetrahedra among ``cells``.

    The arithmetic of :func:`~dolfinx_universal.cells.tet.signed_volumes`,
    :func:`~dolfinx_universal.cells.tet.cell_diameters` and
    :func:`~dolfinx_universal.cells.tet.dihedral_angles` (bitwise the same values), in
    one pass: the moved cells selected once, each corner gathered once per position array,
    and the images' volumes shared by the inversion test and the angles.

    Parameters
    ----------
    x, y
        Background vertex positions and their images ``(num_vertices, 3)``.
    moved
        Vertices whose image differs from their position ``(num_vertices,)``.
    cells
        Kept tetrahedra that may have moved ``(k, 4)``.
    """
    mv = moved[cells[:, 0]]
    for k in range(1, 4):
        mv |= moved[cells[:, k]]
    cells = cells[mv]
    q, p = _soa_corners(x, cells), _soa_corners(y, cells)
    d2 = np.zeros(len(cells))
    for i, j in EDGES:  # the longest edge, by squared lengths (sqrt is monotone)
        np.maximum(d2, _soa_sq(_soa_sub(q[j], q[i])), out=d2)
    v6 = _soa_det6(p)
    angles = _soa_dihedral(p, v6)
    return TetMeasures(cells, _soa_det6(q) / 6.0, v6 / 6.0, np.sqrt(d2), angles)


def conforming_problems(
    x: Float,
    y: Float,
    moved: Bool,
    cells: Int,
    in_kept: Bool,
    outer_vertices: Int,
    measures: TetMeasures | None = None,
) -> list[Problem]:
    """Local problems with the conforming triangles: inversion, degeneracy, moved outer boundary.

    Parameters
    ----------
    x, y
        Background vertex positions and their images ``M_h(x)`` ``(num_vertices, 2)``.
    moved
        Vertices whose image differs from their position ``(num_vertices,)``.
    cells
        Kept triangles that may have moved (those near Gamma) ``(m, 3)``.
    in_kept
        Vertices of kept triangles near Gamma ``(num_vertices,)``.
    outer_vertices
        Vertices on the boundary of the background ``(k,)``.
    measures
        Tetrahedra: :func:`tet_measures` of ``cells``, if computed already.

    Returns
    -------
    This rank's problems.
    """
    problems = []
    k = cell_kernels(cells.shape[1] - 1)
    if measures is not None:
        cells, a0, a1, d = measures[:4]
    else:
        cells = cells[moved[cells].any(axis=1)]  # unmoved cells keep their shape
        a0, a1 = k.signed_measures(x, cells), k.signed_measures(y, cells)
        d = k.cell_diameters(x, cells)
    # degenerate: measure below 1e-10 of the diameter's square or cube (relative)
    inverted = (np.sign(a1) != np.sign(a0)) | (np.abs(a1) <= 1e-10 * d**k.tdim)
    if inverted.any():
        centre = y[cells[inverted]].mean(axis=1)
        problems.append(
            Problem(
                f"{{count}} conforming {k.plural} would be inverted or degenerate near {{where}}: "
                "the background is too coarse or not acute there; refine near those points "
                "or use an acute (e.g. equilateral or A15) background",
                centre,
                int(inverted.sum()),
            )
        )
    ev = outer_vertices
    shifted = ev[in_kept[ev] & moved[ev]]
    if len(shifted):
        problems.append(
            Problem(
                "the boundary of the background mesh would move at {where}: Gamma comes "
                "within R_r of it there; enlarge the background or reduce R_r",
                x[shifted],
                len(shifted),
                refinable=False,
            )
        )
    return problems


class TopologyMessages(NamedTuple):
    """The messages of the Gamma_h topology checks of both dimensions, in one place:
    :func:`gamma_h_topology` (triangles: loops of positive edges following curves) and
    :func:`~dolfinx_universal.conforming.checks_tet.surface_topology` (tetrahedra: closed pieces of
    positive faces following surfaces). Each returns a :class:`Problem` template
    (``{where}`` and ``{count}`` filled in by :func:`raise_collective`)."""

    part: str
    """A connected part of Gamma: "curve" or "surface"."""
    facet: str
    """"edge" or "face"."""
    loop: str
    """A closed part of Gamma_h: "loop" or "piece"."""
    cells: str
    """"triangles" or "tetrahedra"."""

    def empty(self, num_parts: int) -> str:
        return (
            f"Gamma_h is empty: no positive {self.facet} follows any of the {num_parts} "
            f"{self.part}s of the boundary near {{where}}; the background is too coarse for "
            "the domain there; refine near those points"
        )

    def joined(self, pairs: list[tuple[int, int]]) -> str:
        """Parts ``(i, j)`` of Gamma followed by one closed part of Gamma_h."""
        names = ", ".join(f"{i} and {j}" for i, j in pairs[:3])
        return (
            f"Gamma_h joins different {self.part}s of the boundary ({self.part}s {names}) "
            "near {where}: the gap between them is not resolved by the background; refine "
            "to below the gap there"
        )

    def lost(self, k: int, first: Float) -> str:
        """Part ``k`` of Gamma followed by nothing (``first``: one of its samples)."""
        return (
            f"{self.part} {k} of the boundary (near {where(first)}) is lost: no {self.loop} "
            "of Gamma_h follows it, so the mesh would ignore that part of the boundary (a "
            f"body or feature smaller than the background's {self.cells}); refine the "
            "background near it (places: {where})"
        )

    def split(self, k: int, n: int) -> str:
        """Part ``k`` of Gamma followed by ``n`` closed parts of Gamma_h."""
        return (
            f"{self.part} {k} of the boundary is split into {n} {self.loop}s of Gamma_h: a "
            "neck or thin part of the domain (or a gap) is narrower than the background's "
            f"{self.cells} near {{where}}; refine the background there"
        )

    def wrong_side(self, k: int) -> str:
        return (
            f"Gamma_h around {self.part} {k} keeps the wrong side of it near {{where}}: the "
            "background is too coarse for the domain there; refine near it"
        )

    def pieces(self, pieces: int, expected: int) -> str:
        return (
            f"the kept {self.cells} form {pieces} connected pieces where the domain has "
            f"{expected}, near {{where}}: refine the background near them"
        )


TOPOLOGY_MESSAGES = {
    2: TopologyMessages("curve", "edge", "loop", "triangles"),
    3: TopologyMessages("surface", "face", "piece", "tetrahedra"),
}
"""The messages of the Gamma_h topology checks by topological dimension."""


def _loops(gids: npt.NDArray[np.int64]) -> tuple[int, npt.NDArray[np.int64]]:
    """Connected components of the graph of edges ``gids (m, 2)``: ``(count, label per edge)``,
    labelled in the order of their smallest node (as scipy's ``connected_components``).

    Where every node has one edge leaving and one entering (Gamma_h once every vertex on it
    has two positive edges, each edge oriented with its kept cell on the left), the
    components are cycles of the successor map, labelled by pointer doubling in ``log2`` of
    the longest cycle's length; otherwise by scipy's graph search.
    """
    nodes, inv = np.unique(gids, return_inverse=True)
    inv = inv.reshape(-1, 2)
    n, m = len(nodes), len(inv)
    tail, head = inv[:, 0], inv[:, 1]
    out_edge = np.full(n, -1, dtype=np.int64)
    out_edge[tail] = np.arange(m)
    if m == n and np.array_equal(np.sort(tail), np.arange(n)) and (out_edge[head] >= 0).all():
        succ = out_edge[head]  # a permutation of the edges: a union of cycles
        low = np.minimum(tail, head)  # smallest node of each cycle, by doubling
        for _ in range(max(1, int(np.ceil(np.log2(max(m, 2)))))):
            low = np.minimum(low, low[succ])
            succ = succ[succ]
        roots, label = np.unique(low, return_inverse=True)
        return len(roots), label.astype(np.int64)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(m), (tail, head)), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    return int(count), label[tail]


def gamma_h_topology(
    comm: MPI.Comm,
    edges_global: npt.NDArray[np.int64],
    pu: Float,
    pv: Float,
    pw: Float,
    samples: CurveSamples,
    far_kept: bool,
) -> tuple[list[Problem], int, int]:
    """Check that Gamma_h has one closed loop per curve of Gamma, with the domain's side kept.

    Gamma_h (the union of positive edges) is a union of disjoint closed polygons once every
    vertex on it has two positive edges (checked locally). Each polygon must follow exactly
    one curve of Gamma (every edge's nearest curve the same), each curve must be followed by
    exactly one polygon, and the kept cells must lie on the side of the polygon where the
    domain lies. Then the kept region has as many connected pieces as the domain: each kept
    piece is bounded from outside by one polygon around which it lies inside, except the
    piece touching the background's boundary. A feature thinner than the background (a
    body between two lattice rows, a neck) breaks one of these. Collective; the edges are
    gathered on rank 0 (their number grows with the boundary, not with the mesh).

    Parameters
    ----------
    comm
        Communicator of the mesh.
    edges_global
        Positive edges of this rank's owned positively cut cells as global vertex indices
        ``(m, 2)``; each positive edge is listed by exactly one rank.
    pu, pv, pw
        Coordinates of the edge end points and of the cells' inside vertices ``(m, 2)``.
    samples
        Dense samples of Gamma with curve labels
        (:func:`~dolfinx_universal.sizing.fields.curve_samples`).
    far_kept
        Whether kept cells touch the boundary of the background (same on every rank).

    Returns
    -------
    problems
        Problems found, on rank 0 (empty lists elsewhere).
    num_loops, num_pieces
        Loops of Gamma_h and connected pieces of the kept region (every rank).
    """
    data = comm.gather((edges_global, pu, pv, pw), root=0)
    result: tuple[list[Problem], int, int] = ([], 0, 0)
    if comm.rank == 0:
        assert data is not None  # gather returns the list on the root
        result = _topology(data, samples, far_kept)
    counts = comm.bcast(result[1:], root=0)
    return result[0], counts[0], counts[1]


def _topology(data: list, samples: CurveSamples, far_kept: bool) -> tuple[list[Problem], int, int]:
    """:func:`gamma_h_topology` on the gathered edges (rank 0)."""
    g = np.concatenate([d[0] for d in data]).reshape(-1, 2)
    a = np.concatenate([d[1] for d in data]).reshape(-1, 2)
    b = np.concatenate([d[2] for d in data]).reshape(-1, 2)
    c = np.concatenate([d[3] for d in data]).reshape(-1, 2)
    ncurves = samples.num_curves
    messages = TOPOLOGY_MESSAGES[2]
    problems: list[Problem] = []
    if len(g) == 0:
        return (
            [Problem(messages.empty(ncurves), samples.points)],
            0,
            int(far_kept),
        )
    from scipy.spatial import cKDTree

    # Orient each edge with its kept cell on the left.
    d, e = b - a, c - a
    left = d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0] > 0
    a, b = np.where(left[:, None], a, b), np.where(left[:, None], b, a)
    nloops, loop = _loops(np.where(left[:, None], g, g[:, ::-1]))
    area = np.bincount(loop, a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], minlength=nloops) / 2
    mid = 0.5 * (a + b)
    if ncurves == 1:
        curve = np.zeros(len(mid), dtype=np.intp)
    else:
        curve = samples.labels[cKDTree(samples.points).query(mid)[1]]
    # The curve of each loop: the most frequent label among its edges.
    counts = np.zeros((nloops, ncurves), dtype=np.int64)
    np.add.at(counts, (loop, curve), 1)
    main = counts.argmax(axis=1)
    mixed = curve != main[loop]
    if mixed.any():
        pairs = sorted({(int(main[k]), int(j)) for k, j in zip(loop[mixed], curve[mixed])})
        problems.append(Problem(messages.joined(pairs), mid[mixed], int(mixed.sum())))
    per_curve = np.bincount(main, minlength=ncurves)
    for k in np.flatnonzero(per_curve != 1):
        pts = samples.points[samples.labels == k]
        if per_curve[k] == 0:
            text = messages.lost(int(k), pts[:1])
        else:
            text = messages.split(int(k), int(per_curve[k]))
            sel = np.isin(loop, np.flatnonzero(main == k))
            pts = _pinch_points(mid[sel], loop[sel], pts)
        problems.append(Problem(text, pts))
    inside = area > 0
    wrong = inside != samples.encloses_domain[main]
    for k in np.flatnonzero(wrong):
        problems.append(
            Problem(
                messages.wrong_side(int(main[k])),
                mid[loop == k],
            )
        )
    pieces = int(inside.sum()) + int(far_kept)
    if not problems and pieces != samples.expected_pieces:
        problems.append(Problem(messages.pieces(pieces, samples.expected_pieces), mid))
    return problems, nloops, pieces


def _pinch_points(mid: Float, loop: npt.NDArray[np.int64], fallback: Float) -> Float:
    """Places where different loops of one curve come closest to each other (necks)."""
    from scipy.spatial import cKDTree

    ids = np.unique(loop)
    if len(ids) < 2:
        return fallback
    out = []
    for k in ids:  # a handful of loops
        mine, other = mid[loop == k], mid[loop != k]
        dist, _ = cKDTree(other).query(mine)
        out.append(mine[dist <= 1.5 * dist.min() + 1e-300])
    return np.concatenate(out)


def low_quality_cells(
    y: Float, cells: npt.NDArray, min_angle_deg: float, angles: Float | None = None
) -> tuple[Problem | None, float, float]:
    """Conforming cells whose smallest angle (dihedral angle in 3D) is below a floor.

    Parameters
    ----------
    y
        Vertex positions of the conforming mesh ``(num_vertices, gdim)``.
    cells
        Cells to check ``(m, tdim + 1)`` (the moved ones: the others keep the background's
        angles).
    min_angle_deg
        The floor in degrees (0 disables the check).
    angles
        The cells' angles in radians, if computed already (:func:`tet_measures`).

    Returns
    -------
    problem
        A report of the cells below the floor, or None.
    theta_min, theta_max
        Smallest and largest angle (degrees) of these cells (180 and 0 when there are none).
    """
    if len(cells) == 0:
        return None, 180.0, 0.0
    k = cell_kernels(cells.shape[1] - 1)
    ang = np.degrees(k.angles(y, cells) if angles is None else angles)
    small = ang[:, 0].copy()  # column by column: reductions along a short axis are slow
    for j in range(1, ang.shape[1]):
        np.minimum(small, ang[:, j], out=small)
    lo, hi = float(small.min()), float(ang.max())
    bad = small < min_angle_deg
    if not bad.any():
        return None, lo, hi
    what = "an angle" if k.tdim == 2 else "a dihedral angle"
    problem = Problem(
        f"{{count}} conforming {k.plural} have {what} below the quality floor of "
        f"{min_angle_deg:g} degrees near {{where}}: refine the background there (or lower "
        "min_angle)",
        y[cells[bad]].mean(axis=1),
        int(bad.sum()),
    )
    return problem, lo, hi
