"""Checks of a conforming mesh that no local test sees: Gamma_h topology and a quality floor."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from .classify import interior_angles
from .validation import Problem, where

if TYPE_CHECKING:
    from .sizing import CurveSamples

__all__ = ["gamma_h_topology", "low_quality_cells"]

Float = npt.NDArray[np.float64]


def _loops(gids: npt.NDArray[np.int64]) -> tuple[int, npt.NDArray[np.int64]]:
    """Connected components of the graph of edges ``gids (m, 2)``: ``(count, label per edge)``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nodes, inv = np.unique(gids, return_inverse=True)
    inv = inv.reshape(-1, 2)
    n = len(nodes)
    graph = coo_matrix((np.ones(len(inv)), (inv[:, 0], inv[:, 1])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    return int(count), label[inv[:, 0]]


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
        Dense samples of Gamma with curve labels (:func:`~dolfinx_universal.sizing.curve_samples`).
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
    result = _topology(data, samples, far_kept) if comm.rank == 0 else ([], 0, 0)
    counts = comm.bcast(result[1:], root=0)
    return result[0], counts[0], counts[1]


def _topology(data: list, samples: CurveSamples, far_kept: bool) -> tuple[list[Problem], int, int]:
    """:func:`gamma_h_topology` on the gathered edges (rank 0)."""
    g = np.concatenate([d[0] for d in data]).reshape(-1, 2)
    a = np.concatenate([d[1] for d in data]).reshape(-1, 2)
    b = np.concatenate([d[2] for d in data]).reshape(-1, 2)
    c = np.concatenate([d[3] for d in data]).reshape(-1, 2)
    ncurves = samples.num_curves
    problems: list[Problem] = []
    if len(g) == 0:
        return [
            Problem(
                f"Gamma_h is empty: no positive edge follows any of the {ncurves} curves of "
                "the boundary near {where}; the background is too coarse for the domain "
                "there; refine near those points",
                samples.points,
            )
        ], 0, int(far_kept)
    from scipy.spatial import cKDTree

    nloops, loop = _loops(g)
    # Orient each edge with its kept cell on the left.
    d, e = b - a, c - a
    left = d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0] > 0
    a, b = np.where(left[:, None], a, b), np.where(left[:, None], b, a)
    area = np.bincount(loop, a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], minlength=nloops) / 2
    mid = 0.5 * (a + b)
    curve = samples.labels[cKDTree(samples.points).query(mid)[1]]
    # The curve of each loop: the most frequent label among its edges.
    counts = np.zeros((nloops, ncurves), dtype=np.int64)
    np.add.at(counts, (loop, curve), 1)
    main = counts.argmax(axis=1)
    mixed = curve != main[loop]
    if mixed.any():
        pairs = sorted({(int(main[k]), int(j)) for k, j in zip(loop[mixed], curve[mixed])})
        problems.append(
            Problem(
                "Gamma_h joins different curves of the boundary (curves "
                + ", ".join(f"{i} and {j}" for i, j in pairs[:3])
                + ") near {where}: the gap between them is not resolved by the background; "
                "refine to below the gap there",
                mid[mixed],
                int(mixed.sum()),
            )
        )
    per_curve = np.bincount(main, minlength=ncurves)
    for k in np.flatnonzero(per_curve != 1):
        pts = samples.points[samples.labels == k]
        if per_curve[k] == 0:
            text = (
                f"curve {k} of the boundary (near {where(pts[:1])}) is lost: no loop of "
                "Gamma_h follows it, so the mesh would ignore that part of the boundary (a "
                "body or feature smaller than the background's triangles); refine the "
                "background near it (places: {where})"
            )
        else:
            text = (
                f"curve {k} of the boundary is split into {per_curve[k]} loops of Gamma_h: a "
                "neck or thin part of the domain (or a gap) is narrower than the background's "
                "triangles near {where}; refine the background there"
            )
            sel = np.isin(loop, np.flatnonzero(main == k))
            pts = _pinch_points(mid[sel], loop[sel], pts)
        problems.append(Problem(text, pts))
    inside = area > 0
    wrong = inside != samples.encloses_domain[main]
    for k in np.flatnonzero(wrong):
        problems.append(
            Problem(
                f"Gamma_h around curve {int(main[k])} keeps the wrong side of it near "
                "{where}: the background is too coarse for the domain there; refine near it",
                mid[loop == k],
            )
        )
    pieces = int(inside.sum()) + int(far_kept)
    if not problems and pieces != samples.expected_pieces:
        problems.append(
            Problem(
                f"the kept triangles form {pieces} connected pieces where the domain has "
                f"{samples.expected_pieces}, near {{where}}: refine the background near them",
                mid,
            )
        )
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
    y: Float, cells: npt.NDArray, min_angle_deg: float
) -> tuple[Problem | None, float, float]:
    """Conforming triangles whose smallest angle is below a floor.

    Parameters
    ----------
    y
        Vertex positions of the conforming mesh ``(num_vertices, 2)``.
    cells
        Triangles to check ``(m, 3)`` (the moved ones: the others keep the background's
        angles).
    min_angle_deg
        The floor in degrees (0 disables the check).

    Returns
    -------
    problem
        A report of the cells below the floor, or None.
    theta_min, theta_max
        Smallest and largest angle (degrees) of these cells (180 and 0 when there are none).
    """
    if len(cells) == 0:
        return None, 180.0, 0.0
    ang = np.degrees(interior_angles(y, cells))
    small = ang.min(axis=1)
    lo, hi = float(small.min()), float(ang.max())
    bad = small < min_angle_deg
    if not bad.any():
        return None, lo, hi
    problem = Problem(
        "{count} conforming triangles have an angle below the quality floor of "
        f"{min_angle_deg:g} degrees near {{where}}: refine the background there (or lower "
        "min_angle)",
        y[cells[bad]].mean(axis=1),
        int(bad.sum()),
    )
    return problem, lo, hi
