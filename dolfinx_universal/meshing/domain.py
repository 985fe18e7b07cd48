"""Mesh a domain from its boundary alone: size the background, conform, curve, certify."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh

from dolfinx_universal.backgrounds.graded_tet import BandSizeField
from dolfinx_universal.backgrounds.graded_tri import EDGE_FACTOR, graded_mesh, mirror_axis
from dolfinx_universal.backgrounds.lattice_tri import GRADATION
from dolfinx_universal.boundaries.curves import Boundary, Domain
from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.conforming.quality import quality_report
from dolfinx_universal.conforming.universal import IMMERSED, ConformingMesh, conform
from dolfinx_universal.core.arrays import Float, as_box
from dolfinx_universal.core.collective import MeshingError, collective_call, where
from dolfinx_universal.curved.bounds import check_degree
from dolfinx_universal.curved.maps import MAPS, CurvedMesh, curved_mesh
from dolfinx_universal.sizing.fields import (
    MinSize,
    SizeField,
    SizeFunction,
    feature_size,
    target_sizes,
)

__all__ = [
    "DEFAULT_MAP",
    "Certificate",
    "MeshedDomain",
    "UniformPlan",
    "check_components",
    "default_box",
    "mesh_domain",
]


OUTER_BAND = 2.0
"""Half-width (in sizes) of the uniform band of the graded tetrahedral background on the
side of Gamma outside the domain (its cells are cut or dropped, never relaxed); on the
domain's side it is ``relaxation_factor + 2``."""
MAX_CELLS = 5e6
"""Default largest background (cells) that :func:`mesh_domain` and
:meth:`~dolfinx_universal.moving.domain.MovingDomain.from_motion` build."""

DEFAULT_MAP = {2: "I", 3: "I~"}
"""The curved map :func:`mesh_domain` uses when given none, by topological dimension.

Triangles: ``"I"`` (the interpolant of the exactly conforming blend ``G_h`` of the
background's edges). Tetrahedra: ``"I~"`` (that of ``G~_h``, through the straight
conforming mesh). The relaxation slides background vertices by up to about ``0.67 h``, and
projecting the background's faces and edges (``"I"``) then bends the curved tetrahedra more
than projecting the straight mesh's: measured through :func:`mesh_domain` at degree 2 (3),
the proven ``det J / det J_straight`` bound is 0.74 (0.72) for ``"I"`` against 1.00 (0.97)
for ``"I~"`` on the unit sphere at the default sizes (h = 0.33), 0.76 against 0.98 on an
ellipsoid of semi-axes (1, 0.7, 0.5), 0.71 against 0.87 on a torus (1, 0.35), and at twice
the default sizes (``size_factor=1.5``) 0.48 (0.45) against 0.73 (0.63) on the torus; the
P2 Poisson error on the ball differs by less than 1 % (1.36e-3 and 1.34e-3 at h = 0.33),
the volume error of ``"I"`` is up to 1.7 times smaller. ``"I~"`` keeps the larger margin
against inversion (each curved tetrahedron not proven valid costs a refinement round)."""

TET_GRADATION = 0.25
"""Growth of the graded tetrahedral background's size beyond its uniform band around Gamma.
Below 1/3, so that no vertex of a level change lies within its relaxation radius
``R_r = 3 h`` of Gamma (``h`` its local size, up to twice the leaf side there): a vertex at
distance ``d`` beyond the band sees sizes about ``s + g d``, and ``3 (s + g d) < d`` far
away only if ``g < 1/3`` (with 0.5, every far vertex would be relaxed)."""


@dataclass(frozen=True)
class Certificate:
    """What :func:`mesh_domain` verified about its mesh, and with what margin.

    Every figure is global (the same on every rank).
    """

    max_conditioning_angle_deg: float
    """Largest conditioning angle (the method needs < 90)."""
    min_feature_over_h: float
    """Smallest ratio of the local feature size of Gamma (distance to the medial axis:
    curvature, necks, gaps) to the background size there."""
    min_curvature_radius_over_h: float
    """Smallest ratio of the radius of curvature of Gamma to the background size there."""
    min_jacobian_ratio: float
    """Proven lower bound of ``det J / det J_straight`` over the curved cells (Bernstein
    coefficients with subdivision); 1 for straight meshes."""
    min_angle_deg: float
    """Smallest angle of the conforming (straight) triangles; smallest dihedral angle of
    the tetrahedra."""
    max_angle_deg: float
    """Largest angle of the conforming (straight) triangles; largest dihedral angle of the
    tetrahedra."""
    min_angle_floor_deg: float
    """The quality floor that every cell satisfies (an angle; a dihedral angle in 3D)."""
    num_loops: int
    """Closed loops (surfaces in 3D) of Gamma_h: one per curve (surface) of Gamma, each
    following it."""
    num_pieces: int
    """Connected pieces of the mesh (as many as the domain has)."""
    refinement_rounds: int
    """Times the background was refined locally after a failed check."""
    refinements: tuple[str, ...]
    """For each round: the check that failed and where."""
    h_max: float
    """Largest background size asked for."""
    h_min: float
    """Smallest background size used near Gamma."""
    num_cells: int
    num_background_cells: int
    degree: int
    map: str
    background: str = "graded"
    """The background actually used (the last round's): ``"graded"`` (the acute quadtree
    of triangles), ``"graded BCC octree"`` or ``"A15 uniform"`` (tetrahedra)."""
    tdim: int = 2
    """Topological dimension: 2 (triangles) or 3 (tetrahedra)."""

    def __str__(self) -> str:
        if self.tdim == 2:
            cells, bg = "cells", "a graded background"
            loops, angles = "closed loop(s), one per curve", "angles"
        else:
            cells = cell_kernels(self.tdim).plural
            bg = f"the {self.background} background"
            loops, angles = "closed surface(s), one per surface", "dihedral angles"
        lines = [
            f"universal mesh certificate: {self.num_cells} {cells} (degree {self.degree}"
            + (f", map {self.map})" if self.degree > 1 else ")")
            + f" from {bg} of {self.num_background_cells} {cells}, "
            f"h in [{self.h_min:.3g}, {self.h_max:.3g}]",
            f"  Gamma_h: {self.num_loops} {loops}; {self.num_pieces} connected piece(s)",
            f"  conditioning angles <= {self.max_conditioning_angle_deg:.2f} deg (< 90 needed)",
            f"  feature size / h >= {self.min_feature_over_h:.3g}, "
            f"radius of curvature / h >= {self.min_curvature_radius_over_h:.3g}",
            f"  {angles} in [{self.min_angle_deg:.2f}, {self.max_angle_deg:.2f}] deg "
            f"(floor {self.min_angle_floor_deg:g})",
            f"  det J / det J_straight >= {self.min_jacobian_ratio:.4g} (proven)",
            f"  refinement rounds: {self.refinement_rounds}",
        ]
        lines += [f"    {r}" for r in self.refinements]
        return "\n".join(lines)

    def as_dict(self) -> dict[str, object]:
        """The certificate as JSON-ready data."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class MeshedDomain:
    """The result of :func:`mesh_domain`."""

    mesh: dmesh.Mesh
    """The conforming mesh: degree-``degree`` geometry (straight for degree 1)."""
    facet_tags: dmesh.MeshTags
    """:data:`~dolfinx_universal.conforming.universal.IMMERSED` on Gamma,
    :data:`~dolfinx_universal.conforming.universal.OUTER` on the box boundary."""
    certificate: Certificate
    conforming: ConformingMesh
    """The straight conforming mesh and its maps to the background."""
    curved: CurvedMesh | None
    """The curved mesh (None for degree 1)."""
    timings: dict[str, float] = field(default_factory=dict)
    """Seconds (max over ranks): ``sizing``, ``background``, ``conform``, ``curved``, ``total``
    (all rounds)."""

    @property
    def background(self) -> dmesh.Mesh:
        """The graded background mesh of the last round."""
        return self.conforming.background

    def component_facets(self) -> list[npt.NDArray[np.int32]]:
        """The facets tagged ``IMMERSED`` of each component of Gamma (process-local).

        One array per component, in the order of
        :attr:`~dolfinx_universal.boundaries.curves.Domain.components` (the container first, then
        the bodies; one array for a single boundary): each facet goes to the component
        nearest to its midpoint. For boundary conditions or integrals on one surface,
        e.g. ``dmesh.meshtags(md.mesh, tdim - 1, facets, values)``.
        """
        facets = self.facet_tags.find(IMMERSED)
        boundary = self.conforming.boundary
        if not isinstance(boundary, Domain) or len(boundary.components) == 1:
            return [facets]
        fdim = self.mesh.topology.dim - 1
        mid = dmesh.compute_midpoints(self.mesh, fdim, facets)[:, : self.mesh.geometry.dim]
        nearest = boundary.nearest_component(mid)
        return [facets[nearest == k] for k in range(len(boundary.components))]


def check_components(boundary: Boundary, n: int = 2048) -> None:
    """Raise if the components of a :class:`~dolfinx_universal.boundaries.curves.Domain` overlap.

    Each body must lie inside the container and outside every other body; touching counts
    as overlapping (no mesh size resolves a zero gap).

    Raises
    ------
    MeshingError
        Naming the components and a place where they overlap (not refinable).
    """
    if not isinstance(boundary, Domain):
        return
    comps = boundary.components
    for i, (bi, body_i) in enumerate(comps):
        if not body_i:
            continue
        pts = bi.sample(n)
        for j, (bj, body_j) in enumerate(comps):
            if i == j:
                continue
            s = bj.sign(pts)
            bad = s < 0 if body_j else s > 0
            if bad.any():
                what = f"body {i}" + (f" overlaps body {j}" if body_j else " leaves the container")
                raise MeshingError(
                    f"{what} near {where(pts[bad])}: the bodies of a Domain must lie inside the "
                    "container, apart from each other and from it",
                    pts[bad],
                    refinable=False,
                )


def _curvature_radius(points: Float, labels: npt.NDArray) -> Float:
    """Radius of curvature at ordered closed sample loops (circle through three samples)."""
    out = np.full(len(points), np.inf)
    for k in np.unique(labels):  # one pass per closed curve
        idx = np.flatnonzero(labels == k)
        p = points[idx]
        a, b = np.roll(p, 1, axis=0), np.roll(p, -1, axis=0)
        u, v, w = p - a, b - p, b - a
        cross = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
        lengths = np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1) * np.linalg.norm(w, axis=1)
        with np.errstate(divide="ignore"):
            out[idx] = np.where(cross > 0, lengths / (2 * cross), np.inf)
    return out


def default_box(boundary: Boundary, h: float, relaxation_factor: float = 3.0) -> Float:
    """The background box :func:`mesh_domain` uses when it is given none.

    The boundary's bounding box enlarged on every side by ``(relaxation_factor + 2) h``: the
    band of vertices within ``R_r = relaxation_factor h`` of Gamma, and the cells around it,
    then stay off the box boundary.

    Parameters
    ----------
    boundary
        The domain.
    h
        Largest mesh size.
    relaxation_factor
        ``R_r / h``, as in :func:`mesh_domain`.

    Returns
    -------
    ``[[x_min, y_min], [x_max, y_max]]``, ``(2, gdim)``.
    """
    bbox = np.asarray(boundary.bounding_box(), dtype=np.float64)
    bbox = bbox.reshape(2, bbox.size // 2)
    margin = (relaxation_factor + 2.0) * h
    return np.array([bbox[0] - margin, bbox[1] + margin])


def _estimate_cells(points: Float, sizes: Float, box: Float, h: float) -> float:
    """Rough cell count of a background graded from ``sizes`` at ``points`` up to ``h``.

    A triangle of edge ``s`` covers about ``0.4 s^2``; along Gamma (spacing ``ds``) a size
    ``s`` that grows like ``s + GRADATION r`` up to ``h`` covers a strip with
    ``ds / (0.4 GRADATION) (1/s - 1/h)`` cells per side.
    """
    ds = np.full(len(points), 0.0)
    if len(points) > 1:
        d = np.linalg.norm(np.diff(points, axis=0), axis=1)
        ds[:-1] = np.minimum(d, 4 * sizes[:-1])
    near = 2 * ds / (0.4 * GRADATION) * np.maximum(1.0 / sizes - 1.0 / h, 0.0)
    area = float(np.prod(box[1] - box[0]))
    return float(near.sum() + area / (0.4 * h * h))


def size_from_geometry(
    comm: MPI.Comm,
    boundaries: list[Boundary],
    h: float,
    *,
    degree: int = 1,
    box: npt.ArrayLike | None = None,
    relaxation_factor: float = 3.0,
    size_factor: float | None = None,
) -> tuple[Float, SizeField, Float, Float]:
    """The background box and size field for one or several positions of a boundary.

    Computed on rank 0 and broadcast, so that every rank builds the same background.

    Parameters
    ----------
    comm
        Communicator.
    boundaries
        The boundary, or its positions along a motion (the field covers them all).
    h
        Largest size.
    degree, box, relaxation_factor, size_factor
        As in :func:`mesh_domain`.

    Returns
    -------
    box
        ``[[x0, y0], [x1, y1]]``.
    field
        The size field (sources: dense samples of every boundary with their target sizes).
    feature, rho
        Local feature size and radius of curvature at the sources ``(n,)``.

    Raises
    ------
    MeshingError
        Overlapping components, or a boundary leaving the given box (not refinable).
    """
    return _on_root(
        comm, lambda: _sizing(boundaries, h, degree, box, relaxation_factor, size_factor)
    )


def _sizing(
    boundaries: list[Boundary],
    h: float,
    degree: int,
    box: npt.ArrayLike | None,
    relaxation_factor: float,
    size_factor: float | None,
) -> tuple[Float, SizeField, Float, Float]:
    """:func:`size_from_geometry` on one rank."""
    pts, feats, targets, rhos, boxes = [], [], [], [], []
    for b in boundaries:
        check_components(b)
        samples, feature = feature_size(b)
        pts.append(samples.points)
        feats.append(feature)
        targets.append(target_sizes(feature, h, degree, size_factor))
        rhos.append(_curvature_radius(samples.points, samples.labels))
        boxes.append(default_box(b, h, relaxation_factor))
    points, feature = np.concatenate(pts), np.concatenate(feats)
    target, rho = np.concatenate(targets), np.concatenate(rhos)
    if box is None:
        stack = np.array(boxes)
        box_arr = np.array([stack[:, 0].min(axis=0), stack[:, 1].max(axis=0)])
    else:
        box_arr = np.asarray(box, dtype=np.float64).reshape(2, 2)
        out = ~((points > box_arr[0]).all(axis=1) & (points < box_arr[1]).all(axis=1))
        if out.any():
            raise MeshingError(
                f"the domain's boundary leaves the given box {box_arr.tolist()} near "
                f"{where(points[out])}: enlarge the box",
                points[out],
                refinable=False,
            )
        # The band of width R_r must stay off the box boundary: size by the distance to it.
        gap = np.minimum(points - box_arr[0], box_arr[1] - points).min(axis=1)
        target = np.minimum(target, gap / (relaxation_factor + 1.5))
    return box_arr, SizeField(points, target, h, GRADATION), feature, rho


def mesh_domain(
    comm: MPI.Comm,
    boundary: Boundary,
    h: float,
    *,
    degree: int = 1,
    map: str | None = None,
    box: npt.ArrayLike | None = None,
    eta: float = 0.2,
    relaxation_factor: float = 3.0,
    min_angle: float = 10.0,
    size_factor: float | None = None,
    max_rounds: int = 8,
    max_cells: float = MAX_CELLS,
    relax: bool = True,
    tet_background: str = "auto",
    size_field: SizeFunction | None = None,
    mirror: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> MeshedDomain:
    """Mesh the domain bounded by ``boundary``: the one call a user makes (collective).

    The background is a graded acute quadtree mesh
    (:func:`~dolfinx_universal.backgrounds.graded_tri.graded_mesh`)
    whose size near Gamma follows the geometry: the local feature size (distance to the
    medial axis, which accounts for curvature, thin parts, necks and gaps between parts of
    the boundary) divided by a factor that grows with the geometry degree
    (:func:`~dolfinx_universal.sizing.fields.target_sizes`). Away from Gamma the size grows by
    :data:`GRADATION` per unit length up to ``h``. The background is then conformed (the
    straight map ``M_h`` with ``local_size``), curved (the maps ``G_h`` / ``I_h``) and
    checked: conditioning angles, inverted straight or curved cells (a proof with Bernstein
    coefficients), one Gamma_h loop per curve of Gamma on the domain's side, the quality
    floor ``min_angle``. Where a check fails the background is refined locally (the size
    halved around the places named by the check) and the domain meshed again, at most
    ``max_rounds`` times. The same mesh comes out on any number of ranks.

    Parameters
    ----------
    comm
        Communicator of the mesh.
    boundary
        The domain's boundary.
    h
        Largest mesh size (far from Gamma).
    degree
        Geometry degree ``q >= 1`` (1: straight conforming mesh), triangles and tetrahedra
        alike (:func:`~dolfinx_universal.curved.maps.curved_mesh`): the cells along Gamma are
        curved, their nodes on Gamma lie on it, and where a curved cell is not proven valid
        (``det J / det J_straight > 0`` by Bernstein bounds) the background is refined near
        it like after any other failed check. At most
        :data:`~dolfinx_universal.curved.bounds.MAX_DEGREE` (7 for curves, 5 for surfaces).
    map
        Curved map, one of :data:`~dolfinx_universal.curved.maps.MAPS`; default
        :data:`DEFAULT_MAP`: ``"I"`` for curves, ``"I~"`` for surfaces (measured margins
        there).
    box
        ``[[x0, y0], [x1, y1]]``: the background's extent, whose boundary is the outer
        boundary of the mesh where the domain reaches it (e.g. a channel with
        ``Domain(None, bodies)``). Default: :func:`default_box`, the boundary's bounding box
        plus ``(R_r/h + 2) h``.
    eta, relaxation_factor
        See :class:`~dolfinx_universal.conforming.universal.UniversalMesh` (``R_r =
        relaxation_factor``
        times the local size).
    min_angle
        Quality floor (degrees) for the straight conforming triangles.
    size_factor
        Feature size / target size near Gamma (default by degree, see
        :func:`~dolfinx_universal.sizing.fields.target_sizes`).
    max_rounds
        Largest number of local refinements.
    max_cells
        Largest background the geometry may ask for.
    relax
        Relax the vertices near Gamma after ``M_h`` (see
        :class:`~dolfinx_universal.conforming.universal.UniversalMesh`).
    tet_background
        Background of surfaces (one of :data:`TET_BACKGROUNDS`): ``"a15"``, a uniform A15
        lattice of the smallest target size (dihedral angles 53-79 degrees); ``"graded"``, a
        graded BCC octree (:func:`~dolfinx_universal.backgrounds.graded_tet.graded_tet_mesh`),
        uniform
        (BCC, 60-90 degrees) in a band of ``relaxation_factor + 2`` sizes around each
        component of Gamma; ``"auto"`` (default): the octree where it has fewer than
        :data:`AUTO_RATIO` times the tetrahedra of the A15 background (a small body in a
        large box: a tenth), else A15 (whose angles after relaxation are a few degrees
        better); where the octree's dihedral angles leave :data:`AUTO_DIHEDRAL`, the A15
        background of the same smallest size instead (one more round, if within
        ``max_cells``; if that fails, the octree's mesh is kept).
    size_field
        A user size field, ``(n, gdim) -> (n,)`` target edge lengths (``inf``: no
        constraint), the same function on every rank (e.g.
        :func:`~dolfinx_universal.sizing.fields.threshold`,
        :func:`~dolfinx_universal.sizing.fields.box_size`, or the minimum of several;
        :func:`~dolfinx_universal.sizing.fields.refine_size` in an adaptive loop): the background's
        size is the smaller of it and the geometry's own (and at most ``h``). Like every
        size, it is sampled at a few points per quadtree / octree cell (features of it much
        narrower than the cells there can be missed). On surfaces it needs the graded
        octree (``tet_background="auto"`` takes it): each component's uniform band takes
        the smallest value of the field on the component's samples, the field counts as
        given beyond the bands.
    mirror
        Curves only: a line ``(point, normal)`` normal to a coordinate axis, about which
        the domain (and ``size_field``) is symmetric near Gamma, e.g. the horizontal line
        through a cylinder's centre in a channel: the mesh is made the mirror image of
        itself there, to rounding. The background's root cells are made symmetric about
        the line (rows of them on each side, as many as the box allows, at most ``h``
        / :data:`~dolfinx_universal.backgrounds.graded_tri.EDGE_FACTOR` and smaller where that
        needs it;
        :func:`~dolfinx_universal.backgrounds.graded_tri.graded_mesh`), its leaves split alike on
        both
        sides and tiled below the line with the stencils' mirror images; the relaxation's
        choices are made symmetric
        (:class:`~dolfinx_universal.conforming.universal.UniversalMesh`), and
        a failed check refines at its places' images too. A quantity that is a difference
        of the two halves' contributions (the lift on a body in a nearly symmetric flow)
        then gets discretisation errors that largely cancel, as on a symmetric
        body-fitted mesh.

    Returns
    -------
    The mesh, its facet tags and a :class:`Certificate`.

    Raises
    ------
    MeshingError
        Only for inputs that no mesh size can mesh: components that overlap or touch, a
        domain that leaves the given box, a geometry needing more than ``max_cells`` cells,
        or checks that still fail after ``max_rounds`` refinements (with the places).
    ValueError
        Bad parameters.
    """
    t_start = time.perf_counter()
    h = float(h)
    if not (h > 0 and math.isfinite(h)):
        raise ValueError(f"h must be positive and finite, got {h}")
    gdim = 3 if getattr(boundary, "gdim", 2) == 3 else 2
    degree = check_degree(degree, gdim)
    if box is not None:
        as_box(box, gdim)
    if map is None:
        map = DEFAULT_MAP[gdim]
    if map not in MAPS:
        raise ValueError(f"unknown map {map!r}: choose one of {MAPS}")
    if size_field is not None and not callable(size_field):
        raise ValueError(f"size_field must be a callable of points, got {size_field!r}")
    if int(max_rounds) != max_rounds or max_rounds < 0:
        raise ValueError(f"max_rounds must be a non-negative integer, got {max_rounds}")
    if mirror is not None:
        if gdim != 2:
            raise ValueError("mirror is supported for curves only")
        mirror_axis(mirror, 2)  # (ValueError unless normal to an axis)
    if tet_background not in TET_BACKGROUNDS:
        raise ValueError(
            f"unknown tet_background {tet_background!r}: choose one of {TET_BACKGROUNDS}"
        )
    degree = int(degree)
    timings = {"sizing": 0.0, "background": 0.0, "conform": 0.0, "curved": 0.0}

    t = time.perf_counter()
    plan: _Plan
    if gdim == 3:
        plan = _tet_plan(
            comm, boundary, h, degree, box, relaxation_factor, size_factor, tet_background,
            max_cells, size_field,
        )  # fmt: skip
    else:
        plan = _GradedPlan.create(comm, boundary, h, degree, box, relaxation_factor, size_factor)
        plan.mirror = mirror
        if size_field is not None:
            plan.user = _UserSize(comm, size_field, plan.box)
    timings["sizing"] += time.perf_counter() - t

    def attempt(plan: _Plan, background: dmesh.Mesh) -> _Attempt:
        """Conform, curve and rate the background of one round (raises MeshingError)."""
        t = time.perf_counter()
        cm = conform(
            background,
            boundary,
            eta=eta,
            relaxation_factor=relaxation_factor,
            local_size=plan.local_size,
            min_angle=min_angle,
            on_low_quality="raise",
            relax=relax,
            mirror=mirror,
        )
        timings["conform"] += time.perf_counter() - t
        t = time.perf_counter()
        curved = curved_mesh(cm, degree, map) if degree > 1 else None
        timings["curved"] += time.perf_counter() - t
        return _Attempt(plan, background, cm, curved, quality_report(cm))

    def build(plan: _Plan) -> dmesh.Mesh:
        t = time.perf_counter()
        background = plan.background(comm)
        timings["background"] += time.perf_counter() - t
        return background

    done, rounds = _refinement_rounds(comm, plan, build, attempt, max_rounds, max_cells)
    certificate = _certificate(comm, done, rounds, h, degree, map, min_angle)
    timings["total"] = time.perf_counter() - t_start
    timings = {k: comm.allreduce(v, op=MPI.MAX) for k, v in timings.items()}
    msh = done.curved.mesh if done.curved is not None else done.cm.mesh
    tags = done.curved.facet_tags if done.curved is not None else done.cm.facet_tags
    return MeshedDomain(msh, tags, certificate, done.cm, done.curved, timings)


@dataclass
class _Attempt:
    """One round of :func:`mesh_domain` that passed every check."""

    plan: _Plan
    background: dmesh.Mesh
    cm: ConformingMesh
    curved: CurvedMesh | None
    quality: dict


def _refinement_rounds(
    comm: MPI.Comm,
    plan: _Plan,
    build: Callable[[_Plan], dmesh.Mesh],
    attempt: Callable[[_Plan, dmesh.Mesh], _Attempt],
    max_rounds: int,
    max_cells: float,
) -> tuple[_Attempt, list[str]]:
    """The rounds of :func:`mesh_domain` (collective): build the plan's background and
    ``attempt`` it; where a check fails, refine the plan around the places it names (at
    most ``max_rounds`` times); where ``tet_background="auto"`` chose the octree and its
    angles leave :data:`AUTO_DIHEDRAL`, try the A15 alternative (keeping the octree's mesh
    if that fails). Returns the round that passed and the record of the rounds."""
    rounds: list[str] = []
    fallback: tuple[_Attempt, int] | None = None  # the octree's while "auto" tries A15
    while True:
        plan.check_size(max_cells, rounds)
        background = build(plan)
        try:
            done = attempt(plan, background)
            quality = done.quality
            alt = getattr(plan, "alternative", None)
            if alt is None or not _below_auto_floor(quality) or alt.estimate() > max_cells:
                return done, rounds
            # tet_background="auto" chose the octree: its BCC band fell below the angles
            # that A15 keeps (measured: 23 degrees on tori where A15 gives 32); take A15.
            fallback = (done, len(rounds))
            rounds.append(
                f"round {len(rounds) + 1}: dihedral angles in "
                f"[{quality['theta_min_deg']:.3g}, {quality['theta_max_deg']:.3g}] deg on the "
                f"{plan.name} (auto keeps it within {AUTO_DIHEDRAL}), then the {alt.name} "
                f"background of size {alt.size:.3g}"
            )
            setattr(plan, "alternative", None)  # noqa: B010 (a _GradedTetPlan)
            plan = alt
        except MeshingError as e:
            first = str(e).splitlines()[0]
            if fallback is not None:  # A15 failed where the octree's mesh was valid: keep it
                kept, k = fallback
                rounds[k] += f" (which failed: {_short(first)}; the octree's mesh kept)"
                del rounds[k + 1 :]
                return kept, rounds
            if not e.refinable or len(e.points) == 0:
                raise
            if len(rounds) >= max_rounds:
                raise MeshingError(
                    f"still failing after {max_rounds} local refinements ("
                    + "; ".join(rounds)
                    + f"): {e}",
                    e.points,
                    refinable=False,
                ) from None
            rounds.append(f"round {len(rounds) + 1}: {_short(first)}")
            plan, note = _refined(plan, e.points, comm, max_cells)
            rounds[-1] += note


def _certificate(
    comm: MPI.Comm,
    done: _Attempt,
    rounds: list[str],
    h: float,
    degree: int,
    map: str,
    min_angle: float,
) -> Certificate:
    """The :class:`Certificate` of the round that passed (collective)."""
    plan, cm, curved, quality = done.plan, done.cm, done.curved, done.quality
    jac = curved.min_jacobian_ratio if curved is not None else 1.0
    hvals = plan.sizes()
    size_used = comm.allreduce(float(hvals.min()), op=MPI.MIN)
    msh = curved.mesh if curved is not None else cm.mesh
    tdim = msh.topology.dim
    return Certificate(
        max_conditioning_angle_deg=cm.max_conditioning_angle,
        min_feature_over_h=float(np.min(plan.feature / hvals)),
        min_curvature_radius_over_h=float(np.min(plan.rho / hvals)),
        min_jacobian_ratio=float(jac),
        min_angle_deg=float(quality["theta_min_deg"]),
        max_angle_deg=float(quality["theta_max_deg"]),
        min_angle_floor_deg=float(min_angle),
        num_loops=cm.num_loops,
        num_pieces=cm.num_pieces,
        refinement_rounds=len(rounds),
        refinements=tuple(rounds),
        h_max=h,
        h_min=size_used,
        num_cells=msh.topology.index_map(tdim).size_global,
        num_background_cells=done.background.topology.index_map(tdim).size_global,
        degree=degree,
        map=map,
        background=plan.name,
        tdim=tdim,
    )


class _Plan:
    """The background of :func:`mesh_domain` and how it is refined where a check fails."""

    points: Float
    """Samples of Gamma where sizes are checked ``(n, gdim)``."""
    feature: Float
    """Local feature sizes at ``points`` ``(n,)``."""
    rho: Float
    """Radii of curvature at ``points`` ``(n,)``."""
    local_size: bool
    """Whether the background is graded (``local_size`` of the conforming step)."""
    name: str
    """The background, as :attr:`Certificate.background` names it."""

    def sizes(self) -> Float:
        """Background size at ``points`` ``(n,)``."""
        raise NotImplementedError

    def estimate(self) -> float:
        """Rough number of background cells."""
        raise NotImplementedError

    def background(self, comm: MPI.Comm) -> dmesh.Mesh:
        """Build the background (collective)."""
        raise NotImplementedError

    def refine(self, places: Float) -> None:
        """Halve the size around ``places`` ``(k, gdim)``."""
        raise NotImplementedError

    def check_size(self, max_cells: float, rounds: list[str]) -> None:
        """Raise when the background would exceed ``max_cells``."""
        estimate = self.estimate()
        if estimate <= max_cells:
            return
        current = self.sizes()
        i = int(np.argmin(current))
        raise MeshingError(
            f"the geometry asks for about {estimate:.3g} background cells (more than "
            f"max_cells = {max_cells:.3g}): the smallest size needed is "
            f"{current[i]:.3g} near {where(self.points[i : i + 1])}"
            + (f" after {len(rounds)} refinement rounds ({'; '.join(rounds)})" if rounds else "")
            + "; raise max_cells or simplify the geometry there",
            self.points[i : i + 1],
            refinable=False,
        )


class _UserSize:
    """A user's ``size_field``, its values checked, and the cells it adds to an estimate."""

    SAMPLES = {2: 128, 3: 32}
    """Lattice points per side of the box at which :meth:`extra_cells` samples the field
    (16384 in 2D, 32768 in 3D: a few milliseconds for the usual fields)."""

    def __init__(self, comm: MPI.Comm, fn: SizeFunction, box: Float) -> None:
        self.comm, self.fn, self.box = comm, fn, box

    def __call__(self, x: Float) -> Float:
        x = np.asarray(x, dtype=np.float64)
        out = np.asarray(self.fn(x), dtype=np.float64)
        if out.shape != (len(x),):
            raise ValueError(f"size_field returned shape {out.shape} for {len(x)} points")
        bad = ~(out > 0)  # NaN too (inf: no constraint)
        if bad.any():
            raise ValueError(
                f"size_field returned {out[bad][0]!r} at {where(x[bad])}: sizes must be "
                "positive (or inf)"
            )
        return out

    def extra_cells(self, h: float, cells_per_volume: float) -> float:
        """Cells the field adds to a background of size ``h`` (collective): the integral of
        ``cells_per_volume (s^-d - h^-d)`` where ``s = min(field, h) < h``, by the midpoint
        rule on a lattice of :data:`SAMPLES` points per side (features narrower than its
        spacing are missed, as the quadtree may miss them)."""
        d = self.box.shape[1]
        n = self.SAMPLES[d]
        axes = [
            self.box[0, i] + (np.arange(n) + 0.5) * (self.box[1, i] - self.box[0, i]) / n
            for i in range(d)
        ]
        pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d)
        mine = pts[self.comm.rank :: self.comm.size]
        sizes = collective_call(self.comm, "the size field", self, mine)
        s = np.minimum(sizes, h)
        cell = float(np.prod(self.box[1] - self.box[0])) / len(pts)
        local = float(np.sum(cells_per_volume * cell * (s**-d - h**-d)))
        return float(self.comm.allreduce(local, op=MPI.SUM))


class _GradedPlan(_Plan):
    """Triangles: a graded acute quadtree background sized by a field refined locally."""

    local_size = True
    name = "graded"
    user: _UserSize | None = None
    """The user's ``size_field``, in the minimum with :attr:`field`."""
    mirror: tuple[npt.ArrayLike, npt.ArrayLike] | None = None
    """The mirror line of :func:`mesh_domain`, or ``None``."""

    def __init__(self, box: Float, field_: SizeField, feature: Float, rho: Float, h: float):
        self.box, self.field, self.feature, self.rho, self.h = box, field_, feature, rho, h
        self.points = field_.points

    @classmethod
    def create(
        cls,
        comm: MPI.Comm,
        boundary: Boundary,
        h: float,
        degree: int,
        box: npt.ArrayLike | None,
        relaxation_factor: float,
        size_factor: float | None,
    ) -> _GradedPlan:
        box_arr, field_, feature, rho = size_from_geometry(
            comm,
            [boundary],
            h,
            degree=degree,
            box=box,
            relaxation_factor=relaxation_factor,
            size_factor=size_factor,
        )
        return cls(box_arr, field_, feature, rho, h)

    def _size(self) -> SizeFunction:
        return self.field if self.user is None else MinSize(self.field, self.user)

    def sizes(self) -> Float:
        return self._size()(self.points)

    def estimate(self) -> float:
        near = _estimate_cells(self.points, self.sizes(), self.box, self.h)
        if self.user is None:
            return near
        return near + self.user.extra_cells(self.h, 1.0 / 0.4)  # 0.4 s^2 per triangle

    def background(self, comm: MPI.Comm) -> dmesh.Mesh:
        return graded_mesh(
            comm,
            self.box,
            self._size(),
            max_size=self.h,
            root_size=self.h / EDGE_FACTOR,
            mirror=self.mirror,
        )

    def refine(self, places: Float) -> None:
        if self.mirror is not None:  # and at the places' images
            axis, a = mirror_axis(self.mirror, 2)
            images = places.copy()
            images[:, axis] = 2.0 * a - images[:, axis]
            places = np.vstack([places, images])
        self.field = self.field.refined(places, 0.5 * self._size()(places))


TET_BACKGROUNDS = ("auto", "graded", "a15")
"""Backgrounds of :func:`mesh_domain` for surfaces (``tet_background``)."""

AUTO_RATIO = 0.5
"""``tet_background="auto"`` takes the graded octree when it has fewer than this many times
the tetrahedra of the uniform A15 background (whose angles are better: A15 where it costs
at most twice as much)."""


AUTO_DIHEDRAL = (30.0, 125.0)
"""Dihedral angles (degrees) that ``tet_background="auto"`` keeps: where the graded octree
it chose gives a smaller or larger one (its uniform bands are BCC, which the relaxation
cannot always bring to these), it conforms the A15 background of the same smallest size
instead, if that stays within ``max_cells`` (A15 met them on every sphere, ellipsoid and
torus of ``demos/quality_3d.py``)."""


def _below_auto_floor(quality: dict) -> bool:
    lo, hi = AUTO_DIHEDRAL
    return bool(quality["theta_min_deg"] < lo or quality["theta_max_deg"] > hi)


def _tet_plan(
    comm: MPI.Comm,
    boundary: Boundary,
    h: float,
    degree: int,
    box: npt.ArrayLike | None,
    relaxation_factor: float,
    size_factor: float | None,
    kind: str,
    max_cells: float,
    size_field: SizeFunction | None = None,
) -> _Plan:
    """The background plan of a surface: graded, A15, or (auto) the graded octree where it
    has fewer than :data:`AUTO_RATIO` times the tetrahedra of the A15 background (counted
    on the octree itself, built once, unless either is estimated above ``max_cells``: then
    the smaller estimate, which :meth:`_Plan.check_size` refuses)."""
    # Every size is at most h: before Gamma is sampled at h / 4, the box around it needs at
    # least its volume / h^3 cells (one per cube of side h); the same on every rank.
    bb = np.asarray(boundary.bounding_box(), dtype=np.float64)
    least = float(np.prod(bb[1] - bb[0])) / h**3
    if least > max_cells:
        raise MeshingError(
            f"h = {h:.3g} asks for at least {least:.3g} background cells (the box around "
            f"the boundary, {(bb[1] - bb[0]).tolist()}, in cells of size at most h; more "
            f"than max_cells = {max_cells:.3g}): raise h or max_cells",
            refinable=False,
        )
    args = (comm, boundary, h, degree, box, relaxation_factor, size_factor)
    if size_field is not None:  # a uniform background cannot follow a field
        if kind == "a15":
            raise ValueError(
                'size_field needs a graded background: tet_background="a15" is uniform'
            )
        return _GradedTetPlan.create(*args, max_cells, user=size_field)
    if kind == "a15":
        return UniformPlan.create(*args)
    graded = _GradedTetPlan.create(*args, max_cells)
    if kind == "graded":
        return graded
    uniform = UniformPlan.from_graded(graded, boundary, box, relaxation_factor)
    if graded.top <= graded.base * (1 + 1e-9):  # one level: the same size everywhere
        return uniform
    if max(graded.estimate(), uniform.estimate()) > max_cells:
        choice = graded if graded.estimate() < uniform.estimate() else uniform
    else:
        choice = graded if graded.count(comm) < AUTO_RATIO * uniform.count() else uniform
    if choice is graded:
        graded.alternative = uniform
    return choice


def _refined(plan: _Plan, places: Float, comm: MPI.Comm, max_cells: float) -> tuple[_Plan, str]:
    """The plan of the next round after a refinable failure near ``places`` (collective),
    and a note for the round's record.

    The plan refined around the places; but on the first failure of a graded octree that
    ``tet_background="auto"`` chose over A15, the A15 plan of the same smallest size where
    that has fewer tetrahedra than the refined octree, or where only it stays within
    ``max_cells``. The octree's uniform bands are BCC (dihedral angles of 90 degrees): a
    small body (a spherical hole of 4-7 sizes' radius) can leave inverted tetrahedra after
    the snap there where the acute A15 lattice of the same size has none; and halving a
    body's size halves that of every component whose band it reaches (a body near its
    container: the container's whole band), which can cost more than the A15 background
    (8 times the tetrahedra near Gamma, above ``max_cells`` where the A15 one fits)."""
    alt = getattr(plan, "alternative", None)
    plan.refine(places)
    if not isinstance(plan, _GradedTetPlan) or alt is None:
        return plan, ""
    plan.alternative = None  # once
    if alt.estimate() > max_cells:
        return plan, ""
    if plan.estimate() > max_cells or alt.count() < plan.count(comm):
        return alt, f" (then the {alt.name} background of size {alt.size:.3g})"
    return plan, ""


class UniformPlan(_Plan):
    """Tetrahedra: a uniform A15 background (acute, every dihedral angle in [53, 79]
    degrees) of the smallest target size near Gamma, halved where a check fails."""

    local_size = False
    name = "A15 uniform"

    def __init__(self, box: Float, size: float, points: Float, feature: Float, rho: Float):
        self.box, self.size = box, size
        self.points, self.feature, self.rho = points, feature, rho

    @classmethod
    def create(
        cls,
        comm: MPI.Comm,
        boundary: Boundary,
        h: float,
        degree: int,
        box: npt.ArrayLike | None,
        relaxation_factor: float,
        size_factor: float | None,
    ) -> UniformPlan:
        def sizing() -> tuple[Float, float, Float, Float, Float]:
            from dolfinx_universal.sizing.surfaces import surface_feature_size

            check_components(boundary)
            sf = surface_feature_size(boundary, 0.25 * h)
            target = target_sizes(sf.feature, h, degree, size_factor)
            size = float(target.min())
            box_arr = _checked_box(boundary, sf.points, size, box, relaxation_factor)
            rho = np.full(len(sf.points), float(boundary.min_radius_of_curvature()))
            return box_arr, size, sf.points, sf.feature, rho

        box_arr, size, points, feature, rho = _on_root(comm, sizing)
        return cls(box_arr, size, points, feature, rho)

    @classmethod
    def from_graded(
        cls,
        plan: _GradedTetPlan,
        boundary: Boundary,
        box: npt.ArrayLike | None,
        relaxation_factor: float,
    ) -> UniformPlan:
        """The uniform A15 plan of the smallest target size of ``plan``'s sizing."""
        size = plan.smallest
        box_arr = _checked_box(boundary, plan.points, size, box, relaxation_factor)
        return cls(box_arr, size, plan.points, plan.feature, plan.rho)

    def count(self) -> int:
        """Tetrahedra of the background."""
        from dolfinx_universal.backgrounds.lattice_tet import a15_num_cells

        return a15_num_cells(self.box, self.size)

    def sizes(self) -> Float:
        return np.full(len(self.points), self.size)

    def estimate(self) -> float:
        # A15 of size h: 2 vertices and 11.5 tetrahedra per h^3
        return float(np.prod(self.box[1] - self.box[0])) * 11.5 / self.size**3

    def background(self, comm: MPI.Comm) -> dmesh.Mesh:
        from dolfinx_universal.backgrounds.lattice_tet import a15_mesh

        return a15_mesh(comm, self.box.tolist(), self.size)

    def refine(self, places: Float) -> None:
        self.size *= 0.5


class _GradedTetPlan(_Plan):
    """Tetrahedra: a graded BCC octree background
    (:func:`~dolfinx_universal.backgrounds.graded_tet.graded_tet_mesh`), uniform in a band around
    every
    component of Gamma (``relaxation_factor + 2`` sizes deep on the domain's side,
    :data:`OUTER_BAND` on the other), growing by :data:`TET_GRADATION` per unit length beyond.

    Each component ``c`` of Gamma gets one size ``s_c``: the smallest target size on it
    (feature size over ``c``), rounded down to a level ``base 2^k`` (:func:`_levels`), and
    lowered further while another component's field reaches below it inside its band. So
    no level change of the octree lies in a band: the cut and relaxed tetrahedra are BCC ones
    (dihedral angles 60 and 90 degrees), never the half pyramids of the level changes (120,
    and moved by the relaxation they get worse: 29.6-129.7 degrees on a sphere of radius 0.25
    in one of radius 1 when a finer band reached into the coarser one's). A size that
    changes along one component would put level changes across Gamma: the component takes
    its smallest. Where a check fails, the sizes of the components near the places are
    halved."""

    local_size = True
    name = "graded BCC octree"

    def __init__(
        self,
        box: Float,
        points: Float,
        feature: Float,
        rho: Float,
        normals: Float,
        labels: npt.NDArray[np.intp],
        sizes: Float,
        spacing: float,
        areas: Float,
        h: float,
        band: float,
        gradation: float,
    ):
        self.box, self.points, self.feature, self.rho = box, points, feature, rho
        self.normals = normals
        self.labels, self.spacing, self.areas, self.h = labels, spacing, areas, h
        self.band, self.gradation = band, gradation
        self.component_sizes = sizes
        self.smallest = float(sizes.min())  # the smallest target size (before the levels)
        self.sources: list[tuple[Float, Float, float]] = []  # per component: points,
        # normals (out of the domain) and the distance margin (the points' spacing)
        self.max_cells = 5e6  # no dense samples for a background estimated above this
        self._tree: tuple[object, object] | None = None  # octree and leaves, once built
        self.boundary: Boundary | None = None
        self.comm: MPI.Comm | None = None
        self.alternative: UniformPlan | None = None
        """The A15 plan ``tet_background="auto"`` passed over (see :func:`_refined`)."""
        self.user: _UserSize | None = None
        """The user's ``size_field``: the octree's size is its minimum with :meth:`field`."""

    @property
    def base(self) -> float:
        return float(self.component_sizes.min())

    @property
    def top(self) -> float:
        return self.base * 2.0 ** math.floor(math.log2(self.h / self.base) + 1e-9)

    @classmethod
    def create(
        cls,
        comm: MPI.Comm,
        boundary: Boundary,
        h: float,
        degree: int,
        box: npt.ArrayLike | None,
        relaxation_factor: float,
        size_factor: float | None,
        max_cells: float = 5e6,
        gradation: float | None = None,
        user: SizeFunction | None = None,
    ) -> _GradedTetPlan:
        g = TET_GRADATION if gradation is None else float(gradation)
        # The user's field: checked and sampled on rank 0 (sizing), then kept on every rank
        # (not broadcast: a user's function need not pickle).
        user_size = None if user is None else _UserSize(comm, user, np.zeros((2, 3)))

        def sizing() -> _GradedTetPlan:
            from dolfinx_universal.sizing.surfaces import (
                component_boundaries,
                surface_area,
                surface_feature_size,
            )

            check_components(boundary)
            sf = surface_feature_size(boundary, 0.25 * h)
            target = target_sizes(sf.feature, h, degree, size_factor)
            comps = component_boundaries(boundary)
            if user_size is not None:  # a uniform band: the field's smallest on the component
                target = np.minimum(target, user_size(sf.points))
            sizes = np.array([target[sf.labels == k].min() for k in range(len(comps))])
            areas = np.array([surface_area(c) for c in comps])
            rho = np.full(len(sf.points), float(boundary.min_radius_of_curvature()))
            band = relaxation_factor + 2.0
            plan = cls(
                np.zeros((2, 3)), sf.points, sf.feature, rho, sf.normals, sf.labels,
                _levels(sizes, areas, band, g), float(sf.spacing), areas, h, band, g,
            )  # fmt: skip
            plan.smallest, plan.max_cells = float(sizes.min()), float(max_cells)
            plan._settle(boundary)
            plan.box = _checked_box(
                boundary, sf.points, float(plan.component_sizes.max()), box, relaxation_factor
            )
            return plan

        plan = _on_root(comm, sizing)
        plan.boundary, plan.comm = boundary, comm
        if user_size is not None:
            user_size.box = plan.box
            plan.user = user_size
        return plan

    def __getstate__(self) -> dict[str, object]:
        return {**self.__dict__, "boundary": None, "comm": None, "_tree": None, "user": None}

    def _settle(self, boundary: Boundary) -> None:
        """Sample each component about one size apart and lower each component's size to
        what the other components' fields reach in its band (until no component changes):
        no level change of the octree in any component's band."""
        from dolfinx_universal.sizing.surfaces import component_boundaries

        comps = component_boundaries(boundary)
        comps_i = range(len(comps))
        feature = [
            (self.points[self.labels == k], self.normals[self.labels == k], self.spacing)
            for k in comps_i
        ]
        self.sources = list(feature)
        todo = set(comps_i)
        while todo:
            if self._near_cells(np.minimum(self.component_sizes, self.spacing)) > self.max_cells:
                self.sources = feature  # refused by check_size anyway: no millions of samples
                return
            for k in sorted(todo):
                s = float(self.component_sizes[k])
                if s < self.spacing:  # denser than the feature samples
                    n = max(int(math.ceil(self.areas[k] / s**2)), 4)
                    pts = np.asarray(comps[k].sample(n), dtype=np.float64).reshape(-1, 3)
                    normals = np.asarray(boundary.normal(pts), dtype=np.float64).reshape(-1, 3)
                    normals /= np.linalg.norm(normals, axis=1)[:, None]
                    self.sources[k] = (pts, normals, s)
            todo = set()
            if len(comps) == 1:
                break
            for k in range(len(comps)):
                others = [j for j in range(len(comps)) if j != k]
                h = self._field(others)(self._band_points(k)).min()
                s = float(_round_down(np.array([h]), self.base)[0])
                if s < self.component_sizes[k]:
                    self.component_sizes[k] = s
                    todo.add(k)

    def _band_points(self, k: int) -> Float:
        """Points across the band of component ``k``: its sources moved along the normal,
        ``band`` sizes into the domain and ``OUTER_BAND`` sizes out of it (9 steps)."""
        pts, n, margin = self.sources[k]
        s = float(self.component_sizes[k])
        t = np.linspace(-(self.band * s + margin), OUTER_BAND * s + margin, 9)
        return (pts[None] + t[:, None, None] * n[None]).reshape(-1, 3)

    def _field(self, components: list[int]) -> BandSizeField:
        src = [self.sources[k] for k in components]
        sizes = [np.full(len(p), self.component_sizes[k]) for (p, _, _), k in zip(src, components)]
        return BandSizeField(
            np.concatenate([p for p, _, _ in src]), np.concatenate(sizes), self.top, self.band,
            self.gradation, np.concatenate([np.full(len(p), m) for p, _, m in src]),
            np.concatenate([n for _, n, _ in src]), OUTER_BAND,
        )  # fmt: skip

    def field(self) -> BandSizeField:
        """The target size of the octree."""
        return self._field(list(range(len(self.sources))))

    def sizes(self) -> Float:
        return self.component_sizes[self.labels]

    def _near_cells(self, margins: Float) -> float:
        """Estimated tetrahedra near Gamma. BCC: 12 per cube of side ``s``; per unit area of
        a component the band holds ``w / s^3`` cubes (``w`` its width) and the graded shells
        beyond it about
        ``1 / (g s^2)`` (two sides); twice that for the leaves straddling the band's edges
        and the balance (measured: 1.6 times on a sphere with a small body)."""
        s = self.component_sizes
        w = (self.band + OUTER_BAND) * s + 2.0 * margins
        return float(24.0 * np.sum(self.areas * (w / s**3 + 1.0 / (self.gradation * s**2))))

    def estimate(self) -> float:
        far = 12.0 * np.prod(self.box[1] - self.box[0]) / self.top**3
        near = self._near_cells(np.array([m for _, _, m in self.sources])) + float(far)
        if self.user is None:
            return near
        return near + self.user.extra_cells(self.top, 12.0)  # BCC: 12 per cube of side s

    def _octree(self, comm: MPI.Comm) -> tuple[Any, Any]:
        """The octree of the current sizes and its leaves (built once per sizes)."""
        from dolfinx_universal.backgrounds import graded_tet as graded_tet

        if self._tree is None:
            size = self.field() if self.user is None else MinSize(self.field(), self.user)
            t = graded_tet._octree(self.box, size, self.top, self.base, comm)
            self._tree = (t, graded_tet._classify(t))
        return self._tree

    def count(self, comm: MPI.Comm) -> int:
        """Tetrahedra of the background (collective)."""
        return int(self._octree(comm)[1].weight.sum())

    def background(self, comm: MPI.Comm) -> dmesh.Mesh:
        from dolfinx_universal.backgrounds import graded_tet as graded_tet

        t, leaves = self._octree(comm)
        return graded_tet._mesh(comm, t, leaves)

    def refine(self, places: Float) -> None:
        from scipy.spatial import cKDTree

        near = []
        for k, (pts, _, margin) in enumerate(self.sources):
            d = cKDTree(pts).query(places)[0]
            near.append(d - (self.band * self.component_sizes[k] + margin))
        dist = np.array(near)  # (components, places): <= 0 inside a component's band
        hit = (dist <= 0).any(axis=1)
        hit[np.argmin(dist, axis=0)] = True  # and the component nearest to each place
        self.component_sizes = np.where(hit, 0.5 * self.component_sizes, self.component_sizes)
        assert self.boundary is not None and self.comm is not None
        boundary = self.boundary

        def settle() -> tuple[Float, list[tuple[Float, Float, float]]]:
            self._settle(boundary)
            return self.component_sizes, self.sources

        self.component_sizes, self.sources = _on_root(self.comm, settle)
        self._tree = None


def _levels(sizes: Float, areas: Float, band: float, gradation: float) -> Float:
    """Component sizes rounded down to ``base 2^k``, with the finest level ``base`` in
    ``(min / 2, min]`` chosen among the sizes halved to that range (each component's size is
    then exactly a level: nothing rounded down by up to a half) to minimise the cells near
    Gamma, ``sum area (2 band / s + 1 / gradation) / s^2``."""
    smallest = float(sizes.min())
    k = np.ceil(np.log2(sizes / smallest) - 1e-9)
    candidates = np.unique(np.minimum(sizes / 2.0**k, smallest))
    best, out = np.inf, sizes
    for base in candidates[::-1]:  # the largest first: ties keep it
        s = _round_down(sizes, float(base))
        cost = float(np.sum(areas * (2.0 * band / s + 1.0 / gradation) / s**2))
        if cost < best * (1 - 1e-9):
            best, out = cost, s
    return out


def _round_down(sizes: Float, base: float) -> Float:
    """``sizes`` rounded down to ``base 2^k`` (at least ``base``)."""
    k = np.floor(np.log2(np.maximum(sizes, base) / base) + 1e-9)
    return base * 2.0**k


def _checked_box(
    boundary: Boundary,
    points: Float,
    size: float,
    box: npt.ArrayLike | None,
    relaxation_factor: float,
) -> Float:
    """The default box for ``size``, or the given box once it contains ``points``."""
    if box is None:
        return default_box(boundary, size, relaxation_factor)
    d = points.shape[1]
    box_arr = np.asarray(box, dtype=np.float64).reshape(2, d)
    out = ~((points > box_arr[0]).all(axis=1) & (points < box_arr[1]).all(axis=1))
    if out.any():
        raise MeshingError(
            f"the domain's boundary leaves the given box {box_arr.tolist()} near "
            f"{where(points[out])}: enlarge the box",
            points[out],
            refinable=False,
        )
    return box_arr


T = TypeVar("T")


def _on_root(comm: MPI.Comm, fn: Callable[[], T]) -> T:
    """``fn()`` computed on rank 0 and broadcast; its errors raised on every rank."""
    result: object = None
    if comm.rank == 0:
        try:
            result = fn()
        except (MeshingError, ValueError) as e:
            result = e
        except Exception as e:  # a user callback failing: the same error on every rank
            result = MeshingError(
                f"sizing the boundary failed: {type(e).__name__}: {e}", refinable=False
            )
    result = comm.bcast(result, root=0)
    if isinstance(result, Exception):
        raise result
    return result  # type: ignore[return-value]


def _short(text: str, n: int = 160) -> str:
    return text if len(text) <= n else text[: n - 3] + "..."
