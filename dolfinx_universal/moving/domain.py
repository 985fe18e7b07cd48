"""Moving domains on one universal background: geometry updated in place, topology fixed."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

from mpi4py import MPI

import basix
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem, la
from dolfinx import mesh as dmesh

from dolfinx_universal.backgrounds.graded_tri import EDGE_FACTOR, graded_mesh
from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.conforming.classify import positively_cut
from dolfinx_universal.conforming.quality import cell_quality
from dolfinx_universal.conforming.universal import StraightMap, UniversalMesh
from dolfinx_universal.core.arrays import all_rows, any_rows, write_cell_nodes
from dolfinx_universal.core.collective import (
    MeshingError,
    Problem,
    collective_call,
    raise_collective,
    vertex_reduce,
    where,
)
from dolfinx_universal.core.compiled import pointer, relax_kernels
from dolfinx_universal.curved.bounds import check_degree
from dolfinx_universal.curved.maps import CELL_MAPS, MAPS, jacobian_ratio
from dolfinx_universal.io import redistribute
from dolfinx_universal.meshing.domain import MAX_CELLS, UniformPlan, size_from_geometry
from dolfinx_universal.moving import quality_tet, quality_tri
from dolfinx_universal.sizing.fields import CurveSamples, SizeField, feature_size, target_sizes

COVERAGE_TOLERANCE = 1.5
"""A step may ask for sizes this much finer than the background built for the motion."""

__all__ = ["MovingDomain", "StepReport"]

_QUALITY = {2: quality_tri, 3: quality_tet}
"""The quality of the cells a step leaves unaltered, per topological dimension."""


@dataclass
class StepReport:
    """What one :meth:`MovingDomain.update` did and how good the result is."""

    step: int
    timings: dict[str, float]
    """Seconds of the stages on this rank: ``classify``, ``project``, ``map`` (perturbation,
    M_h, checks), ``geometry`` (curved nodes written in place, validity of curved cells),
    ``total``."""
    quality: dict[str, float | int]
    """:func:`~dolfinx_universal.conforming.quality.cell_quality` of the active (straight)
    triangles."""
    num_active_cells: int
    num_updated_cells: int
    """Cells whose geometry nodes were rewritten (global): those with a vertex moved or on
    Gamma now or at the previous step, and those whose activity changed."""
    min_jacobian_ratio: float


def _balanced(background: dmesh.Mesh) -> dmesh.Mesh:
    """The background, on several ranks redistributed by DOLFINx's graph partitioner
    (:func:`~dolfinx_universal.io.redistribute`; the same global mesh).

    The lattice backgrounds keep the slabs of cell layers they are built in (A15,
    equilateral): a moving boundary then lies on the few ranks whose slabs it crosses, and
    so do the relaxation's work and the domain's cells; compact parts spread both over more
    ranks. (Graded backgrounds, runs of leaves along a space-filling curve with most cells
    near Gamma, share the band about as well as the graph partitioner does: on the propeller
    demo's, 1.15 against 1.14 times the mean on 4 ranks.) Measured on the moving
    torus of ``benchmarks/conform_floor_3d.py`` (1e6 A15 tetrahedra; the busiest rank's
    share over the mean, slabs -> graph): the relaxation's work 2.07 -> 1.16 on 4 ranks and
    3.50 -> 2.21 on 16, the active cells 2.14 -> 1.24 and 3.88 -> 2.91.
    """
    if background.comm.size == 1:
        return background
    return redistribute(background)[0]


def _far_extreme(
    values: npt.NDArray[np.float64],
    order: npt.NDArray[np.intp],
    mask: npt.NDArray[np.bool_],
    lowest: bool,
) -> float | None:
    """``values[mask].min()`` (``lowest``) or ``.max()``, None for an empty mask, from the
    ascending ``order`` of ``values``: the first masked cell in that order (or the
    reverse). The cells left out (near Gamma, outside the domain) are few, so a short head
    of the order holds one: the same value as the full reduction, without it."""
    idx = order if lowest else order[::-1]
    for head in (idx[:_HEAD], idx):
        hit = mask[head]
        if hit.any():
            return float(values[head[np.argmax(hit)]])
    return None


BRANCH_ANGLE = 45.0
"""Degrees between the normals at a vertex's closest points on two positions of Gamma
beyond which :meth:`MovingDomain.nodes_at` takes its projection to have jumped to another
branch (a vertex near the medial axis): its path is then held at its current place."""

_HEAD = 4096
"""Cells of the sorted order :func:`_far_extreme` tries before the whole order."""


class MovingDomain:
    """A background mesh re-conformed in place to a moving domain at every step.

    One universal mesh serves every position of the domain (Rangarajan & Lew 2014).

    The DOLFINx mesh :attr:`mesh` is the *whole* background with a degree-q coordinate
    element; it is created once, so its topology, dofmaps, sparsity patterns and every form
    compiled on it are reused for all steps. :meth:`update` rewrites, in place, the geometry
    nodes of the cells with a vertex moved or on Gamma (now or at the previous step) and the
    cell indicator :attr:`active` (1 on ``T_h^sub``, 0 on the triangles outside the domain).
    Forms are written with the indicator::

        a = md.active * inner(grad(u), grad(v)) * dx

    and the degrees of freedom of inactive cells are fixed by :meth:`inactive_dofs`.
    Integrals over the immersed boundary are one-sided interior-facet integrals
    (:meth:`immersed_integral`); :mod:`dolfinx_universal.moving.problems` assembles and
    solves on it reusing one matrix. Geometry outside the domain is meaningless (triangles may
    fold there) and never integrated with a nonzero weight.

    Parameters
    ----------
    background
        Degree-1 background mesh (shared-facet ghosts), acute near every position of Gamma.
    degree
        Geometry degree ``q``, at most :data:`~dolfinx_universal.curved.bounds.MAX_DEGREE` (7 for
        triangles, 5 for tetrahedra: the validity proof's limit).
    map
        ``"I"``/``"G"`` (blend ``G_h``) or ``"I~"``/``"G~"`` (``G~_h``); see
        :data:`~dolfinx_universal.curved.maps.MAPS`.
    options
        Keyword options of :class:`~dolfinx_universal.conforming.universal.UniversalMesh`: ``R_r``,
        ``alpha``, ``eta``, ``relaxation_factor``, ``local_size`` (``True`` for graded
        backgrounds), ``min_angle``, ``on_low_quality``, ``relax`` (the vertex relaxation
        after ``M_h``, on by default).

    Notes
    -----
    Under MPI the background's partition decides how the work near Gamma and the solve on
    the active cells are shared: the lattice backgrounds (A15, equilateral) keep the slabs
    of layers they are built in, so pass ``dolfinx_universal.io.redistribute(background)[0]``
    (the same mesh, compact parts; :meth:`from_motion` does it for surfaces). On the
    moving torus of
    ``benchmarks/conform_floor_3d.py`` (1e6 tetrahedra, 4 ranks) the busiest rank then
    does 1.16 times the mean of the relaxation's work instead of 2.07, and holds 1.24
    times the mean of the active cells instead of 2.14.

    See Also
    --------
    from_motion : a background sized automatically for a given motion.
    """

    def __init__(
        self,
        background: dmesh.Mesh,
        degree: int = 2,
        map: str = "I",
        **options: Any,
    ):
        if map not in MAPS:
            raise ValueError(f"unknown map {map!r}: choose one of {MAPS}")
        degree = check_degree(degree, background.topology.dim)
        self.universal = UniversalMesh(background, **options)
        self.refinement_rounds = 0
        """Local refinements made by :meth:`from_motion` (0 otherwise)."""
        self.degree, self.map = int(degree), map
        self._kind = "G" if map in ("I", "G") else "G~"
        self.tdim = tdim = background.topology.dim
        ce = fem.coordinate_element(
            background.topology.cell_type, self.degree, basix.LagrangeVariant.gll_warped
        )
        self.mesh: dmesh.Mesh = fem.interpolate_geometry(background, ce)
        """The background with degree-q geometry; its nodes move, its topology never does."""
        self.comm: MPI.Comm = background.comm
        self._x0 = self.mesh.geometry.x[:, :tdim].copy()
        self._node_vector: la.Vector | None = None  # owned -> ghost copies of moved nodes
        self._dofmap = self.mesh.geometry.dofmaps[0]
        topo = self.mesh.topology
        self._nco = topo.index_map(tdim).size_local
        self._c2v = self.universal.cell_vertices
        self._c2f = self.universal.cell_facets
        self._dirty = np.zeros(len(self._c2v), dtype=bool)
        self._kept = np.zeros(len(self._c2v), dtype=bool)  # as the indicator: 0
        Q0 = fem.functionspace(self.mesh, ("DG", 0))
        self.active = fem.Function(Q0, name="active")
        """Cell indicator of ``T_h^sub``: 1 inside the current domain, 0 outside."""
        self._cell_dof = Q0.dofmap.list[:, 0]
        self.boundary: Boundary | None = None
        self.immersed_facets = np.empty(0, dtype=np.int32)
        """Background facets on Gamma_h (process-local, owned and ghost)."""
        self.active_cells = np.empty(0, dtype=np.int32)
        """Cells of ``T_h^sub`` (process-local, owned and ghost)."""
        self._cells = np.arange(len(self._c2v), dtype=np.int32)
        self._maps = CELL_MAPS[tdim]
        self._unaltered = _QUALITY[tdim]
        # the angle histogram of the owned kept cells (background angles; tetrahedra)
        self._kept_histogram = np.zeros(self._unaltered.HISTOGRAM_BINS, dtype=np.int64)
        self._active_tags: dmesh.MeshTags | None = self._tags()
        self.steps: list[StepReport] = []
        self._step_map: tuple[StraightMap, Boundary] | None = None
        self._images: tuple[npt.NDArray[np.float64], ...] | None = None
        self._coverage: tuple[SizeField, npt.NDArray[np.float64], int, float | None] | None = None

    @classmethod
    def from_motion(
        cls,
        comm: MPI.Comm,
        motion: Sequence[Boundary] | Callable[[float], Boundary],
        h: float,
        *,
        times: Sequence[float] | None = None,
        degree: int = 2,
        map: str = "I",
        box: npt.ArrayLike | None = None,
        size_factor: float | None = None,
        max_rounds: int = 8,
        **options: Any,
    ) -> MovingDomain:
        """A moving domain on one graded background sized for a whole motion (collective).

        The background's size near the swept band follows the geometry of every position
        (as :func:`~dolfinx_universal.meshing.domain.mesh_domain` does for one); every position is
        then conformed once, and where a check fails the background is refined there and the
        positions conformed again (at most ``max_rounds`` times). Later :meth:`update` calls
        check that their boundary stays in the region the background was sized for.

        Surfaces: a uniform A15 background (every dihedral angle 53-79 degrees) of the
        smallest target size over the positions, on the union of their boxes, halved
        everywhere where a position fails (at most
        :data:`~dolfinx_universal.meshing.domain.MAX_CELLS` tetrahedra); later updates are not
        checked against it. On several ranks it is redistributed by DOLFINx's graph
        partitioner (the same mesh): the lattice is built in slabs of layers, compact parts
        share the moving band and the domain's cells among more ranks.

        Parameters
        ----------
        comm
            Communicator of the mesh.
        motion
            The boundary's positions, or a callable ``t -> Boundary`` evaluated at ``times``.
        h
            Largest mesh size.
        times
            Times at which to evaluate a callable ``motion``.
        degree, map
            As in :class:`MovingDomain`.
        box
            The background's extent (default: the positions' bounding boxes plus a margin).
        size_factor, max_rounds
            As in :func:`~dolfinx_universal.meshing.domain.mesh_domain`.
        options
            ``eta``, ``relaxation_factor``, ``min_angle`` (default 10 degrees) as in
            :class:`~dolfinx_universal.conforming.universal.UniversalMesh` (``local_size`` is on).

        Raises
        ------
        MeshingError
            When the positions cannot be meshed within ``max_rounds`` refinements, naming the
            position and the place.
        """
        if callable(motion):
            if times is None:
                raise ValueError("a callable motion needs the times at which to evaluate it")
            positions = [motion(float(t)) for t in times]
        else:
            positions = list(motion)
        if not positions:
            raise ValueError("the motion has no positions")
        build = {2: cls._from_curve_motion, 3: cls._from_surface_motion}
        return build[getattr(positions[0], "gdim", 2)](
            comm, positions, h, degree, map, box, size_factor, max_rounds, options
        )

    @classmethod
    def _from_curve_motion(
        cls,
        comm: MPI.Comm,
        positions: list[Boundary],
        h: float,
        degree: int,
        map: str,
        box: npt.ArrayLike | None,
        size_factor: float | None,
        max_rounds: int,
        options: dict[str, Any],
    ) -> MovingDomain:
        """:meth:`from_motion` for curves: the graded background sized by the geometry of
        every position, refined near the points where a position fails a refinable check."""
        box_arr, field, _, _ = size_from_geometry(
            comm,
            positions,
            h,
            degree=degree,
            box=box,
            relaxation_factor=options.get("relaxation_factor", 3.0),
            size_factor=size_factor,
        )
        options = {**options, "local_size": True}
        state = {"field": field}

        def refine(points: npt.NDArray[np.float64]) -> bool:
            if len(points) == 0:
                return False
            f = state["field"]
            state["field"] = f.refined(points, 0.5 * f(points))
            return True

        md = cls._conformed_to_motion(
            positions,
            lambda: graded_mesh(
                comm, box_arr, state["field"], max_size=h, root_size=h / EDGE_FACTOR
            ),
            refine,
            degree,
            map,
            options,
            max_rounds,
        )
        md._coverage = (state["field"], box_arr, degree, size_factor)
        return md

    @classmethod
    def _conformed_to_motion(
        cls,
        positions: list[Boundary],
        background: Callable[[], dmesh.Mesh],
        refine: Callable[[npt.NDArray[np.float64]], bool],
        degree: int,
        map: str,
        options: dict[str, Any],
        max_rounds: int,
    ) -> MovingDomain:
        """Conform every position on ``background()``; after a refinable failure near some
        points, ``refine(points)`` (False: it cannot) and build again, at most
        ``max_rounds`` times (collective)."""
        rounds = 0
        while True:
            md = cls(background(), degree, map, **options, on_low_quality="raise")
            k = 0
            try:
                for k in range(len(positions)):
                    md.update(positions[k])
                break
            except MeshingError as e:
                if not e.refinable or rounds >= max_rounds or not refine(e.points):
                    raise MeshingError(
                        f"position {k} of the motion cannot be meshed"
                        + (f" after {rounds} refinements" if rounds else "")
                        + f": {e}",
                        e.points,
                        refinable=False,
                    ) from None
                rounds += 1
        md.universal.on_low_quality = "warn"
        md.steps.clear()
        md.refinement_rounds = rounds
        return md

    @classmethod
    def _from_surface_motion(
        cls,
        comm: MPI.Comm,
        positions: list[Boundary],
        h: float,
        degree: int,
        map: str,
        box: npt.ArrayLike | None,
        size_factor: float | None,
        max_rounds: int,
        options: dict[str, Any],
    ) -> MovingDomain:
        """:meth:`from_motion` for surfaces: the uniform A15 background (acute, as
        :func:`~dolfinx_universal.meshing.domain.mesh_domain` takes for one position) of the
        smallest target size over the positions, in the union of their boxes; halved
        everywhere where a position fails a refinable check."""
        rf = float(options.get("relaxation_factor", 3.0))
        plans = [UniformPlan.create(comm, p, h, degree, box, rf, size_factor) for p in positions]
        union = UniformPlan(
            np.array([np.min([p.box[0] for p in plans], axis=0),
                      np.max([p.box[1] for p in plans], axis=0)]),
            min(p.size for p in plans),
            *(np.concatenate([getattr(p, a) for p in plans]) for a in ("points", "feature", "rho")),
        )  # fmt: skip
        rounds: list[str] = []

        def background() -> dmesh.Mesh:
            union.check_size(MAX_CELLS, rounds)
            return _balanced(union.background(comm))

        def refine(points: npt.NDArray[np.float64]) -> bool:
            union.refine(points)  # halved everywhere
            rounds.append(f"halved to {union.size:.3g}")
            return True

        return cls._conformed_to_motion(
            positions, background, refine, degree, map, options, max_rounds
        )

    # -- the update -----------------------------------------------------------------------

    def update(self, boundary: Boundary) -> StepReport:
        """Conform the background to the domain bounded by ``boundary`` (collective).

        Raises
        ------
        MeshingError
            On every rank if the domain cannot be meshed (nothing is changed then).
        """
        t0 = time.perf_counter()
        sm = self._straight_map(boundary)
        t1 = time.perf_counter()
        near, flip, redo = self._cells_to_rewrite(sm)
        cells, kept = self._c2v[redo], sm.kept[redo]
        cut = np.flatnonzero(kept & positively_cut(sm.sign, cells))
        # the facets of Gamma_h: of each positively cut cell, the one opposite its inside vertex
        positive = self._c2f[redo[cut], np.argmin(sm.sign[cells[cut]], axis=1)]
        curve, nodes = self._curved_nodes(sm, boundary, redo, cut, positive)
        ratio = self._proven_valid(nodes[np.flatnonzero(kept[curve])])
        self._write_nodes(sm.y, redo, curve, kept, nodes)
        self._set_domain(sm, near, flip, redo, positive, boundary)
        t2 = time.perf_counter()
        report = self._report(
            sm, near, redo, ratio, dict(sm.timings, geometry=t2 - t1, total=t2 - t0)
        )
        self.steps.append(report)
        return report

    @property
    def active_mask(self) -> npt.NDArray[np.bool_]:
        """Whether each process-local cell (owned and ghost) is active (in ``T_h^sub``)."""
        return self._kept

    def nodes_at(self, boundaries: Sequence[Boundary]) -> list[npt.NDArray[np.float64]]:
        """The geometry nodes that the current triangulation takes for other positions of
        Gamma: paths of the nodes through them (collective; nothing is changed).

        The classification of the last :meth:`update` (signs, snapped and relocated
        vertices, active cells, which cells are curved) is kept, and the vertex images and
        curved nodes are computed for each of ``boundaries``: for the last step's boundary
        these are the current nodes (bitwise without the relaxation), and for the positions
        of a smooth motion near it each node follows a smooth path in time. Vertices whose
        image is no smooth function of Gamma keep their current place along the paths (on
        Gamma: slide onto it): those the relaxation moved, and those whose closest point
        jumps between the branches of the projection over ``boundaries`` (vertices near
        the medial axis pushed inwards by ``M_h``; normals more than
        :data:`BRANCH_ANGLE` apart). Time integrators take the mesh velocity and the
        previous solutions along these paths
        (:class:`~dolfinx_universal.moving.stepping.TimeStepper`).

        Returns
        -------
        For each boundary, the nodes ``(num_nodes, gdim)`` (process-local, owned and ghost).
        """
        if self._step_map is None:
            raise RuntimeError("nodes_at needs a triangulation: call update first")
        sm, now = self._step_map
        images = [self.universal.images_at(b, sm) for b in boundaries]
        band = np.flatnonzero(np.isfinite(sm.phi))
        fixed = self._relaxed_vertices().copy()
        normal_now = self._now_images()[2]
        cos = np.cos(np.radians(BRANCH_ANGLE))
        for _, _, normal in images:
            fixed[band] |= np.einsum("nd,nd->n", normal[band], normal_now[band]) < cos
        fixed = vertex_reduce(self.mesh.topology.index_map(0), fixed.astype(np.float64), "max") > 0
        near = np.flatnonzero(self._dirty)
        cells = self._c2v[near]
        cut = np.flatnonzero(sm.kept[near] & positively_cut(sm.sign, cells))
        positive = self._c2f[near[cut], np.argmin(sm.sign[cells[cut]], axis=1)]
        out = []
        for boundary, (xp, y, _) in zip(boundaries, images, strict=True):
            # on every rank, with or without fixed vertices: the projection is collective
            xp[fixed] = sm.x[fixed]  # the background place the curved map blends from
            inside = fixed & ~sm.on_gamma
            y[inside] = sm.y[inside]
            sliding = np.flatnonzero(fixed & sm.on_gamma)
            y[sliding] = collective_call(
                self.comm, "closest-point projection", boundary.closest_point, sm.y[sliding]
            )
            curve, nodes = self._curved_nodes(replace(sm, x=xp, y=y), boundary, near, cut, positive)
            x = self.mesh.geometry.x.copy()
            self._write_nodes(y, near, curve, sm.kept[near], nodes, x)
            out.append(x[:, : self.tdim])
        return out

    def _now_images(self) -> tuple[npt.NDArray[np.float64], ...]:
        """:meth:`~dolfinx_universal.conforming.universal.UniversalMesh.images_at` of the
        last step's own boundary (collective, once per step)."""
        if self._images is None:
            sm, now = self._step_map  # type: ignore[misc]
            self._images = self.universal.images_at(now, sm)
        return self._images

    def _relaxed_vertices(self) -> npt.NDArray[np.bool_]:
        """Vertices whose image the relaxation of the last step moved (collective)."""
        sm, now = self._step_map  # type: ignore[misc]
        if not self.universal.relax:
            return np.zeros(len(sm.y), dtype=bool)
        xp, y, _ = self._now_images()
        return (y != sm.y).any(axis=1) | (xp != sm.x).any(axis=1)

    def _straight_map(self, boundary: Boundary) -> StraightMap:
        """The straight map ``M_h`` of the step, after the coverage check of
        :meth:`from_motion`'s background (collective); its errors name the step."""
        if self._coverage is not None:
            self._check_coverage(boundary)
        try:
            return self.universal.straight_map(boundary)
        except MeshingError as e:
            raise type(e)(f"step {len(self.steps)}: {e}", e.points, e.refinable) from None

    def _cells_to_rewrite(
        self, sm: StraightMap
    ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_], npt.NDArray[np.intp]]:
        """The cells whose nodes differ from the background's now (``near``: a vertex moved
        or on Gamma, as every curved cell has), the cells entering or leaving the domain
        (``flip``), and the cells to rewrite (``redo``): those, and those that differed at
        the previous step (restored to their straight background shape). Cells whose
        activity changed elsewhere (a large jump of the body) are rewritten to set their
        indicator. All of them are among the band's cells."""
        c2v, band = self._c2v, sm.near_cells
        near = np.zeros(len(c2v), dtype=bool)
        near[band[any_rows((sm.moved | sm.on_gamma)[c2v[band]])]] = True
        flip = sm.kept != self._kept
        return near, flip, np.flatnonzero(near | self._dirty | flip)

    def _curved_nodes(
        self,
        sm: StraightMap,
        boundary: Boundary,
        redo: npt.NDArray[np.intp],
        cut: npt.NDArray[np.intp],
        positive: npt.NDArray[np.int32],
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.float64]]:
        """The cells among ``redo`` that the curved map changes (indices into ``redo``) and
        their nodes (collective); every other node is the affine image of its entity's
        vertices. ``cut``: the positively cut kept cells among ``redo``; ``positive``: their
        facets on Gamma_h."""
        if self.degree == 1:  # straight cells: nothing is curved
            return cut[:0], np.empty((0, self.tdim + 1, self.tdim))
        cells = self._c2v[redo]
        curve, cell_map = self._maps.curved_cells(
            self.mesh,
            cells,
            cut,
            positive,
            sm.on_gamma,
            sm.sign,
            sm.x,
            self.degree,
            self._kind,
            boundary.closest_point,
            rows=redo,
        )
        nodes = collective_call(self.comm, "the curved map", cell_map, cells[curve], sm.y)
        return curve, nodes

    def _proven_valid(self, nodes: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """The proven lower bounds of ``det J / det J_affine`` of the active curved cells
        ``nodes``; raises on every rank if one would be inverted (collective)."""
        ratio = jacobian_ratio(nodes, self.degree) if self.degree > 1 else np.ones(0)
        bad = ratio <= 0
        plural = cell_kernels(self.tdim).plural
        raise_collective(
            self.comm,
            [
                Problem(
                    f"step {len(self.steps)}: "
                    + "{count} curved "
                    + plural
                    + " would be inverted near {where}: refine the background there",
                    nodes[bad].mean(axis=1),
                    int(bad.sum()),
                )
            ]
            if bad.any()
            else [],
        )
        return ratio

    def _write_nodes(
        self,
        y: npt.NDArray[np.float64],
        redo: npt.NDArray[np.intp],
        curve: npt.NDArray[np.intp],
        kept: npt.NDArray[np.bool_],
        nodes: npt.NDArray[np.float64],
        x: npt.NDArray[np.float64] | None = None,
    ) -> None:
        """Write the nodes of the cells ``redo`` in place (into the mesh, or into the copy
        ``x`` of its nodes): the affine ones, then the curved cells' (inactive ones first,
        so that on Gamma_h the active cell's curved nodes win), and copy them to the ghosts
        (collective)."""
        into_mesh = x is None
        x = self.mesh.geometry.x if x is None else x
        touched = self._write_affine_nodes(redo, y, x)
        order = np.argsort(kept[curve], kind="stable")
        written = redo[curve[order]]
        write_cell_nodes(x, self._dofmap, written, nodes, order)
        rows = np.concatenate([touched, self._dofmap[written].ravel()])
        if into_mesh:
            self._sync_ghost_nodes(rows, x)
        else:
            self._sync_ghost_copy(x)

    def _set_domain(
        self,
        sm: StraightMap,
        near: npt.NDArray[np.bool_],
        flip: npt.NDArray[np.bool_],
        redo: npt.NDArray[np.intp],
        positive: npt.NDArray[np.int32],
        boundary: Boundary,
    ) -> None:
        """Record the step's domain: the kept cells' histogram, the cells to restore at the
        next step, the indicator, the active cells, the facets of Gamma_h, the boundary."""
        owned = np.flatnonzero(flip[: self._nco])
        kept_now = sm.kept[owned]
        self._kept_histogram += self._histogram(owned[kept_now])
        self._kept_histogram -= self._histogram(owned[~kept_now])
        self._dirty, self._kept = near, sm.kept
        self._step_map = (sm, boundary)
        self._images = None  # found when asked for (nodes_at)
        self.active.x.array[self._cell_dof[redo]] = sm.kept[redo].astype(np.float64)
        self.active_cells = np.flatnonzero(sm.kept).astype(np.int32)
        self._active_tags = None  # made when asked for (active_tags)
        self.immersed_facets = np.unique(positive).astype(np.int32)
        self.boundary = boundary

    def _report(
        self,
        sm: StraightMap,
        near: npt.NDArray[np.bool_],
        redo: npt.NDArray[np.intp],
        ratio: npt.NDArray[np.float64],
        timings: dict[str, float],
    ) -> StepReport:
        """The :class:`StepReport` of the step (collective)."""
        quality = self._quality(sm, near)
        return StepReport(
            step=len(self.steps),
            timings=timings,
            quality=quality,
            num_active_cells=int(quality["n_cells"]),
            num_updated_cells=self.comm.allreduce(int(np.count_nonzero(redo < self._nco))),
            min_jacobian_ratio=self.comm.allreduce(
                float(ratio.min()) if len(ratio) else 1.0, op=MPI.MIN
            ),
        )

    @cached_property
    def _node_entity(self) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
        """For each geometry node, one cell holding it and the slot there (``cell * ndofs +
        slot``), and the barycentric coordinates of the reference nodes ``(ndofs, tdim + 1)``."""
        dofmap = self._dofmap
        code = np.empty(self.mesh.geometry.x.shape[0], dtype=np.int64)
        code[dofmap] = np.arange(dofmap.size, dtype=np.int64).reshape(dofmap.shape)
        lam = self._maps.reference_nodes(self.degree)
        return code, lam

    def _write_affine_nodes(
        self, redo: npt.NDArray[np.intp], y: npt.NDArray[np.float64], x: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.int64]:
        """Write the affine images (under the vertex images ``y``) of the nodes of the cells
        ``redo`` into ``x``, each node once, and return them.

        A node is the image of its reference point in one cell holding it, summed in vertex
        order (the sums of :func:`~dolfinx_universal.curved.maps_tri.map_nodes`): the same value as
        from any other cell for a node on a vertex or an edge, within an ulp on a face. A C
        kernel where available (one pass over the cells), else numpy: bitwise the same.
        """
        code, lam = self._node_entity
        kernels = relax_kernels()
        if kernels is not None:
            ffi, redo = kernels.ffi, np.ascontiguousarray(redo, dtype=np.int64)
            y = np.ascontiguousarray(y)
            mark = np.zeros(len(x), dtype=np.uint8)
            touched = np.empty(len(x), dtype=np.int64)
            n = kernels.lib.affine_nodes(
                pointer(ffi, redo, "int64_t"), len(redo), pointer(ffi, self._dofmap, "int32_t"),
                lam.shape[0], pointer(ffi, self._c2v, "int32_t"), lam.shape[1],
                pointer(ffi, code, "int64_t"), pointer(ffi, lam, "double"),
                pointer(ffi, y, "double"), y.shape[1], pointer(ffi, x, "double"),
                pointer(ffi, mark, "uint8_t"), pointer(ffi, touched, "int64_t"),
            )  # fmt: skip
            return touched[:n]
        mark = np.zeros(len(x), dtype=bool)
        mark[self._dofmap[redo]] = True
        touched = np.flatnonzero(mark)
        cell, slot = np.divmod(code[touched], lam.shape[0])
        v, w = self._c2v[cell], lam[slot]
        value = w[:, :1] * y[v[:, 0]]
        for k in range(1, v.shape[1]):
            value += w[:, k : k + 1] * y[v[:, k]]
        x[touched, : self.tdim] = value
        return touched

    def _sync_ghost_nodes(self, rows: npt.NDArray[np.int32], x: npt.NDArray[np.float64]) -> None:
        """Copy the owners' values of the rewritten nodes to their ghosts (collective).

        A rank that holds only the outside (inactive, affine) cell of an immersed facet as a
        ghost would otherwise keep a straight node there; the owner of a facet node owns one
        of its two cells and has the other as a shared-facet ghost, so its value is the
        active cell's.
        """
        if self.comm.size == 1:
            return
        d = self.tdim
        if self._node_vector is None:  # the current nodes; then only the rewritten ones
            self._node_vector = la.vector(self.mesh.geometry.index_map(), d, dtype=np.float64)
            self._node_vector.array[:] = x[:, :d].ravel()
        values = self._node_vector.array.reshape(-1, d)
        values[rows] = x[rows, :d]
        self._node_vector.scatter_forward()
        n = self.mesh.geometry.index_map().size_local
        x[n:, :d] = values[n:]

    def _sync_ghost_copy(self, x: npt.NDArray[np.float64]) -> None:
        """Copy the owners' values of all nodes of ``x`` (a copy of the mesh's) to their
        ghosts (collective)."""
        if self.comm.size == 1:
            return
        d, vector = self.tdim, self._copy_vector
        vector.array[:] = x[:, :d].ravel()
        vector.scatter_forward()
        n = self.mesh.geometry.index_map().size_local
        x[n:, :d] = vector.array.reshape(-1, d)[n:]

    @cached_property
    def _copy_vector(self) -> la.Vector:
        """The nodes' vector of :meth:`_sync_ghost_copy` (made once)."""
        return la.vector(self.mesh.geometry.index_map(), self.tdim, dtype=np.float64)

    def _check_coverage(self, boundary: Boundary) -> None:
        """Raise if ``boundary`` needs a finer background than :meth:`from_motion` built."""
        field, box, degree, factor = self._coverage  # type: ignore[misc]

        def needs() -> tuple[CurveSamples, npt.NDArray[np.float64]]:
            samples, feature = feature_size(boundary)
            return samples, target_sizes(feature, float(field.h_max), degree, factor)

        samples, target = collective_call(self.comm, "sizing the boundary", needs)
        pts = samples.points
        # One sampling for both: the feature samples serve the Gamma_h checks of this step
        # when they are fine enough.
        self.universal.use_samples(boundary, samples)
        outside = ~((pts > box[0]).all(axis=1) & (pts < box[1]).all(axis=1))
        coarse = target < field(pts) / COVERAGE_TOLERANCE
        bad = outside | coarse
        if bad.any():
            what = (
                "leaves the background"
                if outside.any()
                else ("needs a finer background than the one sized for the motion")
            )
            raise MeshingError(
                f"step {len(self.steps)}: the boundary {what} near {where(pts[bad])}: include "
                "this position in the motion given to MovingDomain.from_motion",
                pts[bad],
                refinable=False,
            )

    def _quality(self, sm: StraightMap, near: npt.NDArray[np.bool_]) -> dict[str, float | int]:
        """Quality of the active triangles: computed where they moved or have a vertex
        outside, background values elsewhere (unmoved triangles with all vertices inside:
        those away from Gamma and some near it)."""
        nco, c2v = self._nco, self._c2v
        kept = sm.kept[:nco]
        near_kept = np.flatnonzero(kept & near[:nco])
        cv = c2v[near_kept]
        plain = ~any_rows(sm.moved[cv]) & all_rows(sm.sign[cv] < 0)
        x = self.universal.vertex_coordinates
        rep = cell_quality(self.comm, sm.y, x, cv[~plain], sm.sign, sm.moved)
        far = kept & ~near[:nco]
        far[near_kept[plain]] = True
        b = self._background_quality
        red = self.comm.allreduce
        n_far = red(int(np.count_nonzero(far)))
        if n_far:

            def ext(key, op, empty):
                lowest = op is np.min
                value = _far_extreme(b[key], self._background_order[key], far, lowest)
                return red(empty if value is None else value, op=MPI.MIN if lowest else MPI.MAX)

            rep["theta_min_deg"] = min(rep["theta_min_deg"], ext("theta_min", np.min, 180.0))
            rep["theta_max_deg"] = max(rep["theta_max_deg"], ext("theta_max", np.max, 0.0))

            def histogram() -> npt.NDArray[np.int64]:
                hist = self._kept_histogram - self._histogram(near_kept[~plain])
                self.comm.Allreduce(MPI.IN_PLACE, hist, op=MPI.SUM)
                return hist

            self._unaltered.merge_far(rep, ext, histogram)
            rep["n_cells"] += n_far
            rep["n_unaltered"] += n_far
            rep["percent_unaltered"] = 100.0 * rep["n_unaltered"] / max(rep["n_cells"], 1)
        return rep

    def _histogram(self, cells: npt.NDArray[np.intp]) -> npt.NDArray[np.int64]:
        """Histogram of the background angles of owned ``cells`` (tetrahedra: dihedral
        angles; triangles: empty)."""
        bins = self._background_quality["bins"][cells].ravel()
        return np.bincount(bins, minlength=self._unaltered.HISTOGRAM_BINS).astype(np.int64)

    @cached_property
    def _background_quality(self) -> dict[str, npt.NDArray[Any]]:
        """Per-cell quality of the owned background cells."""
        x, cells = self.universal.vertex_coordinates, self._c2v[: self._nco]
        return self._unaltered.background_quality(x, cells)

    @cached_property
    def _background_order(self) -> dict[str, npt.NDArray[np.intp]]:
        """The owned background cells sorted by each per-cell quality (ascending)."""
        b = self._background_quality
        return {k: np.argsort(v, kind="stable") for k, v in b.items() if v.ndim == 1}

    # -- what forms and boundary conditions need --------------------------------------------

    def _tags(self) -> dmesh.MeshTags:
        values = np.zeros(len(self._cells), dtype=np.int32)
        values[self.active_cells] = 1
        tags = dmesh.meshtags(self.mesh, self.mesh.topology.dim, self._cells, values)
        tags.name = "active"
        return tags

    @property
    def active_tags(self) -> dmesh.MeshTags:
        """The cells of ``T_h^sub`` as cell tags: 1 on active cells, 0 on the others.

        Every process-local cell (owned and ghost) is tagged. A new object is made after each
        :meth:`update`, when first asked for (0 everywhere before the first update).
        Integration entities are read from tags when a form is compiled, so a form built
        once and reused over the steps must use the indicator :attr:`active`; the tags
        serve output, submeshes
        (``dolfinx.mesh.create_submesh(md.mesh, 2, md.active_tags.find(1))``) and forms
        made for one step (``ufl.dx(subdomain_data=md.active_tags, subdomain_id=1)``).
        """
        if self._active_tags is None:
            self._active_tags = self._tags()
        return self._active_tags

    def inactive_dofs(self, V: fem.FunctionSpace) -> npt.NDArray[np.int32]:
        """Dofs of ``V`` (block indices, process-local) that belong to no active cell.

        Fix them (e.g. a zero Dirichlet condition) so that the system on the whole
        background is nonsingular. Collective.
        """
        dofmap = V.dofmap
        imap = dofmap.index_map
        mark = np.zeros(imap.size_local + imap.num_ghosts)
        owned_active = self.active_cells[self.active_cells < self._nco]
        mark[dofmap.list[owned_active].ravel()] = 1.0
        mark = vertex_reduce(imap, mark, "sum")
        return np.flatnonzero(mark == 0).astype(np.int32)

    def immersed_dofs(
        self, V: fem.FunctionSpace | Sequence[fem.FunctionSpace]
    ) -> npt.NDArray[np.int32] | list[npt.NDArray[np.int32]]:
        """Dofs of ``V`` on the immersed boundary Gamma_h (process-local). Collective.

        ``V`` is what :func:`dolfinx.fem.locate_dofs_topological` accepts: a space, a
        sub-space (``W.sub(0)`` of a mixed space: dofs of ``W``), or a pair
        ``(W.sub(0), V0)`` with ``V0, _ = W.sub(0).collapse()``, which gives
        ``[dofs of W, dofs of V0]`` for :func:`dolfinx.fem.dirichletbc` with a function on
        ``V0``.
        """
        fdim = self.tdim - 1
        self.mesh.topology.create_connectivity(fdim, self.tdim)
        if not isinstance(V, fem.FunctionSpace):
            V = list(V)
            if len(V) != 2:
                raise ValueError("immersed_dofs: give a space or a pair (sub-space, collapsed)")
        return fem.locate_dofs_topological(V, fdim, self.immersed_facets)

    def immersed_integral(self, integrand: Callable[[str], ufl.core.expr.Expr]) -> ufl.Form:
        """``∫_Gamma integrand ds`` as a one-sided interior-facet form on the background.

        ``integrand(side)`` must return the integrand restricted to ``side`` (``"+"`` or
        ``"-"``), e.g. ``lambda s: dot(sigma(s) * n(s), e)`` with
        ``n = ufl.FacetNormal(md.mesh)``. On a facet of Gamma_h exactly one side is active,
        and its outward normal is the domain's outward normal; every other facet gets weight
        zero. The form does not change from step to step.
        """
        chi = self.active
        weight = {s: chi(s) * (1 - chi(o)) for s, o in (("+", "-"), ("-", "+"))}
        return (weight["+"] * integrand("+") + weight["-"] * integrand("-")) * ufl.dS(
            domain=self.mesh
        )

    def immersed_nodes(self) -> npt.NDArray[np.float64]:
        """Geometry nodes on Gamma_h (process-local), ``(n, gdim)``: they lie on Gamma."""
        fdim = self.tdim - 1
        self.mesh.topology.create_connectivity(fdim, self.tdim)
        nodes = dmesh.entities_to_geometry(self.mesh, fdim, self.immersed_facets)
        return self.mesh.geometry.x[nodes.ravel(), : self.tdim]
