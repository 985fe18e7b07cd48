"""Gamma_h of a tetrahedral background: conditioning, repair and the surface's topology.

The per-dimension part of the classification checks for tetrahedra (Rangarajan, Kabaria &
Lew 2019): the positive faces (the faces opposite the inside vertex of the positively cut
tetrahedra) must form, for each surface of Gamma, one closed, consistently oriented
2-manifold with that surface's Euler characteristic, on the domain's side. An interior face
with its three vertices outside (both tetrahedra beside it kept) is repaired by counting the
shallower of the two inside vertices as on Gamma. Pure numpy on process-local arrays, except
:func:`surface_topology`, which is collective.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from dolfinx_universal.conforming.locate import (
    cells_near_points,
    missing_samples_problems,
    points_in_cells,
    samples_in_stars,
)
from dolfinx_universal.conforming.messages import TOPOLOGY_MESSAGES
from dolfinx_universal.core.arrays import Bool, Float, Int
from dolfinx_universal.core.collective import Problem, collective_call

if TYPE_CHECKING:
    from dolfinx_universal.boundaries.base import Boundary
    from dolfinx_universal.conforming.snap import PositiveFacets

__all__ = [
    "Containment",
    "SurfaceParts",
    "all_outside_faces",
    "conditioning_dihedral",
    "conditioning_problem",
    "open_chains",
    "sample_gamma",
    "surface_parts",
    "surface_topology",
    "topology_problems",
]


def conditioning_dihedral(x: Float, facets: Int, w: Int) -> Float:
    """Largest dihedral angle (radians) at the edges of the positive face of each positively
    cut tetrahedron, ``(m,)``.

    The 3D counterpart of the conditioning angle: the positive face is projected onto the
    surface, and the tetrahedron stays well shaped when its angles at that face are at
    most right (acute lattices such as A15 have all dihedral angles below 79 degrees, BCC
    at most 90).

    Parameters
    ----------
    x
        Vertex coordinates ``(num_vertices, 3)``.
    facets
        Positive faces ``(m, 3)``.
    w
        Inside vertex of each cell ``(m,)``.
    """
    if len(facets) == 0:
        return np.zeros(0)
    # coordinates as contiguous (m,) arrays: norms along a short axis are slow in numpy
    p = [[x[:, d][facets[:, i]] for d in range(3)] for i in range(3)]
    q = [x[:, d][w] for d in range(3)]

    def dot(u: list[Float], v: list[Float]) -> Float:
        return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]

    out = np.zeros(len(facets))
    for i in range(3):  # the edge (a, b) of the face, c the face's third vertex
        a, b, c = p[i], p[(i + 1) % 3], p[(i + 2) % 3]
        e = [b[d] - a[d] for d in range(3)]
        le = np.sqrt(dot(e, e))
        e = [e[d] / le for d in range(3)]
        u = [c[d] - a[d] for d in range(3)]
        v = [q[d] - a[d] for d in range(3)]
        ue, ve = dot(u, e), dot(v, e)
        u = [u[d] - ue * e[d] for d in range(3)]
        v = [v[d] - ve * e[d] for d in range(3)]
        cos = dot(u, v) / (np.sqrt(dot(u, u)) * np.sqrt(dot(v, v)))
        out = np.maximum(out, np.arccos(np.clip(cos, -1.0, 1.0)))
    return out


def conditioning_problem(
    xp: Float, x0: Float, phi: Float, faces: PositiveFacets
) -> tuple[float, Problem | None]:
    """The largest :func:`conditioning_dihedral` (radians) of the positively cut tetrahedra,
    and the problem of those above 90 degrees (None if there are none).

    Parameters
    ----------
    xp, x0
        Perturbed and unperturbed vertex positions ``(num_vertices, 3)``: the angles are a
        property of the background cells, measured at the unperturbed positions.
    phi
        Signed distances ``(num_vertices,)`` (not read).
    faces
        Positive faces of the owned positively cut tetrahedra (at least one).
    """
    theta = conditioning_dihedral(x0, faces.facets, faces.w)
    bad = theta > np.pi / 2 + 1e-9  # right angles (BCC) allowed up to rounding
    if not bad.any():
        return float(theta.max()), None
    text = (
        "dihedral angle above 90 degrees at the positive face of {count} positively "
        "cut tetrahedra near {where}: use a background mesh that is non-obtuse near "
        "the boundary (e.g. a15_mesh or bcc_mesh)"
    )
    return float(theta.max()), Problem(text, xp[faces.facets[bad]].mean(axis=1), int(bad.sum()))


def open_chains(count: Int) -> Bool:
    """No vertex flagged ``(n,)``: the surface of positive faces is checked as a whole, by
    :func:`surface_topology` (the triangles' counterpart flags vertices of Gamma_h without
    two positive edges)."""
    return np.zeros(len(count), dtype=bool)


class Containment:
    """The containment check of a tetrahedron background: samples of Gamma located in the
    stars of the vertices near Gamma, then, for the few left, in the cells near them.

    Parameters
    ----------
    x
        Background vertex coordinates ``(num_vertices, 3)``.
    c2v
        Background cells ``(num_cells, 4)``.
    """

    def __init__(self, x: Float, c2v: Int) -> None:
        self.x, self.c2v = x, c2v

    def problems(
        self,
        comm: MPI.Comm,
        pts: Float,
        phi: Float,
        h: Float,
        near_cells: npt.NDArray[np.int32],
        near_cv: Int,
        v2c: tuple[Int, Int],
    ) -> list[Problem]:
        """The samples ``pts`` of Gamma in no cell of any rank (collective). Only the cells
        that can hold a sample are searched: each vertex within its size ``h`` (at least the
        diameter of its cells) of Gamma (``|phi| <= h``), and next to a sample."""
        x = self.x
        near_v = np.abs(phi) <= h
        size = float(h[near_v].max()) if near_v.any() else 0.0
        v2c_offsets, v2c_cells = v2c
        found, left = samples_in_stars(x, near_v, v2c_offsets, v2c_cells, self.c2v, pts, size)
        if left.any():  # the exhaustive search, rarely needed
            r = np.flatnonzero(left)
            cv = near_cv[cells_near_points(x, near_cv, near_v, pts[r], size)]
            found[r] = points_in_cells(x, cv, pts[r], size)
        return missing_samples_problems(comm, pts, found)


def topology_problems(
    comm: MPI.Comm,
    gids: npt.NDArray[np.int64],
    xp: Float,
    faces: PositiveFacets,
    parts: SurfaceParts,
    far_kept: bool,
) -> tuple[list[Problem], int, int]:
    """:func:`surface_topology` of the positive ``faces`` (global vertex indices ``gids``)
    at positions ``xp`` (collective)."""
    f = faces.facets
    return surface_topology(comm, gids, xp[f[:, 0]], xp[f[:, 1]], xp[f[:, 2]], parts, far_kept)


def all_outside_faces(
    s: Float,
    phi: Float,
    cells: Int,
    facets: Int,
    w: Int,
    c2v: Int,
    c2f: Int,
    f2c_offsets: Int,
    f2c: Int,
    kept: npt.NDArray[np.bool_],
) -> tuple[Int, Int]:
    """Positive faces whose other tetrahedron is kept too, and the vertex that repairs each.

    Such a face has its three vertices outside with an inside vertex on both sides: the
    domain is under-resolved there (typically a saddle), and the snapped face would squeeze
    a tetrahedron between itself and the surface. Counting the shallower of the two inside
    vertices (the larger ``phi``) as on Gamma removes the face.

    Parameters
    ----------
    s, phi
        Vertex signs and signed distances ``(num_vertices,)``.
    cells
        Positively cut cells ``(m,)``; ``facets (m, 3)`` their positive faces and ``w (m,)``
        their inside vertices.
    c2v, c2f
        Cell -> vertex and cell -> face connectivity ``(num_cells, 4)``.
    f2c_offsets, f2c
        Face -> cell adjacency list.
    kept
        Kept cells ``(num_cells,)``.

    Returns
    -------
    rows
        Indices into ``cells`` of the faces concerned ``(k,)``.
    vertices
        The vertex to count as on Gamma for each ``(k,)``.
    """
    if len(cells) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    k = np.argmin(s[c2v[cells]], axis=1)  # local facet k is opposite local vertex k
    f = c2f[cells, k]
    off = f2c_offsets
    two = np.flatnonzero(off[f + 1] - off[f] == 2)
    c0, c1 = f2c[off[f[two]]], f2c[off[f[two]] + 1]
    other = np.where(c0 == cells[two], c1, c0)
    rows = two[kept[other]]
    other = other[kept[other]]
    ov = c2v[other]
    in_face = (ov[:, :, None] == facets[rows][:, None, :]).any(axis=2)
    opposite = ov[~in_face]  # one vertex each
    mine = w[rows]
    pick = np.where(phi[opposite] > phi[mine], opposite, mine)
    return rows, pick


@dataclass(frozen=True)
class SurfaceParts:
    """The closed surfaces of Gamma, sampled, with what the positive faces must match."""

    points: Float
    """Samples of Gamma ``(n, 3)``."""
    labels: Int
    """Surface of each sample ``(n,)``."""
    euler: Int
    """Euler characteristic of each surface (of all its pieces) ``(num_surfaces,)``."""
    pieces: Int
    """Connected pieces of each surface ``(num_surfaces,)`` (an implicit surface may have
    several)."""
    encloses_domain: npt.NDArray[np.bool_]
    """Whether the domain lies inside each surface ``(num_surfaces,)``."""
    expected_pieces: int
    """Connected pieces of the domain in a box containing Gamma."""

    @property
    def num_surfaces(self) -> int:
        return len(self.euler)


def surface_parts(boundary: Boundary, n: int = 4096) -> SurfaceParts:
    """Samples, Euler characteristics and sides of the surfaces of ``boundary``.

    A :class:`~dolfinx_universal.boundaries.domains.Domain` has one surface per component (the
    container encloses the domain, the bodies do not); any other surface is one component
    enclosing the domain.
    """
    components = getattr(boundary, "components", None)
    parts = [(boundary, False)] if components is None else components
    pts, labels, euler, pieces, encloses = [], [], [], [], []
    for k, (surface, is_body) in enumerate(parts):
        p = np.asarray(surface.sample(n), dtype=np.float64)
        pts.append(p)
        labels.append(np.full(len(p), k))
        euler.append(int(getattr(surface, "euler_characteristic", 2)))
        pieces.append(int(getattr(surface, "num_components", 1)))
        encloses.append(not is_body)
    lo, hi = np.asarray(boundary.bounding_box(), dtype=np.float64)
    far = hi + max(float(np.linalg.norm(hi - lo)), 1.0)
    far_inside = bool(np.asarray(boundary.sign(far[None, :]))[0] < 0)
    return SurfaceParts(
        points=np.concatenate(pts),
        labels=np.concatenate(labels),
        euler=np.asarray(euler, dtype=np.int64),
        pieces=np.asarray(pieces, dtype=np.int64),
        encloses_domain=np.asarray(encloses, dtype=bool),
        expected_pieces=int(sum(p for p, e in zip(pieces, encloses) if e)) + int(far_inside),
    )


def _sorted_unique(key: Int) -> tuple[Int, Int, Int, Int]:
    """``np.unique(key, return_inverse=True, return_counts=True)`` by a sort (numpy's
    hashing unique is many times slower here), and the sort order ``(n,)``."""
    order = np.argsort(key, kind="stable")
    sk = key[order]
    first = np.ones(len(sk), dtype=bool)
    first[1:] = sk[1:] != sk[:-1]
    inv = np.empty(len(key), dtype=np.int64)
    inv[order] = np.cumsum(first) - 1
    starts = np.flatnonzero(first)
    return sk[starts], inv, np.diff(np.append(starts, len(sk))), order


def _components(nodes: int, i: Int, j: Int) -> tuple[int, Int]:
    """Connected components of the graph with ``nodes`` nodes and edges ``(i, j)``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(nodes, nodes))
    count, label = connected_components(graph, directed=False)
    return int(count), label


def surface_topology(
    comm: MPI.Comm,
    faces_global: npt.NDArray[np.int64],
    pa: Float,
    pb: Float,
    pc: Float,
    parts: SurfaceParts,
    far_kept: bool,
) -> tuple[list[Problem], int, int]:
    """Check that the positive faces form one closed oriented surface per surface of Gamma.

    The faces are gathered on rank 0 (their number grows with the surface, not the mesh).
    Checks: every edge lies in exactly two faces, traversed once each way (closed and
    consistently oriented); the faces around every vertex form one fan (a 2-manifold);
    every connected piece follows one surface of Gamma (the nearest surface of all its
    faces), every surface is followed by exactly one piece with its Euler characteristic;
    each piece keeps the domain's side (its enclosed volume, from the outward-oriented
    faces, is positive exactly when the domain lies inside the surface); the kept region
    has as many pieces as the domain.

    Parameters
    ----------
    comm
        Communicator of the mesh.
    faces_global
        Positive faces of this rank's owned positively cut cells as global vertex indices,
        oriented out of the domain ``(m, 3)``; each face listed by exactly one rank.
    pa, pb, pc
        Coordinates of their vertices ``(m, 3)``.
    parts
        The surfaces of Gamma (:func:`surface_parts`).
    far_kept
        Whether kept cells touch the background's boundary (same on every rank).

    Returns
    -------
    problems
        Problems found, on rank 0 (empty elsewhere).
    num_surfaces, num_pieces
        Closed pieces of Gamma_h and connected pieces of the kept region (every rank).
    """
    data = comm.gather((faces_global, pa, pb, pc), root=0)
    result: tuple[list[Problem], int, int] = ([], 0, 0)
    if comm.rank == 0:
        assert data is not None
        result = _topology(data, parts, far_kept)
    counts = comm.bcast(result[1:], root=0)
    return result[0], counts[0], counts[1]


def _topology(data: list, parts: SurfaceParts, far_kept: bool) -> tuple[list[Problem], int, int]:
    """:func:`surface_topology` on the gathered faces (rank 0)."""
    g = np.concatenate([d[0] for d in data]).reshape(-1, 3).astype(np.int64)
    a, b, c = (np.concatenate([d[k] for d in data]).reshape(-1, 3) for k in (1, 2, 3))
    messages = TOPOLOGY_MESSAGES[3]
    if len(g) == 0:
        points = parts.points[:: max(1, len(parts.points) // 16)]
        return [Problem(messages.empty(parts.num_surfaces), points)], 0, int(far_kept)
    mid = (a + b + c) / 3.0
    nodes, inv, _, _ = _sorted_unique(g.ravel())
    f = inv.reshape(-1, 3)
    edges = _face_edges(f, len(nodes))
    problems = _open_edge_problems(edges, mid)
    # Pieces: faces joined through shared edges (consecutive in the edges' sort order).
    se = edges.inverse[edges.order]
    same = np.flatnonzero(se[1:] == se[:-1])
    face_order = edges.face_of[edges.order]
    npieces, piece = _components(len(f), face_order[same], face_order[same + 1])
    problems += _pinch_problems(f, edges, mid)
    chi = _euler_characteristics(f, edges, piece, npieces)
    main, follow = _following_problems(parts, mid, piece, npieces, chi)
    problems += follow
    side, pieces = _side_problems(parts, (a, b, c), mid, piece, npieces, main, far_kept)
    problems += side
    if not problems and pieces != parts.expected_pieces:
        problems.append(Problem(messages.pieces(pieces, parts.expected_pieces), mid))
    return problems, npieces, pieces


class _FaceEdges(NamedTuple):
    """The directed edges ``(i -> j)`` of the faces (three per face, in face order) and the
    undirected edges they traverse."""

    di: Int
    """Start of each directed edge ``(3 nf,)``."""
    dj: Int
    """End of each directed edge ``(3 nf,)``."""
    face_of: Int
    """The face of each directed edge ``(3 nf,)``."""
    keys: Int
    """The undirected edges ``min * nn + max``, sorted and distinct ``(ne,)``."""
    inverse: Int
    """The undirected edge of each directed edge ``(3 nf,)``."""
    traversals: Int
    """How many directed edges traverse each undirected edge ``(ne,)``."""
    order: Int
    """The directed edges sorted by their undirected edge ``(3 nf,)``."""
    balance: Float
    """Traversals from the smaller to the larger end less those back ``(ne,)``."""
    num_nodes: int
    """Number of vertices ``nn``."""


def _face_edges(f: Int, nn: int) -> _FaceEdges:
    """The directed and undirected edges of faces ``f`` ``(nf, 3)`` on ``nn`` vertices."""
    di = f.ravel()
    dj = f[:, [1, 2, 0]].ravel()
    face_of = np.repeat(np.arange(len(f)), 3)
    key = np.minimum(di, dj) * nn + np.maximum(di, dj)
    sign = np.where(di < dj, 1, -1)
    ukey, einv, ecount, order = _sorted_unique(key)
    balance = np.bincount(einv, sign, minlength=len(ukey))
    return _FaceEdges(di, dj, face_of, ukey, einv, ecount, order, balance, nn)


def _open_edge_problems(edges: _FaceEdges, mid: Float) -> list[Problem]:
    """The edges not traversed exactly once each way: a closed oriented surface has none."""
    bad_edge = (edges.traversals != 2) | (edges.balance != 0)
    if not bad_edge.any():
        return []
    e = np.flatnonzero(bad_edge[edges.inverse])
    return [
        Problem(
            "the positive faces do not form a closed, consistently oriented surface at "
            "{count} edges near {where}: the background is too coarse for the surface's "
            "curvature or for the gap between its parts there; refine near them",
            mid[edges.face_of[e]],
            int(bad_edge.sum()),
        )
    ]


def _pinch_problems(f: Int, edges: _FaceEdges, mid: Float) -> list[Problem]:
    """The vertices where the faces around a vertex form more than one fan (its link is not
    connected): two sheets of Gamma_h touch there."""
    di, dj, einv, nn = edges.di, edges.dj, edges.inverse, edges.num_nodes
    # The link of vertex v: a node per edge (v, u), node 2 e + (v > u) of edge e; the face
    # (v, p, q) joins the nodes of its edges (v, p) and (q, v).
    up = di > dj  # the corner's vertex di is the larger end of its outgoing edge
    prev = (np.arange(3 * len(f)).reshape(-1, 3)[:, [2, 0, 1]]).ravel()  # the edge into di
    n1 = 2 * einv + up
    n2 = 2 * einv[prev] + ~up[prev]
    nlink, llabel = _components(2 * len(edges.keys), n1, n2)
    lo, hi = edges.keys // nn, edges.keys % nn
    owner = np.column_stack([lo, hi]).ravel()  # the vertex of node 2 e + side
    comp_owner = np.zeros(nlink, dtype=np.int64)
    comp_owner[llabel] = owner
    fans = np.bincount(comp_owner, minlength=nn)
    pinched = np.flatnonzero(fans > 1)
    if not len(pinched):
        return []
    at = np.isin(f.ravel(), pinched)
    return [
        Problem(
            "the positive faces pinch at {count} vertices near {where} (two sheets of "
            "Gamma_h touch): a gap or thin part is not resolved there; refine near them",
            mid[edges.face_of[at]],
            len(pinched),
        )
    ]


def _euler_characteristics(f: Int, edges: _FaceEdges, piece: Int, npieces: int) -> Int:
    """The Euler characteristic ``V - E + F`` of each piece of faces ``(npieces,)``."""
    v_piece = np.zeros(edges.num_nodes, dtype=np.int64)
    v_piece[f.ravel()] = np.repeat(piece, 3)
    e_piece = np.zeros(len(edges.keys), dtype=np.int64)
    e_piece[edges.inverse] = piece[edges.face_of]
    return (
        np.bincount(v_piece, minlength=npieces)
        - np.bincount(e_piece, minlength=npieces)
        + np.bincount(piece, minlength=npieces)
    )


def _following_problems(
    parts: SurfaceParts, mid: Float, piece: Int, npieces: int, chi: Int
) -> tuple[Int, list[Problem]]:
    """The surface of Gamma each piece follows (the nearest surface of most of its faces)
    ``(npieces,)``, and the problems of pieces that join surfaces, of surfaces followed by
    too few or too many pieces, and of pieces with the wrong Euler characteristic."""
    messages = TOPOLOGY_MESSAGES[3]
    nsurf, nf = parts.num_surfaces, len(piece)
    problems: list[Problem] = []
    if nsurf == 1:  # every face follows the one surface (no tree of its samples needed)
        surface = np.zeros(nf, dtype=np.int64)
    else:
        tree = cKDTree(parts.points, balanced_tree=False, compact_nodes=False)
        surface = parts.labels[tree.query(mid)[1]]
    votes = np.bincount(piece * nsurf + surface, minlength=npieces * nsurf)
    main = votes.reshape(npieces, nsurf).argmax(axis=1)
    mixed = surface != main[piece]
    if mixed.any():
        pairs = np.unique(main[piece[mixed]] * nsurf + surface[mixed])  # a few pairs
        pairs_list = [(int(p // nsurf), int(p % nsurf)) for p in pairs]
        problems.append(Problem(messages.joined(pairs_list), mid[mixed], int(mixed.sum())))
    per_surface = np.bincount(main, minlength=nsurf)
    for k in np.flatnonzero(per_surface != parts.pieces):
        pts = parts.points[parts.labels == k]
        if per_surface[k] == 0:
            text = messages.lost(int(k), pts[:1])
        elif per_surface[k] < parts.pieces[k]:
            text = (
                f"surface {k} of the boundary has {parts.pieces[k]} pieces but Gamma_h "
                f"follows it with {per_surface[k]}: pieces of it are joined or lost near "
                "{where}; refine the background there"
            )
        else:
            text = messages.split(int(k), int(per_surface[k]))
            pts = mid[np.isin(piece, np.flatnonzero(main == k))]
        problems.append(Problem(text, pts))
    chi_surface = np.bincount(main, chi, minlength=nsurf).astype(np.int64)
    for k in np.flatnonzero((chi_surface != parts.euler) & (per_surface == parts.pieces)):
        problems.append(
            Problem(
                f"Gamma_h following surface {k} has Euler characteristic {chi_surface[k]} "
                f"where the surface has {int(parts.euler[k])} (a handle or hole of the "
                "surface is not resolved, or a spurious one appears) near {where}: refine "
                "the background there",
                mid[np.isin(piece, np.flatnonzero(main == k))],
            )
        )
    return main, problems


def _side_problems(
    parts: SurfaceParts,
    corners: tuple[Float, Float, Float],
    mid: Float,
    piece: Int,
    npieces: int,
    main: Int,
    far_kept: bool,
) -> tuple[list[Problem], int]:
    """The pieces that keep the wrong side of their surface, from their enclosed volumes
    (divergence theorem, faces oriented out of the domain), and the number of connected
    pieces of the kept region."""
    a, b, c = corners
    messages = TOPOLOGY_MESSAGES[3]
    vol = np.bincount(piece, (a * np.cross(b, c)).sum(axis=1), minlength=npieces) / 6.0
    inside = vol > 0
    wrong = inside != parts.encloses_domain[main]
    problems = [
        Problem(messages.wrong_side(int(main[k])), mid[piece == k]) for k in np.flatnonzero(wrong)
    ]
    return problems, int(inside.sum()) + int(far_kept)


def sample_gamma(comm: MPI.Comm, boundary: Boundary, spacing: float) -> SurfaceParts:
    """:func:`surface_parts` with about one sample per ``spacing**2`` of area, at least 4096
    per surface (collective: a failure of the boundary's sampler is raised on every rank).

    A boundary of one surface gets 4096: its samples only place messages (every positive
    face follows that surface; the dense samples tell the surfaces of several apart)."""
    lo, hi = np.asarray(boundary.bounding_box(), dtype=np.float64)
    extent = float(np.max(hi - lo))
    n = int(min(max(4096, 4.0 * np.pi * (extent / max(spacing, 1e-300)) ** 2), 400_000))
    if len(getattr(boundary, "components", None) or [None]) == 1:
        n = 4096
    return collective_call(comm, "sampling the boundary", surface_parts, boundary, n)
