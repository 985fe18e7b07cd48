"""Curved tetrahedra: the 3D blend of the closest-point projection, the 3D part of
:func:`~dolfinx_universal.curved.maps.curved_mesh` (the same names as :mod:`.maps_tri`).

A tetrahedron touches Gamma_h by a positive face (three vertices on Gamma), by edges of
positive faces only, or by a vertex. Its map is the affine map ``A`` through the ``M_h``
images of its vertices plus displacements built from face and edge data only::

    G = A + sum_{e on Gamma_h} E_e + E_F                 (E_F only with a positive face F)

With ``delta(mu) = pi(sum_k mu_k S_k) - sum_k mu_k Y_k`` (``S``: background positions for
``G_h``, the images ``Y`` for ``G~_h``; ``Y = pi(S)`` at the vertices on Gamma):

* an edge ``e = (i, j)`` of Gamma_h contributes the 2D transfinite blend of Rangarajan &
  Lew (2014) in the variables ``(l_i, l_j)`` only::

      E_e = 1/2 [ l_j / (1 - l_i) delta(s = l_i) + l_i / (1 - l_j) delta(s = 1 - l_j) ]

  with ``delta(s)`` at ``mu = s e_i + (1 - s) e_j``. It is ``pi`` of the straight edge point
  on ``e``, vanishes on every face without ``e`` and is, on a face with ``e``, the 2D blend
  of that triangle: every cell around ``e`` gives a shared node the same position. It is
  smooth (``delta`` vanishes at the end points).
* the positive face ``F = (a, b, c)`` opposite the inside vertex ``d`` contributes the same
  blend one dimension up, along the three edges ``d - v``::

      E_F = 1/3 sum_{v in F} l_v / (l_v + l_d) R_F(P_v),   P_v = l + l_d (e_v - e_d)

  of the remainder ``R_F = delta - sum_{e in F} E_e`` on ``F`` (zero on the edges of
  ``F``). ``E_F`` vanishes on the three other faces, and ``G = pi(straight face point)`` on
  ``F``: the map is exactly conforming. In 2D the same construction is the blend of
  :func:`~dolfinx_universal.curved.maps_tri.transfinite_map`.

Cells touching Gamma at a vertex only stay affine. Every term is ``weight * delta(mu)`` with
weights and points ``mu`` fixed by the reference node, the inside vertex ``d`` and the set
of curved edges: each such pattern is tabulated once.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
import numpy.typing as npt
from dolfinx import fem, la
from dolfinx import mesh as dmesh

from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.core.arrays import Float, Int, any_rows, lagrange_element, project_together
from dolfinx_universal.core.compiled import pointer, relax_kernels
from dolfinx_universal.core.lagrange import lagrange_geometry

__all__ = [
    "LOCAL_EDGES",
    "coordinate_geometry",
    "curved_cells",
    "gamma_entities",
    "map_nodes",
    "reference_nodes",
    "tangents",
]

LOCAL_EDGES = np.array([[2, 3], [1, 3], [1, 2], [0, 3], [0, 2], [0, 1]])
"""Local vertices of the six edges of a DOLFINx (basix) tetrahedron; face ``k`` is opposite
vertex ``k``."""

_ZERO = 1e-13
"""Barycentric coordinates of basix's reference points below this are zero (``1 - X - Y - Z``
leaves a few ulps on the opposite face)."""


@lru_cache(maxsize=16)
def reference_nodes(degree: int) -> Float:
    """Barycentric coordinates of the degree-q GLL-warped Lagrange nodes, ``(ndofs, 4)``.

    Column ``i`` is the coordinate of local vertex ``i``; rows follow DOLFINx's node order
    (vertices, edges 0-5, faces 0-3, interior). Coordinates within ``1e-13`` of 0 are 0
    (read-only).
    """
    p = lagrange_element("tetrahedron", degree).points
    lam = np.column_stack([1.0 - p.sum(axis=1), p])
    lam[np.abs(lam) < _ZERO] = 0.0
    lam.setflags(write=False)
    return lam


def gamma_entities(
    msh: object, on_gamma: npt.NDArray[np.bool_], immersed: Int, cells: Int | None = None
) -> tuple[npt.NDArray[np.int8], npt.NDArray[np.bool_]]:
    """Positive faces and edges of Gamma_h of local cells (owned and ghost). Collective.

    Parameters
    ----------
    msh
        The straight conforming tetrahedral mesh.
    on_gamma
        Vertices on Gamma ``(num_vertices,)``.
    immersed
        Owned faces of Gamma_h (the immersed facet tags) ``(k,)``.
    cells
        The local cells to answer for (default: all); each cell with a face of Gamma_h
        must be among them.

    Returns
    -------
    face
        Local vertex opposite the positive face of each cell, -1 where it has none,
        ``(num_cells,)``.
    edges
        Whether each local edge (:data:`LOCAL_EDGES`) is an edge of a positive face,
        ``(num_cells, 6)``; the same answer on every rank holding the edge.
    """
    topo = msh.topology  # type: ignore[attr-defined]
    topo.create_connectivity(3, 2)
    topo.create_entities(1)
    topo.create_connectivity(3, 1)
    c2f = topo.connectivity(3, 2).array.reshape(-1, 4)
    c2e = topo.connectivity(3, 1).array.reshape(-1, 6)
    c2v = topo.connectivity(3, 0).array.reshape(-1, 4)
    if cells is not None:  # (the face and edge rows of the few cells that need them below)
        c2v = c2v[cells]
    else:
        cells = np.arange(len(c2v))

    fv = la.vector(topo.index_map(2), 1)
    fv.array[:] = 0.0
    fv.array[immersed] = 1.0
    fv.scatter_forward()  # the owners' tags on the ghost faces
    # A face of Gamma_h has its three vertices on Gamma (which also guards against a stale
    # tag), an edge of it two: only the cells with that many look at the tags.
    count = on_gamma[c2v[:, 0]].astype(np.int8)
    for k in range(1, 4):  # by columns: a sum along a short axis is slow
        count += on_gamma[c2v[:, k]]
    rows = np.flatnonzero(count >= 3)
    og = on_gamma[c2v[rows]]
    o0, o1, o2, o3 = og[:, 0], og[:, 1], og[:, 2], og[:, 3]
    on_face = (fv.array[c2f[cells[rows]]] > 0) & np.column_stack(
        [o1 & o2 & o3, o0 & o2 & o3, o0 & o1 & o3, o0 & o1 & o2]
    )
    face = np.full(len(c2v), -1, dtype=np.int8)
    found = on_face.any(axis=1)
    face[rows[found]] = np.argmax(on_face[found], axis=1)

    has = np.flatnonzero(face >= 0)
    # the edges of face k are the edges without vertex k
    face_edges = np.array([[e for e in range(6) if k not in LOCAL_EDGES[e]] for k in range(4)])
    ev = la.vector(topo.index_map(1), 1)
    ev.array[:] = 0.0
    ev.array[c2e[cells[has][:, None], face_edges[face[has]]].ravel()] = 1.0
    ev.scatter_reverse(la.InsertMode.add)
    ev.scatter_forward()
    two = np.flatnonzero(count >= 2)
    edges = np.zeros((len(c2v), 6), dtype=bool)
    edges[two] = ev.array[c2e[cells[two]]] > 0
    return face, edges


@lru_cache(maxsize=512)
def _terms(degree: int, d: int, mask: int) -> tuple[Int, Int, Float]:
    """The nonzero weights of :func:`_program`'s pattern by node (compressed rows):
    ``start (p + 1,)``, their points ``(t,)`` (increasing in each row) and values ``(t,)``."""
    weights = _program(degree, d, mask)[2]
    node, r = np.nonzero(weights)
    start = np.searchsorted(node, np.arange(len(weights) + 1)).astype(np.int64)
    return start, r.astype(np.int64), np.ascontiguousarray(weights[node, r])


def _affine(w: Float, cells: Int, x: Float, kernels) -> Float:
    """:func:`_contract` ``(w, x[cells])``, ``(m, p, 3)``: a C loop where the kernels are
    built (``cells`` int64 and ``x`` float64, C-contiguous; the same sums, bitwise)."""
    if kernels is None:
        return np.ascontiguousarray(_contract(w, x[cells]))
    out = np.empty((len(cells), len(w), 3))
    ffi, w = kernels.ffi, np.ascontiguousarray(w)
    kernels.lib.contract_cells(
        pointer(ffi, cells, "int64_t"), len(cells), cells.shape[1], pointer(ffi, w, "double"),
        len(w), pointer(ffi, x, "double"), pointer(ffi, out, "double"),
    )  # fmt: skip
    return out


@lru_cache(maxsize=512)
def _program(degree: int, d: int, mask: int) -> tuple[Float, npt.NDArray[np.intp], Float]:
    """The blend at the reference nodes of one pattern as ``weight * delta(mu)`` terms.

    Parameters
    ----------
    degree
        Geometry degree.
    d
        Local vertex opposite the positive face, -1 if none.
    mask
        Curved local edges, bit ``e`` for edge ``e`` of :data:`LOCAL_EDGES`.

    Returns
    -------
    points
        Barycentric points ``mu`` to project, ``(r, 4)``.
    direct
        For each node, the point whose projection it is (nodes on Gamma_h), else -1, ``(p,)``.
    weights
        ``(p, r)``: the node's image is ``A + weights @ delta(points)`` where ``direct < 0``.
    """
    lam = reference_nodes(degree)
    p = len(lam)
    index: dict[tuple[float, ...], int] = {}
    points: list[Float] = []

    def request(mu: Float) -> int:
        key = tuple(mu.tolist())
        if key not in index:
            index[key] = len(points)
            points.append(mu)
        return index[key]

    terms: list[tuple[int, int, float]] = []

    def edge_blend(node: int, mu: Float, i: int, j: int, scale: float) -> None:
        li, lj = mu[i], mu[j]
        if li <= 0.0 or lj <= 0.0:
            return
        for a, b in ((i, j), (j, i)):  # delta(s = l_a) with weight l_b / (1 - l_a)
            nu = np.zeros(4)
            nu[a], nu[b] = mu[a], 1.0 - mu[a]
            terms.append((node, request(nu), scale * 0.5 * mu[b] / (1.0 - mu[a])))

    curved = [tuple(LOCAL_EDGES[e]) for e in range(6) if mask >> e & 1]
    face = [v for v in range(4) if v != d] if d >= 0 else []
    face_edges = [(i, j) for i, j in LOCAL_EDGES.tolist() if d >= 0 and d not in (i, j)]
    direct = np.full(p, -1, dtype=np.intp)
    for node, mu in enumerate(lam):
        if (mu == 1.0).any():
            continue  # a vertex: its M_h image
        if d >= 0 and mu[d] == 0.0:
            direct[node] = request(mu)  # on the positive face
            continue
        support = set(np.flatnonzero(mu > 0.0).tolist())
        if any(support <= {i, j} for i, j in curved):
            direct[node] = request(mu)  # on a curved edge
            continue
        for i, j in curved:
            edge_blend(node, mu, i, j, 1.0)
        if d >= 0 and (mu[face] > 0.0).all():
            for v in face:
                w = mu[v] / (mu[v] + mu[d]) / 3.0
                pv = mu.copy()
                pv[v] += mu[d]
                pv[d] = 0.0
                terms.append((node, request(pv), w))
                for i, j in face_edges:
                    edge_blend(node, pv, i, j, -w)
    pts = np.array(points).reshape(-1, 4)
    weights = np.zeros((p, len(pts)))
    for node, r, w in terms:
        weights[node, r] += w
    for a in (pts, direct, weights):
        a.setflags(write=False)
    return pts, direct, weights


def _contract(w: Float, a: Float) -> Float:
    """``einsum("pk,ckd->cpd", w, a)``, ``(c, p, d)``.

    Each value is summed over ``k`` in order by plain products and sums, so that a cell's
    nodes are the same bitwise whatever the batch it is in and its place there (a moving
    update and a fresh ``curved_mesh`` group the cells differently, and so do different
    numbers of ranks). A matrix product is not: BLAS picks kernels by shape (one row: a
    matrix-vector kernel) with fused multiply-adds, and a query point that moves by an ulp
    may move its projection onto Gamma by the projection's tolerance (measured: 2e-11 on a
    superellipsoid at q = 4 on 2 ranks). einsum on the ``k``-major copy runs as fast as the
    matrix product did.
    """
    return np.einsum("pk,kcd->cpd", w, np.ascontiguousarray(a.transpose(1, 0, 2)))


def map_nodes(
    cells: Int,
    y: Float,
    x_background: Float,
    face: npt.NDArray[np.int8],
    edges: npt.NDArray[np.bool_],
    degree: int,
    kind: str,
    closest_point: Callable[[Float], Float],
) -> Float:
    """Images of the degree-q reference nodes of tetrahedra under ``G_h`` or ``G~_h``.

    Parameters
    ----------
    cells
        Tetrahedra ``(m, 4)`` (process-local vertex indices).
    y
        ``M_h`` images of the vertices ``(num_vertices, 3)``.
    x_background
        Background positions of the vertices ``(num_vertices, 3)``.
    face
        Local vertex opposite each cell's positive face, -1 if none, ``(m,)``.
    edges
        Curved local edges (edges of Gamma_h) of each cell, ``(m, 6)``.
    degree
        Lagrange degree of the nodes.
    kind
        ``"G"`` (project the background's faces and edges) or ``"G~"`` (project those of the
        straight mesh).
    closest_point
        Projection onto Gamma, ``(n, 3) -> (n, 3)``; called once.

    Returns
    -------
    Node coordinates ``(m, ndofs, 3)`` in DOLFINx's node order.
    """
    kernels = relax_kernels()
    lam = reference_nodes(degree)
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    # the corners whose faces are projected
    sc = np.ascontiguousarray(x_background, dtype=np.float64) if kind == "G" else y
    nodes = _affine(lam, cells, y, kernels)  # affine images
    mask = (edges.astype(np.int64) << np.arange(6)).sum(axis=1)
    key = (face.astype(np.int64) + 1) * 64 + mask
    groups = [(k, np.flatnonzero(key == k)) for k in np.unique(key)]
    programs = [_program(degree, int(k) // 64 - 1, int(k) % 64) for k, _ in groups]
    queries = [
        _affine(prog[0], cells[rows], sc, kernels)
        for prog, (_, rows) in zip(programs, groups, strict=True)
    ]
    projected = project_together(closest_point, queries, 3)
    for (points, direct, weights), (k, rows), pi in zip(programs, groups, projected, strict=True):
        if not len(points):
            continue
        if kernels is None:
            delta = pi - _contract(points, y[cells[rows]])
            blend = nodes[rows] + _contract(weights, delta)
            on = direct >= 0
            blend[:, on] = pi[:, direct[on]]
            nodes[rows] = blend
            continue
        start, term_r, term_w = _terms(degree, int(k) // 64 - 1, int(k) % 64)
        ffi, rows = kernels.ffi, rows.astype(np.int64)
        pi, direct = np.ascontiguousarray(pi), np.ascontiguousarray(direct, dtype=np.int64)
        kernels.lib.blend_nodes(
            pointer(ffi, rows, "int64_t"), len(rows), pointer(ffi, cells, "int64_t"), 4,
            pointer(ffi, y, "double"), pointer(ffi, np.ascontiguousarray(points), "double"),
            len(points), pointer(ffi, pi, "double"), len(lam), pointer(ffi, direct, "int64_t"),
            pointer(ffi, start, "int64_t"), pointer(ffi, term_r, "int64_t"),
            pointer(ffi, term_w, "double"), pointer(ffi, nodes, "double"),
            pointer(ffi, np.empty(3 * len(points)), "double"),
        )  # fmt: skip
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
    """The cells a curved map changes and the map of their nodes: the tetrahedra with an
    edge on Gamma_h (a positive face, or only edges of other cells' positive faces), found
    from the faces of Gamma_h and the mesh's edges (collective).

    Parameters
    ----------
    msh
        The (straight or background) tetrahedral mesh of the cells.
    cells
        Local cells to answer for, as vertex indices ``(m, 4)``.
    cut
        Indices into ``cells`` of the positively cut cells of the domain (not needed for
        tetrahedra: the faces of Gamma_h say more).
    positive_facets
        Faces of Gamma_h (process-local; the owned ones count, repeats allowed).
    on_gamma
        Vertices on Gamma ``(num_vertices,)``.
    sign
        Vertex signs (not needed for tetrahedra).
    x_background
        Background positions of the vertices ``(num_vertices, 3)``.
    degree, kind, closest_point
        As in :func:`map_nodes`.
    rows
        The process-local cell of each row of ``cells`` (default: every local cell in order).

    Returns
    -------
    curve
        Indices into ``cells`` of the tetrahedra to curve ``(k,)``.
    map
        ``(cells (k, 4), y (num_vertices, 3)) -> nodes (k, ndofs, 3)``.
    """
    msh.topology.create_entities(2)
    owned = msh.topology.index_map(2).size_local
    faces = np.unique(positive_facets[positive_facets < owned])
    face, edges = gamma_entities(msh, on_gamma, faces, rows)
    curve = np.flatnonzero(any_rows(edges))

    def tetrahedra(chosen: Int, y: Float) -> Float:
        return map_nodes(
            chosen, y, x_background, face[curve], edges[curve], degree, kind, closest_point
        )

    return curve, tetrahedra


def coordinate_geometry(msh: dmesh.Mesh, element: fem.CoordinateElement) -> dmesh.Mesh:
    """``msh`` with the degree-q coordinate ``element``, every cell the affine image of its
    vertices, numbered from the entities
    (:func:`~dolfinx_universal.core.lagrange.lagrange_geometry`): 1.3-2.5x faster than
    DOLFINx's reordered dof layout on 1e5-2e5 tetrahedra at q = 2, 3."""
    return lagrange_geometry(msh, element)


def tangents(boundary: Boundary, y: Float) -> Float:
    """Orthonormal tangent bases of the surface at its points ``y``, ``(n, 2, 3)``."""
    return boundary.tangent_basis(y)
