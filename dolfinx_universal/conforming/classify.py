"""Classification of a background mesh against a domain, and the straight map M_h.

Pure numpy on process-local arrays: ``x`` are vertex coordinates ``(num_vertices, gdim)``,
``cells`` vertex indices ``(num_cells, tdim + 1)`` (triangles or tetrahedra), ``s`` vertex
signs (-1 inside, +1 outside or on Gamma), ``phi`` signed distances. Only the signs at
vertices are used to classify.
The triangle geometry (``signed_areas``, ``cell_diameters``, ``interior_angles``) lives in
:mod:`dolfinx_universal.core.arrays` and is re-exported here.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from dolfinx_universal.cells.tri import cell_diameters, interior_angles, signed_areas
from dolfinx_universal.core.arrays import Bool, Float, Int

__all__ = [
    "cell_diameters",
    "FACET_ORDER",
    "conditioning_angle",
    "interior_angles",
    "inward_push",
    "kept_cells",
    "perturbation_candidates",
    "positive_edges",
    "positive_facets",
    "positively_cut",
    "proximal_vertex",
    "shifted_vertices",
    "signed_areas",
    "straight_map",
]


FACET_ORDER = {
    2: np.array([[1, 2], [2, 0], [0, 1]]),
    3: np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]),
}
"""Row ``k``: the vertices of the facet opposite local vertex ``k`` of a simplex, ordered so
that ``(k, *row)`` is an even permutation of the cell's vertices. A positive facet listed in
this order keeps the orientation of its cell: its normal (the right-hand rule in 3D, the
clockwise turn of the edge in 2D) points away from the inside vertex, out of the domain."""


def positively_cut(s: Float, cells: Int) -> Bool:
    """Cells with ``s = -1`` at exactly one vertex (``s = +1`` at the others), ``(num_cells,)``.

    Their facet opposite the inside vertex is a positive facet (edge of a triangle, face of a
    tetrahedron)."""
    pos = s > 0  # counted column by column: a sum along a short axis is slow in numpy
    count = pos[cells[:, 0]].astype(np.int8)
    for k in range(1, cells.shape[1]):
        count += pos[cells[:, k]]
    return count == cells.shape[1] - 1


def kept_cells(s: Float, cells: Int) -> Bool:
    """Cells of ``T_h^sub``: ``s = -1`` at one vertex or more, shape ``(num_cells,)``."""
    neg = s < 0
    kept = neg[cells[:, 0]] | neg[cells[:, 1]]
    for k in range(2, cells.shape[1]):
        kept |= neg[cells[:, k]]
    return kept


def positive_facets(s: Float, cells: Int) -> tuple[Int, Int]:
    """Positive facets of the positively cut cells among ``cells``.

    Parameters
    ----------
    s
        Vertex signs.
    cells
        Cells ``(m, tdim + 1)``, all positively cut.

    Returns
    -------
    facets
        Vertex indices of the facet opposite the inside vertex ``(m, tdim)``, in the order of
        :data:`FACET_ORDER` (the cell's orientation kept).
    w
        The inside vertex of each cell ``(m,)``.
    """
    k = np.argmin(s[cells], axis=1)  # local index of the one vertex inside
    rows = np.arange(len(cells))
    order = FACET_ORDER[cells.shape[1] - 1][k]
    return cells[rows[:, None], order], cells[rows, k]


def positive_edges(s: Float, cells: Int) -> tuple[Int, Int, Int]:
    """Positive edges of the positively cut cells among ``cells``.

    Parameters
    ----------
    s
        Vertex signs.
    cells
        Cells ``(m, 3)``, all positively cut.

    Returns
    -------
    u, v, w
        Vertex indices, each ``(m,)``: the positive edge is ``(u, v)`` and ``w`` the vertex
        inside. ``(u, v, w)`` is a cyclic shift of the cell's own vertex order, so it keeps
        the cell's orientation.
    """
    facets, w = positive_facets(s, cells)
    return facets[:, 0], facets[:, 1], w


def _stack_columns(u: Int, v: Int, w: Int) -> Int:
    """``(m, 3)`` array of the columns ``u, v, w``."""
    # numpy's stubs lose the dtype of a union of integer arrays; the result is an integer array
    return cast(Int, np.column_stack([u, v, w]))


def proximal_vertex(x: Float, phi: Float, u: Int, v: Int, w: Int) -> Int:
    """Proximal vertex of positively cut cells: the positive-edge vertex closest to Gamma.

    Ties (equal distances to rounding) go to the vertex with the smaller interior angle.

    Parameters
    ----------
    x, phi
        Vertex coordinates and signed distances.
    u, v, w
        Positive edge ``(u, v)`` and inside vertex ``w`` of each cell, from
        :func:`positive_edges`.

    Returns
    -------
    Vertex index of the proximal vertex of each cell, ``(m,)``.
    """
    ang = interior_angles(x, _stack_columns(u, v, w))
    du, dv = np.abs(phi[u]), np.abs(phi[v])
    scale = np.linalg.norm(x[u, :2] - x[v, :2], axis=1)
    tie = np.abs(du - dv) <= 1e-12 * scale
    pick_u = np.where(tie, ang[:, 0] <= ang[:, 1], du < dv)
    return np.where(pick_u, u, v)


def conditioning_angle(x: Float, phi: Float, u: Int, v: Int, w: Int) -> Float:
    """Conditioning angle (radians) of positively cut cells: the angle at the proximal vertex.

    It must be strictly below 90 degrees.

    Returns
    -------
    Angles, shape ``(m,)``.
    """
    ang = interior_angles(x, _stack_columns(u, v, w))
    p = proximal_vertex(x, phi, u, v, w)
    return np.where(p == u, ang[:, 0], ang[:, 1])


def perturbation_candidates(x: Float, phi: Float, s: Float, cells: Int, eta: float) -> Int:
    """Inside vertices to relocate onto Gamma by the quality perturbation (parameter eta).

    For each positively cut cell with vertices ordered ``phi(a) >= phi(b) >= phi(c)``, ``c``
    is selected when ``phi(b) - phi(c) < eta * h_K`` (``h_K`` the cell's diameter).

    Returns
    -------
    Unique vertex indices (process-local), possibly empty.
    """
    if eta <= 0:
        return np.empty(0, dtype=np.int64)
    pc = cells[positively_cut(s, cells)]
    if len(pc) == 0:
        return np.empty(0, dtype=np.int64)
    order = np.argsort(-phi[pc], axis=1, kind="stable")
    rows = np.arange(len(pc))[:, None]
    b, c = pc[rows, order][:, 1], pc[rows, order][:, 2]
    hit = phi[b] - phi[c] < eta * cell_diameters(x, pc)
    # numpy's stubs lose the dtype of a union of integer arrays; unique keeps c's dtype
    return cast(Int, np.unique(c[hit & (s[c] < 0)]))


def shifted_vertices(phi: Float, s: Float, eta: float, h: Float) -> Int:
    """Inside vertices within ``eta h`` of Gamma, to count as on Gamma (tetrahedra).

    The tetrahedral form of the quality perturbation (Rangarajan, Kabaria & Lew 2019): a
    vertex with ``-eta h <= phi < 0`` is relocated onto Gamma. Without it, inside vertices
    just below the surface are passed by the snapped positive faces (chords of the surface)
    and their tetrahedra invert. ``phi`` is ``-inf`` at inside vertices outside the band.

    Returns
    -------
    Vertex indices (process-local), possibly empty.
    """
    if eta <= 0:
        return np.empty(0, dtype=np.int64)
    return np.flatnonzero((s < 0) & (phi >= -eta * h))


def straight_map(
    x: Float,
    phi: Float,
    closest: Float,
    normal: Float,
    on_gamma: Bool,
    h: Float,
    R_r: Float,
    alpha: float,
) -> Float:
    """The straight-edged map ``M_h`` at vertices.

    ``M_h(x) = pi(x)`` on vertices of positive edges; otherwise
    ``M_h(x) = x - alpha h max(0, 1 + phi/R_r) N(pi(x))`` for vertices inside within
    ``R_r`` of Gamma, and ``x`` elsewhere.

    Parameters
    ----------
    x
        Vertex coordinates ``(n, gdim)``.
    phi
        Signed distances ``(n,)``; only used where ``|phi| < R_r`` (may be ``inf`` elsewhere).
    closest, normal
        Closest points ``pi(x)`` and outward normals there ``(n, gdim)``; only read where the
        vertex moves.
    on_gamma
        Vertex flags ``(n,)``.
    h, R_r
        Mesh size and relaxation radius at each vertex ``(n,)``.
    alpha
        Relaxation factor.

    Returns
    -------
    Images ``M_h(x)``, shape ``(n, gdim)``.
    """
    y = np.array(x, dtype=np.float64, copy=True)
    inward_push(y, (~on_gamma) & (phi < 0) & (phi > -R_r), phi, normal, h, R_r, alpha)
    y[on_gamma] = closest[on_gamma]
    return y


def inward_push(
    y: Float, rows: Any, phi: Float, normal: Float, h: Float, R_r: Float, alpha: float
) -> None:
    """Move the vertices ``rows`` (a mask or indices) of ``y`` inwards by ``M_h``'s push
    ``alpha h (1 + phi / R_r) N``, in place (:func:`straight_map`; continued beyond
    ``(-R_r, 0)`` by :func:`~dolfinx_universal.conforming.snap.frozen_images`)."""
    f = alpha * h[rows] * (1.0 + phi[rows] / R_r[rows])
    y[rows] -= f[:, None] * normal[rows]
