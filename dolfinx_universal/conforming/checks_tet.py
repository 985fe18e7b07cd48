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
from typing import TYPE_CHECKING

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.conforming.checks import TOPOLOGY_MESSAGES
from dolfinx_universal.core.arrays import Float, Int
from dolfinx_universal.core.collective import Problem, collective_call

if TYPE_CHECKING:
    from dolfinx_universal.boundaries.curves import Boundary

__all__ = [
    "SurfaceParts",
    "all_outside_faces",
    "conditioning_dihedral",
    "surface_parts",
    "surface_topology",
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

    A :class:`~dolfinx_universal.boundaries.curves.Domain` has one surface per component (the
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
    nsurf = parts.num_surfaces
    messages = TOPOLOGY_MESSAGES[3]
    if len(g) == 0:
        return (
            [
                Problem(
                    messages.empty(nsurf),
                    parts.points[:: max(1, len(parts.points) // 16)],
                )
            ],
            0,
            int(far_kept),
        )
    from scipy.spatial import cKDTree

    problems: list[Problem] = []
    mid = (a + b + c) / 3.0
    nodes, inv, _, _ = _sorted_unique(g.ravel())
    f = inv.reshape(-1, 3)
    nf, nn = len(f), len(nodes)
    # Directed edges (i -> j) of every face; a closed oriented surface has each edge once
    # each way.
    di = f.ravel()
    dj = f[:, [1, 2, 0]].ravel()
    face_of = np.repeat(np.arange(nf), 3)
    key = np.minimum(di, dj) * nn + np.maximum(di, dj)
    sign = np.where(di < dj, 1, -1)
    ukey, einv, ecount, order = _sorted_unique(key)
    balance = np.bincount(einv, sign, minlength=len(ukey))
    bad_edge = (ecount != 2) | (balance != 0)
    if bad_edge.any():
        e = np.flatnonzero(bad_edge[einv])
        problems.append(
            Problem(
                "the positive faces do not form a closed, consistently oriented surface at "
                "{count} edges near {where}: the background is too coarse for the surface's "
                "curvature or for the gap between its parts there; refine near them",
                mid[face_of[e]],
                int(bad_edge.sum()),
            )
        )
    # Pieces: faces joined through shared edges (consecutive in the edges' sort order).
    se = einv[order]
    same = np.flatnonzero(se[1:] == se[:-1])
    npieces, piece = _components(nf, face_of[order][same], face_of[order][same + 1])
    # Manifold vertices: the faces around a vertex form one fan (its link is connected).
    corner_v = f.ravel()
    corner_face = face_of
    # The link of vertex v: a node per edge (v, u), node 2 e + (v > u) of edge e; the face
    # (v, p, q) joins the nodes of its edges (v, p) and (q, v).
    up = di > dj  # the corner's vertex di is the larger end of its outgoing edge
    prev = (np.arange(3 * nf).reshape(-1, 3)[:, [2, 0, 1]]).ravel()  # the edge into di
    n1 = 2 * einv + up
    n2 = 2 * einv[prev] + ~up[prev]
    nlink, llabel = _components(2 * len(ukey), n1, n2)
    lo, hi = ukey // nn, ukey % nn
    owner = np.column_stack([lo, hi]).ravel()  # the vertex of node 2 e + side
    comp_owner = np.zeros(nlink, dtype=np.int64)
    comp_owner[llabel] = owner
    fans = np.bincount(comp_owner, minlength=nn)
    pinched = np.flatnonzero(fans > 1)
    if len(pinched):
        at = np.isin(corner_v, pinched)
        problems.append(
            Problem(
                "the positive faces pinch at {count} vertices near {where} (two sheets of "
                "Gamma_h touch): a gap or thin part is not resolved there; refine near them",
                mid[corner_face[at]],
                len(pinched),
            )
        )
    # Euler characteristic and surface of each piece.
    v_piece = np.zeros(nn, dtype=np.int64)
    v_piece[f.ravel()] = np.repeat(piece, 3)
    e_piece = np.zeros(len(ukey), dtype=np.int64)
    e_piece[einv] = piece[face_of]
    chi = (
        np.bincount(v_piece, minlength=npieces)
        - np.bincount(e_piece, minlength=npieces)
        + np.bincount(piece, minlength=npieces)
    )
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
    # Enclosed volume of each piece (divergence theorem, faces oriented out of the domain).
    vol = np.bincount(piece, (a * np.cross(b, c)).sum(axis=1), minlength=npieces) / 6.0
    inside = vol > 0
    wrong = inside != parts.encloses_domain[main]
    for k in np.flatnonzero(wrong):
        problems.append(Problem(messages.wrong_side(int(main[k])), mid[piece == k]))
    pieces = int(inside.sum()) + int(far_kept)
    if not problems and pieces != parts.expected_pieces:
        problems.append(Problem(messages.pieces(pieces, parts.expected_pieces), mid))
    return problems, npieces, pieces


def sampled_parts(comm: MPI.Comm, boundary: Boundary, spacing: float) -> SurfaceParts:
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
