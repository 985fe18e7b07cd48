"""Seeded random smooth closed surfaces with independently computed data, for 3D property tests.

The 3D counterpart of ``tests/random_domains.py``. ``random_surface(seed)`` returns a
:class:`RandomSurface`: the package boundary of a solid Omega, its exact (or accurately
computed) volume, the Euler characteristic of its boundary, its smallest radius of
curvature and local feature size, and a coarse largest mesh size ``h``. The kind is
``KINDS[seed % 5]``; every parameter comes from ``numpy.random.default_rng(seed)``. Every
shape is scaled by ``s`` (log-uniform in [0.5, 2]), placed at a random centre and turned
by a uniformly random rotation; ``h = extent / ratio``, ``ratio`` log-uniform in
:data:`RATIO_RANGE` (``extent``: the largest side of the bounding box of Gamma).

* ``ellipsoid``: :class:`~dolfinx_universal.Ellipsoid`, ``a = s``, aspect ``a / c``
  log-uniform in [1, 6], ``b / c = (a / c)^U(0, 1)``.
* ``torus``: :class:`~dolfinx_universal.Torus`, ``R = s U(0.8, 1.2)``, ``r / R`` in
  [0.25, 0.55], axis uniform on the sphere.
* ``superellipsoid``: ``sum_i |p_i / a_i|^(e_i) = 1`` with exponents ``e_i`` in [2, 4] (C^2
  and convex), semi-axes ``s (1, U(0.5, 1), U(0.4, 1))``: an
  :class:`~dolfinx_universal.ImplicitSurface` in its own frame moved by a
  :class:`~dolfinx_universal.RigidMotion`.
* ``blob``: ``{sum_k w_k exp(-|p - c_k|^2 / (2 sigma_k^2)) > T}``, a unit Gaussian at the
  origin and 1-4 satellites; the satellites' weights are damped (by 0.85) until the blob is
  star-shaped about the origin with margin (``n . p >= 0.3 |p|`` on Gamma), its smallest
  radius of curvature and local feature size are at least ``0.12 s``; an
  ImplicitSurface moved by a RigidMotion.
* ``container``: :class:`~dolfinx_universal.Domain`: a sphere, a mild ellipsoid or a mild
  superellipsoid container (size ``R = s U(1.2, 1.5)``) minus 1-3 bodies of size
  ``s U(0.3, 0.5)`` (:data:`BODY_KINDS`: spheres, ellipsoids of aspect <= 1.6, tori with
  ``r / R`` in [0.4, 0.5], mild superellipsoids) placed at random without overlap (200
  tries per body; a body that finds no place is left out), every gap (body-body and
  body-container) at least ``max(0.5 h, 0.3 s)``, measured between dense samples (20 000
  on the container, 8 000 per body: an upper estimate within a few sample spacings).

Exact quantities use private copies of the shapes (:class:`_Shape`, never the package):
volumes in closed form for ellipsoids, tori and spheres, ``V = 8 abc prod_i Gamma(1 + 1 /
e_i) / Gamma(1 + sum_i 1 / e_i)`` for superellipsoids, and ``V = 1/3 int_{S^2} r(u)^3 du``
for the star-shaped blobs (Gauss-Legendre in ``cos theta`` times the trapezoidal rule in the
azimuth: spectral for a smooth radial function; :attr:`RandomSurface.volume_error` is the
difference between the 72 x 144 and 48 x 96 rules, ~1e-15 relative). Curvatures are
analytic for spheres, ellipsoids (``c^2 / a``) and tori (``min(r, R - r)``), sampled from the
analytic Hessian at 12 000 points otherwise. The local feature size (distance from Gamma to
its medial axis, both sides) equals the smallest radius of curvature for smooth convex
bodies (Blaschke's rolling theorem), is ``min(r, R - r)`` for tori, and is estimated for
blobs by the largest empty tangent balls of 2500 samples (a brute-force shrinking ball); for
containers it is also at most half of each gap. Star-shapedness of a blob is checked on
3000 rays scanned at 150 points each (one sign change of ``phi`` per ray).
:meth:`RandomSurface.signed_distance` is ``phi / |grad phi|`` of the private level sets,
exact to ``O(phi^2 kappa)``: for the checks near Gamma.

``random_surface(seed, mild=True)`` draws from mild ranges whose meshes are cheap (the test
suite's cases): ellipsoids of aspect <= 1.6, tori with ``r / R`` in [0.45, 0.55], mild
superellipsoids (semi-axes ``s (1, U(0.7, 1), U(0.7, 1))``, exponents in [2, 3]), the same
blobs, and compact containers: a sphere or mild ellipsoid container with one sphere,
ellipsoid (aspect <= 1.3) or mild superellipsoid body of size ``R_min U(0.3, 0.4)``
within ``0.06 R_min`` (per coordinate) of the container's centre (``R_min``: its smallest
semi-axis).
:attr:`RandomSurface.estimated_cells` is the size of a uniform A15 background of
``mesh_domain``'s first plan (:func:`estimate_cells`: size ``min(h, feature / 3)``, the box
padded by 5 sizes), an upper estimate of its work.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree
from scipy.special import gammaln

import dolfinx_universal as du

__all__ = [
    "KINDS",
    "RATIO_RANGE",
    "MovedSurface",
    "RandomSurface",
    "estimate_cells",
    "moved_surface",
    "random_surface",
]

Float = npt.NDArray[np.float64]

KINDS = ("ellipsoid", "torus", "superellipsoid", "blob", "container")
"""Kinds of random surfaces; seed ``s`` has kind ``KINDS[s % len(KINDS)]``."""

BODY_KINDS = ("sphere", "ellipsoid", "torus", "superellipsoid")
"""Kinds of the bodies in containers."""

RATIO_RANGE = (3.0, 8.0)
"""Range of ``extent / h`` (log-uniform): ``h`` is coarse; the feature size decides the
background size of the 3D plan (``min(h, feature / 3)``)."""

A15_TETS_PER_H3 = 11.5
"""Tetrahedra of the A15 lattice of size ``h`` per ``h^3``."""


@dataclass(frozen=True)
class RandomSurface:
    """A random smooth solid and its exact data.

    Attributes
    ----------
    seed, kind
        The seed and the kind (one of :data:`KINDS`).
    mild
        Whether drawn from the mild ranges.
    boundary
        The package boundary of Omega (a surface or a Domain of surfaces).
    exact_volume
        Volume of Omega (closed form, or quadrature for blobs).
    volume_error
        Bound on the error of ``exact_volume`` (0 for closed forms).
    euler_characteristic
        Euler characteristic of Gamma (sum over its components).
    component_euler
        Euler characteristic of each component of Gamma (container first).
    h
        Suggested largest mesh size.
    extent
        Largest side of the bounding box of Gamma.
    min_radius_of_curvature
        Smallest principal radius of curvature of Gamma.
    min_gap
        Smallest gap between two components (``inf`` for one).
    min_feature
        Smallest local feature size: ``min(lfs of the components, gaps / 2)``.
    estimated_cells
        Tetrahedra of the uniform A15 background ``mesh_domain`` is expected to build.
    description
        One line with the parameters, for failure messages.
    params
        The parameters, JSON-serialisable.
    """

    seed: int
    kind: str
    mild: bool
    boundary: du.Boundary
    exact_volume: float
    volume_error: float
    euler_characteristic: int
    component_euler: tuple[int, ...]
    h: float
    extent: float
    min_radius_of_curvature: float
    min_gap: float
    min_feature: float
    estimated_cells: float
    description: str
    params: dict[str, Any] = field(default_factory=dict)
    shapes: tuple[Any, ...] = field(default=(), repr=False)
    """Private copies of the components (``_Shape``), container first."""
    is_body: tuple[bool, ...] = field(default=(), repr=False)

    @property
    def label(self) -> str:
        """``seed=S kind=K`` (and ``mild``), to reproduce a case."""
        return f"seed={self.seed} kind={self.kind}" + (" mild" if self.mild else "")

    @property
    def n_components(self) -> int:
        """Number of closed surfaces of Gamma."""
        return len(self.shapes)

    @property
    def max_curvature(self) -> float:
        """Largest principal curvature ``1 / min_radius_of_curvature``."""
        return 1.0 / self.min_radius_of_curvature

    def _nearest(self, x: Float) -> tuple[Float, Float]:
        """Signed distance estimates of ``x (n, 3)`` to each component ``(k, n)``, oriented
        for Omega (negative in Omega), and the outward normals ``(k, n, 3)``."""
        ds, ns = [], []
        for shape, body in zip(self.shapes, self.is_body):
            phi, g = shape.phi(x), shape.grad(x)
            gn = np.linalg.norm(g, axis=1)
            s = -1.0 if body else 1.0
            ds.append(s * phi / gn)
            ns.append(s * g / gn[:, None])
        return np.array(ds), np.array(ns)

    def signed_distance(self, x: npt.ArrayLike) -> Float:
        """``phi / |grad phi|`` of the nearest component ``(n,)``, negative in Omega.

        The private level sets, not the package: exact to ``O(phi^2 kappa)`` near Gamma
        (the distance itself where ``phi`` is one, spheres and tori).
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        d, _ = self._nearest(x)
        k = np.argmin(np.abs(d), axis=0)
        return d[k, np.arange(len(x))]

    def normal(self, x: npt.ArrayLike) -> Float:
        """Unit normals ``grad phi / |grad phi|`` of the nearest component, out of Omega."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        d, n = self._nearest(x)
        k = np.argmin(np.abs(d), axis=0)
        return n[k, np.arange(len(x))]


@dataclass(frozen=True)
class MovedSurface(RandomSurface):
    """A :class:`RandomSurface` under the rigid motion ``y -> c + R (y - c) + t``.

    Volumes, curvatures, feature sizes and Euler characteristics are those of the surface;
    :attr:`boundary` is the package's :class:`~dolfinx_universal.RigidMotion` of each
    component, and :meth:`signed_distance` and :meth:`normal` evaluate the private level
    sets at the points moved back (``c + R^T (x - c - t)``), normals turned by ``R``.
    """

    rotation: Float = field(default_factory=lambda: np.eye(3), repr=False)
    center: Float = field(default_factory=lambda: np.zeros(3), repr=False)
    translation: Float = field(default_factory=lambda: np.zeros(3), repr=False)

    def _back(self, x: npt.ArrayLike) -> Float:
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        return self.center + (x - self.center - self.translation) @ self.rotation

    def signed_distance(self, x: npt.ArrayLike) -> Float:
        return super().signed_distance(self._back(x))

    def normal(self, x: npt.ArrayLike) -> Float:
        return super().normal(self._back(x)) @ self.rotation.T


def moved_surface(
    d: RandomSurface, rotation: npt.ArrayLike, center: npt.ArrayLike, translation: npt.ArrayLike
) -> MovedSurface:
    """``d`` turned by the rotation matrix ``rotation`` about ``center``, then translated."""
    R = np.asarray(rotation, dtype=np.float64)
    c = np.asarray(center, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)

    def move(b: du.Boundary) -> du.Boundary:
        return du.RigidMotion(b, center=c, translation=t, rotation=R)

    b = d.boundary
    if isinstance(b, du.Domain):
        boundary: du.Boundary = du.Domain(
            move(b.container) if b.container is not None else None, [move(x) for x in b.bodies]
        )
    else:
        boundary = move(b)
    base = {f: getattr(d, f) for f in RandomSurface.__dataclass_fields__}
    base["boundary"] = boundary
    return MovedSurface(**base, rotation=R, center=c, translation=t)


# ----------------------------------------------------------------------------- helpers
def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _rotation(rng: np.random.Generator) -> Float:
    """A uniformly random rotation matrix (unit quaternion from a Gaussian)."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _fibonacci(n: int) -> Float:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(np.maximum(1 - z * z, 0.0))
    a = np.pi * (3 - np.sqrt(5.0)) * i
    return np.column_stack([r * np.cos(a), r * np.sin(a), z])


def _sphere_rule(n: int) -> tuple[Float, Float]:
    """Directions ``(2 n^2, 3)`` and weights of the product rule on the unit sphere:
    Gauss-Legendre in ``cos theta`` (``n`` nodes) times the trapezoidal rule in the azimuth
    (``2 n`` nodes); exact for spherical harmonics of degree < ``2 n``."""
    z, wz = np.polynomial.legendre.leggauss(n)
    a = (np.arange(2 * n) + 0.5) * (np.pi / n)
    Z, A = np.meshgrid(z, a, indexing="ij")
    r = np.sqrt(1 - Z * Z)
    u = np.column_stack([(r * np.cos(A)).ravel(), (r * np.sin(A)).ravel(), Z.ravel()])
    w = np.repeat(wz, 2 * n) * (np.pi / n)
    return u, w


def _curvatures(g: Float, H: Float) -> Float:
    """Principal curvatures ``(n, 2)`` of the level set through points with gradients
    ``g (n, 3)`` and Hessians ``H (n, 3, 3)`` (positive: convex towards ``-grad``)."""
    n = g / np.linalg.norm(g, axis=1)[:, None]
    P = np.eye(3) - n[:, :, None] * n[:, None, :]
    K = P @ H @ P / np.linalg.norm(g, axis=1)[:, None, None]
    ev = np.linalg.eigvalsh(0.5 * (K + K.transpose(0, 2, 1)))
    # one eigenvalue (along n) is zero: drop the one nearest to zero in the normal direction
    nn = np.einsum("ki,kij,kj->k", n, K, n)
    drop = np.argmin(np.abs(ev - nn[:, None]), axis=1)
    keep = np.ones_like(ev, dtype=bool)
    keep[np.arange(len(ev)), drop] = False
    return ev[keep].reshape(-1, 2)


def _tangent_ball_radii(p: Float, n: Float) -> Float:
    """Radius of the largest ball tangent at each sample ``p (m, 3)`` (outward normals
    ``n``) on either side that contains no other sample: ``min_q |p - q|^2 / (2 |(q - p).n|)``
    over the samples ``q`` on that side (brute force, chunked)."""
    out = np.full(len(p), np.inf)
    for s in range(0, len(p), 256):
        d = p[None, :, :] - p[s : s + 256, None, :]  # q - p
        dn = np.einsum("kqi,ki->kq", d, n[s : s + 256])
        d2 = np.einsum("kqi,kqi->kq", d, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(np.abs(dn) > 1e-14 * np.sqrt(d2), d2 / (2 * np.abs(dn)), np.inf)
        out[s : s + 256] = r.min(axis=1)
    return out


# ----------------------------------------------------------------------------- exact shapes
class _Shape:
    """A closed surface ``{phi = 0}`` (``phi < 0`` inside) in a frame ``x = c + Q p``."""

    name: str
    euler: int
    center: Float
    Q: Float
    volume: float
    volume_error: float = 0.0
    rho: float  # smallest principal radius of curvature
    lfs: float  # smallest local feature size (both sides)

    def _local(self, x: Float) -> Float:
        return (np.asarray(x, dtype=np.float64).reshape(-1, 3) - self.center) @ self.Q

    def phi_local(self, p: Float) -> Float:
        raise NotImplementedError

    def grad_local(self, p: Float) -> Float:
        raise NotImplementedError

    def hess_local(self, p: Float) -> Float:
        raise NotImplementedError

    def phi(self, x: Float) -> Float:
        return self.phi_local(self._local(x))

    def grad(self, x: Float) -> Float:
        return self.grad_local(self._local(x)) @ self.Q.T

    def samples_local(self, n: int) -> Float:
        raise NotImplementedError

    def samples(self, n: int) -> Float:
        """About ``n`` points of the surface (world frame), well spread."""
        return self.center + self.samples_local(n) @ self.Q.T

    def boundary(self) -> du.Boundary:
        raise NotImplementedError

    def describe(self) -> str:
        raise NotImplementedError

    def params(self) -> dict[str, Any]:
        return {"name": self.name, "center": self.center.tolist(), "Q": self.Q.tolist()}

    def bbox(self) -> Float:
        s = self.samples(20000)
        pad = 0.01 * float((s.max(0) - s.min(0)).max())
        return np.array([s.min(0) - pad, s.max(0) + pad])


class _SphereShape(_Shape):
    name, euler = "sphere", 2

    def __init__(self, center: Float, radius: float) -> None:
        self.center, self.Q, self.r = np.asarray(center, float), np.eye(3), float(radius)
        self.volume = 4 / 3 * np.pi * self.r**3
        self.rho = self.lfs = self.r

    def phi_local(self, p: Float) -> Float:
        return np.linalg.norm(p, axis=1) - self.r

    def grad_local(self, p: Float) -> Float:
        return p / np.linalg.norm(p, axis=1)[:, None]

    def samples_local(self, n: int) -> Float:
        return self.r * _fibonacci(n)

    def boundary(self) -> du.Boundary:
        return du.Sphere(self.center, self.r)

    def describe(self) -> str:
        return f"sphere r={self.r:.4g}"

    def params(self) -> dict[str, Any]:
        return {**super().params(), "radius": self.r}


class _EllipsoidShape(_Shape):
    name, euler = "ellipsoid", 2

    def __init__(self, center: Float, axes: Float, Q: Float) -> None:
        self.center, self.e, self.Q = np.asarray(center, float), np.asarray(axes, float), Q
        self.volume = 4 / 3 * np.pi * float(np.prod(self.e))
        self.rho = self.lfs = float(self.e.min() ** 2 / self.e.max())

    def phi_local(self, p: Float) -> Float:
        return ((p / self.e) ** 2).sum(axis=1) - 1

    def grad_local(self, p: Float) -> Float:
        return 2 * p / self.e**2

    def samples_local(self, n: int) -> Float:
        stretch = self.e.max() / self.e.min()
        return self.e * _fibonacci(int(n * min(stretch, 6)))

    def boundary(self) -> du.Boundary:
        return du.Ellipsoid(self.center, self.e, rotation=self.Q)

    def describe(self) -> str:
        a, b, c = self.e
        return f"ellipsoid ({a:.4g}, {b:.4g}, {c:.4g}) aspect {a / c:.2f}"

    def params(self) -> dict[str, Any]:
        return {**super().params(), "semi_axes": self.e.tolist()}


class _TorusShape(_Shape):
    """Axis ``Q[:, 2]``; ``phi`` is the signed distance itself."""

    name, euler = "torus", 0

    def __init__(self, center: Float, R: float, r: float, Q: Float) -> None:
        self.center, self.R, self.r, self.Q = np.asarray(center, float), float(R), float(r), Q
        self.volume = 2 * np.pi**2 * self.R * self.r**2
        self.rho = self.lfs = min(self.r, self.R - self.r)

    def _parts(self, p: Float) -> tuple[Float, Float, Float]:
        rho = np.hypot(p[:, 0], p[:, 1])
        return rho, np.hypot(rho - self.R, p[:, 2]), p[:, 2]

    def phi_local(self, p: Float) -> Float:
        return self._parts(p)[1] - self.r

    def grad_local(self, p: Float) -> Float:
        rho, D, z = self._parts(p)
        w = p[:, :2] / rho[:, None]
        return np.column_stack([((rho - self.R) / D)[:, None] * w, z / D])

    def samples_local(self, n: int) -> Float:
        m = max(8, int(np.sqrt(n * self.r / self.R)))
        k = max(8, n // m)
        v, u = np.meshgrid(2 * np.pi * np.arange(m) / m, 2 * np.pi * np.arange(k) / k)
        rad = self.R + self.r * np.cos(v)
        return np.column_stack(
            [(rad * np.cos(u)).ravel(), (rad * np.sin(u)).ravel(), (self.r * np.sin(v)).ravel()]
        )

    def boundary(self) -> du.Boundary:
        return du.Torus(self.center, self.R, self.r, axis=self.Q[:, 2])

    def describe(self) -> str:
        ax = self.Q[:, 2]
        return f"torus R={self.R:.4g} r={self.r:.4g} axis ({ax[0]:.3f}, {ax[1]:.3f}, {ax[2]:.3f})"

    def params(self) -> dict[str, Any]:
        return {**super().params(), "major": self.R, "minor": self.r}


class _RadialShape(_Shape):
    """A star-shaped implicit surface about the origin of its frame, meshed by the package
    as an ImplicitSurface (with the analytic Hessian) moved by a RigidMotion."""

    t_max: float

    def hess_local(self, p: Float) -> Float:
        raise NotImplementedError

    def radii(self, u: Float, steps: int = 0) -> tuple[Float, Float]:
        """Radius ``r(u)`` of the surface along unit directions ``u (m, 3)`` and the number
        of sign changes of ``phi`` along each ray (scanned on ``steps`` points when
        ``steps > 0``, else assumed 1: a monotone ``phi``)."""
        m = len(u)
        lo, hi = np.zeros(m), np.full(m, self.t_max)
        count = np.ones(m)
        if steps:  # phi(0) < 0: count the sign changes on the grid, bracket the first one
            t = np.linspace(0, self.t_max, steps + 1)[1:]
            f = self.phi_local((t[None, :, None] * u[:, None, :]).reshape(-1, 3)).reshape(m, -1)
            pos = f > 0
            count = pos[:, 0] + (pos[:, 1:] != pos[:, :-1]).sum(axis=1)
            first = np.argmax(pos, axis=1)
            lo = np.where(first > 0, t[np.maximum(first - 1, 0)], 0.0)
            hi = t[first]
        # Newton's method on t -> phi(t u), kept in the bracket (bisection where it leaves
        # it), to rounding
        t = 0.5 * (lo + hi)
        act = np.arange(m)
        for _ in range(100):
            f, df = self.phi_slope(t[act, None] * u[act], u[act])
            inside = f < 0
            lo[act] = np.where(inside, t[act], lo[act])
            hi[act] = np.where(inside, hi[act], t[act])
            with np.errstate(divide="ignore", invalid="ignore"):
                tn = t[act] - f / df
            mid = 0.5 * (lo[act] + hi[act])
            tn = np.where((tn > lo[act]) & (tn < hi[act]), tn, mid)
            done = (np.abs(tn - t[act]) <= 1e-15 * self.t_max) | (f == 0)
            t[act] = np.where(f == 0, t[act], tn)
            act = act[~done & (hi[act] - lo[act] > 1e-15 * self.t_max)]
            if not act.size:
                break
        return t, count

    def phi_slope(self, p: Float, u: Float) -> tuple[Float, Float]:
        """``phi`` at ``p (m, 3)`` and its derivative along ``u (m, 3)``."""
        return self.phi_local(p), (self.grad_local(p) * u).sum(axis=1)

    def samples_local(self, n: int) -> Float:
        key = ("samples", n, self.center.tobytes())
        if getattr(self, "_cache_key", None) != key:  # bbox() and boundary() share them
            u = _fibonacci(n)
            self._cache_key, self._cache = key, self.radii(u)[0][:, None] * u
        return self._cache

    def quadrature_volume(self) -> tuple[float, float]:
        """``1/3 int r(u)^3 du`` by the 72 x 144 product rule, and its difference from the
        48 x 96 rule (the error estimate)."""
        vols = []
        for n in (48, 72):
            u, w = _sphere_rule(n)
            vols.append(float(w @ self.radii(u)[0] ** 3) / 3)
        return vols[1], abs(vols[1] - vols[0])

    def curvature_radius(self, n: int = 12000) -> float:
        """Smallest principal radius of curvature at ``n`` samples."""
        u = _fibonacci(n)
        y = self.radii(u)[0][:, None] * u
        return float(1 / np.abs(_curvatures(self.grad_local(y), self.hess_local(y))).max())

    def feature_size(self, n: int = 2500) -> float:
        """Smallest radius of the empty tangent balls of ``n`` samples (both sides)."""
        u = _fibonacci(n)
        y = self.radii(u)[0][:, None] * u
        g = self.grad_local(y)
        return float(_tangent_ball_radii(y, g / np.linalg.norm(g, axis=1)[:, None]).min())

    def boundary(self) -> du.Boundary:
        s = self.samples_local(20000)
        pad = 0.02 * float((s.max(0) - s.min(0)).max())
        base = du.ImplicitSurface(
            self.phi_local,
            self.grad_local,
            [s.min(0) - pad, s.max(0) + pad],
            genus=0,
            min_radius_of_curvature=self.rho,
            hess=self.hess_local,
        )
        return du.RigidMotion(base, center=np.zeros(3), translation=self.center, rotation=self.Q)


class _SuperellipsoidShape(_RadialShape):
    name, euler = "superellipsoid", 2

    def __init__(self, center: Float, axes: Float, exps: Float, Q: Float) -> None:
        self.center, self.Q = np.asarray(center, float), Q
        self.a, self.e = np.asarray(axes, float), np.asarray(exps, float)
        self.t_max = 1.01 * float(np.linalg.norm(self.a))  # inside the box [-a, a]
        inv = 1 / self.e
        self.volume = float(
            8 * np.prod(self.a) * np.exp(gammaln(1 + inv).sum() - gammaln(1 + inv.sum()))
        )
        self.rho = self.lfs = self.curvature_radius()  # convex: lfs = rho (Blaschke)

    def phi_local(self, p: Float) -> Float:
        return (np.abs(p / self.a) ** self.e).sum(axis=1) - 1

    def grad_local(self, p: Float) -> Float:
        t = p / self.a
        return self.e * np.abs(t) ** (self.e - 1) * np.sign(t) / self.a

    def hess_local(self, p: Float) -> Float:
        t = np.abs(p / self.a)
        d = self.e * (self.e - 1) * t ** (self.e - 2) / self.a**2
        return d[:, :, None] * np.eye(3)

    def describe(self) -> str:
        a, e = self.a, self.e
        return (
            f"superellipsoid axes ({a[0]:.4g}, {a[1]:.4g}, {a[2]:.4g}) exponents "
            f"({e[0]:.2f}, {e[1]:.2f}, {e[2]:.2f})"
        )

    def params(self) -> dict[str, Any]:
        return {**super().params(), "semi_axes": self.a.tolist(), "exponents": self.e.tolist()}


class _BlobShape(_RadialShape):
    name, euler = "blob", 2

    def __init__(self, center: Float, c: Float, sigma: Float, w: Float, T: float, Q: Float):
        self.center, self.Q = np.asarray(center, float), Q
        self.c, self.sigma, self.w, self.T = c, sigma, w, float(T)
        # beyond |p| = t_max every Gaussian is below T / (2 k) (and phi > 0)
        k = len(w)
        reach = np.linalg.norm(c, axis=1) + sigma * np.sqrt(2 * np.log(2 * k * w.max() / T))
        self.t_max = float(reach.max())

    def _terms(self, p: Float) -> tuple[Float, Float]:
        d = p[:, None, :] - self.c[None]
        e = self.w * np.exp(np.einsum("nki,nki->nk", d, d) / (-2 * self.sigma**2))
        return d, e

    def phi_local(self, p: Float) -> Float:
        return self.T - self._terms(p)[1].sum(axis=1)

    def phi_slope(self, p: Float, u: Float) -> tuple[Float, Float]:
        d, e = self._terms(p)
        g = np.einsum("nk,nki->ni", e / self.sigma**2, d)
        return self.T - e.sum(axis=1), (g * u).sum(axis=1)

    def grad_local(self, p: Float) -> Float:
        d, e = self._terms(p)
        return np.einsum("nk,nki->ni", e / self.sigma**2, d)

    def hess_local(self, p: Float) -> Float:
        d, e = self._terms(p)
        s2 = self.sigma**2
        outer = np.einsum("nk,nki,nkj->nij", e / s2**2, d, d)
        return (e / s2).sum(axis=1)[:, None, None] * np.eye(3) - outer

    def star_margin(self, n: int = 3000) -> tuple[bool, float]:
        """Whether every ray from the origin (``n`` of them, scanned on 150 points) crosses
        Gamma once, and the smallest ``n . u`` at the crossings."""
        u = _fibonacci(n)
        r, count = self.radii(u, steps=150)
        if (count != 1).any():
            return False, -1.0
        g = self.grad_local(r[:, None] * u)
        cos = (g * u).sum(axis=1) / np.linalg.norm(g, axis=1)
        return True, float(cos.min())

    def describe(self) -> str:
        sat = ", ".join(
            f"w={w:.2f} sigma={s:.3g} at |c|={np.linalg.norm(c):.3g}"
            for c, s, w in zip(self.c[1:], self.sigma[1:], self.w[1:])
        )
        return f"blob T={self.T:.3f}, sigma0={self.sigma[0]:.3g}, satellites: {sat}"

    def params(self) -> dict[str, Any]:
        return {
            **super().params(),
            "centres": self.c.tolist(),
            "sigma": self.sigma.tolist(),
            "weights": self.w.tolist(),
            "T": self.T,
        }


# ----------------------------------------------------------------------------- kinds
def _centre(rng: np.random.Generator, scale: float) -> Float:
    return rng.uniform(-0.3, 0.3, 3) * scale


def _ellipsoid(rng: np.random.Generator, scale: float, max_aspect: float = 6.0) -> _Shape:
    aspect = _log_uniform(rng, 1.0, max_aspect)
    c = scale / aspect
    b = c * aspect ** rng.uniform(0, 1)
    return _EllipsoidShape(_centre(rng, scale), np.array([scale, b, c]), _rotation(rng))


def _torus(rng: np.random.Generator, scale: float, mild: bool = False) -> _Shape:
    R = scale * rng.uniform(0.8, 1.2)
    r = R * (rng.uniform(0.45, 0.55) if mild else rng.uniform(0.25, 0.55))
    return _TorusShape(_centre(rng, scale), R, r, _rotation(rng))


def _superellipsoid(rng: np.random.Generator, scale: float, mild: bool = False) -> _Shape:
    axes = scale * np.array([1.0, rng.uniform(0.5, 1.0), rng.uniform(0.4, 1.0)])
    if mild:
        axes = scale * np.array([1.0, rng.uniform(0.7, 1.0), rng.uniform(0.7, 1.0)])
    exps = rng.uniform(2.0, 3.0 if mild else 4.0, 3)
    return _SuperellipsoidShape(_centre(rng, scale), axes, exps, _rotation(rng))


def _blob(rng: np.random.Generator, scale: float) -> _Shape:
    k = int(rng.integers(1, 5))
    dirs = rng.normal(size=(k, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    c = np.vstack([np.zeros(3), dirs * rng.uniform(0.5, 1.0, k)[:, None]]) * scale
    sigma = np.concatenate([[1.0], rng.uniform(0.45, 0.8, k)]) * scale
    w = np.concatenate([[1.0], rng.uniform(0.4, 1.0, k)])
    T = rng.uniform(0.35, 0.55)
    centre, Q = _centre(rng, scale), _rotation(rng)
    for _ in range(60):
        blob = _BlobShape(centre, c, sigma, w, T, Q)
        star, margin = blob.star_margin()
        if star and margin >= 0.3:
            blob.rho = blob.curvature_radius()
            if blob.rho >= 0.12 * scale:
                blob.lfs = min(blob.rho, blob.feature_size())
                if blob.lfs >= 0.12 * scale:
                    blob.volume, blob.volume_error = blob.quadrature_volume()
                    return blob
        w = np.concatenate([[1.0], 0.85 * w[1:]])
    raise RuntimeError("blob: no admissible damping")  # w -> 0 is a sphere: unreachable


def _body(
    rng: np.random.Generator, size: float, kinds: tuple[str, ...], max_aspect: float = 1.6
) -> _Shape:
    """A body of largest semi-axis (or major radius) ``size`` centred at the origin (moved
    into place by the caller)."""
    kind = str(rng.choice(kinds))
    if kind == "sphere":
        return _SphereShape(np.zeros(3), size)
    if kind == "ellipsoid":
        e = _ellipsoid(rng, size, max_aspect=max_aspect)
        e.center = np.zeros(3)
        return e
    if kind == "torus":
        return _TorusShape(np.zeros(3), size, size * rng.uniform(0.4, 0.5), _rotation(rng))
    s = _superellipsoid(rng, size, mild=True)
    s.center = np.zeros(3)
    return s


def _cloud_gap(p: Float, tree: cKDTree, bound: float = np.inf) -> float:
    """Smallest distance from the points ``p`` to the tree's (``inf`` beyond ``bound``)."""
    return float(tree.query(p, distance_upper_bound=bound)[0].min())


@dataclass
class _Parts:
    shapes: list[_Shape]
    is_body: list[bool]
    boundary: du.Boundary
    description: str
    params: dict[str, Any]
    gaps: list[float] = field(default_factory=list)


def _single(shape: _Shape) -> _Parts:
    return _Parts([shape], [False], shape.boundary(), shape.describe(), shape.params())


def _container(rng: np.random.Generator, scale: float, ratio: float, mild: bool) -> _Parts:
    which = str(rng.choice(["sphere", "ellipsoid"] if mild else ["sphere", "ellipsoid",
                                                                   "superellipsoid"]))  # fmt: skip
    R = scale * rng.uniform(1.2, 1.5)
    R_in = R  # the smallest semi-axis
    if which == "sphere":
        cont: _Shape = _SphereShape(_centre(rng, scale), R)
    elif which == "ellipsoid":
        axes = R * np.array([1.0, *rng.uniform(0.75, 1.0, 2)])
        cont = _EllipsoidShape(_centre(rng, scale), axes, _rotation(rng))
        R_in = float(axes.min())
    else:
        cont = _superellipsoid(rng, R, mild=True)
    cs = cont.samples(20000)
    box = np.array([cs.min(0), cs.max(0)])
    h = float((box[1] - box[0]).max()) / ratio
    gmin = max(0.5 * h, 0.3 * scale)
    bodies: list[_Shape] = []
    samples: list[Float] = []
    trees: list[cKDTree] = []
    for _ in range(1 if mild else int(rng.integers(1, 4))):
        if mild:  # one round body near the centre: the cheapest containers
            kinds = ("sphere", "ellipsoid", "superellipsoid")
            body = _body(rng, R_in * rng.uniform(0.3, 0.4), kinds, max_aspect=1.3)
        else:
            body = _body(rng, scale * rng.uniform(0.3, 0.5), BODY_KINDS)
        bs0 = body.samples(8000)
        for _attempt in range(200):
            if mild:
                centre = cont.center + R_in * rng.uniform(-0.06, 0.06, 3)
            else:
                centre = box[0] + (box[1] - box[0]) * rng.random(3)
            bs = bs0 + centre
            if (cont.phi(bs) >= 0).any():
                continue
            if any((b.phi(bs[:1]) < 0).any() or (b.phi(centre[None]) < 0).any() for b in bodies):
                continue
            if any((body.phi(s[:1] - centre) < 0).any() for s in samples):
                continue
            # query the body's tree (from inside a sphere, every point of the
            # container's samples is about equally far: a k-d tree query is then slow)
            tree = cKDTree(bs)
            if min(_cloud_gap(s, tree, 1.05 * gmin) for s in [cs, *samples]) < 1.05 * gmin:
                continue
            body.center = centre
            bodies.append(body)
            samples.append(bs)
            trees.append(tree)
            break
    if not bodies:
        return _container(rng, scale, ratio, mild)
    gaps = [_cloud_gap(s, trees[i]) for i in range(len(bodies)) for s in [cs, *samples[:i]]]
    boundary = du.Domain(cont.boundary(), [b.boundary() for b in bodies])
    desc = (
        f"{cont.describe()} minus {len(bodies)} bodies ("
        + "; ".join(b.describe() for b in bodies)
        + f"), smallest gap {min(gaps):.4g} = {min(gaps) / h:.2f} h"
    )
    params = {"container": cont.params(), "bodies": [b.params() for b in bodies], "h": h}
    return _Parts([cont, *bodies], [False] + [True] * len(bodies), boundary, desc, params, gaps)


def estimate_cells(boundary: du.Boundary, h: float, feature: float) -> float:
    """Tetrahedra of ``mesh_domain``'s uniform A15 background: size ``min(h, feature / 3)``
    over the bounding box of Gamma padded by 5 sizes (``(R_r / h + 2) h``)."""
    size = min(h, feature / 3)
    b = np.asarray(boundary.bounding_box(), dtype=np.float64)
    return float(A15_TETS_PER_H3 * np.prod(b[1] - b[0] + 10 * size) / size**3)


def _draw(rng: np.random.Generator, kind: str, mild: bool) -> tuple[_Parts, float, float]:
    scale = _log_uniform(rng, 0.5, 2.0)
    ratio = _log_uniform(rng, *RATIO_RANGE)
    if kind == "container":
        return _container(rng, scale, ratio, mild), scale, ratio
    if kind == "ellipsoid":
        shape = _ellipsoid(rng, scale, max_aspect=1.6 if mild else 6.0)
    elif kind == "torus":
        shape = _torus(rng, scale, mild)
    elif kind == "superellipsoid":
        shape = _superellipsoid(rng, scale, mild)
    else:
        shape = _blob(rng, scale)
    return _single(shape), scale, ratio


def random_surface(seed: int, mild: bool = False) -> RandomSurface:
    """The random solid of ``seed`` (see the module docstring).

    Parameters
    ----------
    seed
        Seed of ``numpy.random.default_rng``; the kind is ``KINDS[seed % 5]``.
    mild
        Draw from the mild ranges (cheap meshes, for the test suite; see the module
        docstring).
    """
    kind = KINDS[seed % len(KINDS)]
    rng = np.random.default_rng(seed)
    parts, scale, ratio = _draw(rng, kind, mild)
    shapes = parts.shapes
    lo, hi = shapes[0].bbox()
    extent = float((hi - lo).max())
    h = float(parts.params.get("h", extent / ratio))
    rho = min(s.rho for s in shapes)
    gap = min(parts.gaps) if parts.gaps else np.inf
    feature = min(min(s.lfs for s in shapes), gap / 2)
    est = estimate_cells(parts.boundary, h, feature)
    volume = shapes[0].volume - sum(s.volume for s in shapes[1:])
    params = {"scale": scale, "ratio": ratio, "mild": mild, **parts.params}
    return RandomSurface(
        seed=seed,
        kind=kind,
        mild=mild,
        boundary=parts.boundary,
        exact_volume=float(volume),
        volume_error=float(sum(s.volume_error for s in shapes)),
        euler_characteristic=int(sum(s.euler for s in shapes)),
        component_euler=tuple(int(s.euler) for s in shapes),
        h=h,
        extent=extent,
        min_radius_of_curvature=float(rho),
        min_gap=float(gap),
        min_feature=float(feature),
        estimated_cells=est,
        description=f"{parts.description}; h={h:.4g} (extent/{ratio:.2f}), "
        f"feature {feature:.4g}, ~{est:.3g} background tets",
        params=params,
        shapes=tuple(shapes),
        is_body=tuple(parts.is_body),
    )
