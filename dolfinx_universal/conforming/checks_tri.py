"""The checks of triangle backgrounds: conditioning angle, Gamma_h's loops, containment.

The per-dimension part of the classification checks for triangles (Rangarajan & Lew 2014):
the conditioning angle of the positively cut triangles must stay below 90 degrees, and the
positive edges must form one closed simple loop per curve of Gamma, on the domain's side.
"""

from __future__ import annotations

from functools import cached_property
from typing import TYPE_CHECKING

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.conforming.classify import conditioning_angle, proximal_vertex
from dolfinx_universal.conforming.locate import (
    CellLocator,
    containment_problems,
    missing_samples_problems,
)
from dolfinx_universal.conforming.messages import TOPOLOGY_MESSAGES
from dolfinx_universal.core.arrays import Bool, Float, Int
from dolfinx_universal.core.collective import Problem, collective_call
from dolfinx_universal.sizing.fields import CurveSamples, curve_samples

if TYPE_CHECKING:
    from dolfinx_universal.boundaries.base import Boundary
    from dolfinx_universal.conforming.snap import PositiveFacets

__all__ = [
    "Containment",
    "conditioning_problem",
    "gamma_h_topology",
    "no_measures",
    "open_chains",
    "sample_gamma",
    "topology_problems",
]


def conditioning_problem(
    xp: Float, x0: Float, phi: Float, edges: PositiveFacets
) -> tuple[float, Problem | None]:
    """The largest conditioning angle (radians) of the positively cut triangles, and the
    problem of those at 90 degrees or more (None if there are none).

    Parameters
    ----------
    xp, x0
        Perturbed and unperturbed vertex positions ``(num_vertices, 2)`` (the angle is that
        of the perturbed triangles).
    phi
        Signed distances ``(num_vertices,)``.
    edges
        Positive edges of the owned positively cut triangles (at least one).
    """
    u, v, w = edges.u, edges.v, edges.w
    theta = conditioning_angle(xp, phi, u, v, w)
    bad = theta >= np.pi / 2 - 1e-12
    if not bad.any():
        return float(theta.max()), None
    places = xp[proximal_vertex(xp, phi, u[bad], v[bad], w[bad])]
    text = (
        "conditioning angle of 90 degrees or more in {count} positively cut "
        "triangles near {where}: use a background mesh that is acute near the "
        "boundary (e.g. equilateral or graded_mesh)"
    )
    return float(theta.max()), Problem(text, places, int(bad.sum()))


def open_chains(count: Int) -> Bool:
    """Vertices of Gamma_h without exactly two positive edges ``(n,)`` from their numbers of
    positive edges ``count``: Gamma_h is a set of closed simple curves where there are none."""
    return (count > 0) & (count != 2)


def no_measures(x: Float, y: Float, moved: Bool, cells: Int) -> None:
    """Triangles: the output checks measure the moved triangles themselves (the
    tetrahedra's counterpart measures them once for both checks)."""
    return None


def sample_gamma(comm: MPI.Comm, boundary: Boundary, spacing: float) -> CurveSamples:
    """Dense labelled samples of the curves of Gamma, ``spacing`` apart (collective)."""
    return collective_call(comm, "sampling the boundary", curve_samples, boundary, spacing)


class Containment:
    """The containment check of a triangle background: samples of Gamma located in the
    cells near Gamma (the first check of a background, a static domain) or, from the second
    check on (moving domains), with a locator of all cells, built once and cached.

    Parameters
    ----------
    x
        Background vertex coordinates ``(num_vertices, 2)``.
    c2v
        Background cells ``(num_cells, 3)``.
    """

    def __init__(self, x: Float, c2v: Int) -> None:
        self.x, self.c2v = x, c2v
        self.num_checks = 0

    @cached_property
    def locator(self) -> CellLocator:
        """Point location in the background's local cells (built at the first use)."""
        return CellLocator(self.x, self.c2v)

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
        """The samples ``pts`` of Gamma in no cell ``near_cells`` of any rank (collective;
        the arguments after ``pts`` follow the tetrahedra's check)."""
        cells = near_cells.astype(np.int32)
        if "locator" in self.__dict__ or self.num_checks:
            # The locator of all cells, built at the second check of this background
            # and cached (moving domains: one per step would cost more).
            problems = containment_problems(self.locator, pts, cells, comm)
        else:  # the first check (a static domain): a locator of the band's cells only
            found = CellLocator(self.x, self.c2v[cells]).contains(pts)
            problems = missing_samples_problems(comm, pts, found)
        self.num_checks += 1
        return problems


def topology_problems(
    comm: MPI.Comm,
    gids: npt.NDArray[np.int64],
    xp: Float,
    edges: PositiveFacets,
    samples: CurveSamples,
    far_kept: bool,
) -> tuple[list[Problem], int, int]:
    """:func:`gamma_h_topology` of the positive ``edges`` (global vertex indices ``gids``)
    at positions ``xp`` (collective)."""
    u, v, w = edges.u, edges.v, edges.w
    return gamma_h_topology(comm, gids, xp[u], xp[v], xp[w], samples, far_kept)


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
