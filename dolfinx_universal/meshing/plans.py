"""What the background plans of :func:`~dolfinx_universal.meshing.domain.mesh_domain` share."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh

from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.conforming.universal import ConformingMesh
from dolfinx_universal.core.arrays import Float
from dolfinx_universal.core.collective import MeshingError, collective_call, where
from dolfinx_universal.sizing.fields import SizeFunction
from dolfinx_universal.sizing.gaps import narrow_gap

__all__ = [
    "Plan",
    "PlanRequest",
    "UserSize",
    "check_components",
    "checked_box",
    "default_box",
    "on_root",
]


@dataclass(frozen=True)
class PlanRequest:
    """The arguments of :func:`~dolfinx_universal.meshing.domain.mesh_domain` that size its
    background (see there)."""

    h: float
    degree: int
    box: npt.ArrayLike | None
    relaxation_factor: float
    size_factor: float | None
    max_cells: float
    size_field: SizeFunction | None
    tet_background: str
    mirror: tuple[npt.ArrayLike, npt.ArrayLike] | None


def check_components(boundary: Boundary, n: int = 2048) -> None:
    """Raise if the components of a :class:`~dolfinx_universal.boundaries.domains.Domain` overlap.

    Each body must lie inside the container and outside every other body. Components that
    touch (no mesh size resolves a zero gap) pass here where no sample lies across the
    other: the sizing then asks for more than ``max_cells`` cells at the contact, and
    :meth:`Plan.check_size` names them
    (:func:`~dolfinx_universal.sizing.gaps.narrow_gap`).

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


def default_box(boundary: Boundary, h: float, relaxation_factor: float = 3.0) -> Float:
    """The background box :func:`~dolfinx_universal.meshing.domain.mesh_domain` uses when it is
    given none.

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
        ``R_r / h``, as in :func:`~dolfinx_universal.meshing.domain.mesh_domain`.

    Returns
    -------
    ``[[x_min, y_min], [x_max, y_max]]``, ``(2, gdim)``.
    """
    bbox = np.asarray(boundary.bounding_box(), dtype=np.float64)
    bbox = bbox.reshape(2, bbox.size // 2)
    margin = (relaxation_factor + 2.0) * h
    return np.array([bbox[0] - margin, bbox[1] + margin])


class Plan:
    """The background of :func:`~dolfinx_universal.meshing.domain.mesh_domain` and how it is
    refined where a check fails."""

    points: Float
    """Samples of Gamma where sizes are checked ``(n, gdim)``."""
    feature: Float
    """Local feature sizes at ``points`` ``(n,)``."""
    rho: Float
    """Radii of curvature at ``points`` ``(n,)``."""
    local_size: bool
    """Whether the background is graded (``local_size`` of the conforming step)."""
    name: str
    """The background, as
    :attr:`~dolfinx_universal.meshing.domain.Certificate.background` names it."""
    alternative: Plan | None = None
    """Another background, tried once where this one's mesh misses the quality it aims at
    (:meth:`misses_target`) or fails a refinable check (:meth:`refined`)."""

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

    def target_margin(self, quality: dict) -> float:
        """How far a mesh of this background that passed every check lies inside the
        quality it aims at (negative: outside; ``inf``: no aim), from ``quality``, that of
        :func:`~dolfinx_universal.conforming.quality.quality_report`."""
        return math.inf

    def misses_target(self, quality: dict) -> bool:
        """Whether a mesh that passed every check misses the quality this background aims
        at (:meth:`target_margin` below 0)."""
        return self.target_margin(quality) < 0.0

    def target_text(self, quality: dict) -> str:
        """The miss, in words, for the record of the rounds."""
        return f"{self.name} missed its target"

    def fallback(self, max_cells: float) -> Plan | None:
        """The plan to try where a mesh of this one misses its target: :attr:`alternative`
        where it stays within ``max_cells``."""
        alt = self.alternative
        return alt if alt is not None and alt.estimate() <= max_cells else None

    def target_misses(self, cm: ConformingMesh) -> Float:
        """Centroids of the cells of ``cm`` that miss the quality this plan aims at
        (:meth:`misses_target`), the same on every rank (collective): none here."""
        return np.zeros((0, cm.mesh.geometry.dim))

    def refined(self, places: Float, comm: MPI.Comm, max_cells: float) -> tuple[Plan, str]:
        """The plan of the next round after a refinable failure near ``places``
        (collective), and a note for the round's record: this plan refined there."""
        self.refine(places)
        return self, ""

    def check_size(
        self, max_cells: float, rounds: list[str], boundary: Boundary | None = None
    ) -> None:
        """Raise when the background would exceed ``max_cells``, naming where the smallest
        size is needed (of equal sizes, where the feature size is smallest) and, given the
        ``boundary``, the components of a Domain that nearly touch there
        (:func:`~dolfinx_universal.sizing.gaps.narrow_gap`; a gap of width ``g`` has a feature
        size of about ``g / 2``)."""
        estimate = self.estimate()
        if estimate <= max_cells:
            return
        current = self.sizes()
        i = int(np.lexsort((self.feature, current))[0])
        at = self.points[i : i + 1]
        gap = "" if boundary is None else narrow_gap(boundary, at, 2.5 * float(self.feature[i]))
        after = f" after {len(rounds)} refinement rounds ({'; '.join(rounds)})" if rounds else ""
        if gap:
            message = (
                f"{gap}: the gap asks for a size of {current[i]:.3g} there, about "
                f"{estimate:.3g} background cells (more than max_cells = {max_cells:.3g})"
                f"{after}; the components of a Domain must lie apart from each other: move "
                "them apart"
            )
        else:
            message = (
                f"the geometry asks for about {estimate:.3g} background cells (more than "
                f"max_cells = {max_cells:.3g}): the smallest size needed is "
                f"{current[i]:.3g} near {where(at)}{after}; raise max_cells or simplify the "
                "geometry there"
            )
        raise MeshingError(message, at, refinable=False)


class UserSize:
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


def checked_box(
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


def on_root(comm: MPI.Comm, fn: Callable[[], T]) -> T:
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
