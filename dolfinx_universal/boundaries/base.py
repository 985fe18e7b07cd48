"""The interface of the immersed boundaries Gamma (curves in 2D, surfaces in 3D):
:class:`Boundary`."""

from __future__ import annotations

import abc
from functools import cached_property

import numpy as np
import numpy.typing as npt

from dolfinx_universal.boundaries.grid import SignGrid, chords
from dolfinx_universal.boundaries.numerics import distances, normd, plane_basis
from dolfinx_universal.core.arrays import Bool, Float, as_points, rot90

__all__ = ["ONTO_REACH", "Boundary", "native", "onto_or_closest"]


ONTO_REACH = 2.5
"""The level-set boundaries' :meth:`Boundary.onto_gamma` accepts a point of Gamma on a point's
gradient line only within this many times Newton's estimate of the offset
(``|f| / |grad f|``): at a point near Gamma the zero lies within a few percent of the
estimate; one farther out is left to the closest point."""


def native(obj: object, cls: type, *names: str) -> bool:
    """Whether ``obj``'s class keeps ``cls``'s methods ``names`` (no subclass overrides them):
    shortcuts that bypass them are then exact."""
    return all(getattr(type(obj), n) is getattr(cls, n) for n in names)


def onto_or_closest(
    b: Boundary, x: Float, y: Float, ok: Bool, f: Float, g: Float, scale: float
) -> tuple[Float, Float]:
    """The level-set boundaries' :meth:`Boundary.onto_gamma` from points ``y`` moved onto
    Gamma along gradient lines (``ok`` where that succeeded) with the level-set function
    ``f`` and its gradient ``g`` there: the points on Gamma to the closest points' tolerance
    (``|f| <= 1e-12 scale |g|``) with the unit normals ``g / |g|``, the closest points and
    normals of ``x`` elsewhere. ``y`` is overwritten."""
    gn = normd(g)
    ok = ok & (gn > 0) & (np.abs(f) <= 1e-12 * scale * gn)
    n = np.zeros_like(y)
    n[ok] = g[ok] / gn[ok, None]
    bad = np.flatnonzero(~ok)
    if bad.size:
        y[bad], n[bad] = b.closest_normal(x[bad])
    return y, n


def _curve_tangents(b: Boundary, y: npt.ArrayLike) -> Float:
    """The unit tangents of a curve as bases ``(n, 1, 2)``."""
    return b.tangent(y)[:, None, :]


def _surface_tangents(b: Boundary, y: npt.ArrayLike) -> Float:
    """The tangent bases ``(n, 2, 3)`` of a surface from its normals (:func:`plane_basis`)."""
    return plane_basis(b.normal(y))


_TANGENT_BASES = {2: _curve_tangents, 3: _surface_tangents}
""":meth:`Boundary.tangent_basis` by the dimension of the space."""


class Boundary(abc.ABC):
    """The boundary Gamma (one or several closed C2 curves) of an open planar domain Omega.

    Point arguments are arrays ``(n, 2)`` or ``(n, 3)`` (only the first two columns are used,
    ``n`` may be 0); results are float64 arrays ``(n,)`` or ``(n, 2)``. Non-finite points
    raise :class:`ValueError`. Points on Gamma are outside Omega (sign +1).

    :attr:`gdim` is the dimension of the space of Omega: 2 here, 3 for the surfaces of
    :mod:`dolfinx_universal.boundaries.surfaces` (whose points are ``(n, 3)``; see
    :class:`~dolfinx_universal.boundaries.surfaces.Surface`).
    """

    gdim: int = 2
    """Dimension of the space (2: curves bound planar domains, 3: surfaces bound solids)."""

    @abc.abstractmethod
    def sign(self, x: npt.ArrayLike) -> Float:
        """Exact classification of points.

        Parameters
        ----------
        x
            Points ``(n, 2)``.

        Returns
        -------
        ``(n,)``: -1.0 in Omega, +1.0 outside or on Gamma.
        """

    @abc.abstractmethod
    def closest_point(self, x: npt.ArrayLike) -> Float:
        """Closest points ``pi(x)`` of Gamma, ``(n, 2)``, for points ``x (n, 2)``."""

    @abc.abstractmethod
    def normal(self, y: npt.ArrayLike) -> Float:
        """Unit outward normals of Omega at ``pi(y)``, ``(n, 2)``, for points ``y (n, 2)``."""

    @abc.abstractmethod
    def bounding_box(self) -> Float:
        """Box ``[[xmin, ymin], [xmax, ymax]]`` containing Gamma (possibly slightly larger)."""

    @abc.abstractmethod
    def sample(self, n: int) -> Float:
        """``n`` roughly equally spaced points of Gamma, ``(n, 2)``."""

    @abc.abstractmethod
    def min_radius_of_curvature(self) -> float:
        """Smallest radius of curvature of Gamma (``inf`` where straight)."""

    def project(self, x: npt.ArrayLike) -> tuple[Float, Float]:
        """Signed distances and closest points from a single projection.

        Parameters
        ----------
        x
            Points ``(n, 2)``.

        Returns
        -------
        phi
            ``(n,)``: ``sign(x) |x - pi(x)|``, negative in Omega.
        y
            ``(n, 2)``: the closest points ``pi(x)``.
        """
        x = as_points(x, dim=self.gdim)
        y = self.closest_point(x)
        return self.sign(x) * normd(x - y), y

    def signed_distance(self, x: npt.ArrayLike) -> Float:
        """Signed distance ``phi (n,)`` to Gamma of points ``x (n, 2)``, negative in Omega."""
        return self.project(x)[0]

    def tangent(self, y: npt.ArrayLike) -> Float:
        """Unit tangents ``(-n_y, n_x)`` at ``pi(y)``, ``(n, 2)``: Omega lies on their left."""
        return rot90(self.normal(y))

    def tangent_basis(self, y: npt.ArrayLike) -> Float:
        """Orthonormal bases of the tangent spaces of Gamma at ``pi(y)``.

        Parameters
        ----------
        y
            Points ``(n, gdim)``.

        Returns
        -------
        ``(n, gdim - 1, gdim)``: in 2D the unit tangent of :meth:`tangent` ``(n, 1, 2)``; in
        3D two unit tangents ``t1, t2`` with ``t1 x t2`` the outward normal ``(n, 2, 3)``.
        """
        return _TANGENT_BASES[self.gdim](self, y)

    def project_normal(self, x: npt.ArrayLike) -> tuple[Float, Float, Float]:
        """Signed distances, closest points and the outward normals there, from one projection.

        Parameters
        ----------
        x
            Points ``(n, 2)``.

        Returns
        -------
        phi
            ``(n,)``: as in :meth:`project`.
        y
            ``(n, 2)``: the closest points ``pi(x)``.
        normal
            ``(n, 2)``: the unit outward normals ``N(pi(x))``.
        """
        x = as_points(x, dim=self.gdim)
        phi, y = self.project(x)
        return phi, y, self.normal(y)

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        """Closest points ``(n, gdim)`` of points ``x (n, gdim)`` and the unit outward normals
        there ``(n, gdim)``, in one call: the projection the conforming step uses
        (subclasses compute both at once where that is cheaper)."""
        y = self.closest_point(x)
        return y, self.normal(y)

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        """Points of Gamma ``(n, gdim)`` near points ``x (n, gdim)`` that lie close to it,
        and the unit outward normals there ``(n, gdim)``.

        The vertex relaxation moves its sliding candidates (steps along the tangent of Gamma
        from a vertex on Gamma, far closer to Gamma than its feature size) onto Gamma with
        it: any nearby point of Gamma will do there, not only the closest one. By default
        the closest points (:meth:`closest_normal`); a subclass may return others where
        that is much cheaper (:class:`~dolfinx_universal.boundaries.curves.ImplicitCurve` and
        :class:`~dolfinx_universal.boundaries.surfaces.ImplicitSurface`: along the gradient
        line of their level-set functions;
        :class:`~dolfinx_universal.boundaries.curves.PolarCurve`: along the ray from its pole).
        """
        return self.closest_normal(x)

    def _sign_closest_normal(self, x: Float) -> tuple[Float, Float, Float]:
        """:meth:`project_normal` as :meth:`Boundary.project` computes ``phi`` (the sign and
        the distance to the closest point), with the normals of :meth:`closest_normal`."""
        y, n = self.closest_normal(x)
        return self.sign(x) * normd(x - y), y, n

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        """Cheap superset of the points within ``distance`` of Gamma.

        Parameters
        ----------
        x
            Points ``(n, 2)``.
        distance
            Distance ``>= 0``: one for all points, or one per point ``(n,)``.

        Returns
        -------
        ``(n,)`` mask, true at every point with ``dist(x, Gamma) <= distance`` and possibly at
        points up to about one sample spacing farther (a grid lower bound of the distance
        discards most points; the nearest dense sample of Gamma, within ``distance + spacing``
        of every point within ``distance``, settles the others).
        """
        x = as_points(x)
        d = distances(distance, len(x))
        on_grid = type(self).lower_bound is Boundary.lower_bound
        if on_grid:  # the grid's bound, its cells kept for the test below
            cells = self._grid.cells(x)
            lb = self._grid.lower_bound(x, cells)
        else:
            lb = self.lower_bound(x)
        mask = lb <= d
        if mask.any():
            g = self._grid
            test = mask.copy()
            if on_grid:
                # In the grid the bound is within 3 sqrt(2) cells of the distance (see
                # SignGrid): a point whose bound is that much below ``distance`` is near.
                sure = cells[0] & (lb * (1 + 1e-5) + 3 * np.sqrt(2.0) * g.h <= d)
                test &= ~sure
            if test.any():
                reach = (d[test] + g.spacing) * (1 + 1e-12)
                dist = g.tree.query(x[test], distance_upper_bound=float(reach.max()))[0]
                mask[test] = dist <= reach
        return mask

    # Samples and measures that sizing and the acceleration grid use; overridden where cheaper
    # or not applicable.
    def loops(self, spacing: float) -> list[Float]:
        """Ordered dense samples of each closed curve of Gamma, at most ``spacing`` apart."""
        n = 1024
        while True:
            p = self.sample(n)
            longest = float(chords(p).max())
            if longest <= spacing:
                return [p]
            n = int(np.ceil(n * longest / spacing * 1.1))

    def loops_normals(self, spacing: float) -> tuple[list[Float], list[Float]]:
        """:meth:`loops` and the outward normals of Omega at their points (same shapes)."""
        loops = self.loops(spacing)
        normals = np.asarray(self.normal(np.concatenate(loops)), dtype=np.float64)
        return loops, np.split(normals, np.cumsum([len(q) for q in loops])[:-1])

    def length(self) -> float:
        """Length of Gamma (approximate)."""
        return float(sum(chords(q).sum() for q in self.loops(np.inf)))

    def measure(self) -> float:
        """Measure of Gamma (approximate): its length in 2D, its area in 3D."""
        return self.length()

    def lower_bound(self, x: Float) -> Float:
        """Cheap lower bound of the distance from ``x (n, 2)`` to Gamma, shape ``(n,)``."""
        return self._grid.lower_bound(x)

    @cached_property
    def _grid(self) -> SignGrid:
        return SignGrid(self.loops, np.asarray(self.bounding_box(), dtype=np.float64))
