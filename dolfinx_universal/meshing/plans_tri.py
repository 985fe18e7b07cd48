"""Triangle backgrounds of mesh_domain: a graded acute quadtree sized from the curves."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh

from dolfinx_universal.backgrounds.graded_tri import EDGE_FACTOR, graded_mesh, mirror_axis
from dolfinx_universal.backgrounds.lattice_tri import GRADATION
from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.core.arrays import Float
from dolfinx_universal.core.collective import MeshingError, where
from dolfinx_universal.meshing.plans import (
    Plan,
    PlanRequest,
    UserSize,
    check_components,
    default_box,
    on_root,
)
from dolfinx_universal.sizing.fields import (
    MinSize,
    SizeField,
    SizeFunction,
    feature_size,
    target_sizes,
)

__all__ = ["GradedPlan", "make_plan", "size_from_geometry"]


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
        As in :func:`~dolfinx_universal.meshing.domain.mesh_domain`.

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
    return on_root(
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


class GradedPlan(Plan):
    """Triangles: a graded acute quadtree background sized by a field refined locally."""

    local_size = True
    name = "graded"
    user: UserSize | None = None
    """The user's ``size_field``, in the minimum with :attr:`field`."""
    mirror: tuple[npt.ArrayLike, npt.ArrayLike] | None = None
    """The mirror line of :func:`~dolfinx_universal.meshing.domain.mesh_domain`, or ``None``."""

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
    ) -> GradedPlan:
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


def make_plan(comm: MPI.Comm, boundary: Boundary, request: PlanRequest) -> GradedPlan:
    """The plan of a domain bounded by curves (collective): the graded quadtree of the
    curves' sizing, with the request's mirror line and size field."""
    plan = GradedPlan.create(
        comm,
        boundary,
        request.h,
        request.degree,
        request.box,
        request.relaxation_factor,
        request.size_factor,
    )
    plan.mirror = request.mirror
    if request.size_field is not None:
        plan.user = UserSize(comm, request.size_field, plan.box)
    return plan
