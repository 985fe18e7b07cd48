"""Classification of a background triangulation against a domain, and the straight map M_h.

Pure numpy on process-local arrays: ``x`` are vertex coordinates ``(num_vertices, 2)``,
``cells`` vertex indices ``(num_cells, 3)``, ``s`` vertex signs (-1 inside, +1 outside or on
Gamma), ``phi`` signed distances. Only the signs at vertices are used to classify.
The triangle geometry (``signed_areas``, ``cell_diameters``, ``interior_angles``) lives in
:mod:`dolfinx_universal._geometry` and is re-exported here.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from ._geometry import Bool, Float, Int, cell_diameters, interior_angles, signed_areas

__all__ = [
    "cell_diameters",
    "conditioning_angle",
    "interior_angles",
    "kept_cells",
    "perturbation_candidates",
    "positive_edges",
    "positively_cut",
    "proximal_vertex",
    "signed_areas",
    "straight_map",
]


def positively_cut(s: Float, cells: Int) -> Bool:
    """Cells with ``s = +1`` at exactly two vertices, shape ``(num_cells,)``."""
    return (s[cells] > 0).sum(axis=1) == 2


def kept_cells(s: Float, cells: Int) -> Bool:
    """Cells of ``T_h^sub``: ``s = -1`` at one vertex or more, shape ``(num_cells,)``."""
    neg = s < 0
    return neg[cells[:, 0]] | neg[cells[:, 1]] | neg[cells[:, 2]]


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
    k = np.argmin(s[cells], axis=1)  # local index of the one vertex inside
    rows = np.arange(len(cells))
    w = cells[rows, k]
    u = cells[rows, (k + 1) % 3]
    v = cells[rows, (k + 2) % 3]
    return u, v, w


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


def straight_map(
    x: Float,
    phi: Float,
    closest: Float,
    normal: Float,
    on_positive_edge: Bool,
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
        Vertex coordinates ``(n, 2)``.
    phi
        Signed distances ``(n,)``; only used where ``|phi| < R_r`` (may be ``inf`` elsewhere).
    closest, normal
        Closest points ``pi(x)`` and outward normals there ``(n, 2)``; only read where the
        vertex moves.
    on_positive_edge
        Vertex flags ``(n,)``.
    h, R_r
        Mesh size and relaxation radius at each vertex ``(n,)``.
    alpha
        Relaxation factor.

    Returns
    -------
    Images ``M_h(x)``, shape ``(n, 2)``.
    """
    y = np.array(x[:, :2], dtype=np.float64, copy=True)
    relax = (~on_positive_edge) & (phi < 0) & (phi > -R_r)
    f = alpha * h[relax] * (1.0 + phi[relax] / R_r[relax])
    y[relax] -= f[:, None] * normal[relax]
    y[on_positive_edge] = closest[on_positive_edge]
    return y
