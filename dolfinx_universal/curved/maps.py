"""Curved universal meshes: the maps G_h, G~_h and their degree-k interpolants I_h, I~_h.

The driver :func:`curved_mesh` serves both dimensions; the triangle blend is in this module,
the tetrahedron blend in :mod:`._curved_tet`, picked by the cell type.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

from mpi4py import MPI

import basix
import numpy as np
import numpy.typing as npt
from dolfinx import fem
from dolfinx import mesh as dmesh

from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.conforming.classify import positively_cut
from dolfinx_universal.conforming.universal import IMMERSED, ConformingMesh
from dolfinx_universal.core.arrays import (
    Bool,
    Float,
    any_rows,
    lagrange_element,
    project_together,
    write_cell_nodes,
)
from dolfinx_universal.core.collective import Problem, collective_call, raise_collective
from dolfinx_universal.core.lagrange import lagrange_geometry
from dolfinx_universal.curved import maps_tet as _curved_tet
from dolfinx_universal.curved.bounds import check_degree, jacobian_bounds

__all__ = [
    "MAPS",
    "CurvedMesh",
    "boundary_dof_data",
    "curved_mesh",
    "jacobian_ratio",
    "map_nodes",
    "reference_nodes",
    "transfinite_map",
]


MAPS = ("I", "I~", "G", "G~")
"""Map names. ``"I"``/``"G"`` interpolate the exactly conforming blend ``G_h``; ``"I~"``/``"G~"``
interpolate ``G~_h`` (through the straight mesh). DOLFINx geometry is polynomial, so ``G`` is
realised as its degree-q interpolant: ``"G"`` with a geometry degree above the space degree is
the superparametric approximation of ``G_h``; with equal degrees it is ``I_h``. Triangles and
tetrahedra alike (the tetrahedron blend: :mod:`dolfinx_universal.curved.maps_tet`)."""


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
    if np.ndim(lam) == 2:
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


def _cell_nodes(cm: ConformingMesh, degree: int, kind: str) -> Float:
    """Images of the reference nodes of every local cell of ``cm``, ``(num_cells, ndofs, 2)``."""
    return map_nodes(
        cm.cells, cm.x, cm.background_x, cm.sign, degree, kind, cm.boundary.closest_point
    )


def _curved_cells(
    cm: ConformingMesh, degree: int, kind: str
) -> tuple[npt.NDArray[np.intp], Callable[[npt.NDArray, Float], Float]]:
    """The local cells a curved map changes and the map of their nodes, per dimension.

    Triangles: the positively cut ones. Tetrahedra: those with an edge on Gamma_h (a positive
    face, or only edges of other cells' positive faces), found from the immersed facet tags
    and the mesh's edges (collective).

    Returns
    -------
    cells
        Indices of the cells to curve ``(k,)``.
    map
        ``(cells (k, tdim + 1), y (num_vertices, gdim)) -> nodes (k, ndofs, gdim)``.
    """
    closest = cm.boundary.closest_point
    if cm.mesh.topology.dim == 2:
        pc = np.flatnonzero(positively_cut(cm.sign, cm.cells))

        def triangles(cells: npt.NDArray, y: Float) -> Float:
            return map_nodes(cells, y, cm.background_x, cm.sign, degree, kind, closest)

        return pc, triangles
    face, edges = _curved_tet.gamma_entities(cm.mesh, cm.on_gamma, cm.facet_tags.find(IMMERSED))
    curved = np.flatnonzero(any_rows(edges))

    def tetrahedra(cells: npt.NDArray, y: Float) -> Float:
        return _curved_tet.map_nodes(
            cells, y, cm.background_x, face[curved], edges[curved], degree, kind, closest
        )

    return curved, tetrahedra


def jacobian_ratio(
    nodes: Float, degree: int, resolution: int | None = None, *, threshold: float = 0.0
) -> Float:
    """Proven lower bound of the ratio ``det J / det J_affine`` over each curved cell.

    ``det J`` of a degree-k triangle (tetrahedron) is a polynomial of degree ``2(k-1)``
    (``3(k-1)``) in the reference coordinates;
    :func:`~dolfinx_universal.curved.bounds.jacobian_bounds`
    writes it in the Bernstein basis and subdivides until the bound decides ``threshold`` and
    lies within 5 % (5e-4 near 0) of an attained value (``det J_affine``: the cell through the
    vertex nodes). ``ratio <= threshold`` is therefore a safe failure test: a cell above it
    is proven valid; an undecided cell (after 8 subdivision levels, 6 for tetrahedra) stays
    at or below it.

    Parameters
    ----------
    nodes
        Node coordinates of each cell, ``(m, ndofs, 2)`` (triangles) or ``(m, ndofs, 3)``
        (tetrahedra).
    degree
        Geometry degree.
    resolution
        Deprecated and ignored (the former sampling lattice's subdivisions per edge).
    threshold
        The ratio to decide exactly (default 0: inversion).

    Returns
    -------
    The lower bound for each cell, ``(m,)`` (1 for an affine cell).
    """
    if resolution is not None:
        warnings.warn(
            "jacobian_ratio(resolution=...) is ignored: the bound is proven, not sampled",
            DeprecationWarning,
            stacklevel=2,
        )
    return jacobian_bounds(nodes, degree, threshold=threshold)[0]


@lru_cache(maxsize=16)
def _coordinate_element(cell_type: dmesh.CellType, degree: int) -> fem.CoordinateElement:
    """DOLFINx's GLL-warped Lagrange coordinate element, built once per cell type and degree
    (the build costs about as much as the curved map of 1e4 triangles)."""
    return fem.coordinate_element(cell_type, degree, basix.LagrangeVariant.gll_warped)


@dataclass
class CurvedMesh:
    """A degree-k conforming mesh on the topology of a straight conforming mesh."""

    mesh: dmesh.Mesh
    """The curved mesh (Lagrange coordinate element of degree ``degree``, GLL-warped nodes)."""
    facet_tags: dmesh.MeshTags
    """:data:`~dolfinx_universal.conforming.universal.IMMERSED` /
    :data:`~dolfinx_universal.conforming.universal.OUTER`."""
    conforming: ConformingMesh
    degree: int
    map: str
    min_jacobian_ratio: float
    """Global minimum of ``det J / det J_straight`` over the curved cells: a proven lower
    bound, within 5 % of the minimum (:func:`jacobian_ratio`)."""


def curved_mesh(
    cm: ConformingMesh, degree: int, map: str = "I", *, min_ratio: float = 0.0
) -> CurvedMesh:
    """Degree-k DOLFINx mesh whose nodes are the images of the Lagrange nodes under a curved map.

    Triangles: only positively cut cells are curved (their positive edge follows Gamma
    through the closest-point projection). Tetrahedra: the cells with a positive face (it
    follows Gamma) and those touching Gamma_h by an edge (it follows the curved edge), see
    :mod:`dolfinx_universal.curved.maps_tet`. Every other cell is the affine image of its ``M_h``
    vertices. Nodes on Gamma lie exactly on Gamma. Collective.

    Parameters
    ----------
    cm
        Straight conforming mesh from :func:`~dolfinx_universal.conforming.universal.conform`.
    degree
        Geometry degree ``q >= 1``, at most :data:`~dolfinx_universal.curved.bounds.MAX_DEGREE`
        (7 for triangles, 5 for tetrahedra). ``degree = 1`` returns a copy of the straight
        mesh.
    map
        One of :data:`MAPS`.
    min_ratio
        Smallest allowed ``det J / det J_straight`` in a curved cell (0: only inversion is
        an error).

    Raises
    ------
    MeshingError
        If a curved cell is inverted (its Jacobian determinant changes sign).
    ValueError
        If the degree is not an integer from 1 to the limit above, or the map is unknown.
    """
    if not isinstance(cm, ConformingMesh):
        raise TypeError(
            "curved_mesh needs the ConformingMesh returned by conform (it carries the "
            f"background positions, signs and the boundary), got {type(cm).__name__}: use "
            "curved_mesh(conform(background, boundary), degree)"
        )
    if map not in MAPS:
        raise ValueError(f"unknown map {map!r}: choose one of {MAPS}")
    tdim = cm.mesh.topology.dim
    degree = check_degree(degree, tdim)
    kernels = cell_kernels(tdim)
    kind = "G" if map in ("I", "G") else "G~"
    ce = _coordinate_element(kernels.cell_type, degree)
    # The degree-q geometry is the affine image of every cell: only the curved cells change
    # (affine on their straight entities, so shared nodes agree). Tetrahedra: numbered from
    # the entities (``_lagrange``), 1.3-2.5x faster than DOLFINx's reordered dof layout on
    # 1e5-2e5 cells at q = 2, 3; triangles: DOLFINx's is the faster (measured 15 against
    # 17 ms at q = 2, 26 against 34 ms at q = 3 on 1e5 cells).
    if tdim == 3:
        msh = lagrange_geometry(cm.mesh, ce)
    else:
        msh = fem.interpolate_geometry(cm.mesh, ce)
    cells = cm.cells
    pc, cell_map = _curved_cells(cm, degree, kind)
    dofmap = msh.geometry.dofmaps[0]
    # Vertex positions of the curved cells only (a node shared by a curved cell and an
    # affine one agrees up to rounding: the curved map is affine on the straight entities).
    corners = cm.mesh.geometry.x[cm.mesh.geometry.dofmaps[0][pc], :tdim]  # (k, tdim + 1, tdim)
    y = np.zeros((len(cm.sign), tdim))
    y[cells[pc]] = corners
    nodes = collective_call(msh.comm, "the curved map", cell_map, cells[pc], y)
    write_cell_nodes(msh.geometry.x, dofmap, pc, nodes)

    ratio = (
        jacobian_ratio(nodes, degree, threshold=min_ratio) if degree > 1 and len(pc) else np.ones(0)
    )
    bad = ratio <= min_ratio
    problems = []
    if bad.any():
        problems.append(
            Problem(
                f"{{count}} curved {kernels.plural} are not proven valid (det J / "
                f"det J_straight >= {min_ratio:g} fails) near " + "{where}: the background is "
                "too coarse for the "
                "boundary's curvature there; refine near those points",
                nodes[bad].mean(axis=1),
                int(bad.sum()),
            )
        )
    raise_collective(msh.comm, problems)
    local_min = float(ratio.min()) if len(ratio) else 1.0
    tags = dmesh.meshtags(msh, tdim - 1, cm.facet_tags.indices, cm.facet_tags.values)
    return CurvedMesh(
        mesh=msh,
        facet_tags=tags,
        conforming=cm,
        degree=int(degree),
        map=map,
        min_jacobian_ratio=msh.comm.allreduce(local_min, op=MPI.MIN),
    )


def boundary_dof_data(
    V: fem.FunctionSpace, curved: CurvedMesh, tag: int = IMMERSED
) -> tuple[npt.NDArray[np.int32], Float, Float, Float]:
    """Boundary degrees of freedom of ``V`` on a tagged boundary, with the true geometry there.

    Parameters
    ----------
    V
        A (scalar, or blocked vector) Lagrange space on ``curved.mesh``.
    curved
        The curved mesh.
    tag
        Facet tag (default the immersed boundary).

    Returns
    -------
    dofs
        Process-local dof (block) indices on the tagged facets, owned and ghost, ``(n,)``.
    closest
        Closest points of Gamma to the dof coordinates, ``(n, gdim)`` (the dofs lie on Gamma
        when the space and geometry degrees agree).
    normal
        Unit outward normal of Gamma there, ``(n, gdim)``.
    tangent
        Unit tangent of a curve ``(n, 2)``; orthonormal tangent bases of a surface
        ``(n, 2, 3)`` (:meth:`~dolfinx_universal.boundaries.surfaces.Surface.tangent_basis`).
    """
    tdim = curved.mesh.topology.dim
    facets = curved.facet_tags.find(tag)
    dofs = fem.locate_dofs_topological(V, tdim - 1, facets)
    xd = V.tabulate_dof_coordinates()[dofs, :tdim]
    boundary = curved.conforming.boundary

    def frames() -> tuple[Float, Float, Float]:
        y = boundary.closest_point(xd) if len(dofs) else np.zeros((0, tdim))
        tangent = boundary.tangent(y) if tdim == 2 else boundary.tangent_basis(y)
        return y, boundary.normal(y), tangent

    # Collective: the projection runs on each rank's own nodes, and fails on all if on one.
    y, normal, tangent = collective_call(V.mesh.comm, "closest-point projection", frames)
    return dofs, y, normal, tangent
