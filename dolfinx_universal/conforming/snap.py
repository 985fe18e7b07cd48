"""Stages of the straight map: signs near Gamma, band projection, eta perturbation, Gamma_h, M_h.

Each stage works on process-local arrays of one background (owned and ghost vertices, owned
cells first) and is collective where it calls the boundary or combines vertex values.
:meth:`dolfinx_universal.conforming.universal.UniversalMesh.straight_map` runs them in order.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh

from dolfinx_universal.conforming.checks_tet import all_outside_faces
from dolfinx_universal.conforming.classify import (
    inward_push,
    kept_cells,
    perturbation_candidates,
    positive_facets,
    positively_cut,
    shifted_vertices,
)
from dolfinx_universal.conforming.classify import straight_map as _straight_map
from dolfinx_universal.core.arrays import Bool, Float, Int
from dolfinx_universal.core.collective import (
    Problem,
    collective_call,
    raise_collective,
    vertex_reduce,
)

if TYPE_CHECKING:
    from dolfinx.common import IndexMap

    from dolfinx_universal.boundaries.base import Boundary

__all__ = [
    "Band",
    "BandCells",
    "PositiveFacets",
    "band_cells",
    "classify_near",
    "frozen_images",
    "gamma_h",
    "map_band",
    "perturb",
    "project_band",
    "relocate",
    "scan_cells",
    "tetrahedron_band",
    "tetrahedron_candidates",
    "tetrahedron_repair",
    "triangle_band",
    "triangle_candidates",
    "triangle_repair",
]


def classify_near(
    comm: MPI.Comm, boundary: Boundary, x: Float, h: Float, R_r: Float
) -> tuple[Float, Int]:
    """Vertex signs, and the vertices within ``R_r`` of Gamma (collective).

    Gamma lies in its bounding box, so every vertex outside the box (enlarged by the band
    width) has the sign of the far field: only the vertices in the box are tested, and only
    those within their own ``R_r`` of Gamma are in the band (to be projected; a cheap
    superset, :meth:`~dolfinx_universal.boundaries.base.Boundary.near`).

    Parameters
    ----------
    comm
        Communicator of the mesh.
    boundary
        The domain.
    x
        Vertex coordinates ``(num_vertices, gdim)``.
    h, R_r
        Mesh size and relaxation radius at each vertex ``(num_vertices,)``.

    Returns
    -------
    s
        Vertex signs (-1 inside, +1 outside or on Gamma) ``(num_vertices,)``.
    band
        Indices of the vertices in the band ``(num_band,)``.
    """
    nv = len(x)
    rmax = float(R_r.max()) if nv else 0.0
    pad = rmax + 2.0 * (float(h.max()) if nv else 0.0)

    def local() -> tuple[Float, Int]:  # the boundary's calls, checked on all ranks at once
        box = np.asarray(boundary.bounding_box(), dtype=float)
        lo, hi = box[0] - pad, box[1] + pad
        far = np.asarray(boundary.sign((hi + pad)[None]), dtype=float)[0]
        inbox = (x[:, 0] >= lo[0]) & (x[:, 0] <= hi[0])  # by columns: an all() along a
        for k in range(1, x.shape[1]):  # short axis is slow in numpy
            inbox &= (x[:, k] >= lo[k]) & (x[:, k] <= hi[k])
        cand = np.flatnonzero(inbox)
        s = np.full(nv, far)
        s[cand] = boundary.sign(x[cand])
        return s, cand[np.asarray(boundary.near(x[cand], R_r[cand]), dtype=bool)]

    return collective_call(comm, "the sign and band tests", local)


def project_band(
    comm: MPI.Comm, boundary: Boundary, x: Float, s: Float, band: Int, h: Float
) -> tuple[Float, Float, Float, Float]:
    """Signed distances, closest points and normals of the band vertices (collective).

    Points on Gamma count as outside. A vertex on Gamma up to rounding that the
    sign test put inside would be relaxed inwards while its neighbours snap onto it; it is
    treated as on Gamma (sign +1, distance 0).

    Parameters
    ----------
    comm, boundary, x
        As in :func:`classify_near`.
    s
        Vertex signs from :func:`classify_near` ``(num_vertices,)`` (not modified).
    band
        Band vertices ``(num_band,)``.
    h
        Mesh size at each vertex ``(num_vertices,)``.

    Returns
    -------
    s
        Signs with the vertices on Gamma set to +1 ``(num_vertices,)``.
    phi
        Signed distances; ``+-inf`` (by sign) outside the band ``(num_vertices,)``.
    closest, normal
        Closest points ``pi(x)`` and outward normals there; NaN outside the band
        ``(num_vertices, gdim)``.

    Raises
    ------
    MeshingError
        On every rank, when the projection returns NaN/inf somewhere.
    """
    nv, gdim = x.shape
    s = s.copy()
    phi = np.where(s < 0, -np.inf, np.inf)
    closest = np.full((nv, gdim), np.nan)
    normal = np.full((nv, gdim), np.nan)
    xb = x[band]
    phi_b, y_b, n_b = collective_call(comm, "closest-point projection", boundary.project_normal, xb)
    bad = ~(np.isfinite(phi_b) & np.isfinite(y_b).all(axis=1))
    raise_collective(
        comm,
        [Problem("closest-point projection returned NaN/inf for vertices at {where}",
                 xb[bad], int(bad.sum()), refinable=False)]
        if bad.any()
        else [],
    )  # fmt: skip
    phi[band], closest[band] = phi_b, y_b
    on_gamma = band[(phi_b <= 0) & (phi_b > -1e-10 * h[band])]
    s[on_gamma], phi[on_gamma] = 1.0, 0.0
    normal[band] = n_b
    return s, phi, closest, normal


def band_cells(
    topology: dmesh.Topology, band: Int, num_owned_cells: int
) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int32]]:
    """Cells of a triangle background with a vertex in the band: all of them, and the owned
    ones (DOLFINx's incident entities of the band's vertices).

    Every moved or positively cut cell is among them. Tetrahedra: :func:`scan_cells`.

    Parameters
    ----------
    topology
        Background topology (vertex -> cell connectivity created).
    band
        Band vertices ``(num_band,)``.
    num_owned_cells
        Number of owned cells (the first ones).

    Returns
    -------
    near_all
        Owned and ghost cells at the band ``(m,)``.
    near_owned
        The owned ones among them ``(m_owned,)``.
    """
    near_all = dmesh.compute_incident_entities(topology, band.astype(np.int32), 0, 2)
    return near_all, near_all[near_all < num_owned_cells]


@dataclass
class BandCells:
    """The cells at the band of a tetrahedral background, found by one scan of all cells.

    Attributes
    ----------
    cells
        Owned and ghost cells with a vertex in the band, increasing (owned ones first)
        ``(m,)``.
    num_owned
        How many of them are owned.
    cv
        Their vertices ``(m, 4)`` (``c2v[cells]``, gathered once for every stage).
    any_inside
        Cells with a vertex inside the domain by the signs of :func:`classify_near`
        ``(num_cells,)``. Later stages change signs of band vertices only, so this is the
        kept flag of every cell away from the band.
    """

    cells: npt.NDArray[np.int32]
    num_owned: int
    cv: Int
    any_inside: Bool

    @property
    def owned(self) -> npt.NDArray[np.int32]:
        """The owned cells among them ``(m_owned,)``."""
        return self.cells[: self.num_owned]


def scan_cells(c2v: Int, band: Int, s: Float, num_owned_cells: int) -> BandCells:
    """The cells at the band and the cells with an inside vertex, by one scan of all cells.

    Each vertex gets a code (1: in the band, 2: inside); a cell's codes are or-ed over its
    vertices. Tetrahedra: this replaces :func:`band_cells` and the scan of
    :func:`~dolfinx_universal.conforming.classify.kept_cells` (about 20 ms each at 1e6
    tetrahedra).

    Parameters
    ----------
    c2v
        Tetrahedra as vertex indices (owned cells first) ``(num_cells, 4)``.
    band
        Band vertices ``(num_band,)``.
    s
        Vertex signs from :func:`classify_near` ``(num_vertices,)``.
    num_owned_cells
        Number of owned cells.
    """
    code = (s < 0).astype(np.uint8) << 1
    code[band] |= 1
    # a cell's 4 codes as the bytes of one uint32: 3 times faster than 4 gathers
    word = np.take(code, c2v).view(np.uint32).ravel()
    near, inside = (word & 0x01010101) != 0, (word & 0x02020202) != 0
    cells = np.flatnonzero(near).astype(np.int32)
    num_owned = int(np.searchsorted(cells, num_owned_cells))
    return BandCells(cells, num_owned, c2v[cells], inside)


class Band(NamedTuple):
    """The cells at the band (a vertex within ``R_r`` of Gamma), as the stages after the
    projection use them."""

    cells: npt.NDArray[np.int32]
    """Owned and ghost cells at the band ``(m,)``."""
    owned: npt.NDArray[np.int32]
    """The owned ones among them ``(m_owned,)``."""
    owned_cv: Int
    """The vertices of the owned ones ``(m_owned, tdim + 1)``."""
    scan: BandCells | None
    """Tetrahedra: the scan of all cells that found them (:func:`scan_cells`), which also
    gives the kept cells away from the band; None for triangles."""


def triangle_band(
    topology: dmesh.Topology, c2v: Int, band: Int, s: Float, num_owned_cells: int
) -> Band:
    """The cells at the band of a triangle background (:func:`band_cells`)."""
    near_all, near_owned = band_cells(topology, band, num_owned_cells)
    return Band(near_all, near_owned, c2v[near_owned], None)


def tetrahedron_band(
    topology: dmesh.Topology, c2v: Int, band: Int, s: Float, num_owned_cells: int
) -> Band:
    """The cells at the band of a tetrahedron background: one scan of all cells for the band
    and the kept cells (:func:`scan_cells`)."""
    bc = scan_cells(c2v, band, s, num_owned_cells)
    return Band(bc.cells, bc.owned, bc.cv[: bc.num_owned], bc)


def triangle_candidates(x: Float, phi: Float, s: Float, near: Int, eta: float, h: Float) -> Int:
    """The vertices the eta perturbation relocates on triangles:
    :func:`~dolfinx_universal.conforming.classify.perturbation_candidates` of the cells
    ``near`` (Rangarajan & Lew 2014)."""
    return perturbation_candidates(x, phi, s, near, eta)


def tetrahedron_candidates(x: Float, phi: Float, s: Float, near: Int, eta: float, h: Float) -> Int:
    """The vertices the eta perturbation relocates on tetrahedra: the inside vertices within
    ``eta h`` of Gamma (:func:`~dolfinx_universal.conforming.classify.shifted_vertices`)."""
    return shifted_vertices(phi, s, eta, h)


def perturb(
    comm: MPI.Comm,
    imv: IndexMap,
    x: Float,
    phi: Float,
    s: Float,
    closest: Float,
    near: Int,
    eta: float,
    h: Float,
    candidates: Callable[[Float, Float, Float, Int, float, Float], Int],
) -> tuple[Float, Float, Float, int]:
    """The eta quality perturbation: relocate inside vertices too close to Gamma (collective).

    Vertices selected on any rank move to their closest point on Gamma (sign +1, distance
    0), until a fixed point. Triangles: those of
    :func:`~dolfinx_universal.conforming.classify.perturbation_candidates` (Rangarajan & Lew 2014);
    tetrahedra: the inside vertices within ``eta h`` of Gamma
    (:func:`~dolfinx_universal.conforming.classify.shifted_vertices`).

    Parameters
    ----------
    comm
        Communicator of the mesh.
    imv
        Vertex index map.
    x, closest
        Vertex coordinates and closest points ``(num_vertices, gdim)``.
    phi, s
        Signed distances and signs ``(num_vertices,)`` (not modified).
    near
        Owned cells at the band, as vertex indices ``(m, tdim + 1)``.
    eta
        Perturbation threshold; 0 disables the perturbation.
    h
        Mesh size at each vertex ``(num_vertices,)``.
    candidates
        The vertices to relocate, ``(x, phi, s, near, eta, h) -> (k,)``:
        :func:`triangle_candidates` or :func:`tetrahedron_candidates`.

    Returns
    -------
    xp, phi, s
        Perturbed positions ``(num_vertices, gdim)``, distances and signs
        ``(num_vertices,)``.
    num_relocated
        Number of vertices relocated (global).
    """
    nv = len(x)
    xp, phi, s = x.copy(), phi.copy(), s.copy()
    relocated = np.zeros(nv, dtype=bool)
    while eta > 0:
        cand = candidates(xp, phi, s, near, eta, h)
        if not comm.allreduce(bool((~relocated[cand]).any()), op=MPI.LOR):
            break  # nothing new on any rank (no reduction of flags needed)
        flag = np.zeros(nv)
        flag[cand] = 1.0
        new = (vertex_reduce(imv, flag, "sum") > 0) & ~relocated
        if comm.allreduce(int(new[: imv.size_local].sum())) == 0:
            break
        at = np.flatnonzero(new)  # (indices: one pass over the vertices, not four)
        xp[at], phi[at], s[at] = closest[at], 0.0, 1.0
        relocated[at] = True
    return xp, phi, s, comm.allreduce(int(relocated[: imv.size_local].sum()))


def relocate(
    comm: MPI.Comm, imv: IndexMap, xp: Float, phi: Float, s: Float, closest: Float, vertices: Int
) -> int:
    """Relocate ``vertices`` (found on any rank) onto Gamma in place: ``xp = pi(x)``, sign
    +1, distance 0 (collective). Returns the global number of vertices relocated."""
    flag = np.zeros(len(xp))
    flag[vertices] = 1.0
    new = (vertex_reduce(imv, flag, "sum") > 0) & (s < 0)
    xp[new], phi[new], s[new] = closest[new], 0.0, 1.0
    return int(comm.allreduce(int(new[: imv.size_local].sum())))


@dataclass
class PositiveFacets:
    """Positive facets of the owned positively cut cells, and the kept cells (Gamma_h).

    Attributes
    ----------
    cells
        Owned positively cut cells ``(m,)``.
    facets
        Their positive facets ``(m, tdim)`` (edges of triangles, faces of tetrahedra), in
        the order of :data:`~dolfinx_universal.conforming.classify.FACET_ORDER` (normals out of the
        domain).
    w
        Their inside vertices ``(m,)``.
    count
        Global number of positive facets at each vertex ``(num_vertices,)``.
    on_gamma
        Vertices of a positive facet (snapped onto Gamma) ``(num_vertices,)``.
    kept
        Cells of ``T_h^sub`` (owned and ghost) ``(num_cells,)``.
    near_kept
        Owned kept cells at the band ``(k,)``.
    in_kept
        Vertices of ``near_kept`` cells on any rank ``(num_vertices,)``.
    near_kept_cv
        The vertices of the ``near_kept`` cells ``(k, tdim + 1)``.
    """

    cells: Int
    facets: Int
    w: Int
    count: Float
    on_gamma: Bool
    kept: Bool
    near_kept: Int
    in_kept: Bool
    near_kept_cv: Int

    @property
    def u(self) -> Int:
        """First vertex of each positive edge (triangles) ``(m,)``."""
        return self.facets[:, 0]

    @property
    def v(self) -> Int:
        """Second vertex of each positive edge (triangles) ``(m,)``."""
        return self.facets[:, 1]


def gamma_h(
    imv: IndexMap, s: Float, c2v: Int, near_cells: Int, band: BandCells | None = None
) -> PositiveFacets:
    """Positive facets, Gamma_h and the kept cells from the final signs (collective).

    A vertex outside the domain in a kept cell is next to an inside vertex, hence in the
    band: the incidence counts near the band are all that the checks need.

    Parameters
    ----------
    imv
        Vertex index map.
    s
        Final vertex signs ``(num_vertices,)``.
    c2v
        Cell -> vertex connectivity (owned cells first) ``(num_cells, tdim + 1)``.
    near_cells
        Owned cells at the band ``(m,)`` (:func:`band_cells`).
    band
        Tetrahedra: the cells at the band from :func:`scan_cells` (``near_cells`` its owned
        ones): the kept cells are then updated at the band only, and the band's vertices
        are not gathered again.

    Returns
    -------
    The positive facets and incidences.
    """
    nv = len(s)
    if band is None:
        near = c2v[near_cells]
        kept = kept_cells(s, c2v)
        cut = positively_cut(s, near)
        in_kept_cells = kept[near_cells]
    else:
        near = band.cv[: band.num_owned]
        kept = band.any_inside.copy()
        # per cell, the numbers of inside and outside vertices (codes 1 and 16) summed as
        # the bytes of one uint32 (at most 4 * 17: no carry) for the cut and kept tests:
        # one gather instead of eight
        code = (s < 0).astype(np.uint8) | ((s > 0).astype(np.uint8) << 4)
        word = np.take(code, band.cv).view(np.uint32).ravel()
        total = (word * np.uint32(0x01010101)) >> np.uint32(24)
        kept_band = (total & 15) > 0
        cut = (total[: band.num_owned] >> 4) == 3
        kept[band.cells] = kept_band
        in_kept_cells = kept_band[: band.num_owned]
    pc_owned = near_cells[cut]
    facets, w = positive_facets(s, near[cut])
    near_kept = near_cells[in_kept_cells]
    kept_cv = near[in_kept_cells]
    # both incidences in one reduction over the ranks
    local = np.column_stack(
        [
            np.bincount(facets.ravel(), minlength=nv),
            np.bincount(kept_cv.ravel(), minlength=nv),
        ]
    ).astype(np.float64)
    both = vertex_reduce(imv, local, "sum")
    count, in_kept = both[:, 0].copy(), both[:, 1] > 0
    return PositiveFacets(pc_owned, facets, w, count, count > 0, kept, near_kept, in_kept, kept_cv)


def map_band(
    x: Float,
    xp: Float,
    phi: Float,
    closest: Float,
    normal: Float,
    on_gamma: Bool,
    h: Float,
    R_r: Float,
    alpha: float,
    band: Int,
) -> tuple[Float, Bool]:
    """``M_h`` on the perturbed background; it moves band vertices only.

    Parameters
    ----------
    x, xp
        Original and perturbed vertex positions ``(num_vertices, gdim)``.
    phi
        Signed distances ``(num_vertices,)``.
    closest, normal
        Closest points and normals ``(num_vertices, gdim)``.
    on_gamma
        Vertices of positive facets ``(num_vertices,)``.
    h, R_r
        Mesh size and relaxation radius at each vertex ``(num_vertices,)``.
    alpha
        Relaxation factor.
    band
        Band vertices ``(num_band,)``.

    Returns
    -------
    y
        Images ``M_h(xp)`` ``(num_vertices, gdim)``.
    moved
        Vertices whose image differs from their original position ``(num_vertices,)``.
    """
    y = xp.copy()
    if alpha == 0.0:  # tetrahedra: M_h only snaps (the zero push skipped)
        snapped = band[on_gamma[band]]
        y[snapped] = closest[snapped]
    else:
        y[band] = _straight_map(
            xp[band], phi[band], closest[band], normal[band], on_gamma[band], h[band],
            R_r[band], alpha,
        )  # fmt: skip
    moved = np.zeros(len(x), dtype=bool)
    yb, xb = y[band], x[band]
    diff = yb[:, 0] != xb[:, 0]
    for k in range(1, x.shape[1]):
        diff |= yb[:, k] != xb[:, k]
    moved[band] = diff
    return y, moved


def triangle_repair(
    comm: MPI.Comm,
    imv: IndexMap,
    s: Float,
    phi: Float,
    xp: Float,
    closest: Float,
    pe: PositiveFacets,
    near: Band,
    c2v: Int,
    c2f: Int,
    f2c_offsets: Int,
    f2c: Int,
) -> tuple[PositiveFacets, int]:
    """Triangles need no repair of Gamma_h: ``pe`` as it is, no vertex relocated (the
    arguments of :func:`tetrahedron_repair`)."""
    return pe, 0


def tetrahedron_repair(
    comm: MPI.Comm,
    imv: IndexMap,
    s: Float,
    phi: Float,
    xp: Float,
    closest: Float,
    pe: PositiveFacets,
    near: Band,
    c2v: Int,
    c2f: Int,
    f2c_offsets: Int,
    f2c: Int,
) -> tuple[PositiveFacets, int]:
    """Remove the interior faces with three vertices outside (collective).

    The shallower inside vertex beside each such face counts as on Gamma
    (:func:`~dolfinx_universal.conforming.checks_tet.all_outside_faces`); repeated until none
    is left (a few rounds at most: each round relocates vertices within ``h`` of Gamma).
    ``s``, ``phi`` and ``xp`` are updated in place.

    Parameters
    ----------
    comm, imv
        Communicator and vertex index map of the background.
    s, phi, xp, closest
        Signs, signed distances, perturbed positions and closest points of the vertices.
    pe
        The positive facets (:func:`gamma_h`).
    near
        The cells at the band (:func:`tetrahedron_band`).
    c2v, c2f
        Cell -> vertex and cell -> facet connectivity ``(num_cells, 4)``.
    f2c_offsets, f2c
        Facet -> cell adjacency list.

    Returns
    -------
    The positive facets after the repair, and the number of vertices relocated (global).
    """
    total = 0
    for _ in range(8):
        _, verts = all_outside_faces(
            s, phi, pe.cells, pe.facets, pe.w, c2v, c2f, f2c_offsets, f2c, pe.kept
        )
        moved = relocate(comm, imv, xp, phi, s, closest, verts)
        if moved == 0:
            break
        total += moved
        pe = gamma_h(imv, s, c2v, near.owned, near.scan)
    return pe, total


def frozen_images(
    x: Float,
    on_gamma: Bool,
    relocated: Bool,
    pushed_mask: Bool,
    phi: Float,
    closest: Float,
    normal: Float,
    h: Float,
    R_r: Float,
    alpha: float,
    band: Int,
) -> tuple[Float, Float]:
    """``M_h`` of one triangulation for another position of Gamma: the images a step's
    classification gives (its signs, positive facets, relocated vertices and band frozen)
    when the projections are those of the other position.

    For the step's own position these are :func:`map_band`'s images, bitwise; for the
    others the same formulas for the same vertices, smooth in Gamma (the inward push of
    the step's pushed vertices continues linearly in ``phi`` beyond the relaxation radius
    and beyond Gamma, where :func:`map_band` would clip it: a kink in time), so that a
    node follows a smooth path while Gamma moves and the triangulation stays.

    Parameters
    ----------
    x
        Original vertex positions ``(num_vertices, gdim)``.
    on_gamma, relocated, pushed_mask
        The frozen classification: vertices of positive facets, vertices the eta
        perturbation moved onto Gamma, vertices pushed inwards ``(num_vertices,)``.
    phi, closest, normal
        Signed distances, closest points and normals of the band's vertices for the other
        position (rows outside ``band`` are not read).
    h, R_r, alpha, band
        As in :func:`map_band`.

    Returns
    -------
    xp
        The perturbed positions (relocated vertices on the other position's Gamma).
    y
        The images ``(num_vertices, gdim)``.
    """
    xp = x.copy()
    moved = band[relocated[band]]
    xp[moved] = closest[moved]
    y = xp.copy()
    if alpha != 0.0:
        inward_push(y, band[pushed_mask[band]], phi, normal, h, R_r, alpha)
    snapped = band[on_gamma[band]]
    y[snapped] = closest[snapped]
    return xp, y
