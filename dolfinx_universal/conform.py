"""Conform a background mesh to an immersed domain: classify, apply M_h, build the DOLFINx mesh."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import geometry as dgeometry
from dolfinx import mesh as dmesh

from .checks import gamma_h_topology, low_quality_cells
from .classify import (
    cell_diameters,
    conditioning_angle,
    kept_cells,
    perturbation_candidates,
    positive_edges,
    positively_cut,
    proximal_vertex,
    signed_areas,
    straight_map,
)
from .validation import (
    MeshingError,
    Problem,
    collective_call,
    raise_collective,
    vertex_reduce,
    where,
)

if TYPE_CHECKING:
    from .boundaries import Boundary
    from .sizing import CurveSamples

__all__ = ["IMMERSED", "OUTER", "ConformingMesh", "StraightMap", "UniversalMesh", "conform"]

IMMERSED = 1
"""Facet tag of the immersed boundary (the snapped positive edges)."""
OUTER = 2
"""Facet tag of the background's own boundary where it bounds the domain."""


@dataclass
class ConformingMesh:
    """A straight-edged mesh conforming to an immersed domain, with maps to its background.

    Indices are process-local. ``mesh`` is a DOLFINx submesh of ``background`` (same cells,
    moved vertices, no vertex added); per-vertex arrays are indexed by ``mesh`` vertices.
    """

    mesh: dmesh.Mesh
    """Conforming mesh with degree-1 geometry (vertices at ``M_h`` images)."""
    facet_tags: dmesh.MeshTags
    """Exterior facets: :data:`IMMERSED` on Gamma_h, :data:`OUTER` on the background boundary."""
    background: dmesh.Mesh
    boundary: Boundary
    cell_map: npt.NDArray[np.int32]
    """``mesh`` cell -> ``background`` cell, ``(num_cells,)``."""
    vertex_map: npt.NDArray[np.int32]
    """``mesh`` vertex -> ``background`` vertex, ``(num_vertices,)``."""
    node_map: npt.NDArray[np.int32]
    """``mesh`` geometry node -> ``background`` geometry node."""
    sign: npt.NDArray[np.float64]
    """Final vertex signs (-1 inside, +1 on Gamma after snapping), ``(num_vertices,)``."""
    background_x: npt.NDArray[np.float64]
    """Vertex positions in the (perturbed) background, ``(num_vertices, 2)``."""
    on_positive_edge: npt.NDArray[np.bool_]
    """Vertices snapped onto Gamma, ``(num_vertices,)``."""
    h: npt.NDArray[np.float64]
    """Mesh size used at each vertex, ``(num_vertices,)``."""
    R_r: npt.NDArray[np.float64]
    """Relaxation radius used at each vertex, ``(num_vertices,)``."""
    alpha: float
    eta: float
    num_relocated: int
    """Vertices relocated onto Gamma by the eta perturbation (global count)."""
    moved: npt.NDArray[np.bool_]
    """Vertices whose position differs from the original background, ``(num_vertices,)``."""
    timings: dict[str, float] = field(default_factory=dict)
    """Wall-clock seconds of the stages (this rank)."""
    max_conditioning_angle: float = 0.0
    """Largest conditioning angle in degrees (global; must be below 90)."""
    moved_angle_range: tuple[float, float] = (180.0, 0.0)
    """Smallest and largest angle in degrees (global) of the triangles that moved."""
    num_loops: int = 0
    """Closed loops of Gamma_h (one per curve of Gamma, checked)."""
    num_pieces: int = 0
    """Connected pieces of the mesh (as many as the domain has, checked)."""

    @property
    def cells(self) -> npt.NDArray[np.int32]:
        """Cell -> vertex connectivity of ``mesh``, ``(num_cells, 3)``."""
        return self.mesh.topology.connectivity(2, 0).array.reshape(-1, 3)

    @property
    def x(self) -> npt.NDArray[np.float64]:
        """Vertex coordinates of ``mesh`` by vertex index, ``(num_vertices, 2)``."""
        v2n = np.empty(len(self.sign), dtype=np.int32)
        v2n[self.cells] = self.mesh.geometry.dofmaps[0][:, :3]
        return self.mesh.geometry.x[v2n, :2]

    @property
    def positively_cut(self) -> npt.NDArray[np.bool_]:
        """Positively cut cells of ``mesh`` (one vertex inside), ``(num_cells,)``."""
        return positively_cut(self.sign, self.cells)


def _check_background(msh: dmesh.Mesh) -> None:
    """A clear error for meshes that are not planar triangle meshes (collective)."""
    topo = msh.topology
    if topo.dim != 2 or topo.cell_type != dmesh.CellType.triangle:
        raise ValueError(
            f"universal meshes are planar triangle meshes (for now); got a {topo.dim}D mesh "
            f"of {topo.cell_type.name} cells"
        )
    z = msh.geometry.x[:, 2]
    off = msh.comm.allreduce(float(np.abs(z).max()) if len(z) else 0.0, op=MPI.MAX)
    if msh.geometry.dim != 2 and off > 0.0:
        raise ValueError(
            f"the background mesh is a triangle mesh in 3D (|z| up to {off:.3g}); universal "
            "meshes need a planar mesh: create it with 2D coordinates (gdim = 2)"
        )


def _local_arrays(msh: dmesh.Mesh):
    """Vertex coordinates, cells and vertex -> node map of a degree-1 mesh (process-local)."""
    topo = msh.topology
    topo.create_connectivity(2, 0)
    dofmap = msh.geometry.dofmaps[0]
    if dofmap.shape[1] != 3:
        raise ValueError("the background mesh must have degree-1 (straight) triangle geometry")
    c2v = topo.connectivity(2, 0).array.reshape(-1, 3)
    imv = topo.index_map(0)
    v2n = np.empty(imv.size_local + imv.num_ghosts, dtype=np.int32)
    v2n[c2v] = dofmap
    return msh.geometry.x[v2n, :2].copy(), c2v, v2n


GRADATION = 0.2
"""Lipschitz bound of the local size field used on graded backgrounds (``local_size``)."""


def _vertex_sizes(imv, x, c2v, num_owned: int, local: bool, comm: MPI.Comm):
    """Mesh size at each vertex: the global max diameter, or a smoothed local size.

    The local size starts as the largest diameter of the vertex's cells and is then raised
    to the smallest field ``h_s >= h`` with ``|h_s(a) - h_s(b)| <= GRADATION |a - b|`` along
    edges (a max-plus relaxation over the mesh graph). The relaxation ``alpha h (1 + phi/R_r)``
    then has a small tangential gradient across the level changes of a graded background,
    where the raw cell size jumps by a factor 2 (which folds triangles there).
    """
    diam = cell_diameters(x, c2v[:num_owned])
    if not local:
        hmax = comm.allreduce(float(diam.max()) if len(diam) else 0.0, op=MPI.MAX)
        return np.full(len(x), hmax)
    hv = np.zeros(len(x))
    np.maximum.at(hv, c2v[:num_owned].ravel(), np.repeat(diam, 3))
    hv = vertex_reduce(imv, hv, "max")
    edges = np.unique(np.sort(np.concatenate([c2v[:, [0, 1]], c2v[:, [1, 2]], c2v[:, [2, 0]]]),
                              axis=1), axis=0)
    a, b = edges[:, 0], edges[:, 1]
    drop = GRADATION * np.linalg.norm(x[a] - x[b], axis=1)
    while True:
        new = hv.copy()
        np.maximum.at(new, a, hv[b] - drop)
        np.maximum.at(new, b, hv[a] - drop)
        new = vertex_reduce(imv, new, "max")
        change = float(np.max(new - hv)) if len(hv) else 0.0
        hv = new
        if comm.allreduce(change, op=MPI.MAX) <= 1e-12 * (float(hv.max()) if len(hv) else 1.0):
            return hv


def _incidence(imv, vertices: npt.NDArray, n: int) -> npt.NDArray[np.float64]:
    """Global number of times each local vertex appears in ``vertices`` (over all ranks)."""
    count = np.bincount(np.asarray(vertices).ravel(), minlength=n).astype(np.float64)
    return vertex_reduce(imv, count, "sum")


def _check_containment(background, boundary, cells, comm) -> list[str]:
    """Points of Gamma that lie in no background cell (collective)."""
    pts = collective_call(comm, "sampling the boundary", boundary.sample, 512)
    pts3 = np.zeros((len(pts), 3))
    pts3[:, :2] = pts
    tree = dgeometry.bb_tree(background, 2, entities=cells.astype(np.int32))
    cand = dgeometry.compute_collisions_points(tree, pts3)
    hits = dgeometry.compute_colliding_cells(background, cand, pts3)
    found = (np.diff(hits.offsets) > 0).astype(np.int32)
    found = comm.allreduce(found, op=MPI.SUM) if comm.size > 1 else found
    missing = pts[found == 0]
    if len(missing) and comm.rank == 0:
        return [Problem(
            "the immersed boundary leaves the background mesh near {where}: enlarge the "
            "background so that it contains the domain's boundary", missing, len(missing),
            refinable=False,
        )]
    return []


@dataclass
class StraightMap:
    """Classification of the background vertices against a domain and their images under M_h.

    Arrays are indexed by process-local background vertices (owned and ghost) or cells.
    """

    sign: npt.NDArray[np.float64]
    """Final vertex signs (after the eta perturbation), ``(num_vertices,)``."""
    phi: npt.NDArray[np.float64]
    """Signed distances; ``+-inf`` outside the band near Gamma, ``(num_vertices,)``."""
    closest: npt.NDArray[np.float64]
    """Closest points ``pi(x)`` (NaN outside the band), ``(num_vertices, 2)``."""
    x: npt.NDArray[np.float64]
    """Background positions after the eta perturbation, ``(num_vertices, 2)``."""
    y: npt.NDArray[np.float64]
    """Images ``M_h(x)``, ``(num_vertices, 2)``."""
    on_positive_edge: npt.NDArray[np.bool_]
    kept: npt.NDArray[np.bool_]
    """Cells of ``T_h^sub`` (owned and ghost cells), ``(num_cells,)``."""
    moved: npt.NDArray[np.bool_]
    """Vertices whose image differs from their original position, ``(num_vertices,)``."""
    near_cells: npt.NDArray[np.int32]
    """Cells (owned and ghost) with a vertex within ``R_r`` of Gamma: every moved or
    positively cut cell is among them."""
    num_relocated: int
    timings: dict[str, float]
    max_conditioning_angle: float = 0.0
    """Largest conditioning angle in degrees (global)."""
    moved_angle_range: tuple[float, float] = (180.0, 0.0)
    """Smallest and largest angle (degrees, global) of the kept triangles that moved."""
    num_loops: int = 0
    """Closed loops of Gamma_h (one per curve of Gamma)."""
    num_pieces: int = 0
    """Connected pieces of the kept triangles (as many as the domain has)."""


class UniversalMesh:
    """A background mesh prepared once to be conformed to any number of domains (SPEC §5).

    Everything that depends only on the background (vertex arrays, connectivities, mesh
    sizes, parameters) is computed here; :meth:`conform` then costs a classification, the
    projections of the vertices near Gamma and the DOLFINx mesh construction.

    Parameters
    ----------
    background
        Degree-1 triangle mesh containing the closure of the domain, acute near Gamma;
        distributed with shared-facet ghosts (see :mod:`dolfinx_universal.background`).
    R_r
        Relaxation radius; default ``relaxation_factor * h``. Must exceed ``h``.
    alpha
        Relaxation factor in ``[(1 + h/R_r)^-1, 1]``; default ``(1 + h/R_r)^-1``.
    eta
        Quality perturbation threshold; 0 disables it.
    relaxation_factor
        ``R_r / h`` when ``R_r`` is not given.
    local_size
        Graded backgrounds: use at each vertex a local size as ``h`` (the largest diameter
        of its cells, smoothed to vary by at most :data:`GRADATION` per unit length) instead
        of the global largest diameter; ``R_r`` then scales with it.
    min_angle
        Quality floor in degrees: conforming triangles with a smaller angle are reported
        (0 disables the check).
    on_low_quality
        ``"warn"`` (a :class:`UserWarning` naming the places) or ``"raise"`` (a
        :class:`~dolfinx_universal.validation.MeshingError`).
    """

    def __init__(
        self,
        background: dmesh.Mesh,
        *,
        R_r: float | None = None,
        alpha: float | None = None,
        eta: float = 0.2,
        relaxation_factor: float = 3.0,
        local_size: bool = False,
        min_angle: float = 10.0,
        on_low_quality: str = "warn",
    ):
        _check_background(background)
        eta, min_angle = float(eta), float(min_angle)
        if not 0.0 <= eta < 1.0:  # also rejects NaN
            raise ValueError(f"eta must lie in [0, 1) (0 disables the perturbation), got {eta}")
        if not 0.0 <= min_angle < 60.0:
            raise ValueError(f"min_angle must lie in [0, 60) degrees, got {min_angle}")
        if on_low_quality not in ("warn", "raise"):
            raise ValueError(f"on_low_quality must be 'warn' or 'raise', got {on_low_quality!r}")
        self.background = background
        self.eta, self.min_angle, self.on_low_quality = eta, min_angle, on_low_quality
        self._samples: tuple[object, float, CurveSamples] | None = None
        comm = self.comm = background.comm
        topo = background.topology
        self._imv = topo.index_map(0)
        self._nco = topo.index_map(2).size_local
        x, c2v, v2n = _local_arrays(background)
        self._x, self._c2v, self._v2n = x, c2v, v2n
        nv = len(x)
        bad = ~np.isfinite(x).all(axis=1)
        raise_collective(
            comm, [f"background mesh has NaN/inf coordinates at {where(x[bad])}"] if bad.any()
            else []
        )
        self.h = _vertex_sizes(self._imv, x, c2v, self._nco, local_size, comm)
        self.R_r = relaxation_factor * self.h if R_r is None else np.full(nv, float(R_r))
        ratio = self.h / np.maximum(self.R_r, np.finfo(float).tiny)
        worst = comm.allreduce(float(ratio.max()) if nv else 0.0, op=MPI.MAX)
        if worst >= 1.0:
            raise ValueError(f"R_r must exceed the mesh size h (got R_r/h = {1 / worst:.3g})")
        alpha_min = 1.0 / (1.0 + worst)
        if alpha is None:
            alpha = alpha_min
        elif not (alpha_min - 1e-12 <= alpha <= 1.0):
            raise ValueError(f"alpha must lie in [(1 + h/R_r)^-1, 1] = [{alpha_min:.4g}, 1]")
        self.alpha = float(alpha)
        for a, b in ((2, 1), (1, 2), (1, 0), (0, 2)):
            topo.create_connectivity(a, b)
        self._c2f = topo.connectivity(2, 1).array.reshape(-1, 3)
        f2c = topo.connectivity(1, 2)
        self._f2c_offsets, self._f2c = f2c.offsets, f2c.array
        ext = dmesh.exterior_facet_indices(topo)
        self._outer_vertices = np.unique(topo.connectivity(1, 0).array.reshape(-1, 2)[ext])
        n2v = np.empty(len(background.geometry.x), dtype=np.int32)
        n2v[v2n] = np.arange(nv, dtype=np.int32)
        self._n2v = n2v

    def straight_map(self, boundary: Boundary) -> StraightMap:
        """Classify the background against ``boundary`` and compute ``M_h`` (collective).

        Raises
        ------
        MeshingError
            On every rank, when the domain cannot be meshed on this background; the message
            says where and what to do.
        """
        comm, imv, nco = self.comm, self._imv, self._nco
        x, c2v = self._x, self._c2v
        nv = len(x)
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        # Classification. Gamma lies in its bounding box, so every vertex outside the box
        # (enlarged by the band width) has the sign of the far field: only the vertices in
        # the box are tested, and only those within R_r of Gamma get projected.
        rmax = float(self.R_r.max()) if nv else 0.0
        box = np.asarray(
            collective_call(comm, "the bounding box", boundary.bounding_box), dtype=float
        )
        pad = rmax + 2.0 * (float(self.h.max()) if nv else 0.0)
        lo, hi = box[0] - pad, box[1] + pad
        far = np.asarray(
            collective_call(comm, "the sign test", boundary.sign, (hi + pad)[None]), dtype=float
        )[0]
        cand = np.flatnonzero(
            (x[:, 0] >= lo[0]) & (x[:, 0] <= hi[0]) & (x[:, 1] >= lo[1]) & (x[:, 1] <= hi[1])
        )
        s = np.full(nv, far)
        s[cand] = collective_call(comm, "the sign test", boundary.sign, x[cand])
        near_flag = np.asarray(
            collective_call(comm, "the band test", boundary.near, x[cand], rmax), dtype=bool
        )
        band_idx = cand[near_flag]
        timings["classify"] = time.perf_counter() - t0

        t1 = time.perf_counter()
        phi = np.where(s < 0, -np.inf, np.inf)
        closest = np.full((nv, 2), np.nan)
        normal = np.full((nv, 2), np.nan)
        xb = x[band_idx]
        phi_b, y_b = collective_call(comm, "closest-point projection", boundary.project, xb)
        bad = ~(np.isfinite(phi_b) & np.isfinite(y_b).all(axis=1))
        raise_collective(
            comm,
            [Problem("closest-point projection returned NaN/inf for vertices at {where}",
                     xb[bad], int(bad.sum()), refinable=False)]
            if bad.any()
            else [],
        )
        phi[band_idx], closest[band_idx] = phi_b, y_b
        # Points on Gamma count as outside (SPEC §2). A vertex on Gamma up to rounding that
        # the sign test put inside would be relaxed inwards while its neighbours snap onto
        # it; treat it as on Gamma.
        on_gamma = band_idx[(phi_b <= 0) & (phi_b > -1e-10 * self.h[band_idx])]
        s[on_gamma], phi[on_gamma] = 1.0, 0.0
        normal[band_idx] = collective_call(comm, "the normal", boundary.normal, y_b)
        timings["project"] = time.perf_counter() - t1

        # Quality perturbation: relocate inside vertices too close to Gamma, to a fixed point.
        t2 = time.perf_counter()
        near_all = dmesh.compute_incident_entities(  # the cells at the band
            self.background.topology, band_idx.astype(np.int32), 0, 2
        )
        near_cells = near_all[near_all < nco]
        owned = c2v[:nco]
        near = owned[near_cells]
        xp = x.copy()
        relocated = np.zeros(nv, dtype=bool)
        while self.eta > 0:
            flag = np.zeros(nv)
            flag[perturbation_candidates(xp, phi, s, near, self.eta)] = 1.0
            new = (vertex_reduce(imv, flag, "sum") > 0) & ~relocated
            if comm.allreduce(int(new[: imv.size_local].sum())) == 0:
                break
            xp[new], phi[new], s[new] = closest[new], 0.0, 1.0
            relocated |= new
        num_relocated = comm.allreduce(int(relocated[: imv.size_local].sum()))

        # Positive edges, Gamma_h, and the checks of SPEC §6. A vertex outside the domain in
        # a kept triangle is next to an inside vertex, hence in the band: the incidence
        # counts near the band are all that the checks need.
        pc_owned = near_cells[positively_cut(s, near)]
        u, v, w = positive_edges(s, owned[pc_owned])
        pe_count = _incidence(imv, np.concatenate([u, v]), nv)
        on_pe = pe_count > 0
        kept = kept_cells(s, c2v)
        near_kept = near_cells[kept[near_cells]]
        in_kept = _incidence(imv, owned[near_kept], nv) > 0
        if comm.allreduce(int(np.count_nonzero(kept[:nco]))) == 0:
            raise MeshingError(
                "no background vertex lies inside the domain: the domain is outside the "
                "background mesh or smaller than its triangles; move or refine the background",
                collective_call(comm, "sampling the boundary", boundary.sample, 64),
            )
        problems, theta = self._check_classification(
            xp, s, phi, pc_owned, u, v, w, pe_count, in_kept, kept
        )
        raise_collective(comm, problems)
        near_cells = near_cells.astype(np.int32)
        raise_collective(comm, _check_containment(self.background, boundary, near_cells, comm))
        max_theta = comm.allreduce(theta, op=MPI.MAX)
        ev = self._outer_vertices
        far_kept = comm.allreduce(bool(np.any(s[ev] < 0)), op=MPI.LOR)
        samples = self._curve_samples(boundary, band_idx)
        topo_problems, num_loops, num_pieces = gamma_h_topology(
            comm, imv.local_to_global(np.concatenate([u, v]).astype(np.int32)).reshape(2, -1).T,
            xp[u], xp[v], xp[w], samples, far_kept,
        )
        raise_collective(comm, topo_problems)

        # M_h moves band vertices only.
        y = xp.copy()
        y[band_idx] = straight_map(
            xp[band_idx], phi[band_idx], closest[band_idx], normal[band_idx], on_pe[band_idx],
            self.h[band_idx], self.R_r[band_idx], self.alpha,
        )
        moved = np.zeros(nv, dtype=bool)
        moved[band_idx] = np.any(y[band_idx] != x[band_idx], axis=1)
        problems = self._check_output(y, moved, near_kept, in_kept)
        raise_collective(comm, problems)
        moved_kept = c2v[near_kept]
        moved_kept = moved_kept[moved[moved_kept].any(axis=1)]
        low, lo, hi = low_quality_cells(y, moved_kept, self.min_angle)
        self._report_quality(low)
        timings["map"] = time.perf_counter() - t2
        return StraightMap(
            sign=s, phi=phi, closest=closest, x=xp, y=y, on_positive_edge=on_pe, kept=kept,
            moved=moved, near_cells=near_all.astype(np.int32), num_relocated=num_relocated,
            timings=timings, max_conditioning_angle=float(np.degrees(max_theta)),
            moved_angle_range=(comm.allreduce(lo, op=MPI.MIN), comm.allreduce(hi, op=MPI.MAX)),
            num_loops=num_loops, num_pieces=num_pieces,
        )

    def _curve_samples(self, boundary: Boundary, band_idx: npt.NDArray) -> CurveSamples:
        """Dense labelled samples of Gamma, spaced well below the mesh size near it (cached
        for the last boundary)."""
        from .sizing import curve_samples

        hmin = self.comm.allreduce(
            float(self.h[band_idx].min()) if len(band_idx) else np.inf, op=MPI.MIN
        )
        if not np.isfinite(hmin):  # no vertex near Gamma (an error is reported anyway)
            hmin = float(np.max(self.h)) if len(self.h) else 1.0
            hmin = self.comm.allreduce(hmin, op=MPI.MAX)
        spacing = 0.25 * hmin
        cached = self._samples
        if cached is not None and cached[0] is boundary and cached[1] <= spacing:
            return cached[2]
        samples = collective_call(
            self.comm, "sampling the boundary", curve_samples, boundary, spacing
        )
        self._samples = (boundary, spacing, samples)
        return samples

    def _report_quality(self, low: Problem | None) -> None:
        """Warn about (or raise for) triangles below the quality floor (collective)."""
        if self.on_low_quality == "raise":
            raise_collective(self.comm, [low] if low is not None else [])
            return
        try:
            raise_collective(self.comm, [low] if low is not None else [])
        except MeshingError as e:
            if self.comm.rank == 0:
                warnings.warn(str(e), UserWarning, stacklevel=4)

    def conform(self, boundary: Boundary) -> ConformingMesh:
        """The straight conforming mesh of the domain bounded by ``boundary`` (collective).

        Vertices of positive edges are snapped onto Gamma, inside vertices within ``R_r`` of
        Gamma are relaxed inwards by at most ``alpha h``, triangles with all vertices
        outside are dropped. No vertex is added; the kept triangles keep their connectivity.

        Raises
        ------
        MeshingError
            On every rank, when the domain cannot be meshed on this background.
        """
        sm = self.straight_map(boundary)
        t3 = time.perf_counter()
        kc = np.flatnonzero(sm.kept[: self._nco]).astype(np.int32)
        sub, cell_emap, vertex_emap, node_map = dmesh.create_submesh(self.background, 2, kc)
        sub.geometry.x[:, :2] = sm.y[self._n2v[node_map]]
        sub.geometry.x[:, 2] = 0.0
        stopo = sub.topology
        stopo.create_connectivity(2, 0)
        simv, simc = stopo.index_map(0), stopo.index_map(2)
        nsv = simv.size_local + simv.num_ghosts
        vmap = vertex_emap.sub_topology_to_topology(np.arange(nsv, dtype=np.int32), False)
        cmap = cell_emap.sub_topology_to_topology(
            np.arange(simc.size_local + simc.num_ghosts, dtype=np.int32), False
        )
        stopo.create_connectivity(1, 2)
        stopo.create_connectivity(1, 0)
        facets = dmesh.exterior_facet_indices(stopo)
        fv = stopo.connectivity(1, 0).array.reshape(-1, 2)[facets]
        values = np.where(sm.on_positive_edge[vmap[fv]].all(axis=1), IMMERSED, OUTER)
        tags = dmesh.meshtags(sub, 1, facets.astype(np.int32), values.astype(np.int32))
        timings = dict(sm.timings, mesh=time.perf_counter() - t3)
        moved = sm.moved
        return ConformingMesh(
            mesh=sub,
            facet_tags=tags,
            background=self.background,
            boundary=boundary,
            cell_map=np.asarray(cmap, dtype=np.int32),
            vertex_map=np.asarray(vmap, dtype=np.int32),
            node_map=np.asarray(node_map, dtype=np.int32),
            sign=sm.sign[vmap],
            background_x=sm.x[vmap],
            on_positive_edge=sm.on_positive_edge[vmap],
            h=self.h[vmap],
            R_r=self.R_r[vmap],
            alpha=self.alpha,
            eta=self.eta,
            num_relocated=sm.num_relocated,
            moved=moved[vmap],
            timings=timings,
            max_conditioning_angle=sm.max_conditioning_angle,
            moved_angle_range=sm.moved_angle_range,
            num_loops=sm.num_loops,
            num_pieces=sm.num_pieces,
        )

    def _check_classification(
        self, xp, s, phi, pc_owned, u, v, w, pe_count, in_kept, kept
    ) -> list[str]:
        """Local problems with the classification (SPEC §2, §6), and the largest
        conditioning angle (radians, 0 without positively cut cells)."""
        problems = []
        theta_max = 0.0
        if len(pc_owned):
            theta = conditioning_angle(xp, phi, u, v, w)
            theta_max = float(theta.max())
            bad = theta >= np.pi / 2 - 1e-12
            if bad.any():
                p = xp[proximal_vertex(xp, phi, u[bad], v[bad], w[bad])]
                problems.append(Problem(
                    "conditioning angle of 90 degrees or more in {count} positively cut "
                    "triangles near {where}: use a background mesh that is acute near the "
                    "boundary (e.g. equilateral or graded_mesh)", p, int(bad.sum()),
                ))
            # The positive edge is the facet opposite the inside vertex.
            k = np.argmin(s[self._c2v[pc_owned]], axis=1)
            f = self._c2f[pc_owned, k]
            off = self._f2c_offsets
            ncell = off[f + 1] - off[f]
            lone = ncell == 1
            if lone.any():
                problems.append(Problem(
                    "the domain reaches the boundary of the background mesh near {where}: "
                    "enlarge the background", 0.5 * (xp[u[lone]] + xp[v[lone]]),
                    int(lone.sum()), refinable=False,
                ))
            two = np.flatnonzero(ncell == 2)
            c0, c1 = self._f2c[off[f[two]]], self._f2c[off[f[two]] + 1]
            other = np.where(c0 == pc_owned[two], c1, c0)
            shared = two[kept[other]]
            if len(shared):
                problems.append(Problem(
                    "Gamma crosses both triangles beside the positive edge near {where} (a "
                    "thin part of the domain or of its exterior): the background is too "
                    "coarse there, refine near it", 0.5 * (xp[u[shared]] + xp[v[shared]]),
                    len(shared),
                ))
        nvo = self._imv.size_local
        chain = (pe_count[:nvo] > 0) & (pe_count[:nvo] != 2)
        if chain.any():
            problems.append(Problem(
                "Gamma_h (the union of positive edges) is not a set of closed simple curves at "
                "vertices {where}: the background is too coarse for the boundary's curvature "
                "or for the gap between its parts there; refine near them", xp[:nvo][chain],
                int(chain.sum()),
            ))
        lost = in_kept[:nvo] & (s[:nvo] > 0) & (pe_count[:nvo] == 0)
        if lost.any():
            problems.append(Problem(
                "vertices outside the domain at {where} belong to kept triangles but to no "
                "positive edge, so they would not be snapped: Gamma is under-resolved there; "
                "refine the background near them", xp[:nvo][lost], int(lost.sum()),
            ))
        return problems, theta_max

    def _check_output(self, y, moved, kc, in_kept) -> list[str]:
        """Local problems with the conforming triangles: inversion, degeneracy, moved outer
        boundary."""
        problems = []
        x = self._x
        cells = self._c2v[kc]
        cells = cells[moved[cells].any(axis=1)]  # unmoved triangles keep their shape
        a0, a1 = signed_areas(x, cells), signed_areas(y, cells)
        d2 = cell_diameters(x, cells) ** 2
        inverted = (np.sign(a1) != np.sign(a0)) | (np.abs(a1) <= 1e-10 * d2)
        if inverted.any():
            centre = y[cells[inverted]].mean(axis=1)
            problems.append(Problem(
                "{count} conforming triangles would be inverted or degenerate near {where}: "
                "the background is too coarse or not acute there; refine near those points "
                "or use an acute (e.g. equilateral) background", centre, int(inverted.sum()),
            ))
        ev = self._outer_vertices
        shifted = ev[in_kept[ev] & moved[ev]]
        if len(shifted):
            problems.append(Problem(
                "the boundary of the background mesh would move at {where}: Gamma comes "
                "within R_r of it there; enlarge the background or reduce R_r", x[shifted],
                len(shifted), refinable=False,
            ))
        return problems


def conform(
    background: dmesh.Mesh,
    boundary: Boundary,
    *,
    R_r: float | None = None,
    alpha: float | None = None,
    eta: float = 0.2,
    relaxation_factor: float = 3.0,
    local_size: bool = False,
    min_angle: float = 10.0,
    on_low_quality: str = "warn",
) -> ConformingMesh:
    """Conform a background triangulation to the domain bounded by ``boundary`` (SPEC §2-3).

    Shorthand for ``UniversalMesh(background, ...).conform(boundary)``; use
    :class:`UniversalMesh` to conform one background to many domains.

    Parameters
    ----------
    background
        Degree-1 triangle mesh containing the closure of the domain, acute near Gamma;
        distributed with shared-facet ghosts (see :mod:`dolfinx_universal.background`).
    boundary
        The domain (signs, closest points, normals).
    R_r, alpha, eta, relaxation_factor, local_size, min_angle, on_low_quality
        See :class:`UniversalMesh`.

    Returns
    -------
    The conforming mesh and its maps back to the background.

    Raises
    ------
    MeshingError
        On every rank, when the domain cannot be meshed on this background; the message says
        where and what to do.
    """
    um = UniversalMesh(
        background, R_r=R_r, alpha=alpha, eta=eta, relaxation_factor=relaxation_factor,
        local_size=local_size, min_angle=min_angle, on_low_quality=on_low_quality,
    )
    return um.conform(boundary)


