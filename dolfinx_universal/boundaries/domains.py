"""Domains bounded by several curves or surfaces: :class:`Domain`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from dolfinx_universal.boundaries.base import Boundary, native
from dolfinx_universal.boundaries.numerics import normd, split
from dolfinx_universal.core.arrays import Bool, Float, Int, as_points

__all__ = ["Domain"]


class Domain(Boundary):
    """Omega = inside(``container``) minus the closures of the ``bodies``.

    ``container=None`` is the whole plane or space (the background mesh clips it). Each body
    is a :class:`Boundary` whose own inside is the solid. The components are all curves
    (``gdim = 2``) or all surfaces (``gdim = 3``,
    :class:`~dolfinx_universal.boundaries.surfaces.Surface`);
    :attr:`gdim` is theirs. The components are assumed pairwise disjoint and separated
    (bodies inside the container, apart from each other and from it), so the distance to
    Gamma is the smallest distance to a component. Sign rule:
    ``sign(x) = -1`` iff ``container.sign(x) == -1`` and ``body.sign(x) == +1`` for every
    body; a point exactly on a body's curve (measure zero) therefore counts as in Omega.
    Normals point out of Omega: into the bodies.

    Parameters
    ----------
    container
        Boundary of the region containing Omega, or None (the whole plane).
    bodies
        Boundaries of the solids removed from it.
    """

    def __init__(self, container: Boundary | None = None, bodies: Sequence[Boundary] = ()) -> None:
        self.container = container
        self.bodies = tuple(bodies)
        if container is None and not self.bodies:
            raise ValueError("a Domain needs a container or at least one body")
        for b, _ in self.components:
            if not isinstance(b, Boundary):
                raise TypeError(f"Domain components must be Boundary objects, got {type(b)}")
        dims = {int(getattr(b, "gdim", 2)) for b, _ in self.components}
        if len(dims) != 1:
            raise ValueError("the components of a Domain must all be curves or all surfaces")
        self.gdim = dims.pop()

    @property
    def components(self) -> list[tuple[Boundary, bool]]:
        """``(boundary, is_body)`` pairs: the container first (if any), then the bodies."""
        first = [(self.container, False)] if self.container is not None else []
        return first + [(b, True) for b in self.bodies]

    def nearest_component(self, x: npt.ArrayLike) -> npt.NDArray[np.intp]:
        """Index in :attr:`components` of the component nearest to each point ``(n,)``
        (ties: the first, the container)."""
        pts = np.asarray(x, dtype=np.float64)
        dist = [np.abs(c.signed_distance(pts)) for c, _ in self.components]
        return np.argmin(np.reshape(dist, (len(dist), len(pts))), axis=0)

    @property
    def euler_characteristic(self) -> int:
        """Euler characteristic of Gamma: the sum over the components (surfaces only).

        Checks compare it per component: group the faces of the conforming mesh on Gamma by
        :meth:`component_index` of their points and compare each group with
        ``components[k][0].euler_characteristic``.
        """
        return sum(int(b.euler_characteristic) for b, _ in self.components)  # type: ignore

    @property
    def num_components(self) -> int:
        """Number of connected components of Gamma (surfaces only: theirs summed)."""
        return sum(int(b.num_components) for b, _ in self.components)  # type: ignore

    def sign(self, x: npt.ArrayLike) -> Float:
        x = as_points(x, dim=self.gdim)
        s = self.container.sign(x) if self.container is not None else np.full(len(x), -1.0)
        for b in self.bodies:
            m = np.flatnonzero(s < 0)
            s[m[b.sign(x[m]) < 0]] = 1.0
        return s

    def _closest(
        self, x: Float, normals: bool = False, onto: bool = False
    ) -> tuple[Int, Float, Float, Float | None]:
        """Closest component index ``(n,)``, closest point ``(n, gdim)``, distance ``(n,)``
        and, with ``normals``, the outward normals of Omega there ``(n, gdim)`` (else None).

        Each point is projected onto the component with the smallest distance lower bound,
        then onto every other component whose lower bound beats the best distance so far.
        With ``onto`` (and ``normals``), the components' :meth:`onto_gamma` instead of their
        closest points: a point of the nearest component, near ``x``.
        """
        comps = self.components
        if not len(x):
            e = np.empty((0, self.gdim))
            return np.zeros(0, dtype=np.intp), e, np.zeros(0), e.copy() if normals else None
        if len(comps) == 1:  # no lower bounds needed
            b, body = comps[0]
            if normals:
                y, n = b.onto_gamma(x) if onto else b.closest_normal(x)
                return np.zeros(len(x), dtype=np.intp), y, normd(x - y), -n if body else n
            y = b.closest_point(x)
            return np.zeros(len(x), dtype=np.intp), y, normd(x - y), None
        lb = np.array([b.lower_bound(x) for b, _ in comps]).reshape(len(comps), len(x))
        first = lb.argmin(axis=0) if len(x) else np.zeros(0, dtype=np.intp)
        idx, y, d = first.copy(), np.empty((len(x), self.gdim)), np.full(len(x), np.inf)
        out: Float | None = np.empty((len(x), self.gdim)) if normals else None
        for rnd in range(2):
            for k, (b, body) in enumerate(comps):
                m = np.flatnonzero((first == k) if rnd == 0 else (lb[k] < d) & (first != k))
                if m.size:
                    if normals:
                        yk, nk = b.onto_gamma(x[m]) if onto else b.closest_normal(x[m])
                    else:
                        yk = b.closest_point(x[m])
                    dk = normd(x[m] - yk)
                    better = dk < d[m]
                    m = m[better]
                    y[m], d[m] = yk[better], dk[better]
                    if out is not None:
                        out[m] = -nk[better] if body else nk[better]
                    if rnd:
                        idx[m] = k
        return idx, y, d, out

    def component_index(self, y: npt.ArrayLike) -> Int:
        """Index ``(n,)`` into :attr:`components` of the component closest to each point.

        For points ``y (n, gdim)`` on Gamma (e.g. closest points, or the vertices of the
        conforming mesh on Gamma) it is the component they lie on.
        """
        return self._closest(as_points(y, dim=self.gdim))[0]

    def closest_point(self, x: npt.ArrayLike) -> Float:
        return self._closest(as_points(x, dim=self.gdim))[1]

    def project(self, x: npt.ArrayLike) -> tuple[Float, Float]:
        x = as_points(x, dim=self.gdim)
        _, y, d, _ = self._closest(x)
        return self.sign(x) * d, y

    def project_normal(self, x: npt.ArrayLike) -> tuple[Float, Float, Float]:
        x = as_points(x, dim=self.gdim)
        if not native(self, Domain, "project", "closest_point", "normal"):
            return Boundary.project_normal(self, x)
        _, y, d, n = self._closest(x, normals=True)
        return self.sign(x) * d, y, n  # type: ignore[return-value]

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        _, y, _, n = self._closest(x, normals=True)
        return y, n  # type: ignore[return-value]

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        if not native(self, Domain, "closest_point", "normal", "closest_normal"):
            return Boundary.onto_gamma(self, x)
        _, y, _, n = self._closest(x, normals=True, onto=True)
        return y, n  # type: ignore[return-value]

    def normal(self, y: npt.ArrayLike) -> Float:
        return self._closest(as_points(y, dim=self.gdim), normals=True)[3]  # type: ignore

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        x = as_points(x, dim=self.gdim)
        out = np.zeros(len(x), dtype=bool)
        for b, _ in self.components:
            out |= b.near(x, distance)
        return out

    def lower_bound(self, x: Float) -> Float:
        bounds: list[Float] = [b.lower_bound(x) for b, _ in self.components]
        return np.min(bounds, axis=0)

    def bounding_box(self) -> Float:
        boxes = np.array([b.bounding_box() for b, _ in self.components])
        return np.array([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])

    def sample(self, n: int) -> Float:
        comps = [b for b, _ in self.components]
        k = split(n, [b.measure() for b in comps])
        return np.concatenate([b.sample(m) for b, m in zip(comps, k)] + [np.empty((0, self.gdim))])

    def min_radius_of_curvature(self) -> float:
        return min(b.min_radius_of_curvature() for b, _ in self.components)

    def length(self) -> float:
        return sum(b.length() for b, _ in self.components)

    def measure(self) -> float:
        return sum(b.measure() for b, _ in self.components)

    def loops(self, spacing: float) -> list[Float]:
        """The loops of every component (container first), each as that component gives it."""
        return [q for b, _ in self.components for q in b.loops(spacing)]

    def loops_normals(self, spacing: float) -> tuple[list[Float], list[Float]]:
        loops: list[Float] = []
        normals: list[Float] = []
        for b, body in self.components:
            q, n = b.loops_normals(spacing)
            loops += q
            normals += [-v if body else v for v in n]  # out of Omega: into the bodies
        return loops, normals
