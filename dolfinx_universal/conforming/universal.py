"""Conform a background mesh to an immersed domain: classify, apply M_h, build the DOLFINx mesh."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh

from dolfinx_universal.backgrounds.lattice_tri import GRADATION, vertex_sizes
from dolfinx_universal.boundaries.motions import RigidMotion
from dolfinx_universal.conforming.checks import (
    TetMeasures,
    classification_problems,
    conforming_problems,
    containment_samples,
    low_quality_cells,
    require_kept,
)
from dolfinx_universal.conforming.classify import positively_cut
from dolfinx_universal.conforming.kit import conforming_kit
from dolfinx_universal.conforming.relax import RelaxFrame, movable_vertices, relax_vertices
from dolfinx_universal.conforming.snap import (
    classify_near,
    frozen_images,
    gamma_h,
    map_band,
    perturb,
    project_band,
)
from dolfinx_universal.core.arrays import Bool, Float, Int, mirror_line
from dolfinx_universal.core.collective import (
    MeshingError,
    Problem,
    collective_call,
    raise_collective,
)

if TYPE_CHECKING:
    from dolfinx_universal.boundaries.base import Boundary
    from dolfinx_universal.conforming.snap import PositiveFacets
    from dolfinx_universal.sizing.fields import CurveSamples

__all__ = [
    "GRADATION",
    "IMMERSED",
    "OUTER",
    "ConformingMesh",
    "StraightMap",
    "UniversalMesh",
    "conform",
]

_vertex_sizes = vertex_sizes  # the name before the size field moved to background.py

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
    """Conforming mesh with degree-1 geometry (vertices at ``M_h`` images). In parallel it
    has the background's shared-facet ghost cells (the kept ones), so interior facet
    integrals (``dS``: jumps, error indicators, DG forms) assemble on any number of ranks."""
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
    """Vertex positions in the (perturbed) background, ``(num_vertices, gdim)``; a vertex the
    relaxation slid along Gamma has one that projects onto its new image."""
    on_gamma: npt.NDArray[np.bool_]
    """Vertices snapped onto Gamma (of positive edges, or faces), ``(num_vertices,)``."""
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
    """Largest conditioning angle in degrees (global; must be below 90); tetrahedra: the
    largest dihedral angle at a positive face (at most 90)."""
    moved_angle_range: tuple[float, float] = (180.0, 0.0)
    """Smallest and largest angle in degrees (global) of the cells that moved (dihedral
    angles for tetrahedra)."""
    num_loops: int = 0
    """Closed loops (surfaces, for tetrahedra) of Gamma_h, one per curve (surface piece) of
    Gamma, checked."""
    num_pieces: int = 0
    """Connected pieces of the mesh (as many as the domain has, checked)."""
    _facet_tags: dmesh.MeshTags | None = field(default=None, repr=False)

    @property
    def facet_tags(self) -> dmesh.MeshTags:
        """Exterior facets: :data:`IMMERSED` on Gamma_h, :data:`OUTER` on the background
        boundary.

        Built at the first access, with the mesh's edges (a fifth of the cost of
        :meth:`UniversalMesh.conform` otherwise, and not needed to assemble cell
        integrals); the first access is collective, as DOLFINx's ``create_connectivity``.
        """
        if self._facet_tags is None:
            topo = self.mesh.topology
            fdim = topo.dim - 1
            topo.create_connectivity(fdim, topo.dim)
            topo.create_connectivity(fdim, 0)
            facets = dmesh.exterior_facet_indices(topo)
            fv = topo.connectivity(fdim, 0).array.reshape(-1, topo.dim)[facets]
            values = np.where(self.on_gamma[fv].all(axis=1), IMMERSED, OUTER)
            self._facet_tags = dmesh.meshtags(
                self.mesh, fdim, facets.astype(np.int32), values.astype(np.int32)
            )
        return self._facet_tags

    @property
    def on_positive_edge(self) -> npt.NDArray[np.bool_]:
        """Deprecated name of :attr:`on_gamma` (a positive face's vertices in 3D)."""
        warnings.warn(
            "ConformingMesh.on_positive_edge is deprecated: use on_gamma",
            DeprecationWarning,
            stacklevel=2,
        )
        return self.on_gamma

    @property
    def cells(self) -> npt.NDArray[np.int32]:
        """Cell -> vertex connectivity of ``mesh``, ``(num_cells, tdim + 1)``."""
        tdim = self.mesh.topology.dim
        return self.mesh.topology.connectivity(tdim, 0).array.reshape(-1, tdim + 1)

    @property
    def x(self) -> npt.NDArray[np.float64]:
        """Vertex coordinates of ``mesh`` by vertex index, ``(num_vertices, gdim)``."""
        tdim = self.mesh.topology.dim
        v2n = np.empty(len(self.sign), dtype=np.int32)
        v2n[self.cells] = self.mesh.geometry.dofmaps[0][:, : tdim + 1]
        return self.mesh.geometry.x[v2n, :tdim]

    @property
    def positively_cut(self) -> npt.NDArray[np.bool_]:
        """Positively cut cells of ``mesh`` (one vertex inside), ``(num_cells,)``."""
        return positively_cut(self.sign, self.cells)


def _check_background(msh: dmesh.Mesh) -> None:
    """A clear error for meshes that are neither planar triangle nor tetrahedron meshes
    (collective)."""
    topo = msh.topology
    if topo.cell_type not in (dmesh.CellType.triangle, dmesh.CellType.tetrahedron):
        raise ValueError(
            "universal meshes are planar triangle meshes or tetrahedron meshes; got a "
            f"{topo.dim}D mesh of {topo.cell_type.name} cells"
        )
    # coordinates beyond the topological dimension (z of triangles) must vanish
    z = msh.geometry.x[:, topo.dim :]
    off = msh.comm.allreduce(float(np.abs(z).max(initial=0.0)), op=MPI.MAX)
    if off > 0.0:
        raise ValueError(
            f"the background mesh is a triangle mesh in 3D (|z| up to {off:.3g}); universal "
            "meshes need a planar mesh: create it with 2D coordinates (gdim = 2)"
        )


def _local_arrays(
    msh: dmesh.Mesh,
) -> tuple[Float, npt.NDArray[np.int32], npt.NDArray[np.int32]]:
    """Vertex coordinates ``(num_vertices, tdim)``, cells ``(num_cells, tdim + 1)`` and
    vertex -> node map of a degree-1 mesh (process-local)."""
    topo = msh.topology
    tdim = topo.dim
    topo.create_connectivity(tdim, 0)
    dofmap = msh.geometry.dofmaps[0]
    if dofmap.shape[1] != tdim + 1:
        raise ValueError("the background mesh must have degree-1 (straight) geometry")
    c2v = topo.connectivity(tdim, 0).array.reshape(-1, tdim + 1)
    imv = topo.index_map(0)
    v2n = np.empty(imv.size_local + imv.num_ghosts, dtype=np.int32)
    v2n[c2v] = dofmap
    return msh.geometry.x[v2n, :tdim].copy(), c2v, v2n


@dataclass
class StraightMap:
    """Classification of the background vertices against a domain and their images under M_h.

    Arrays are indexed by process-local background vertices (owned and ghost) or cells.

    Attributes
    ----------
    sign
        Final vertex signs (after the eta perturbation), ``(num_vertices,)``.
    phi
        Signed distances; ``+-inf`` outside the band near Gamma, ``(num_vertices,)``.
    closest
        Closest points ``pi(x)`` (NaN outside the band), ``(num_vertices, gdim)``.
    x
        Background positions after the eta perturbation, ``(num_vertices, gdim)``.
    y
        Their images ``M_h(x)``, ``(num_vertices, gdim)``.
    on_gamma
        Vertices of positive edges (snapped onto Gamma), ``(num_vertices,)``.
    kept
        Cells of ``T_h^sub`` (owned and ghost cells), ``(num_cells,)``.
    moved
        Vertices whose image differs from their original position, ``(num_vertices,)``.
    near_cells
        Cells (owned and ghost) with a vertex within ``R_r`` of Gamma: every moved or
        positively cut cell is among them.
    num_relocated
        Vertices relocated by the eta perturbation (global count).
    timings
        Wall-clock seconds of the stages (this rank).
    max_conditioning_angle
        Largest conditioning angle in degrees (global).
    moved_angle_range
        Smallest and largest angle (degrees, global; dihedral for tetrahedra) of the kept
        cells that moved.
    num_loops
        Closed loops (surfaces) of Gamma_h, one per curve (surface piece) of Gamma.
    num_pieces
        Connected pieces of the kept cells (as many as the domain has).
    """

    sign: Float
    phi: Float
    closest: Float
    x: Float
    y: Float
    on_gamma: Bool
    kept: Bool
    moved: Bool
    near_cells: npt.NDArray[np.int32]
    num_relocated: int
    timings: dict[str, float]
    max_conditioning_angle: float = 0.0
    moved_angle_range: tuple[float, float] = (180.0, 0.0)
    num_loops: int = 0
    num_pieces: int = 0


class UniversalMesh:
    """A background mesh prepared once to be conformed to any number of domains
    (Rangarajan & Lew 2014).

    Everything that depends only on the background (vertex arrays, connectivities, mesh
    sizes, parameters) is computed here (tetrahedra: the faces at the first
    :meth:`straight_map`); :meth:`conform` then costs a classification, the projections of
    the vertices near Gamma and the DOLFINx mesh construction.

    Parameters
    ----------
    background
        Degree-1 triangle mesh (planar domains) or tetrahedron mesh (domains bounded by
        surfaces) containing the closure of the domain, acute near Gamma (equilateral,
        graded acute, A15 or BCC lattices); distributed with shared-facet ghosts (see
        :mod:`dolfinx_universal.backgrounds.lattice_tri`,
        :mod:`dolfinx_universal.backgrounds.lattice_tet`).
    R_r
        Relaxation radius; default ``relaxation_factor * h``. Must exceed ``h``.
    alpha
        Relaxation factor in ``[(1 + h/R_r)^-1, 1]``; default ``(1 + h/R_r)^-1``. Triangles
        only: on tetrahedra ``M_h`` snaps the positive faces and moves nothing else (the
        relaxation moves the band).
    eta
        Quality perturbation threshold; 0 disables it. Tetrahedra: inside vertices within
        ``eta h`` of Gamma count as on Gamma (Rangarajan, Kabaria & Lew 2019).
    relaxation_factor
        ``R_r / h`` when ``R_r`` is not given.
    local_size
        Graded backgrounds: use at each vertex a local size as ``h`` (the largest diameter
        of its cells, smoothed to vary by at most :data:`GRADATION` per unit length) instead
        of the global largest diameter; ``R_r`` then scales with it.
    min_angle
        Quality floor in degrees: conforming triangles with a smaller angle (tetrahedra: a
        smaller dihedral angle) are reported (0 disables the check).
    on_low_quality
        ``"warn"`` (a :class:`UserWarning` naming the places) or ``"raise"`` (a
        :class:`~dolfinx_universal.core.collective.MeshingError`).
    relax
        Relax the vertices near Gamma after ``M_h`` (:mod:`dolfinx_universal.conforming.relax`): the
        band's inside vertices move and the vertices on Gamma slide along it to raise the
        worst quality (triangles: smallest angle and circumradius / inradius;
        tetrahedra: mean ratio) of the kept cells around them; connectivity unchanged, a
        move is kept only if it helps and keeps the cells valid. ``False`` gives the plain
        ``M_h`` images.
    relax_frame
        The frame of the relaxation's choices (colour priorities, search directions):
        ``"world"`` (fixed axes), or ``"body"``: the frame of the domain's first
        :class:`~dolfinx_universal.boundaries.motions.RigidMotion` (its bodies first, then its
        container; the world if there is none). With ``"body"``, a motion that maps the
        background onto itself (a half turn about a symmetry axis of the lattice, a
        translation by a lattice period) maps the relaxed mesh onto the relaxed mesh, to
        rounding: a periodic motion gives periodic meshes and forces.
    mirror
        A line ``(point, normal)`` about which the background and the domains are
        symmetric (triangles only; e.g. a background of
        :func:`~dolfinx_universal.backgrounds.graded_tri.graded_mesh` with the same ``mirror``): the
        relaxation's choices are made symmetric under the reflection too
        (:attr:`~dolfinx_universal.conforming.relax.RelaxFrame.mirror`), so that the conforming mesh
        is the mirror image of itself where the background is, to rounding. ``M_h`` is
        symmetric without it; the relaxation's colours and search directions are not.
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
        relax: bool = True,
        relax_frame: str = "world",
        mirror: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
    ) -> None:
        _check_background(background)
        eta, min_angle = float(eta), float(min_angle)
        if not 0.0 <= eta < 1.0:  # also rejects NaN
            raise ValueError(f"eta must lie in [0, 1) (0 disables the perturbation), got {eta}")
        self._kit = kit = conforming_kit(background.topology.dim)
        if not 0.0 <= min_angle < kit.cells.max_min_angle:
            raise ValueError(
                f"min_angle must lie in [0, {kit.cells.max_min_angle:.4g}) degrees, got {min_angle}"
            )
        if on_low_quality not in ("warn", "raise"):
            raise ValueError(f"on_low_quality must be 'warn' or 'raise', got {on_low_quality!r}")
        if relax_frame not in ("world", "body"):
            raise ValueError(f"relax_frame must be 'world' or 'body', got {relax_frame!r}")
        self.relax_frame = relax_frame
        self._mirror = _mirror_frame(mirror, background.topology.dim)
        if self._mirror is not None and relax_frame != "world":
            raise ValueError("a mirror needs relax_frame='world'")
        self.background = background
        self.eta, self.min_angle, self.on_low_quality = eta, min_angle, on_low_quality
        self.relax = bool(relax)
        self._samples: tuple[object, float, Any] | None = None
        comm = self.comm = background.comm
        topo = background.topology
        self.tdim = tdim = topo.dim
        self._imv = topo.index_map(0)
        self._nco = topo.index_map(tdim).size_local
        x, c2v, v2n = _local_arrays(background)
        self._x, self._c2v, self._v2n = x, c2v, v2n
        self._containment = kit.containment(x, c2v)
        nv = len(x)
        bad = ~np.isfinite(x).all(axis=1)
        raise_collective(
            comm,
            [
                Problem(
                    "background mesh has NaN/inf coordinates at {count} vertices, e.g. {where}",
                    x[bad],
                    int(bad.sum()),
                    refinable=False,
                )
            ]
            if bad.any()
            else [],
        )
        self.h = vertex_sizes(self._imv, x, c2v, self._nco, local_size, comm)
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
        # the inward push of the band's inside vertices by M_h (0: snap only)
        self._push = self.alpha if kit.cells.inward_push else 0.0
        self._facet_arrays: tuple[Int, Int, Int, Int] | None = None
        if kit.eager_facets:
            self._facets()
        n2v = np.empty(len(background.geometry.x), dtype=np.int32)
        n2v[v2n] = np.arange(nv, dtype=np.int32)
        self._n2v = n2v

    def _facets(self) -> tuple[Int, Int, Int, Int]:
        """Cell -> facet connectivity, facet -> cell adjacency (offsets, cells) and the
        vertices on the background's boundary (collective at the first call).

        Built by the constructor or at the first :meth:`straight_map`, as the kit's
        :attr:`~dolfinx_universal.conforming.kit.ConformingKit.eager_facets` says.
        """
        if self._facet_arrays is None:
            topo, tdim = self.background.topology, self.tdim
            fdim = tdim - 1
            for a, b in ((tdim, fdim), (fdim, tdim), (fdim, 0), (0, tdim)):
                topo.create_connectivity(a, b)
            c2f = topo.connectivity(tdim, fdim).array.reshape(-1, tdim + 1)
            f2c = topo.connectivity(fdim, tdim)
            ext = dmesh.exterior_facet_indices(topo)
            outer = np.unique(topo.connectivity(fdim, 0).array.reshape(-1, tdim)[ext])
            self._facet_arrays = (c2f, f2c.offsets, f2c.array, outer)
        return self._facet_arrays

    @property
    def _v2c(self) -> tuple[Int, Int]:
        """Vertex -> cell adjacency list (offsets, cells), created by :meth:`_facets`."""
        self._facets()
        v2c = self.background.topology.connectivity(0, self.tdim)
        return v2c.offsets, v2c.array

    @property
    def _c2f(self) -> Int:
        """Cell -> facet connectivity ``(num_cells, tdim + 1)`` (:meth:`_facets`)."""
        return self._facets()[0]

    @property
    def _f2c_offsets(self) -> Int:
        return self._facets()[1]

    @property
    def _f2c(self) -> Int:
        return self._facets()[2]

    @property
    def _outer_vertices(self) -> Int:
        """Vertices on the background's boundary ``(k,)`` (:meth:`_facets`)."""
        return self._facets()[3]

    def straight_map(self, boundary: Boundary) -> StraightMap:
        """Classify the background against ``boundary`` and compute ``M_h`` (collective).

        Raises
        ------
        MeshingError
            On every rank, when the domain cannot be meshed on this background; the message
            says where and what to do.
        """
        comm, imv, x, c2v = self.comm, self._imv, self._x, self._c2v
        gdim = getattr(boundary, "gdim", 2)
        if gdim != self.tdim:
            raise ValueError(
                f"a {gdim}D boundary cannot be meshed on a {self.tdim}D background: curves "
                "need a triangle background, surfaces a tetrahedron background"
            )
        self._facets()  # collective at the first call
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        s, band = classify_near(comm, boundary, x, self.h, self.R_r)
        timings["classify"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        s, phi, closest, normal = project_band(comm, boundary, x, s, band, self.h)
        timings["project"] = time.perf_counter() - t1
        t2 = time.perf_counter()
        kit = self._kit
        near = kit.band(self.background.topology, c2v, band, s, self._nco)
        near_all, near_cells, near_cv = near.cells, near.owned, near.owned_cv
        xp, phi, s, num_relocated = perturb(
            comm, imv, x, phi, s, closest, near_cv, self.eta, self.h, kit.perturbation_candidates
        )
        pe = gamma_h(imv, s, c2v, near_cells, near.scan)
        require_kept(comm, pe.kept[: self._nco], boundary)
        pe, repaired = kit.repair(
            comm, imv, s, phi, xp, closest, pe, near, c2v, self._c2f, self._f2c_offsets,
            self._f2c,
        )  # fmt: skip
        num_relocated += repaired
        max_theta, num_loops, num_pieces = self._check_gamma_h(
            boundary, xp, s, phi, pe, band, near_cells, near_cv
        )
        y, moved = map_band(
            x, xp, phi, closest, normal, pe.on_gamma, self.h, self.R_r, self._push, band
        )
        outer = self._outer_vertices
        # without relaxation the inversion and quality checks measure the same moved cells
        # of the same images: once (tetrahedra)
        measures = None if self.relax else kit.measures(x, y, moved, pe.near_kept_cv)
        raise_collective(
            comm, conforming_problems(x, y, moved, pe.near_kept_cv, pe.in_kept, outer, measures)
        )
        if self.relax:
            t_relax = time.perf_counter()
            movable = movable_vertices(imv, s, band, pe.on_gamma, pe.in_kept, outer)
            y, xp, moved = relax_vertices(
                comm, imv, boundary.onto_gamma, x, xp, y, pe.near_kept_cv, movable,
                pe.on_gamma, normal, phi, self.h, frame=self._relax_frame(boundary),
            )[:3]  # fmt: skip
            timings["relax"] = time.perf_counter() - t_relax
        angle_range = self._check_quality(y, moved, pe.near_kept_cv, measures)
        timings["map"] = time.perf_counter() - t2
        return StraightMap(
            sign=s, phi=phi, closest=closest, x=xp, y=y, on_gamma=pe.on_gamma,
            kept=pe.kept, moved=moved, near_cells=near_all.astype(np.int32),
            num_relocated=num_relocated, timings=timings,
            max_conditioning_angle=float(np.degrees(max_theta)), moved_angle_range=angle_range,
            num_loops=num_loops, num_pieces=num_pieces,
        )  # fmt: skip

    def images_at(self, boundary: Boundary, sm: StraightMap) -> tuple[Float, Float, Float]:
        """The vertex images that ``sm``'s triangulation takes for another position of Gamma
        (collective): :func:`~dolfinx_universal.conforming.snap.frozen_images` with the
        projections of the band's vertices onto ``boundary``.

        The relaxation's moves are not in them (they are no function of Gamma). Used by
        time integrators to follow a node along a smooth path over the steps of one
        triangulation (:meth:`~dolfinx_universal.moving.domain.MovingDomain.nodes_at`).

        Returns
        -------
        xp, y
            The perturbed positions and the images ``(num_vertices, gdim)``.
        normal
            The normals at the band's vertices' closest points on ``boundary`` (zero
            elsewhere) ``(num_vertices, gdim)``.
        """
        x = self._x
        band = np.flatnonzero(np.isfinite(sm.phi))
        phi = np.zeros(len(x))
        closest = np.zeros_like(x)
        normal = np.zeros_like(x)
        phi[band], closest[band], normal[band] = collective_call(
            self.comm, "closest-point projection", boundary.project_normal, x[band]
        )
        relocated = np.zeros(len(x), dtype=bool)
        relocated[band] = (sm.x[band] != x[band]).any(axis=1)
        # the vertices map_band pushed inwards (its mask for sm's distances)
        pushed = ~sm.on_gamma & (sm.phi < 0) & (sm.phi > -self.R_r)
        xp, y = frozen_images(
            x, sm.on_gamma, relocated, pushed, phi, closest, normal, self.h, self.R_r,
            self._push, band,
        )  # fmt: skip
        return xp, y, normal

    def _check_gamma_h(
        self,
        boundary: Boundary,
        xp: npt.NDArray[np.float64],
        s: npt.NDArray[np.float64],
        phi: npt.NDArray[np.float64],
        pe: PositiveFacets,
        band: Int,
        near_cells: npt.NDArray[np.int32],
        near_cv: Int,
    ) -> tuple[float, int, int]:
        """Raise for a bad classification, Gamma outside the background or a wrong Gamma_h
        topology (the conditions of the method; collective).

        Returns
        -------
        max_theta
            The largest conditioning angle (radians, global).
        num_loops, num_pieces
            Loops of Gamma_h and connected pieces of the kept cells.
        """
        comm, imv, kit = self.comm, self._imv, self._kit
        # One sampling of Gamma serves the containment and the Gamma_h topology checks.
        samples = self._gamma_samples(boundary, band)
        pts = containment_samples(samples.points)
        # Containment first: a domain leaving the background also breaks Gamma_h there, and
        # "refine" would point the wrong way.
        raise_collective(
            comm,
            self._containment.problems(comm, pts, phi, self.h, near_cells, near_cv, self._v2c),
        )
        problems, theta = classification_problems(
            kit, xp, s, phi, pe, self._c2v, self._c2f, self._f2c_offsets, self._f2c, imv.size_local,
            self._x,
        )  # fmt: skip
        raise_collective(comm, problems)
        max_theta = comm.allreduce(theta, op=MPI.MAX)
        far_kept = comm.allreduce(bool(np.any(s[self._outer_vertices] < 0)), op=MPI.LOR)
        facets = pe.facets
        gids = imv.local_to_global(facets.ravel().astype(np.int32)).reshape(facets.shape)
        topo_problems, num_loops, num_pieces = kit.topology_problems(
            comm, gids, xp, pe, samples, far_kept
        )
        raise_collective(comm, topo_problems)
        return max_theta, num_loops, num_pieces

    def _relax_frame(self, boundary: Boundary) -> RelaxFrame | None:
        """The relaxation's frame for ``boundary`` (``None``: the world's axes)."""
        if self.relax_frame == "world":
            return self._mirror
        parts = list(getattr(boundary, "bodies", ())) + [getattr(boundary, "container", None)]
        for part in [boundary, *parts]:
            if isinstance(part, RigidMotion):  # frame coordinates (x - c - t) @ R
                return RelaxFrame(part.rotation, part.center + part.translation)
        return None

    def _check_quality(
        self,
        y: npt.NDArray[np.float64],
        moved: npt.NDArray[np.bool_],
        cells: Int,
        measures: TetMeasures | None = None,
    ) -> tuple[float, float]:
        """Report the moved ``cells`` below the quality floor; their global angle range
        (``measures``: those of the moved cells, computed already)."""
        if measures is None:
            moved_cells = cells[moved[cells].any(axis=1)]
            low, lo, hi = low_quality_cells(y, moved_cells, self.min_angle)
        else:
            low, lo, hi = low_quality_cells(y, measures.cells, self.min_angle, measures.angles)
        self._report_quality(low)
        return self.comm.allreduce(lo, op=MPI.MIN), self.comm.allreduce(hi, op=MPI.MAX)

    def _gamma_samples(self, boundary: Boundary, band_idx: npt.NDArray) -> Any:
        """Dense samples of Gamma (labelled by curve or surface), spaced well below the mesh
        size near it (:attr:`~dolfinx_universal.conforming.kit.ConformingKit.sample_spacing`;
        cached for the last boundary)."""
        hmin = self.comm.allreduce(
            float(self.h[band_idx].min()) if len(band_idx) else np.inf, op=MPI.MIN
        )
        if not np.isfinite(hmin):  # no vertex near Gamma (an error is reported anyway)
            hmin = float(np.max(self.h)) if len(self.h) else 1.0
            hmin = self.comm.allreduce(hmin, op=MPI.MAX)
        spacing = self._kit.sample_spacing * hmin
        cached = self._samples
        if cached is not None and cached[0] is boundary and cached[1] <= spacing:
            return cached[2]
        samples = self._kit.sample_gamma(self.comm, boundary, spacing)
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

    @property
    def vertex_coordinates(self) -> npt.NDArray[np.float64]:
        """The background's vertex coordinates (owned, then ghost vertices)
        ``(num_vertices, gdim)``, read-only."""
        v = self._x.view()
        v.flags.writeable = False
        return v

    @property
    def cell_vertices(self) -> npt.NDArray[np.int32]:
        """Vertices of the background's local cells (owned, then ghost)
        ``(num_cells, tdim + 1)``, read-only."""
        v = self._c2v.view()
        v.flags.writeable = False
        return v

    @property
    def cell_facets(self) -> Int:
        """Facets of the background's local cells ``(num_cells, tdim + 1)`` (facet ``k``
        opposite vertex ``k``; built at the first use, which is collective)."""
        return self._c2f

    def use_samples(self, boundary: Boundary, samples: CurveSamples) -> None:
        """Take ``samples`` of ``boundary`` (from
        :func:`~dolfinx_universal.sizing.fields.curve_samples`)
        for the Gamma_h checks of the next :meth:`conform` of ``boundary``, where they are
        spaced as finely as the checks ask (one sampling serves the sizing and the checks)."""
        self._samples = (boundary, samples.spacing, samples)

    def conform(self, boundary: Boundary) -> ConformingMesh:
        """The straight conforming mesh of the domain bounded by ``boundary`` (collective).

        Vertices of positive facets (edges of triangles, faces of tetrahedra) are snapped
        onto Gamma, on triangles the inside vertices within ``R_r`` of Gamma are relaxed
        inwards by at most ``alpha h``, cells with all vertices outside are dropped; with
        ``relax`` the band's vertices are then moved to improve the worst cells. No vertex
        is added; the kept cells keep their connectivity. The facet tags (and the mesh's
        facets) are built when first used.

        Raises
        ------
        MeshingError
            On every rank, when the domain cannot be meshed on this background.
        """
        sm = self.straight_map(boundary)
        t3 = time.perf_counter()
        kc = np.flatnonzero(sm.kept).astype(np.int32)  # owned and ghost: shared-facet ghosts
        tdim = self.tdim
        sub, cell_emap, vertex_emap, node_map = dmesh.create_submesh(self.background, tdim, kc)
        sub.geometry.x[:, :tdim] = sm.y[self._n2v[node_map]]
        sub.geometry.x[:, tdim:] = 0.0  # (z of triangles)
        stopo = sub.topology
        stopo.create_connectivity(tdim, 0)
        simv, simc = stopo.index_map(0), stopo.index_map(tdim)
        nsv = simv.size_local + simv.num_ghosts
        vmap = vertex_emap.sub_topology_to_topology(np.arange(nsv, dtype=np.int32), False)
        cmap = cell_emap.sub_topology_to_topology(
            np.arange(simc.size_local + simc.num_ghosts, dtype=np.int32), False
        )
        timings = dict(sm.timings, mesh=time.perf_counter() - t3)
        moved = sm.moved
        return ConformingMesh(
            mesh=sub,
            background=self.background,
            boundary=boundary,
            cell_map=np.asarray(cmap, dtype=np.int32),
            vertex_map=np.asarray(vmap, dtype=np.int32),
            node_map=np.asarray(node_map, dtype=np.int32),
            sign=sm.sign[vmap],
            background_x=sm.x[vmap],
            on_gamma=sm.on_gamma[vmap],
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


def _mirror_frame(
    mirror: tuple[npt.ArrayLike, npt.ArrayLike] | None, tdim: int
) -> RelaxFrame | None:
    """The relaxation frame of a mirror line ``(point, normal)``: origin on the line, second
    axis its unit normal."""
    if mirror is None:
        return None
    if tdim != 2:
        raise ValueError("a mirror is supported on triangles only")
    point, n = mirror_line(mirror, 2)
    rotation = np.array([[n[1], n[0]], [-n[0], n[1]]])  # columns: the line's direction, n
    return RelaxFrame(rotation, point, mirror=1)


def conform(
    background: dmesh.Mesh, boundary: Boundary, *, R_r: float | None = None,
    alpha: float | None = None, eta: float = 0.2, relaxation_factor: float = 3.0,
    local_size: bool = False, min_angle: float = 10.0, on_low_quality: str = "warn",
    relax: bool = True, relax_frame: str = "world",
    mirror: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> ConformingMesh:  # fmt: skip
    """Conform a background triangulation to the domain bounded by ``boundary``.

    Shorthand for ``UniversalMesh(background, ...).conform(boundary)``; use
    :class:`UniversalMesh` to conform one background to many domains.

    Parameters
    ----------
    background
        The background mesh, as in :class:`UniversalMesh`.
    boundary
        The domain (signs, closest points, normals).
    R_r, alpha, eta, relaxation_factor, local_size, min_angle, on_low_quality, relax
        Options of :class:`UniversalMesh`.
    relax_frame, mirror
        Options of :class:`UniversalMesh`.

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
        local_size=local_size, min_angle=min_angle, on_low_quality=on_low_quality, relax=relax,
        relax_frame=relax_frame, mirror=mirror,
    )  # fmt: skip
    return um.conform(boundary)
