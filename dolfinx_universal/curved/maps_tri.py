"""Curved triangles: the transfinite blend of the closest-point projection (Rangarajan & Lew
2014), the 2D part of :func:`~dolfinx_universal.curved.maps.curved_mesh`.

The same names as :mod:`.maps_tet` (:func:`reference_nodes`, :func:`curved_cells`,
:func:`coordinate_geometry`, :func:`tangents`): the driver picks the module by the cell type.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt
from dolfinx import fem
from dolfinx import mesh as dmesh

from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.conforming.classify import positively_cut
from dolfinx_universal.core.arrays import Bool, Float, Int, lagrange_element, project_together

__all__ = [
    "coordinate_geometry",
    "curved_cells",
    "map_nodes",
    "reference_nodes",
    "tangents",
    "transfinite_map",
]


def reference_nodes(degree: int) -> Float:
    """Barycentric coordinates of the degree-k GLL-warped Lagrange nodes, ``(ndofs, 3)``.

    Column ``i`` is the coordinate of local vertex ``i``; rows follow DOLFINx's node order
    (vertices, edges 0-2, interior).
    """
    p = lagrange_element("triangle", degree).points
    return np.column_stack([1.0 - p.sum(axis=1), p])


def _edge_parameters(lam: Float) -> tuple[Float, Bool, Float, Bool]:
    """Where the blend projects: ``pi(s a + (1 - s) b)`` with ``s = s1`` (first term) and
    ``s = s2`` (second term) at barycentric points ``lam (..., p, 3)``, and whether it must.

    On the positive edge (``l_w = 0``) both terms project the same point: ``s2 = l_u``
    there (``1 - l_v`` up to rounding), so that it is projected once. Vertices and points
    with zero weight are not projected.
    """
    lu, lv, lw = lam[..., 0], lam[..., 1], lam[..., 2]
    at_u, at_v = (1.0 - lu) <= _VERTEX, (1.0 - lv) <= _VERTEX
    return lu, (lv > 0) & ~at_u, np.where(lw == 0, lu, 1.0 - lv), (lu > 0) & ~at_v


_VERTEX = 1e-14
"""Barycentric coordinates within this of 1 are the vertex itself (its exact image)."""


def _combine(lam: Float, pu: Float, pv: Float, mw: Float, p1: Float, p2: Float) -> Float:
    """The blend from the projected points ``p1, p2 (m, p, 2)`` (see :func:`transfinite_map`)."""
    lu, lv, lw = lam[..., 0:1], lam[..., 1:2], lam[..., 2:3]
    pu, pv, mw = pu[:, None, :], pv[:, None, :], mw[:, None, :]
    at_u, at_v = (1.0 - lu) <= _VERTEX, (1.0 - lv) <= _VERTEX
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lv * p1 + lu * lw * pu) / (2.0 * (1.0 - lu))
        t2 = (lu * p2 + lv * lw * pv) / (2.0 * (1.0 - lv))
    g = np.where(at_u, 0.0, t1) + np.where(at_v, 0.0, t2) + lw * mw
    g = np.where(at_u, pu, g)
    return np.where(at_v, pv, g)


def _blend(
    patterns: Float,
    which: npt.NDArray[np.intp],
    edge_u: Float,
    edge_v: Float,
    pi_u: Float,
    pi_v: Float,
    m_w: Float,
    closest_point: Callable[[Float], Float],
) -> Float:
    """:func:`transfinite_map` for cells whose barycentric points are one of a few
    ``patterns (r, p, 3)``: cell ``c`` has ``patterns[which[c]]``.

    Every cell projects the points ``s a + (1 - s) b`` of the edge parameters ``s`` in
    ``(0, 1)`` that its own pattern needs (one per cell at degree 2: the midpoint of the
    positive edge; 4 at degree 3, where the three patterns together have 6), in one call of
    ``closest_point``; ``s = 1`` and ``s = 0`` (the end points) take ``pi_u`` and ``pi_v``,
    which are their projections. A point's projection does not depend on the other points
    of the call, so a cell's nodes do not depend on the patterns of the others.
    """
    m, r = len(edge_u), len(patterns)
    s1, need1, s2, need2 = _edge_parameters(patterns)
    inner = []  # the parameters each pattern projects
    for j in range(r):
        values = np.concatenate([s1[j][need1[j]], s2[j][need2[j]]])
        inner.append(np.unique(values[(values > 0) & (values < 1)]))
    ns = max((len(v) for v in inner), default=0)
    groups = [np.flatnonzero(which == j) for j in range(r)]
    queries = [
        (
            v[None, :, None] * edge_u[g][:, None, :]
            + (1.0 - v)[None, :, None] * edge_v[g][:, None, :]
        )
        for v, g in zip(inner, groups, strict=True)
    ]
    # Per cell: the projections of its parameters (padded to ns), then pi_u (s = 1), pi_v (s = 0).
    ext = np.empty((m, ns + 2, 2))
    for g, proj in zip(groups, project_together(closest_point, queries, 2), strict=True):
        ext[g, : proj.shape[1]] = proj
    ext[:, ns], ext[:, ns + 1] = pi_u, pi_v

    def slot(s: Float, need: Bool) -> npt.NDArray[np.intp]:
        out = np.where(need & (s <= 0), ns + 1, ns)
        for j, v in enumerate(inner):
            if len(v):
                i = np.searchsorted(v, s[j]).clip(0, len(v) - 1)
                out[j] = np.where(need[j] & (v[i] == s[j]), i, out[j])
        return out

    rows = np.arange(m)[:, None]
    p1 = ext[rows, slot(s1, need1)[which]]
    p2 = ext[rows, slot(s2, need2)[which]]
    return _combine(patterns[which], pi_u, pi_v, m_w, p1, p2)


def transfinite_map(
    lam: Float,
    edge_u: Float,
    edge_v: Float,
    pi_u: Float,
    pi_v: Float,
    m_w: Float,
    closest_point: Callable[[Float], Float],
) -> Float:
    """The exactly conforming transfinite blend of Rangarajan & Lew (2014) at barycentric
    points of positively cut cells.

    The blend::

        G(x) = [l_v pi(l_u a + (1-l_u) b) + l_u l_w pi_u] / (2 (1 - l_u))
             + [l_u pi((1-l_v) a + l_v b) + l_v l_w pi_v] / (2 (1 - l_v)) + l_w m_w

    with ``(a, b)`` the edge end points: the background vertices ``(u, v)`` for ``G_h``, their
    images ``(pi(u), pi(v))`` for ``G~_h``. Vertex limits are exact (no 0/0). Each distinct
    point of the edge is projected once (one call of ``closest_point``); the end points
    ``a, b`` are not projected: ``pi_u = pi(a)`` and ``pi_v = pi(b)`` are their projections.

    Parameters
    ----------
    lam
        Barycentric coordinates ``(l_u, l_v, l_w)``, ``(m, p, 3)`` or ``(p, 3)``.
    edge_u, edge_v
        End points of the straight edge to project from, ``(m, 2)``.
    pi_u, pi_v, m_w
        Images of the vertices ``u, v`` (on Gamma: the projections of ``edge_u, edge_v``)
        and ``w``, ``(m, 2)``.
    closest_point
        The projection onto Gamma, ``(n, 2) -> (n, 2)``.

    Returns
    -------
    Images of the points, ``(m, p, 2)``.
    """
    m = len(edge_u)
    one_pattern = np.ndim(lam) == 2  # the same barycentric points in every cell
    if one_pattern:
        return _blend(
            np.asarray(lam, dtype=np.float64)[None], np.zeros(m, dtype=np.intp),
            edge_u, edge_v, pi_u, pi_v, m_w, closest_point,
        )  # fmt: skip
    lam = np.broadcast_to(lam, (m,) + np.shape(lam)[-2:])
    s1, need1, s2, need2 = _edge_parameters(lam)
    a, b = edge_u[:, None, :], edge_v[:, None, :]
    q1 = s1[..., None] * a + (1.0 - s1[..., None]) * b
    q2 = s2[..., None] * a + (1.0 - s2[..., None]) * b
    pts = np.concatenate([q1[need1], q2[need2]])
    proj = np.asarray(closest_point(pts), dtype=np.float64) if len(pts) else pts
    p1, p2 = np.zeros_like(q1), np.zeros_like(q2)
    p1[need1], p2[need2] = proj[: int(need1.sum())], proj[int(need1.sum()) :]
    return _combine(lam, pi_u, pi_v, m_w, p1, p2)


def map_nodes(
    cells: npt.NDArray,
    y: Float,
    x_background: Float,
    sign: Float,
    degree: int,
    kind: str,
    closest_point: Callable[[Float], Float],
) -> Float:
    """Images of the degree-k reference nodes of triangles under ``G_h`` or ``G~_h``.

    Parameters
    ----------
    cells
        Triangles ``(m, 3)`` (process-local vertex indices).
    y
        ``M_h`` images of the vertices ``(num_vertices, 2)``.
    x_background
        Background positions of the vertices ``(num_vertices, 2)``.
    sign
        Vertex signs; cells with exactly one ``-1`` are positively cut and get curved.
    degree
        Lagrange degree of the nodes.
    kind
        ``"G"`` (exactly conforming blend) or ``"G~"`` (through the straight mesh).
    closest_point
        Projection onto Gamma.

    Returns
    -------
    Node coordinates ``(m, ndofs, 2)`` in DOLFINx's node order.
    """
    lam = reference_nodes(degree)
    # Affine images; einsum sums in vertex order: a shared edge node gets the same value
    # from both of its cells (a matmul may not: fused multiply-adds).
    nodes = np.einsum("pi,cid->cpd", lam, y[cells])
    pc = np.flatnonzero(positively_cut(sign, cells))
    if len(pc) == 0:
        return nodes
    k = np.argmin(sign[cells[pc]], axis=1)  # local index of the inside vertex w
    order = np.column_stack([(k + 1) % 3, (k + 2) % 3, k])  # (u, v, w), orientation kept
    rows = np.arange(len(pc))[:, None]
    vid = cells[pc][rows, order]
    patterns = np.stack([lam[:, [(j + 1) % 3, (j + 2) % 3, j]] for j in range(3)])  # (3, p, 3)
    pu, pv, mw = y[vid[:, 0]], y[vid[:, 1]], y[vid[:, 2]]
    if kind == "G":
        a, b = x_background[vid[:, 0]], x_background[vid[:, 1]]
    else:
        a, b = pu, pv
    curved = _blend(patterns, k, a, b, pu, pv, mw, closest_point)
    # On the two straight edges the blend is affine: keep the affine values there, bitwise
    # those of the neighbouring cells (the same result whichever cell writes a shared node).
    straight = ((patterns[..., 0] == 0) | (patterns[..., 1] == 0))[k]
    nodes[pc] = np.where(straight[..., None], nodes[pc], curved)
    return nodes


def curved_cells(
    msh: dmesh.Mesh,
    cells: Int,
    cut: Int,
    positive_facets: Int,
    on_gamma: npt.NDArray[np.bool_],
    sign: Float,
    x_background: Float,
    degree: int,
    kind: str,
    closest_point: Callable[[Float], Float],
    rows: Int | None = None,
) -> tuple[Int, Callable[[Int, Float], Float]]:
    """The cells a curved map changes and the map of their nodes: the positively cut
    triangles ``cut``.

    The arguments are those of :func:`~dolfinx_universal.curved.maps_tet.curved_cells`
    (``msh``, ``positive_facets``, ``on_gamma`` and ``rows`` are not needed for triangles).

    Returns
    -------
    curve
        Indices into ``cells`` of the triangles to curve ``(k,)``.
    map
        ``(cells (k, 3), y (num_vertices, 2)) -> nodes (k, ndofs, 2)``.
    """

    def triangles(chosen: Int, y: Float) -> Float:
        return map_nodes(chosen, y, x_background, sign, degree, kind, closest_point)

    return cut, triangles


def coordinate_geometry(msh: dmesh.Mesh, element: fem.CoordinateElement) -> dmesh.Mesh:
    """``msh`` with the degree-q coordinate ``element``, every cell the affine image of its
    vertices: DOLFINx's :func:`dolfinx.fem.interpolate_geometry` (faster for triangles than
    numbering the nodes from the entities: measured 15 against 17 ms at q = 2, 26 against
    34 ms at q = 3 on 1e5 cells)."""
    return fem.interpolate_geometry(msh, element)


def tangents(boundary: Boundary, y: Float) -> Float:
    """Unit tangents of the curve at its points ``y``, ``(n, 2)``."""
    return boundary.tangent(y)
