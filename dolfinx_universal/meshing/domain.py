"""Mesh a domain from its boundary alone: size the background, conform, curve, certify."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from decimal import ROUND_CEILING, Decimal
from typing import Any, NamedTuple

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh

from dolfinx_universal.backgrounds.graded_tri import mirror_axis
from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.conforming.quality import quality_report
from dolfinx_universal.conforming.universal import IMMERSED, ConformingMesh, conform
from dolfinx_universal.core.arrays import as_box
from dolfinx_universal.core.collective import MeshingError
from dolfinx_universal.curved.bounds import check_degree
from dolfinx_universal.curved.maps import MAPS, CurvedMesh, curved_mesh
from dolfinx_universal.meshing import plans_tet, plans_tri
from dolfinx_universal.meshing.plans import Plan, PlanRequest, check_components, default_box
from dolfinx_universal.meshing.plans_tet import TET_BACKGROUNDS, UniformPlan
from dolfinx_universal.meshing.plans_tri import size_from_geometry
from dolfinx_universal.sizing.fields import SizeFunction

__all__ = [
    "DEFAULT_MAP",
    "MAX_CELLS",
    "PLANS",
    "Certificate",
    "MeshedDomain",
    "UniformPlan",
    "check_components",
    "default_box",
    "mesh_domain",
    "size_from_geometry",
]


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

PLANS: dict[int, Callable[[MPI.Comm, Boundary, PlanRequest], Plan]] = {
    2: plans_tri.make_plan,
    3: plans_tet.make_plan,
}
"""The background plan of :func:`mesh_domain` by dimension: the graded quadtree of
triangles (:mod:`~dolfinx_universal.meshing.plans_tri`), the graded BCC octree or the
uniform A15 lattice of tetrahedra (:mod:`~dolfinx_universal.meshing.plans_tet`)."""


class _Words(NamedTuple):
    """How :class:`Certificate` speaks of one dimension."""

    cells: str
    background: str
    loops: str
    angles: str
    conditioning: str
    """What the conditioning angles must satisfy."""


_WORDS = {
    2: _Words(
        "cells",
        "a graded background",
        "closed loop(s), one per curve",
        "angles",
        "< 90 needed",
    ),
    3: _Words(
        cell_kernels(3).plural,
        "the {} background",
        "closed surface(s), one per surface",
        "dihedral angles",
        "<= 90 needed: the right angles of BCC allowed",
    ),
}


@dataclass(frozen=True)
class Certificate:
    """What :func:`mesh_domain` verified about its mesh, and with what margin.

    Every figure is global (the same on every rank).
    """

    max_conditioning_angle_deg: float
    """Largest conditioning angle: below 90 for triangles; at most 90 for tetrahedra (the
    largest dihedral angle at a positive face; the right angles of BCC backgrounds are
    allowed)."""
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
        cells, bg, loops, angles, conditioning = _WORDS[self.tdim]
        bg = bg.format(self.background)
        lines = [
            f"universal mesh certificate: {self.num_cells} {cells} (degree {self.degree}"
            + (f", map {self.map})" if self.degree > 1 else ")")
            + f" from {bg} of {self.num_background_cells} {cells}, "
            f"h in [{self.h_min:.3g}, {self.h_max:.3g}]",
            f"  Gamma_h: {self.num_loops} {loops}; {self.num_pieces} connected piece(s)",
            f"  conditioning angles <= {_below(self.max_conditioning_angle_deg, 90.0)} deg "
            f"({conditioning})",
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
        :attr:`~dolfinx_universal.boundaries.domains.Domain.components` (the container first, then
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
    (:func:`~dolfinx_universal.backgrounds.graded_tri.graded_mesh`) whose size near Gamma
    follows the geometry: the local feature size (distance to the medial axis, which
    accounts for curvature, thin parts, necks and gaps between parts of the boundary)
    divided by a factor that grows with the geometry degree
    (:func:`~dolfinx_universal.sizing.fields.target_sizes`). Away from Gamma the size grows
    by :data:`~dolfinx_universal.backgrounds.lattice_tri.GRADATION` per unit length up to
    ``h``. The background is then conformed (the straight map ``M_h`` with ``local_size``),
    curved (the maps ``G_h`` / ``I_h``) and checked: conditioning angles, inverted straight
    or curved cells (a proof with Bernstein coefficients), one Gamma_h loop per curve of
    Gamma on the domain's side, the quality floor ``min_angle``. Where a check fails the
    background is refined locally (the size halved around the places named by the check) and
    the domain meshed again, at most ``max_rounds`` times. The same mesh comes out on any
    number of ranks.

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
        Background of surfaces (one of
        :data:`~dolfinx_universal.meshing.plans_tet.TET_BACKGROUNDS`): ``"a15"``, a uniform A15
        lattice of the smallest target size (dihedral angles 53-79 degrees); ``"graded"``, a
        graded BCC octree (:func:`~dolfinx_universal.backgrounds.graded_tet.graded_tet_mesh`),
        uniform
        (BCC, 60-90 degrees) in a band of ``relaxation_factor + 2`` sizes around each
        component of Gamma; ``"auto"`` (default): the octree where it has fewer than
        :data:`~dolfinx_universal.meshing.plans_tet.AUTO_RATIO` times the tetrahedra of the
        A15 background (a small body in a large box: a tenth), else A15 (whose angles after
        relaxation are a few degrees better); where the octree's dihedral angles leave
        :data:`~dolfinx_universal.meshing.plans_tet.AUTO_DIHEDRAL`, the A15
        background of the same smallest size instead (one more round, if within
        ``max_cells``, else in the box of Gamma's samples if that is; if A15 fails, the
        octree's mesh is kept); where no A15 background fits, the octree refined around the
        tetrahedra that miss the angles, the best mesh kept where the next background would
        exceed ``max_cells`` or ``max_rounds`` or fails.
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
    gdim, degree, map = _checked_arguments(
        boundary, h, degree, map, box, size_field, max_rounds, mirror, tet_background
    )
    request = PlanRequest(
        float(h), degree, box, relaxation_factor, size_factor, max_cells, size_field,
        tet_background, mirror,
    )  # fmt: skip
    steps = _Steps(
        comm, boundary, degree, map,
        {"eta": eta, "relaxation_factor": relaxation_factor, "min_angle": min_angle,
         "relax": relax, "mirror": mirror},
    )  # fmt: skip
    plan = steps.sized(request)
    done, rounds = _refinement_rounds(comm, plan, steps, max_rounds, max_cells)
    certificate = _certificate(comm, done, rounds, request.h, degree, map, min_angle)
    return steps.result(done, certificate, t_start)


def _checked_arguments(
    boundary: Boundary,
    h: float,
    degree: int,
    map: str | None,
    box: npt.ArrayLike | None,
    size_field: SizeFunction | None,
    max_rounds: int,
    mirror: tuple[npt.ArrayLike, npt.ArrayLike] | None,
    tet_background: str,
) -> tuple[int, int, str]:
    """The arguments of :func:`mesh_domain` checked: the dimension, the degree and the map
    (raises ``ValueError``)."""
    h = float(h)
    if not (h > 0 and math.isfinite(h)):
        raise ValueError(f"h must be positive and finite, got {h}")
    gdim = int(getattr(boundary, "gdim", 2))
    if gdim not in PLANS:
        raise ValueError(f"boundary must be curves or surfaces (gdim 2 or 3), got gdim {gdim}")
    degree = int(check_degree(degree, gdim))
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
    return gdim, degree, map


@dataclass
class _Attempt:
    """One round of :func:`mesh_domain` that passed every check."""

    plan: Plan
    background: dmesh.Mesh
    cm: ConformingMesh
    curved: CurvedMesh | None
    quality: dict


@dataclass
class _Steps:
    """The steps of :func:`mesh_domain` on one boundary, timed: size, build a round's
    background, conform and curve it, and the result."""

    comm: MPI.Comm
    boundary: Boundary
    degree: int
    map: str
    options: dict[str, Any]
    """Keyword arguments of :func:`~dolfinx_universal.conforming.universal.conform`."""
    timings: dict[str, float] = field(
        default_factory=lambda: {"sizing": 0.0, "background": 0.0, "conform": 0.0, "curved": 0.0}
    )

    def sized(self, request: PlanRequest) -> Plan:
        """The first round's plan, by dimension (:data:`PLANS`; collective)."""
        t = time.perf_counter()
        plan = PLANS[int(getattr(self.boundary, "gdim", 2))](self.comm, self.boundary, request)
        self.timings["sizing"] += time.perf_counter() - t
        return plan

    def build(self, plan: Plan) -> dmesh.Mesh:
        """The plan's background (collective)."""
        t = time.perf_counter()
        background = plan.background(self.comm)
        self.timings["background"] += time.perf_counter() - t
        return background

    def attempt(self, plan: Plan, background: dmesh.Mesh) -> _Attempt:
        """Conform, curve and rate the background of one round (raises MeshingError)."""
        t = time.perf_counter()
        cm = conform(
            background,
            self.boundary,
            local_size=plan.local_size,
            on_low_quality="raise",
            **self.options,
        )
        self.timings["conform"] += time.perf_counter() - t
        t = time.perf_counter()
        curved = curved_mesh(cm, self.degree, self.map) if self.degree > 1 else None
        self.timings["curved"] += time.perf_counter() - t
        return _Attempt(plan, background, cm, curved, quality_report(cm))

    def result(self, done: _Attempt, certificate: Certificate, t_start: float) -> MeshedDomain:
        """The :class:`MeshedDomain` of the round that passed, with the timings (max over
        ranks; collective)."""
        self.timings["total"] = time.perf_counter() - t_start
        timings = {k: self.comm.allreduce(v, op=MPI.MAX) for k, v in self.timings.items()}
        out = done.curved if done.curved is not None else done.cm
        return MeshedDomain(out.mesh, out.facet_tags, certificate, done.cm, done.curved, timings)


def _refinement_rounds(
    comm: MPI.Comm, plan: Plan, steps: _Steps, max_rounds: int, max_cells: float
) -> tuple[_Attempt, list[str]]:
    """The rounds of :func:`mesh_domain` (collective): build the plan's background and
    attempt it; where a check fails, refine the plan around the places it names (at most
    ``max_rounds`` times, :meth:`~dolfinx_universal.meshing.plans.Plan.refined`).

    Where a mesh passes every check but misses the plan's target
    (:meth:`~dolfinx_universal.meshing.plans.Plan.misses_target`: ``tet_background="auto"``
    chose the octree and its dihedral angles leave
    :data:`~dolfinx_universal.meshing.plans_tet.AUTO_DIHEDRAL`), try the plan's alternative
    (A15) where it stays within ``max_cells``, else refine the plan around the cells that
    miss it; the best mesh so far is kept where the next round fails or would exceed
    ``max_cells`` or ``max_rounds``. Returns the round that passed and the record of the
    rounds."""
    rounds: list[str] = []
    kept: tuple[_Attempt, int] | None = None  # the best valid mesh while a round aims higher
    while True:
        if kept is not None and plan.estimate() > max_cells:
            return _keep(kept, rounds, f"the {plan.name} would exceed max_cells")
        plan.check_size(max_cells, rounds, steps.boundary)
        background = steps.build(plan)
        try:
            done = steps.attempt(plan, background)
        except MeshingError as e:
            first = str(e).splitlines()[0]
            if kept is not None:  # a valid mesh is known: keep it
                return _keep(kept, rounds, f"which failed: {_short(first)}")
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
            plan, note = plan.refined(e.points, comm, max_cells)
            rounds[-1] += note
            continue
        quality = done.quality
        if not plan.misses_target(quality):
            return done, rounds
        kept = _better(kept, (done, len(rounds)))
        missed = f"round {len(rounds) + 1}: {plan.target_text(quality)}"
        alt = plan.fallback(max_cells)
        if alt is not None:
            rounds.append(
                f"{missed}, then the {alt.name} background of size {float(alt.sizes().min()):.3g}"
            )
            plan.alternative = None
            plan = alt
            continue
        places = plan.target_misses(done.cm)
        if len(places) == 0 or len(rounds) >= max_rounds:
            return _keep(kept, rounds, "")
        rounds.append(f"{missed}, refined there")
        plan.alternative = None  # (A15 exceeds max_cells)
        plan, note = plan.refined(places, comm, max_cells)
        rounds[-1] += note


def _better(kept: tuple[_Attempt, int] | None, new: tuple[_Attempt, int]) -> tuple[_Attempt, int]:
    """Of two valid rounds (with their places in the record), the one that comes closer to
    its plan's target (:meth:`~dolfinx_universal.meshing.plans.Plan.target_margin`; the
    earlier on a tie)."""
    if kept is None:
        return new

    def margin(a: _Attempt) -> float:
        return a.plan.target_margin(a.quality)

    return new if margin(new[0]) > margin(kept[0]) else kept


def _keep(kept: tuple[_Attempt, int], rounds: list[str], why: str) -> tuple[_Attempt, list[str]]:
    """The kept octree round and the record up to it, the rounds after it (and ``why``
    they stopped) in a note."""
    done, k = kept
    if k >= len(rounds):  # the last round's own mesh: nothing after it
        return done, rounds
    notes = [r.split(": ", 1)[-1] for r in rounds[k + 1 :]] + ([why] if why else [])
    rounds[k] += f" ({''.join(n + '; ' for n in notes)}the octree's mesh kept)"
    del rounds[k + 1 :]
    return done, rounds


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


def _below(value: float, limit: float, digits: int = 2) -> str:
    """``value`` with ``digits`` decimals; where that prints ``limit`` or more for a value
    below ``limit``, rounded up at as many more decimals as it takes to print below
    ``limit``: an upper bound of ``value`` that does not contradict ``< limit`` (89.9991
    against 90: ``"89.9991"``, not ``"90.00"``)."""
    text = f"{value:.{digits}f}"
    if not (value < limit and float(text) >= limit):
        return text
    exact = Decimal(repr(float(value)))
    for more in range(digits + 1, 18):
        text = str(exact.quantize(Decimal(1).scaleb(-more), rounding=ROUND_CEILING))
        if float(text) < limit:
            return text
    return repr(float(value))


def _short(text: str, n: int = 160) -> str:
    return text if len(text) <= n else text[: n - 3] + "..."
