"""Tetrahedron backgrounds of mesh_domain: a graded BCC octree or a uniform A15 lattice."""

from __future__ import annotations

import math

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh
from scipy.spatial import cKDTree

from dolfinx_universal.backgrounds.graded_tet import BandSizeField, GradedOctree, graded_octree
from dolfinx_universal.backgrounds.lattice_tet import a15_mesh, a15_num_cells
from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.conforming.universal import ConformingMesh
from dolfinx_universal.core.arrays import Float
from dolfinx_universal.core.collective import MeshingError
from dolfinx_universal.meshing.plans import (
    Plan,
    PlanRequest,
    UserSize,
    check_components,
    checked_box,
    on_root,
)
from dolfinx_universal.sizing.fields import MinSize, SizeFunction, target_sizes
from dolfinx_universal.sizing.surfaces import (
    component_boundaries,
    surface_area,
    surface_feature_size,
)

__all__ = [
    "AUTO_DIHEDRAL",
    "AUTO_RATIO",
    "OUTER_BAND",
    "TET_BACKGROUNDS",
    "TET_GRADATION",
    "GradedTetPlan",
    "UniformPlan",
    "make_plan",
    "tet_plan",
]


OUTER_BAND = 2.0
"""Half-width (in sizes) of the uniform band of the graded tetrahedral background on the
side of Gamma outside the domain (its cells are cut or dropped, never relaxed); on the
domain's side it is ``relaxation_factor + 2``."""


TET_GRADATION = 0.25
"""Growth of the graded tetrahedral background's size beyond its uniform band around Gamma.
Below 1/3, so that no vertex of a level change lies within its relaxation radius
``R_r = 3 h`` of Gamma (``h`` its local size, up to twice the leaf side there): a vertex at
distance ``d`` beyond the band sees sizes about ``s + g d``, and ``3 (s + g d) < d`` far
away only if ``g < 1/3`` (with 0.5, every far vertex would be relaxed)."""


TET_BACKGROUNDS = ("auto", "graded", "a15")
"""Backgrounds of :func:`~dolfinx_universal.meshing.domain.mesh_domain` for surfaces
(``tet_background``)."""

AUTO_RATIO = 0.5
"""``tet_background="auto"`` takes the graded octree when it has fewer than this many times
the tetrahedra of the uniform A15 background (whose angles are better: A15 where it costs
at most twice as much)."""


AUTO_DIHEDRAL = (30.0, 125.0)
"""Dihedral angles (degrees) that ``tet_background="auto"`` keeps: where the graded octree
it chose gives a smaller or larger one (its uniform bands are BCC, which the relaxation
cannot always bring to these), it conforms the A15 background of the same smallest size
instead, if that stays within ``max_cells`` (A15 met them on every sphere, ellipsoid and
torus of ``demos/quality_3d.py``), in the box of Gamma's samples if only that does; else
it refines the octree around the tetrahedra that miss them
(:meth:`GradedTetPlan.target_misses`)."""


def tet_plan(
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
) -> Plan:
    """The background plan of a surface: graded, A15, or (auto) the graded octree where it
    has fewer than :data:`AUTO_RATIO` times the tetrahedra of the A15 background (counted
    on the octree itself, built once, unless either is estimated above ``max_cells``: then
    the smaller estimate, which
    :meth:`~dolfinx_universal.meshing.plans.Plan.check_size` refuses)."""
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
        return GradedTetPlan.create(*args, max_cells, user=size_field)
    if kind == "a15":
        return UniformPlan.create(*args)
    graded = GradedTetPlan.create(*args, max_cells)
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
        graded.alternative, graded.auto = uniform, True
        if box is None:  # the same A15 background in the box of Gamma's samples
            graded.compact = UniformPlan.around(graded.points, uniform, relaxation_factor)
    return choice


class UniformPlan(Plan):
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
            check_components(boundary)
            sf = surface_feature_size(boundary, 0.25 * h)
            target = target_sizes(sf.feature, h, degree, size_factor)
            size = float(target.min())
            box_arr = checked_box(boundary, sf.points, size, box, relaxation_factor)
            rho = np.full(len(sf.points), float(boundary.min_radius_of_curvature()))
            return box_arr, size, sf.points, sf.feature, rho

        box_arr, size, points, feature, rho = on_root(comm, sizing)
        return cls(box_arr, size, points, feature, rho)

    @classmethod
    def from_graded(
        cls,
        plan: GradedTetPlan,
        boundary: Boundary,
        box: npt.ArrayLike | None,
        relaxation_factor: float,
    ) -> UniformPlan:
        """The uniform A15 plan of the smallest target size of ``plan``'s sizing."""
        size = plan.smallest
        box_arr = checked_box(boundary, plan.points, size, box, relaxation_factor)
        return cls(box_arr, size, plan.points, plan.feature, plan.rho)

    @classmethod
    def around(cls, points: Float, plan: UniformPlan, relaxation_factor: float) -> UniformPlan:
        """``plan`` in the box of ``points`` (samples of Gamma) enlarged as
        :func:`~dolfinx_universal.meshing.plans.default_box` enlarges a bounding box: smaller
        than ``plan``'s where the boundary's bounding box is loose (an implicit surface's
        is the box given to it)."""
        margin = (relaxation_factor + 2.0) * plan.size
        box = np.array([points.min(axis=0) - margin, points.max(axis=0) + margin])
        return cls(box, plan.size, plan.points, plan.feature, plan.rho)

    def count(self) -> int:
        """Tetrahedra of the background."""
        return a15_num_cells(self.box, self.size)

    def sizes(self) -> Float:
        return np.full(len(self.points), self.size)

    def estimate(self) -> float:
        # A15 of size h: 2 vertices and 11.5 tetrahedra per h^3
        return float(np.prod(self.box[1] - self.box[0])) * 11.5 / self.size**3

    def background(self, comm: MPI.Comm) -> dmesh.Mesh:
        return a15_mesh(comm, self.box.tolist(), self.size)

    def refine(self, places: Float) -> None:
        self.size *= 0.5


class GradedTetPlan(Plan):
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
        self._tree: GradedOctree | None = None  # the octree, once built
        self.boundary: Boundary | None = None
        self.comm: MPI.Comm | None = None
        self.alternative: UniformPlan | None = None
        """The A15 plan ``tet_background="auto"`` passed over (see :meth:`refined`)."""
        self.compact: UniformPlan | None = None
        """:attr:`alternative` in the box of Gamma's samples (no box given; see
        :meth:`fallback`)."""
        self.auto = False
        """Whether ``tet_background="auto"`` chose this octree over A15: its meshes then
        aim at :data:`AUTO_DIHEDRAL` (:meth:`misses_target`)."""
        self.user: UserSize | None = None
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
    ) -> GradedTetPlan:
        g = TET_GRADATION if gradation is None else float(gradation)
        # The user's field: checked and sampled on rank 0 (sizing), then kept on every rank
        # (not broadcast: a user's function need not pickle).
        user_size = None if user is None else UserSize(comm, user, np.zeros((2, 3)))

        def sizing() -> GradedTetPlan:
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
            plan.box = checked_box(
                boundary, sf.points, float(plan.component_sizes.max()), box, relaxation_factor
            )
            return plan

        plan = on_root(comm, sizing)
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

    def _octree(self, comm: MPI.Comm) -> GradedOctree:
        """The octree of the current sizes (built once per sizes)."""
        if self._tree is None:
            size = self.field() if self.user is None else MinSize(self.field(), self.user)
            self._tree = graded_octree(self.box, size, self.top, self.base, comm)
        return self._tree

    def count(self, comm: MPI.Comm) -> int:
        """Tetrahedra of the background (collective)."""
        return self._octree(comm).num_cells

    def background(self, comm: MPI.Comm) -> dmesh.Mesh:
        return self._octree(comm).mesh(comm)

    def refine(self, places: Float) -> None:
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

        self.component_sizes, self.sources = on_root(self.comm, settle)
        self._tree = None

    def target_margin(self, quality: dict) -> float:
        """Where ``tet_background="auto"`` chose this octree (:attr:`auto`): how far the
        dihedral angles lie inside :data:`AUTO_DIHEDRAL` (what the A15 background keeps)."""
        if not self.auto:
            return math.inf
        lo, hi = AUTO_DIHEDRAL
        return min(quality["theta_min_deg"] - lo, hi - quality["theta_max_deg"])

    def target_text(self, quality: dict) -> str:
        return (
            f"dihedral angles in [{quality['theta_min_deg']:.3g}, "
            f"{quality['theta_max_deg']:.3g}] deg on the {self.name} (auto keeps it within "
            f"{AUTO_DIHEDRAL})"
        )

    def fallback(self, max_cells: float) -> Plan | None:
        """The A15 :attr:`alternative` where it stays within ``max_cells``, else the same
        in the box of Gamma's samples (:attr:`compact`) where that does, else none."""
        for plan in (self.alternative, self.compact if self.alternative is not None else None):
            if plan is not None and plan.estimate() <= max_cells:
                return plan
        return None

    def target_misses(self, cm: ConformingMesh) -> Float:
        """Centroids of the tetrahedra of ``cm`` whose dihedral angles leave
        :data:`AUTO_DIHEDRAL`, gathered from every rank (collective)."""
        nco = cm.mesh.topology.index_map(3).size_local
        cells, x = cm.cells[:nco], cm.x
        theta = np.degrees(cell_kernels(3).angles(x, cells))
        lo, hi = AUTO_DIHEDRAL
        bad = (theta.min(axis=1) < lo) | (theta.max(axis=1) > hi)
        mine = x[cells[bad]].mean(axis=1).reshape(-1, 3)
        return np.concatenate(cm.mesh.comm.allgather(mine)).reshape(-1, 3)

    def refined(self, places: Float, comm: MPI.Comm, max_cells: float) -> tuple[Plan, str]:
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
        alt = self.alternative
        self.refine(places)
        if alt is None:
            return self, ""
        self.alternative = None  # once
        if alt.estimate() > max_cells:
            return self, ""
        if self.estimate() > max_cells or alt.count() < self.count(comm):
            return alt, f" (then the {alt.name} background of size {alt.size:.3g})"
        return self, ""


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


def make_plan(comm: MPI.Comm, boundary: Boundary, request: PlanRequest) -> Plan:
    """The plan of a domain bounded by surfaces (collective; see :func:`tet_plan`)."""
    return tet_plan(
        comm,
        boundary,
        request.h,
        request.degree,
        request.box,
        request.relaxation_factor,
        request.size_factor,
        request.tet_background,
        request.max_cells,
        request.size_field,
    )
