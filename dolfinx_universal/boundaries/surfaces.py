"""Immersed surfaces Gamma of solids in 3D: signs, closest points, distances and normals.

The 3D counterparts of :mod:`dolfinx_universal.boundaries.curves`, with the same interface
(:class:`~dolfinx_universal.boundaries.base.Boundary`): a :class:`Surface` is a closed smooth
surface bounding an open solid Omega. Points are float arrays ``(n, 3)`` (``n`` may be 0);
results are float64 arrays ``(n,)`` or ``(n, 3)``; non-finite points raise
:class:`ValueError`. Sign convention: -1 in Omega, +1 outside or on Gamma; normals point
out of Omega.

* :class:`Sphere` and :class:`Torus`: everything in closed form.
* :class:`Ellipsoid`: closest points from the monotone secular equation of the Lagrange
  multiplier (Eberly's method, with the multiplier shifted so that the degenerate cases near
  the planes of symmetry stay accurate), to about ``1e-15`` relative.
* :class:`ImplicitSurface`: ``{phi = 0}`` of a level-set function; closest points by a
  safeguarded tangential Newton method started from dense samples of Gamma.

:class:`~dolfinx_universal.boundaries.motions.RigidMotion` and
:class:`~dolfinx_universal.boundaries.domains.Domain` accept surfaces.
"""

from __future__ import annotations

import abc
from functools import cached_property

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree
from scipy.special import elliprg

from dolfinx_universal.boundaries.base import ONTO_REACH, Boundary, native, onto_or_closest
from dolfinx_universal.boundaries.grid import SignGrid
from dolfinx_universal.boundaries.numerics import (
    EPS,
    ArrayFn,
    best_pairs,
    bracketed_newton,
    call,
    distances,
    normd,
    plane_basis,
    rotation_matrix,
    split,
    unit,
    vector,
)
from dolfinx_universal.boundaries.topology import grid_topology
from dolfinx_universal.core.arrays import Bool, Float, Int, as_points, positive

__all__ = ["Ellipsoid", "ImplicitSurface", "Sphere", "Surface", "Torus"]

_GOLDEN = np.pi * (3.0 - np.sqrt(5.0))
"""Golden angle (radians) of the Fibonacci lattices."""
_NEWTON_MU = 1e-3
"""Smallest eigenvalue of the reduced Hessian ``Q`` of :class:`ImplicitSurface`'s closest-point
search at which its Newton step is trusted without the distance test (``Q = I`` on a plane;
it is singular only where the point is a centre of curvature of Gamma)."""
_NEWTON_REACH = 1e-4
"""Longest such step, in grid cells of the seeds: far inside the region where Newton's method
converges (a fraction of the radius of curvature), far above the steps that the distance
test cannot resolve."""


# ----------------------------------------------------------------------------- helpers
def _points(x: npt.ArrayLike, name: str = "x") -> Float:
    """``x`` as a contiguous float64 array ``(n, 3)``, checked finite."""
    return as_points(x, name, dim=3)


def _dot(u: Float, v: Float) -> Float:
    return u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1] + u[:, 2] * v[:, 2]


def _dot2(u: Float, v: Float) -> Float:
    return u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1]


def _fmt(v: Float) -> str:
    """A point or vector ``(3,)`` for messages."""
    return "(" + ", ".join(f"{c:.6g}" for c in v) + ")"


def _fibonacci(n: int) -> Float:
    """``n`` unit vectors of the Fibonacci lattice (nearly equal areas), ``(n, 3)``."""
    i = np.arange(n, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / max(n, 1)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.column_stack([r * np.cos(_GOLDEN * i), r * np.sin(_GOLDEN * i), z])


def _morton(p: Float, bits: int = 16) -> npt.NDArray[np.int64]:
    """Z-order keys of points ``(m, 3)`` on a ``2**bits`` grid over their bounding box."""
    lo, hi = p.min(axis=0), p.max(axis=0)
    q = (p - lo) * ((2**bits - 1) / max(float((hi - lo).max()), 1e-300))
    ij = np.clip(q, 0, 2**bits - 1).astype(np.int64)
    key = np.zeros(len(p), dtype=np.int64)
    for b in range(bits):
        for a in range(3):
            key |= ((ij[:, a] >> b) & 1) << (3 * b + a)
    return key


def _stratified(points: Float, weights: Float, n: int) -> Float:
    """``n`` points of a dense set ``(m, 3)`` with area ``weights (m,)``, well spread.

    The points are ordered along a Z-order curve and one is taken in each of ``n`` intervals
    of equal accumulated weight (a stratified choice: about uniform in area, with no two
    picks from the same interval).
    """
    if n <= 0 or not len(points):
        return np.empty((0, 3))
    order = np.argsort(_morton(points), kind="stable")
    cw = np.cumsum(weights[order])
    targets = (np.arange(n) + 0.5) * (cw[-1] / n)
    idx = np.minimum(np.searchsorted(cw, targets), len(points) - 1)
    return points[order[idx]]


# ----------------------------------------------------------------------------- interface
class Surface(Boundary):
    """A closed smooth surface Gamma bounding an open solid Omega in 3D.

    The interface of :class:`~dolfinx_universal.boundaries.base.Boundary` with points ``(n, 3)``
    (``gdim = 3``). Subclasses implement :meth:`sign`, :meth:`closest_point`,
    :meth:`normal`, :meth:`bounding_box`, :meth:`sample`, :meth:`min_radius_of_curvature`,
    :meth:`area` and :meth:`lower_bound`, and set :attr:`euler_characteristic`. The planar
    acceleration grid of the 2D boundaries does not apply: :meth:`near` uses
    :meth:`lower_bound` and :meth:`_upper_bound`, then the exact distance where they do not
    decide. :meth:`tangent` is planar: use :meth:`tangent_basis`.
    """

    gdim = 3
    num_components: int = 1
    """Number of connected components of Gamma."""
    euler_characteristic: int
    """Euler characteristic of Gamma (sum over its components; 2 - 2 genus for one)."""

    def project_normal(self, x: npt.ArrayLike) -> tuple[Float, Float, Float]:
        """Signed distances ``(n,)``, closest points ``(n, 3)`` and outward unit normals
        there ``(n, 3)`` of points ``(n, 3)``, from one projection."""
        x = _points(x)
        if type(self).project is not Boundary.project:  # a subclass's own distances
            phi, y = self.project(x)
            return phi, y, self.normal(y)
        return self._sign_closest_normal(x)

    def tangent(self, y: npt.ArrayLike) -> Float:
        """Planar only: a surface has a tangent plane, see :meth:`tangent_basis`."""
        raise NotImplementedError(f"{type(self).__name__} is a surface: use tangent_basis(y)")

    def tangent_basis(self, y: npt.ArrayLike) -> Float:
        """Orthonormal tangent bases ``(n, 2, 3)`` at ``pi(y)`` for points ``y (n, 3)``.

        Rows ``t1, t2`` with ``t1 x t2`` the outward normal (see
        :func:`~dolfinx_universal.boundaries.numerics.plane_basis` for the choice of ``t1``).
        """
        return plane_basis(self.normal(y))

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        """Superset of the points within ``distance`` of Gamma.

        Parameters
        ----------
        x
            Points ``(n, 3)``.
        distance
            Distance ``>= 0``: one for all points, or one per point ``(n,)``.

        Returns
        -------
        ``(n,)`` mask, true at every point with ``dist(x, Gamma) <= distance``: the cheap
        bounds decide most points, the exact distance (up to a relative ``1e-12``) the rest.
        """
        x = _points(x)
        d = distances(distance, len(x))
        lower, upper = self._bounds_within(x, float(d.max()) if len(d) else 0.0)
        mask = lower <= d
        test = np.flatnonzero(mask)
        if test.size:
            up = self._upper_bound(x[test]) if upper is None else upper[test]
            test = test[up > d[test]]
        if test.size:
            y = self.closest_point(x[test])
            mask[test] = normd(x[test] - y) <= d[test] * (1 + 1e-12)
        return mask

    @abc.abstractmethod
    def lower_bound(self, x: Float) -> Float:
        """Cheap lower bound ``(n,)`` of the distance from points ``x (n, 3)`` to Gamma."""

    def _lower_bound_within(self, x: Float, cap: float) -> Float:
        """:meth:`lower_bound`, where it is at most ``cap``; any value above ``cap``
        elsewhere (what :meth:`near` needs, and may be cheaper)."""
        return self.lower_bound(x)

    def _upper_bound(self, x: Float) -> Float:
        """Cheap upper bound ``(n,)`` of the distance to Gamma (default: none, ``inf``)."""
        return np.full(len(x), np.inf)

    def _bounds_within(self, x: Float, cap: float) -> tuple[Float, Float | None]:
        """:meth:`_lower_bound_within` and, where one computation gives both, the
        :meth:`_upper_bound` of every point (else None: :meth:`near` asks for the upper
        bound of the points the lower bound leaves)."""
        return self._lower_bound_within(x, cap), None

    @abc.abstractmethod
    def area(self) -> float:
        """Area of Gamma (exact for the analytic shapes, approximate otherwise)."""

    def measure(self) -> float:
        return self.area()

    # -- planar hooks that do not apply
    def length(self) -> float:
        raise NotImplementedError(f"{type(self).__name__} is a surface: it has an area()")

    def loops(self, spacing: float) -> list[Float]:
        raise NotImplementedError("sample loops are planar")

    def loops_normals(self, spacing: float) -> tuple[list[Float], list[Float]]:
        raise NotImplementedError("sample loops are planar")

    @property
    def _grid(self) -> SignGrid:
        raise NotImplementedError("the sign/distance grid is planar")


# ----------------------------------------------------------------------------- sphere
class Sphere(Surface):
    """Omega = the open ball of the given ``center`` and ``radius``; all in closed form.

    Parameters
    ----------
    center
        Centre ``(3,)``.
    radius
        Radius ``> 0``. The centre itself projects onto ``center + (radius, 0, 0)``.
    """

    euler_characteristic = 2

    def __init__(self, center: npt.ArrayLike, radius: float) -> None:
        self.center = vector(center, "center", 3)
        self.radius = positive(radius, "radius")

    def sign(self, x: npt.ArrayLike) -> Float:
        d = _points(x) - self.center
        return np.where((d * d).sum(axis=1) < self.radius**2, -1.0, 1.0)

    def _direction(self, x: npt.ArrayLike) -> list[Float]:
        """Unit directions from the centre, as coordinate columns (``(1, 0, 0)`` at the
        centre, which projects onto ``c + (R, 0, 0)``)."""
        x = _points(x)
        d = [x[:, i] - self.center[i] for i in range(3)]
        r = np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        pos = r > 0
        if pos.all():
            return [di / r for di in d]
        r = np.where(pos, r, 1.0)
        return [np.where(pos, di / r, float(i == 0)) for i, di in enumerate(d)]

    def _on_sphere(self, u: list[Float]) -> Float:
        """The points ``center + radius u`` of directions ``u`` (columns), ``(n, 3)``."""
        return np.column_stack([self.center[i] + self.radius * u[i] for i in range(3)])

    def closest_point(self, x: npt.ArrayLike) -> Float:
        return self._on_sphere(self._direction(x))

    def normal(self, y: npt.ArrayLike) -> Float:
        return np.column_stack(self._direction(y))

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        if not native(self, Sphere, "closest_point", "normal"):
            return Boundary.closest_normal(self, x)
        u = self._direction(x)
        return self._on_sphere(u), np.column_stack(u)

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        x = _points(x)
        return self.lower_bound(x) <= distances(distance, len(x))

    def lower_bound(self, x: Float) -> Float:
        return np.abs(normd(x - self.center) - self.radius)

    def bounding_box(self) -> Float:
        r = self.radius * (1 + 4 * EPS)
        return np.array([self.center - r, self.center + r])

    def sample(self, n: int) -> Float:
        """``n`` points of the Fibonacci lattice on the sphere, ``(n, 3)``."""
        return self.center + self.radius * _fibonacci(int(n))

    def min_radius_of_curvature(self) -> float:
        return self.radius

    def area(self) -> float:
        return 4 * np.pi * self.radius**2


# ----------------------------------------------------------------------------- ellipsoid
class Ellipsoid(Surface):
    """Omega = the open ellipsoid ``sum_i (p_i / e_i)^2 < 1``, ``p = rotation^T (x - center)``.

    Closest points: with ``q = |p|`` (the first octant), ``m`` the smallest semi-axis and
    ``d_i = e_i^2 - e_m^2``, the closest point is ``x_i = e_i^2 q_i / (u + d_i)`` where
    ``u > 0`` is the root of the strictly decreasing secular equation
    ``sum_i (e_i q_i / (u + d_i))^2 = 1`` (Eberly's Lagrange multiplier ``t = u - e_m^2``;
    the shift keeps ``u`` accurate when the point is near a plane of symmetry). It is found
    by a bracketed Newton method on ``H(u)^(-1/2) - 1`` (nearly linear) with geometric
    bisection as the safeguard, to a relative ``4 eps``. Degenerate case: a point in the
    plane(s) ``p_m = 0`` inside the evolute, where the root leaves ``u > 0``: then ``u = 0``
    and ``x_m = e_m sqrt(1 - sum_{i != m} (x_i / e_i)^2)`` (the ``+`` side is chosen; the
    centre projects onto ``+e_m`` along the smallest axis). Global and exact for every point.

    Parameters
    ----------
    center
        Centre ``(3,)``.
    semi_axes
        Semi-axes ``(a, b, c)``, all ``> 0``, along the columns of ``rotation``.
    rotation
        Orientation: None (the coordinate axes), an orthogonal ``(3, 3)`` matrix whose
        columns are the directions of the semi-axes, a rotation vector ``(3,)`` or a pair
        ``(axis, angle)``.
    """

    euler_characteristic = 2

    def __init__(
        self, center: npt.ArrayLike, semi_axes: npt.ArrayLike, rotation: object = None
    ) -> None:
        self.center = vector(center, "center", 3)
        e = np.asarray(semi_axes, dtype=np.float64).reshape(-1)
        if e.shape != (3,) or not (np.isfinite(e) & (e > 0)).all():
            raise ValueError(f"semi_axes must be three positive finite numbers, got {semi_axes!r}")
        self.semi_axes = e
        if rotation is not None:
            try:
                mat = np.asarray(rotation, dtype=np.float64)
            except (TypeError, ValueError):  # an (axis, angle) pair
                mat = np.zeros(0)
            if mat.shape == (3, 3) and np.isfinite(mat).all() and np.linalg.det(mat) < 0:
                rotation = mat * np.array([-1.0, 1.0, 1.0])  # a reflection: the same ellipsoid
        self.rotation = np.eye(3) if rotation is None else rotation_matrix(rotation)
        self._m = int(np.argmin(e))
        self._d = e**2 - e[self._m] ** 2
        self._S = self._d == 0  # the smallest semi-axes

    def _local(self, x: npt.ArrayLike) -> Float:
        return (_points(x) - self.center) @ self.rotation

    def _world(self, p: Float) -> Float:
        return self.center + p @ self.rotation.T

    def sign(self, x: npt.ArrayLike) -> Float:
        p = self._local(x) / self.semi_axes
        return np.where((p * p).sum(axis=1) < 1, -1.0, 1.0)

    def _solve(self, p: Float) -> Float:
        """Closest points ``(n, 3)`` in the frame of the axes of local points ``p (n, 3)``."""
        e, d, S = self.semi_axes, self._d, self._S
        q = np.abs(p)
        c = e * q
        c[q <= 1e-100 * e.max()] = 0.0  # below any effect; avoids subnormal multipliers
        zero_s = (c[:, S] == 0).all(axis=1)
        r0 = np.where(S, 0.0, c / np.where(S, 1.0, d))  # x_i / e_i at u = 0
        f0 = (r0 * r0).sum(axis=1) - 1
        deg = zero_s & (f0 <= 0)
        out = np.empty_like(p)
        if deg.any():
            xd = e * r0[deg]
            xd[:, self._m] = e[self._m] * np.sqrt(np.maximum(-f0[deg], 0.0))
            out[deg] = xd
        reg = np.flatnonzero(~deg)
        if reg.size:
            cr = c[reg]
            lo = np.maximum((cr - d).max(axis=1), 0.0)  # H(lo) >= 1
            hi = normd(cr)  # H(hi) <= 1
            u = hi.copy()
            act = np.arange(len(reg))
            for _ in range(200):
                if not act.size:
                    break
                ua, ca = u[act], cr[act]
                den = ua[:, None] + d
                w2 = (ca / den) ** 2
                H, H1 = w2.sum(axis=1), (w2 / den).sum(axis=1)
                below = H > 1  # u below the root
                la = np.where(below, ua, lo[act])
                ha = np.where(below, hi[act], ua)
                lo[act], hi[act] = la, ha
                un = ua + H * (np.sqrt(H) - 1) / H1  # Newton on H^(-1/2) - 1
                geo = (la > 0) & (ha > 2 * la)
                mid = np.where(geo, np.sqrt(la * ha), 0.5 * (la + ha))
                un = np.where((un >= la) & (un <= ha), un, mid)  # converged: un = ua
                un = np.where(H == 1, ua, un)
                u[act] = un
                act = act[(np.abs(un - ua) > 4 * EPS * un) & (ha - la > 4 * EPS * ha)]
            out[reg] = e * cr / (u[:, None] + d)
        return np.copysign(out, p)

    def _local_normal(self, xs: Float) -> Float:
        return unit(xs / self.semi_axes**2)

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        if not native(self, Ellipsoid, "closest_point", "normal"):
            return Boundary.closest_normal(self, x)
        xs = self._solve(self._local(x))
        return self._world(xs), self._local_normal(xs) @ self.rotation.T

    def closest_point(self, x: npt.ArrayLike) -> Float:
        return self._world(self._solve(self._local(x)))

    def normal(self, y: npt.ArrayLike) -> Float:
        return self.closest_normal(_points(y))[1]

    def _radius(self, x: Float) -> tuple[Float, Float]:
        """Ellipsoidal radius ``g = |p / e|`` ``(n,)`` and ``|p|`` ``(n,)``."""
        p = self._local(x)
        return normd(p / self.semi_axes), normd(p)

    def lower_bound(self, x: Float) -> Float:
        # A point of g E is at least |g - 1| e_min from E (E + B((g - 1) e_min) is inside
        # g E for g > 1, and likewise inside), and the distance is at least that to the
        # balls of radii e_min and e_max.
        g, r = self._radius(x)
        e0, e1 = self.semi_axes.min(), self.semi_axes.max()
        lb = np.maximum(np.abs(g - 1) * e0, np.maximum(r - e1, e0 - r))
        return np.maximum(lb, 0.0) * (1 - 1e-12)

    def _upper_bound(self, x: Float) -> Float:
        g, _ = self._radius(x)  # g E is within (g - 1) e_max of E, and E within (1 - g) e_max
        return np.abs(g - 1) * self.semi_axes.max() * (1 + 1e-12)

    def bounding_box(self) -> Float:
        ext = normd(self.rotation * self.semi_axes) * (1 + 4 * EPS)
        return np.array([self.center - ext, self.center + ext])

    def sample(self, n: int) -> Float:
        """About uniformly spread points ``(n, 3)``: a stratified choice (weighted by the
        area element) from a denser mapped Fibonacci lattice."""
        n = int(n)
        if n <= 0:
            return np.empty((0, 3))
        e = self.semi_axes
        m = int(min(64 * n, n * max(4.0, 2 * e.max() / e.min()))) + 16
        u = _fibonacci(m)
        weights = normd(u / e)  # area element of the map u -> e u, up to prod(e)
        return self._world(_stratified(u * e, weights, n))

    def min_radius_of_curvature(self) -> float:
        return float(self.semi_axes.min() ** 2 / self.semi_axes.max())

    def area(self) -> float:
        a, b, c = self.semi_axes
        return float(4 * np.pi * a * b * c * elliprg(1 / a**2, 1 / b**2, 1 / c**2))


# ----------------------------------------------------------------------------- torus
class Torus(Surface):
    """Omega = the open solid ring torus of major radius ``R`` and minor radius ``r < R``.

    The core circle has centre ``center``, radius ``major`` and lies in the plane normal to
    ``axis``. Closest point: ``C + r (x - C) / |x - C|`` with ``C`` the closest point of the
    core circle. Points on the axis (all of the circle is equally close) use the direction
    ``t1`` of the frame (:attr:`frame`, ``t1 x t2 = axis``); points on the core circle
    project radially outwards. Principal curvatures ``1/r`` and
    ``cos v / (R + r cos v)``: the smallest radius of curvature is ``min(r, R - r)``.

    Parameters
    ----------
    center
        Centre ``(3,)``.
    major, minor
        Radii ``R > r > 0``.
    axis
        Axis of symmetry ``(3,)`` (any non-zero length).
    """

    euler_characteristic = 0

    def __init__(
        self,
        center: npt.ArrayLike,
        major: float,
        minor: float,
        axis: npt.ArrayLike = (0.0, 0.0, 1.0),
    ) -> None:
        self.center = vector(center, "center", 3)
        self.major, self.minor = positive(major, "major"), positive(minor, "minor")
        if not self.minor < self.major:
            raise ValueError(f"a ring torus needs minor < major, got {minor} >= {major}")
        k = vector(axis, "axis", 3)
        if not (k @ k) > 0:
            raise ValueError("axis must be non-zero")
        self.axis = k / np.sqrt(k @ k)
        self.frame = plane_basis(self.axis[None])[0]
        """Rows ``t1, t2`` ``(2, 3)`` spanning the plane of the core circle."""

    def _offsets(self, x: Float) -> tuple[list[Float], Float, list[Float], Float]:
        """Offsets ``d = x - center``, axial offsets ``z (n,)``, radial offsets ``w`` and
        radial distances ``rho (n,)`` (``d`` and ``w`` as coordinate columns): all that
        :meth:`sign` and :meth:`near` need (the same arithmetic as :meth:`_direction`)."""
        a = self.axis
        d = [x[:, i] - self.center[i] for i in range(3)]
        z = d[0] * a[0] + d[1] * a[1] + d[2] * a[2]
        w = [d[i] - z * a[i] for i in range(3)]
        zw = w[0] * a[0] + w[1] * a[1] + w[2] * a[2]  # again: rounding left along the axis
        w = [w[i] - zw * a[i] for i in range(3)]
        return d, z, w, np.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)

    def _direction(self, x: Float) -> tuple[list[Float], list[Float]]:
        """Closest points of the core circle and the outward normals (coordinate columns)."""
        d, _, w, rho = self._offsets(x)
        # Radial unit vectors; on the axis (w is rounding, of any direction) t1.
        pos = rho > 4 * EPS * np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        rho = np.where(pos, rho, 1.0)
        t1 = self.frame[0]
        u = [np.where(pos, w[i] / rho, t1[i]) for i in range(3)]
        c = [self.center[i] + self.major * u[i] for i in range(3)]
        v = [x[:, i] - c[i] for i in range(3)]
        s = np.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
        pos = s > 0  # on the core circle: radially outwards
        s = np.where(pos, s, 1.0)
        return c, [np.where(pos, v[i] / s, u[i]) for i in range(3)]

    def sign(self, x: npt.ArrayLike) -> Float:
        _, z, _, rho = self._offsets(_points(x))
        return np.where((rho - self.major) ** 2 + z * z < self.minor**2, -1.0, 1.0)

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        if not native(self, Torus, "closest_point", "normal"):
            return Boundary.closest_normal(self, x)
        c, n = self._direction(_points(x))
        return self._on_torus(c, n), np.column_stack(n)

    def _on_torus(self, c: list[Float], n: list[Float]) -> Float:
        """The points ``c + minor n`` (columns of core points and normals), ``(n, 3)``."""
        return np.column_stack([c[i] + self.minor * n[i] for i in range(3)])

    def closest_point(self, x: npt.ArrayLike) -> Float:
        return self._on_torus(*self._direction(_points(x)))

    def normal(self, y: npt.ArrayLike) -> Float:
        return np.column_stack(self._direction(_points(y))[1])

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        x = _points(x)
        return self.lower_bound(x) <= distances(distance, len(x))

    def lower_bound(self, x: Float) -> Float:
        _, z, _, rho = self._offsets(x)
        return np.abs(np.hypot(rho - self.major, z) - self.minor)

    def bounding_box(self) -> Float:
        ext = self.major * np.sqrt(np.maximum(1 - self.axis**2, 0.0)) + self.minor
        ext = ext * (1 + 4 * EPS)
        return np.array([self.center - ext, self.center + ext])

    def sample(self, n: int) -> Float:
        """``n`` points on rings around the tube, each ring's share proportional to its
        length, ``(n, 3)``."""
        n = int(n)
        if n <= 0:
            return np.empty((0, 3))
        R, r = self.major, self.minor
        rings = int(min(n, max(3, round(np.sqrt(n * r / R)))))
        v = 2 * np.pi * (np.arange(rings) + 0.5) / rings
        counts = np.asarray(split(n, list(R + r * np.cos(v))), dtype=np.intp)
        j = np.repeat(np.arange(rings), counts)
        k = np.arange(n) - np.repeat(np.cumsum(counts) - counts, counts)
        m = counts[j]
        uu = 2 * np.pi * (k + 0.5 + 0.618034 * j) / m
        vv = v[j]
        rad = R + r * np.cos(vv)
        t1, t2 = self.frame
        return (
            self.center
            + (rad * np.cos(uu))[:, None] * t1
            + (rad * np.sin(uu))[:, None] * t2
            + (r * np.sin(vv))[:, None] * self.axis
        )

    def min_radius_of_curvature(self) -> float:
        return min(self.minor, self.major - self.minor)

    def area(self) -> float:
        return 4 * np.pi**2 * self.major * self.minor


# ----------------------------------------------------------------------------- level sets
class ImplicitSurface(Surface):
    """Gamma = {phi = 0}, Omega = {phi < 0} (``phi >= 0`` is outside or on Gamma).

    ``phi`` maps points ``(n, 3)`` to ``(n,)``, ``grad`` to ``(n, 3)``, ``hess`` (optional)
    to ``(n, 3, 3)``; without ``hess``, central differences of ``grad`` with step
    ``fd_step = 6e-6 * diag(bbox)`` (it only affects the convergence rate, not the converged
    point). ``phi`` must be a proper level-set function (``grad phi != 0`` on Gamma).

    Samples: ``phi`` is evaluated on a grid of ``resolution`` cells along the longest side of
    ``bounding_box`` (padded); the crossings of its edges by Gamma, moved onto Gamma along
    the gradient line, are the *seeds*. Every point of Gamma is within about a cell of a
    seed (measured: below 0.9 cells; :meth:`near` and the starts assume 2 cells), provided
    that Gamma has no feature (a bump, neck or component) smaller than a cell: give a tight
    box or raise ``resolution``.

    Closest points: from the seeds that are discrete local minima of the distance near the
    nearest one, a tangential Newton method on ``|y - x|^2 / 2`` over Gamma. With ``T`` a
    tangent basis and ``lam`` the Lagrange multiplier, the step solves the reduced Hessian
    ``Q = T (I + lam H) T^T`` with its eigenvalues taken by magnitude (Newton's step where
    ``Q`` is positive definite, a descent step elsewhere, plus a full step along a direction
    of negative curvature, away from maxima and saddles), limited to one cell; the new point
    is moved back onto Gamma along the gradient line (Newton's method bracketed by a sign
    change of ``phi``, with bisection), and a step that increases the distance is halved.
    Near the end, small Newton steps where ``Q`` is positive definite are taken without the
    distance test (which rounding blinds there), so the points are stationary to rounding.
    The nearest converged result wins (converged: a step below ``1e-12 diag(bbox)`` where
    ``Q`` is positive semi-definite); it is checked to be on Gamma
    (``|phi| / |grad phi| <= 1e-12 diag(bbox)``) with ``x - y`` parallel to ``grad phi``.
    Points none of whose starts pass are retried from their own projection along the
    gradient line, then raise :class:`RuntimeError`.

    Checks, when the seeds are first needed: ``grad`` against central differences of ``phi``
    at the grid's crossings (a :class:`ValueError` naming a point where they disagree, e.g. a
    ``grad`` of the wrong sign); the topology of Gamma (:attr:`num_components`, :attr:`genus`)
    counted on the grid (:func:`~dolfinx_universal.boundaries.topology.grid_topology` of the
    grid points where ``phi < 0``) against the numbers given, if any (a :class:`ValueError`
    naming both where they differ).

    Parameters
    ----------
    phi, grad
        Level-set function and its gradient, vectorised as above.
    bounding_box
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` containing Gamma.
    genus
        Total genus of Gamma (:attr:`euler_characteristic` is ``2 num_components - 2 genus``);
        None: counted on the grid.
    min_radius_of_curvature
        The smallest radius of curvature if known; else estimated from the principal
        curvatures at the seeds (an estimate: it may exceed the true value slightly).
    hess
        Hessian of ``phi`` (optional).
    num_components
        Number of connected components of Gamma; None: counted on the grid.
    resolution
        Grid cells along the longest side of the box (at least 8).
    """

    def __init__(
        self,
        phi: ArrayFn,
        grad: ArrayFn,
        bounding_box: npt.ArrayLike,
        genus: int | None = None,
        min_radius_of_curvature: float | None = None,
        *,
        hess: ArrayFn | None = None,
        num_components: int | None = None,
        resolution: int = 64,
    ) -> None:
        box = np.asarray(bounding_box, dtype=np.float64)
        if box.shape != (2, 3) or not np.isfinite(box).all() or not (box[1] > box[0]).all():
            raise ValueError(
                "bounding_box must be [[xmin, ymin, zmin], [xmax, ymax, zmax]], "
                f"got {bounding_box!r}"
            )
        if genus is not None and (int(genus) != genus or genus < 0):
            raise ValueError(f"genus must be an integer >= 0, got {genus}")
        if num_components is not None and (
            int(num_components) != num_components or num_components < 1
        ):
            raise ValueError(f"num_components must be an integer >= 1, got {num_components}")
        if int(resolution) < 8:
            raise ValueError(f"resolution must be at least 8, got {resolution}")
        self._f, self._gradf, self._hessf = phi, grad, hess
        self._box = box
        self.given_topology = (
            None if num_components is None else int(num_components),
            None if genus is None else int(genus),
        )
        """The numbers of components and the genus as given (None where not given)."""
        self._rmin = (
            None
            if min_radius_of_curvature is None
            else positive(min_radius_of_curvature, "min_radius_of_curvature")
        )
        self.resolution = int(resolution)
        self._scale = float(normd(box[1] - box[0]))
        self.fd_step = 6e-6 * self._scale

    @property
    def num_components(self) -> int:  # type: ignore[override]
        """Number of connected components of Gamma (given, else counted on the grid)."""
        return self._topology[0]

    @property
    def genus(self) -> int:
        """Total genus of Gamma (given, else counted on the grid)."""
        return self._topology[1]

    @property
    def euler_characteristic(self) -> int:  # type: ignore[override]
        """Euler characteristic of Gamma, ``2 num_components - 2 genus``."""
        return 2 * self.num_components - 2 * self.genus

    @cached_property
    def counted_topology(self) -> tuple[int, int]:
        """The number of components and the total genus of Gamma counted on the grid of
        the seeds (:func:`~dolfinx_universal.boundaries.topology.grid_topology`)."""
        return grid_topology(self._base_grid[2] < 0)

    @property
    def topology_counted(self) -> bool:
        """Whether :attr:`num_components` and :attr:`genus` were counted (neither given)."""
        return self.given_topology == (None, None)

    @cached_property
    def _topology(self) -> tuple[int, int]:
        """:attr:`num_components` and :attr:`genus`: those given, checked against those
        counted on the grid; those counted where not given."""
        counted = self.counted_topology
        n, g = self.given_topology
        chosen = (counted[0] if n is None else n, counted[1] if g is None else g)
        if chosen != counted or counted[1] < 0:
            names = ("num_components", "genus")
            given = [f"{k} = {v}" for k, v in zip(names, self.given_topology) if v is not None]
            what = f"but {' and '.join(given)} given" if given else "a negative genus"
            raise ValueError(
                f"ImplicitSurface: the grid of {self.resolution} cells along the box counts "
                f"{counted[0]} component(s) and genus {counted[1]}, {what}: give the "
                "surface's numbers (or none, to use those counted), or raise resolution "
                "where the grid misses a part of the surface or a gap"
            )
        return chosen

    # -- evaluations
    def _phi(self, y: Float) -> Float:
        return call(self._f, y, (len(y),), "phi") if len(y) else np.zeros(0)

    def _g(self, y: Float) -> Float:
        return call(self._gradf, y, (len(y), 3), "grad") if len(y) else np.zeros((0, 3))

    def _H(self, y: Float) -> Float:
        if self._hessf is not None:
            return call(self._hessf, y, (len(y), 3, 3), "hess")
        e = np.eye(3) * self.fd_step
        H = np.stack([self._g(y + e[j]) - self._g(y - e[j]) for j in range(3)], axis=2)
        return (H + H.transpose(0, 2, 1)) / (4 * self.fd_step)

    def sign(self, x: npt.ArrayLike) -> Float:
        return np.where(self._phi(_points(x)) < 0, -1.0, 1.0)

    # -- onto Gamma along the gradient line
    def _to_surface(self, z: Float, reach: float = np.inf) -> tuple[Float, Bool]:
        """Points moved onto Gamma along the line of ``grad phi`` through them ``(m, 3)``,
        and the mask of those that found a sign change within ``2 diag(bbox)`` and within
        ``reach`` times Newton's estimate of the offset (``-phi / |grad phi|``)."""
        m = len(z)
        f0, g0 = self._phi(z), self._g(z)
        gn = normd(g0)
        ok = np.isfinite(f0) & np.isfinite(gn) & (gn > 0)
        u = np.zeros_like(z)
        u[ok] = g0[ok] / gn[ok, None]
        t = np.zeros(m)
        lo, hi = np.zeros(m), np.zeros(m)
        todo = np.flatnonzero(ok & (f0 != 0))
        if todo.size:
            s = -f0[todo] / gn[todo]  # Newton's estimate of the offset
            s = np.where(s == 0, np.copysign(EPS * self._scale, s), s)
            found = np.zeros(todo.size, dtype=bool)
            near_end = np.zeros(todo.size)
            far_end = np.zeros(todo.size)
            k = np.arange(todo.size)
            fac = 1.25
            while k.size and fac <= reach and fac * np.abs(s[k]).min() <= 2 * self._scale:
                tt = s[k] * fac
                ft = self._phi(z[todo[k]] + tt[:, None] * u[todo[k]])
                cross = (ft == 0) | (np.sign(ft) != np.sign(f0[todo[k]]))
                far_end[k[cross]] = tt[cross]
                found[k[cross]] = True
                near_end[k[~cross]] = tt[~cross]
                k = k[~cross & (np.abs(tt) * 2 <= 2 * self._scale)]
                fac *= 2
            neg = f0[todo] < 0  # then phi(t) < 0 at the near end: lo; else the near end is hi
            lo[todo] = np.where(neg, near_end, far_end)
            hi[todo] = np.where(neg, far_end, near_end)
            ok[todo[~found]] = False
            sel = todo[found]
            if sel.size:
                zs, us = z[sel], u[sel]

                def fn(tt: Float, i: Int) -> tuple[Float, Float]:
                    p = zs[i] + tt[:, None] * us[i]
                    return self._phi(p), _dot(self._g(p), us[i])

                t0 = np.clip(-f0[sel] / gn[sel], lo[sel], hi[sel])
                t[sel] = bracketed_newton(fn, t0, lo[sel], hi[sel], 4 * EPS * self._scale)
        y = z + t[:, None] * u
        return y, ok & np.isfinite(y).all(axis=1)

    # -- seeds
    @cached_property
    def _base_grid(self) -> tuple[Float, float, Float]:
        """Origin ``(3,)``, cell size and values of ``phi`` on the padded grid."""
        lo, hi = self._box
        h = float((hi - lo).max()) / self.resolution
        origin = lo - 2 * h
        shape = tuple(int(k) for k in np.ceil((hi - lo) / h).astype(int) + 5)
        axes = [origin[a] + h * np.arange(shape[a]) for a in range(3)]
        X = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        F = self._phi(X).reshape(shape)
        if not np.isfinite(F).all():
            raise ValueError("phi is not finite on the grid over bounding_box")
        faces = [F[0], F[-1], F[:, 0], F[:, -1], F[:, :, 0], F[:, :, -1]]
        if any((f <= 0).any() for f in faces):
            raise ValueError("phi <= 0 on the boundary of bounding_box: enlarge bounding_box")
        if (F > 0).all():
            raise ValueError("phi has no zero level set in bounding_box")
        return origin, h, F

    def _crossings(self, refine: int) -> tuple[Float, Float, float]:
        """Points of Gamma where it crosses the edges of the grid refined ``refine`` times
        in the cells that the base grid shows cut ``(m, 3)``, their area weights ``(m,)``
        (``h^2 / |N|_1``: the crossings per unit area are ``|N|_1 / h^2``) and the fine
        cell size ``h``."""
        return self._on_surface(*self._edge_crossings(refine))

    def _on_surface(self, p: Float, h: float) -> tuple[Float, Float, float]:
        """:meth:`_crossings` from the crossings ``p`` of the edges of the grid of cell size
        ``h`` (:meth:`_edge_crossings`): moved onto Gamma, with their area weights."""
        y, ok = self._to_surface(p)
        y = y[ok]
        g1 = np.abs(unit(self._g(y))).sum(axis=1)
        return y, h * h / g1, h

    def _edge_crossings(self, refine: int) -> tuple[Float, float]:
        """Where the edges of the grid refined ``refine`` times, in the cells that the base
        grid shows cut, change the sign of ``phi`` (linear interpolation, ``(m, 3)``), and the
        fine cell size ``h``."""
        origin, hb, F = self._base_grid
        f = int(refine)
        P = F >= 0
        c = [P[i : P.shape[0] - 1 + i, j : P.shape[1] - 1 + j, k : P.shape[2] - 1 + k]
             for i in (0, 1) for j in (0, 1) for k in (0, 1)]  # fmt: skip
        cut = np.any(c, axis=0) & ~np.all(c, axis=0)
        cells = np.argwhere(cut)
        g = np.arange(f + 1)
        offs = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
        dims = (np.array(F.shape) - 1) * f + 1
        nodes = (cells[:, None, :] * f + offs[None]).reshape(-1, 3)
        key = np.unique(np.ravel_multi_index(tuple(nodes.T), tuple(dims)))
        ijk = np.column_stack(np.unravel_index(key, tuple(dims)))
        h = hb / f
        xs = origin + ijk * h
        if f == 1:
            fv = F.reshape(-1)[key]
        else:
            fv = self._phi(xs)
        pos = fv >= 0
        strides = (dims[1] * dims[2], dims[2], 1)
        pts = []
        for a in range(3):
            nk = key + strides[a]
            j = np.minimum(np.searchsorted(key, nk), len(key) - 1)
            hit = (key[j] == nk) & (ijk[:, a] + 1 < dims[a])
            i = np.flatnonzero(hit & (pos != pos[j]))
            w = fv[i] / (fv[i] - fv[j[i]])
            p = xs[i].copy()
            p[:, a] += w * h
            pts.append(p)
        return np.concatenate(pts), h

    def _check_grad(self, p: Float, h: float) -> None:
        """Raise a :class:`ValueError` where ``grad`` disagrees with the central differences
        of ``phi`` (relative ``1e-2``), at up to 256 of the points ``p (m, 3)`` near Gamma
        (``h``: the grid's cell size). Points where the differences of steps ``1e-3 h`` and
        ``2e-3 h`` disagree (``phi`` not smooth there) are left out."""
        p = p[:: max(1, len(p) // 256)]
        if not len(p):
            return
        g = self._g(p)
        e = np.eye(3) * (1e-3 * h)

        def differences(k: float) -> Float:
            cols = [self._phi(p + k * e[j]) - self._phi(p - k * e[j]) for j in range(3)]
            return np.column_stack(cols) / (2 * k * e[0, 0])

        d1, d2 = differences(1.0), differences(2.0)
        size = np.maximum(normd(g), normd(d1))
        smooth = normd(d1 - d2) <= 1e-3 * normd(d1)
        bad = np.flatnonzero(smooth & ~(normd(g - d1) <= 1e-2 * size))
        if bad.size:
            i = int(bad[0])
            hint = (
                " (the opposite way: phi < 0 inside, so grad phi points out of the solid)"
                if (g[i] @ d1[i]) < 0
                else ""
            )
            raise ValueError(
                f"ImplicitSurface: grad disagrees with phi at {_fmt(p[i])}: grad = "
                f"{_fmt(g[i])}, central differences of phi = {_fmt(d1[i])}{hint}"
            )

    @cached_property
    def _seeds(self) -> tuple[Float, cKDTree, Int, float, float, float]:
        """Seeds ``(m, 3)``, their k-d tree, their 8 nearest other seeds ``(m, 8)``, the
        grid cell size, the covering radius (every point of Gamma is within it of a seed)
        and the area of Gamma (the sum of the weights of the crossings of the grid refined
        once)."""
        raw, h = self._edge_crossings(1)
        self._check_grad(raw, h)
        _ = self._topology  # a topology given is checked against the grid's first
        pts, _, h = self._on_surface(raw, h)
        if len(pts) < 16:
            raise ValueError("phi has too few zero crossings on the grid: raise resolution")
        tree = cKDTree(pts)
        nb = tree.query(pts, k=min(9, len(pts)))[1][:, 1:]
        # Covering radius: a cut cell holds crossings on its edges (within sqrt(3) h of its
        # points); a cap of Gamma poking into an uncut cell reaches a cut neighbour. 2 h
        # (measured: below 0.9 h on the test surfaces).
        return pts, tree, nb, h, 2.0 * h, float(self._crossings(2)[1].sum())

    # -- closest points
    def _descend(self, x: Float, y0: Float) -> tuple[Float, Bool]:
        """Local closest points of ``x (m, 3)`` from starts ``y0 (m, 3)`` on Gamma, and the
        mask of those that converged and passed the checks (see the class docstring)."""
        y = y0.copy()
        dist = normd(y - x)
        ok = np.zeros(len(x), dtype=bool)
        act = np.arange(len(x))
        delta = self._seeds[3]
        tol = 1e-12 * self._scale
        for _ in range(100):
            if not act.size:
                break
            xa, ya = x[act], y[act]
            g = self._g(ya)
            gn = normd(g)
            T = plane_basis(g / gn[:, None])
            r = ya - xa
            lam = -_dot(r, g) / gn**2
            Q = np.eye(2) + lam[:, None, None] * np.einsum("kai,kij,kbj->kab", T, self._H(ya), T)
            b = np.einsum("kai,ki->ka", T, r)
            # Newton's step on |Q| (eigenvalues by magnitude, at least 1e-8): Newton where Q
            # is positive definite, a descent step away from maxima and saddles elsewhere
            mu, V = np.linalg.eigh(0.5 * (Q + Q.transpose(0, 2, 1)))
            c = np.einsum("kab,ka->kb", V, b) / np.maximum(np.abs(mu), 1e-8)
            beta = -np.einsum("kab,kb->ka", V, c)
            neg = mu[:, 0] < -1e-6  # and a full step along a direction of negative curvature
            if neg.any():
                v0 = V[neg, :, 0]
                side = np.where(_dot2(v0, b[neg]) > 0, -1.0, 1.0)
                beta[neg] += (side * delta)[:, None] * v0
            # Stationary already (x - y along grad phi to rounding) where Q is positive
            # semi-definite: no step. Where the minimum is not isolated (x on the axis of a
            # torus: a circle of closest points; the centre of a sphere) Q is singular
            # along the ties and Newton's step there is rounding over 1e-8, which would
            # drift along them for ever; stopping keeps the start's own tie (deterministic).
            # Where Q is well away from singular, the step to the stationary point is taken
            # even then: it moves the point by rounding and makes it stationary to rounding.
            stationary = (np.hypot(b[:, 0], b[:, 1]) <= tol) & ~neg
            beta[stationary & (mu[:, 0] < _NEWTON_MU)] = 0.0
            nb = np.hypot(beta[:, 0], beta[:, 1])
            with np.errstate(divide="ignore", invalid="ignore"):
                beta *= np.minimum(1.0, delta / nb)[:, None]
            step = np.einsum("ka,kai->ki", beta, T)
            size = normd(step)
            # Small Newton steps where Q is positive definite are taken without the distance
            # test: their decrease of the distance, O(size^2 / distance), falls below the
            # rounding of the distance from size ~ 1e-8 sqrt(distance) on, where that test
            # stalled the search (leaving closest points off by up to 2e-9 along Gamma,
            # different for inputs an ulp apart); Newton's method converges there.
            newton = (mu[:, 0] >= _NEWTON_MU) & (size <= _NEWTON_REACH * delta)
            fac = np.ones(len(act))
            pend = np.arange(len(act))
            ynew = ya.copy()
            for _ in range(40):  # halve steps that increase the distance
                if not pend.size:
                    break
                yt, okt = self._to_surface(ya[pend] + fac[pend, None] * step[pend])
                dt = normd(yt - xa[pend])
                small = fac[pend] * size[pend] <= tol
                good = okt & ((dt <= dist[act[pend]] * (1 + 8 * EPS)) | small | newton[pend])
                ynew[pend[good]] = yt[good]
                dist[act[pend[good]]] = dt[good]
                pend = pend[~good]
                fac[pend] *= 0.5
            y[act] = ynew
            done = fac * size <= tol
            ok[act[done & ~neg]] = True  # not at a maximum or saddle
            act = act[~done & np.isfinite(ynew).all(axis=1)]
        return y, ok & self._valid(x, y)

    def _valid(self, x: Float, y: Float) -> Bool:
        """Whether ``y (m, 3)`` is on Gamma and ``x - y`` along ``grad phi`` (both to about
        ``1e-12 diag(bbox)`` and ``1e-9`` relative)."""
        if not len(y):
            return np.zeros(0, dtype=bool)
        g = self._g(y)
        gn = normd(g)
        r = x - y
        tang = normd(r - (_dot(r, g) / gn**2)[:, None] * g)
        on = np.abs(self._phi(y)) <= 1e-12 * self._scale * gn
        return on & (tang <= 1e-9 * (self._scale + normd(r)))

    def _starts(self, x: Float) -> tuple[Int, Int]:
        """Pairs ``(point, seed)`` of starts: the nearest seed of every point, and up to 3
        more among its 16 nearest: those within the nearest distance plus 1.5 covering
        radii, farther than 2 covering radii from the nearest seed (another part of Gamma),
        that are discrete local minima of the distance over their 8 nearest seeds (none of
        these is closer to the point: the closer seeds are the columns before)."""
        pts, tree, nb, _, cover, _ = self._seeds
        k = min(16, len(pts))
        D, J = tree.query(x, k=k)
        far = (D <= D[:, :1] + 1.5 * cover) & (normd(pts[J] - pts[J[:, :1]]) > 2 * cover)
        far[:, 0] = False
        rows = np.flatnonzero(far.any(axis=1))
        ps, ss = [np.arange(len(x))], [J[:, 0]]
        lower = np.tri(k, k, -1, dtype=bool)  # column c' before column c
        for c in range(0, rows.size, 4096):
            r = rows[c : c + 4096]
            Jr = J[r]
            adj = (nb[Jr][:, :, :, None] == Jr[:, None, None, :]).any(axis=2)
            i, col = np.nonzero(far[r] & ~(adj & lower).any(axis=2))
            rank = np.arange(len(i)) - np.searchsorted(i, i)  # nearest first
            keep = rank < 3
            ps.append(r[i[keep]])
            ss.append(Jr[i[keep], col[keep]])
        return np.concatenate(ps), np.concatenate(ss)

    def closest_point(self, x: npt.ArrayLike) -> Float:
        x = _points(x)
        if not len(x):
            return np.empty((0, 3))
        pts = self._seeds[0]
        pi, si = self._starts(x)
        y, ok = self._descend(x[pi], pts[si])
        best = best_pairs(pi, np.where(ok, normd(y - x[pi]), np.inf))
        out, good = y[best], ok[best]
        bad = np.flatnonzero(~good)
        if bad.size:  # from the point's own projection along the gradient line
            y0, ok0 = self._to_surface(x[bad])
            yb, okb = self._descend(x[bad], y0)
            okb &= ok0
            out[bad[okb]] = yb[okb]
            bad = bad[~okb]
        if bad.size:
            raise RuntimeError(
                f"ImplicitSurface.closest_point: no converged projection for {bad.size} "
                f"point(s), e.g. x={x[bad[0]].tolist()} (index {bad[0]})"
            )
        return out

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        if not native(self, ImplicitSurface, "closest_point", "normal"):
            return Boundary.closest_normal(self, x)
        y = self.closest_point(x)
        return y, unit(self._g(y))

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        """Points of Gamma near points ``x (n, 3)`` close to it and the outward normals
        there: ``x`` moved along the line of ``grad phi`` through it (one bracketed Newton
        search, about a tenth of the cost of a closest point; for points a tangent step of
        0.05-0.35 h from Gamma the two differ by about 1e-6 h). Points whose zero on that
        line is not within :data:`~dolfinx_universal.boundaries.base.ONTO_REACH` times Newton's
        estimate of the offset, or is not on Gamma to the closest points' tolerance, get
        their closest points."""
        if not native(self, ImplicitSurface, "closest_point", "normal", "closest_normal"):
            return Boundary.onto_gamma(self, x)
        x = _points(x)
        y, ok = self._to_surface(x, reach=ONTO_REACH)
        return onto_or_closest(self, x, y, ok, self._phi(y), self._g(y), self._scale)

    def normal(self, y: npt.ArrayLike) -> Float:
        y = _points(y)
        g = self._g(y)
        off = np.abs(self._phi(y)) > 1e-12 * self._scale * normd(g)
        if off.any():
            g[off] = self._g(self.closest_point(y[off]))
        return unit(g)

    def lower_bound(self, x: Float) -> Float:
        return self._lower_bound_within(x, np.inf)  # an unbounded query of the seeds

    def _lower_bound_within(self, x: Float, cap: float) -> Float:
        return self._bounds_within(x, cap)[0]

    def _bounds_within(self, x: Float, cap: float) -> tuple[Float, Float | None]:
        # The nearest seed only within (cap + r)(1 + 1e-6) (r: the covering radius); beyond,
        # the lower bound (d - r)(1 - 1e-9) exceeds cap and the query returns inf. A bounded
        # query stops early for the many far points (the background's vertices away from
        # Gamma). The same distance gives the upper bound (inf beyond: no point there is
        # tested).
        if not len(x):
            return np.zeros(0), np.zeros(0)
        r = self._seeds[4]
        d = self._seeds[1].query(x, distance_upper_bound=(cap + r) * (1 + 1e-6))[0]
        return np.maximum(d - r, 0.0) * (1 - 1e-9), d + 1e-12 * self._scale

    def _upper_bound(self, x: Float) -> Float:
        d = self._seeds[1].query(x)[0] if len(x) else np.zeros(0)
        return d + 1e-12 * self._scale  # the seeds are on Gamma to rounding

    def bounding_box(self) -> Float:
        return self._box.copy()

    def sample(self, n: int) -> Float:
        """About uniformly spread points ``(n, 3)``: a stratified choice (weighted by the
        area per crossing) from the grid crossings, refined until they are at least 3 n."""
        n = int(n)
        if n <= 0:
            return np.empty((0, 3))
        m = len(self._seeds[0])
        refine = max(1, int(np.ceil(np.sqrt(3.0 * n / m))))
        pts, w, _ = self._crossings(refine)
        return _stratified(pts, w, n)

    @cached_property
    def _curvature_radius(self) -> float:
        y = self._seeds[0]
        g = self._g(y)
        gn = normd(g)
        T = plane_basis(g / gn[:, None])
        K = np.einsum("kai,kij,kbj->kab", T, self._H(y), T) / gn[:, None, None]
        kappa = np.abs(np.linalg.eigvalsh(K)).max()
        return float(1 / kappa) if kappa > 0 else np.inf

    def min_radius_of_curvature(self) -> float:
        return self._rmin if self._rmin is not None else self._curvature_radius

    def area(self) -> float:
        """Area of Gamma estimated from the crossings of the grid refined once (about 1%)."""
        return self._seeds[5]
