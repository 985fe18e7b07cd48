"""Seeded random smooth domains with independently computed areas, for property tests.

``random_domain(seed)`` returns a :class:`RandomDomain`: a boundary built from the package's
classes, the exact area of the domain from its own parametrisation (never through the
package), and a suggested *largest* mesh size ``h`` that is coarse compared with the
domain's features, so that a mesher must grade itself. The kind is ``KINDS[seed % 5]``;
every parameter comes from ``numpy.random.default_rng(seed)``. Every domain is scaled by
``s`` (log-uniform in [0.5, 2]) and ``h = diameter / ratio`` with ``ratio`` log-uniform in
:data:`RATIO_RANGE`.

* ``spline``: :class:`~dolfinx_universal.PeriodicSpline` through 6-14 points at jittered
  equispaced angles (jitter 0.3 spacing) and radii ``s U(0.5, 1.3)`` about a random centre;
  redrawn until the spline is simple, has an inflection and curvature at most ``25 / s``.
* ``polar``: :class:`~dolfinx_universal.PolarCurve`, ``r = s (1 + sum_k a_k cos(k t +
  phase_k))`` with 1-3 distinct ``k`` in 2..7, analytic ``dr``, ``d2r``; the amplitudes are
  damped until ``r >= 0.3 s`` and the radius of curvature is at least ``0.04 s``.
* ``ellipse``: :class:`~dolfinx_universal.Ellipse`, ``a = s U(0.7, 1.3)``, aspect ratio
  log-uniform in [1, 8], random rotation and centre.
* ``multibody``: :class:`~dolfinx_universal.Domain`: a circle (``R = s U(1.3, 1.7)``) or an
  ellipse container minus 1-3 bodies (circles, ellipses, polar blobs; size ``s U(0.1, 0.4)``)
  placed at random without overlap, gaps at least ``0.5 h``; half of them are then pushed
  towards their nearest neighbour (container or body) to a gap ``U(0.5, 1) h``.
* ``neck``: a dumbbell ``(X cos t, sin t (w/2 + A cos^p t (1 + beta cos t)))`` (``p`` 2 or 4)
  interpolated by a :class:`~dolfinx_universal.PeriodicSpline` through 36-48 points and
  moved by a :class:`~dolfinx_universal.RigidMotion`; neck width ``w = U(0.3, 1) h``.

Exact quantities use a private copy of each curve (:class:`_Curve`): Green's theorem
``A = 1/2 oint (x y' - y x') dt`` by the trapezoidal rule for polar curves (``r^2`` is a
trigonometric polynomial: exact), in closed form for circles and ellipses, and by
Gauss-Legendre quadrature on each interval of the cubic splines (a degree-5 polynomial
there: exact). Splines are rebuilt with SciPy as the package defines them (periodic,
chord-length knots); ``tests/test_mesh_checks.py`` compares the areas with polygons through
the package's curves.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicSpline
from scipy.spatial import ConvexHull, cKDTree

import dolfinx_universal as du

__all__ = ["KINDS", "RandomDomain", "random_domain"]

Float = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

KINDS = ("spline", "polar", "ellipse", "multibody", "neck")
"""Kinds of random domains; seed ``s`` has kind ``KINDS[s % len(KINDS)]``."""

RATIO_RANGE = (8.0, 40.0)
"""Range of ``extent / h`` (log-uniform, ``extent`` the diameter of Gamma): ``h`` is coarse
compared with the features."""


@dataclass(frozen=True)
class RandomDomain:
    """A random smooth domain and its exact data.

    Attributes
    ----------
    seed, kind
        The seed and the kind (one of :data:`KINDS`).
    boundary
        The package boundary of Omega.
    exact_area
        Area of Omega from its exact parametrisation.
    h
        Suggested largest mesh size (``extent / h`` in :data:`RATIO_RANGE`).
    n_curves
        Number of closed curves of Gamma.
    n_pieces
        Number of connected components of Omega.
    length
        Length of Gamma (exact to quadrature accuracy).
    extent
        Diameter of Gamma (largest distance between two of its points).
    min_radius_of_curvature
        Smallest radius of curvature of Gamma (sampled on the exact parametrisation).
    min_gap
        Smallest gap between two curves, or neck width (``inf`` without either).
    min_feature
        ``min(min_radius_of_curvature, min_gap)``.
    description
        One line with the parameters, for failure messages.
    params
        The parameters, JSON-serialisable.
    """

    seed: int
    kind: str
    boundary: du.Boundary
    exact_area: float
    h: float
    n_curves: int
    n_pieces: int
    length: float
    extent: float
    min_radius_of_curvature: float
    min_gap: float
    min_feature: float
    description: str
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        """``seed=S kind=K``, to reproduce a case."""
        return f"seed={self.seed} kind={self.kind}"

    def uniform_size(self) -> float:
        """A uniform mesh size at which ``conform`` resolves every feature (for baselines).

        A third of the smallest radius of curvature, an eighth of the smallest gap or neck
        (so that the relaxation bands ``R_r = 3h`` of the two sides do not meet), at most
        ``h``.
        """
        return float(min(self.h, self.min_radius_of_curvature / 3, self.min_gap / 8))

    def box(self, pad: float) -> Float:
        """Bounding box of Gamma enlarged by ``pad`` on every side, ``[[x0, y0], [x1, y1]]``."""
        b = np.asarray(self.boundary.bounding_box(), dtype=np.float64)
        return np.array([b[0] - pad, b[1] + pad])


# ----------------------------------------------------------------------------- exact curves
def _cross(u: Float, v: Float) -> Float:
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def _rotation(angle: float) -> Float:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


class _Curve:
    """A closed curve ``c(t)``, ``t`` in ``[0, period)``, with exact derivatives."""

    period: float
    center: Float

    def point(self, t: Float) -> Float:
        raise NotImplementedError

    def d1(self, t: Float) -> Float:
        raise NotImplementedError

    def d2(self, t: Float) -> Float:
        raise NotImplementedError

    def inside(self, x: Float) -> Bool:
        """Exact test of points ``(n, 2)`` strictly inside the curve."""
        raise NotImplementedError

    def boundary(self) -> du.Boundary:
        raise NotImplementedError

    def quadrature(self) -> tuple[Float, Float]:
        """Nodes and weights of a rule that integrates the area integrand exactly."""
        n = 2048
        return np.arange(n) * (self.period / n), np.full(n, self.period / n)

    def dense(self, n: int) -> Float:
        """Parameters of ``n`` points spread along the curve."""
        return np.arange(n) * (self.period / n)

    def area(self) -> float:
        t, w = self.quadrature()
        return abs(0.5 * float(w @ _cross(self.point(t), self.d1(t))))

    def length(self) -> float:
        t, w = self.quadrature()
        return float(w @ np.linalg.norm(self.d1(t), axis=1))

    def curvature(self, n: int = 16384) -> Float:
        """Signed curvature at ``n`` points spread along the curve (positive: convex)."""
        t = self.dense(n)
        d1 = self.d1(t)
        return _cross(d1, self.d2(t)) / np.linalg.norm(d1, axis=1) ** 3

    def min_radius_of_curvature(self, n: int = 16384) -> float:
        return float(1.0 / np.abs(self.curvature(n)).max())

    def samples(self, spacing: float) -> Float:
        """Points along the curve at most about ``spacing`` apart."""
        n = max(256, int(np.ceil(1.2 * self.length() / spacing)))
        return self.point(self.dense(n))


class _Circle(_Curve):
    def __init__(self, center: Float, radius: float) -> None:
        self.center, self.radius, self.period = np.asarray(center, float), float(radius), 2 * np.pi

    def point(self, t: Float) -> Float:
        return self.center + self.radius * np.column_stack([np.cos(t), np.sin(t)])

    def d1(self, t: Float) -> Float:
        return self.radius * np.column_stack([-np.sin(t), np.cos(t)])

    def d2(self, t: Float) -> Float:
        return -self.radius * np.column_stack([np.cos(t), np.sin(t)])

    def inside(self, x: Float) -> Bool:
        return np.linalg.norm(x - self.center, axis=1) < self.radius

    def area(self) -> float:
        return float(np.pi * self.radius**2)

    def boundary(self) -> du.Boundary:
        return du.Circle(self.center, self.radius)


class _Ellipse(_Curve):
    def __init__(self, center: Float, a: float, b: float, angle: float) -> None:
        self.center, self.a, self.b, self.angle = np.asarray(center, float), a, b, angle
        self.R, self.period = _rotation(angle), 2 * np.pi

    def point(self, t: Float) -> Float:
        return self.center + np.column_stack([self.a * np.cos(t), self.b * np.sin(t)]) @ self.R.T

    def d1(self, t: Float) -> Float:
        return np.column_stack([-self.a * np.sin(t), self.b * np.cos(t)]) @ self.R.T

    def d2(self, t: Float) -> Float:
        return self.center - self.point(t)

    def inside(self, x: Float) -> Bool:
        p = (x - self.center) @ self.R
        return (p[:, 0] / self.a) ** 2 + (p[:, 1] / self.b) ** 2 < 1

    def area(self) -> float:
        return float(np.pi * self.a * self.b)

    def boundary(self) -> du.Boundary:
        return du.Ellipse(self.center, self.a, self.b, self.angle)


@dataclass
class _Fourier:
    """``r(theta) = r0 (1 + sum_k a_k cos(k theta + phase_k))`` and its derivatives."""

    r0: float
    k: Float
    a: Float
    phase: Float

    def _terms(self, t: Float) -> Float:
        return np.outer(np.asarray(t, dtype=np.float64), self.k) + self.phase

    def r(self, t: Float) -> Float:
        return self.r0 * (1.0 + np.cos(self._terms(t)) @ self.a)

    def dr(self, t: Float) -> Float:
        return -self.r0 * (np.sin(self._terms(t)) @ (self.a * self.k))

    def d2r(self, t: Float) -> Float:
        return -self.r0 * (np.cos(self._terms(t)) @ (self.a * self.k**2))


class _Polar(_Curve):
    def __init__(self, center: Float, f: _Fourier) -> None:
        self.center, self.f, self.period = np.asarray(center, float), f, 2 * np.pi

    def _frame(self, t: Float) -> tuple[Float, Float]:
        u = np.column_stack([np.cos(t), np.sin(t)])
        return u, np.column_stack([-u[:, 1], u[:, 0]])

    def point(self, t: Float) -> Float:
        return self.center + self.f.r(t)[:, None] * self._frame(t)[0]

    def d1(self, t: Float) -> Float:
        u, v = self._frame(t)
        return self.f.dr(t)[:, None] * u + self.f.r(t)[:, None] * v

    def d2(self, t: Float) -> Float:
        u, v = self._frame(t)
        r, dr, d2r = self.f.r(t)[:, None], self.f.dr(t)[:, None], self.f.d2r(t)[:, None]
        return (d2r - r) * u + 2 * dr * v

    def inside(self, x: Float) -> Bool:
        d = x - self.center
        return np.linalg.norm(d, axis=1) < self.f.r(np.arctan2(d[:, 1], d[:, 0]))

    def area(self) -> float:
        n = 512  # r^2 is a trigonometric polynomial of degree <= 14: the rule is exact
        return float(0.5 * np.mean(self.f.r(np.arange(n) * (2 * np.pi / n)) ** 2) * 2 * np.pi)

    def boundary(self) -> du.Boundary:
        return du.PolarCurve(self.f.r, self.f.dr, self.f.d2r, self.center)


class _Spline(_Curve):
    """The periodic chord-length cubic spline of :class:`~dolfinx_universal.PeriodicSpline`."""

    GAUSS = np.polynomial.legendre.leggauss(8)

    def __init__(self, points: Float) -> None:
        p = np.asarray(points, dtype=np.float64)
        closed = np.vstack([p, p[:1]])
        self.knots = np.concatenate(
            [[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))]
        )
        self.points, self.period = p, float(self.knots[-1])
        self.spline = CubicSpline(self.knots, closed, bc_type="periodic", axis=0)

    def point(self, t: Float) -> Float:
        return self.spline(np.mod(t, self.period))

    def d1(self, t: Float) -> Float:
        return self.spline(np.mod(t, self.period), 1)

    def d2(self, t: Float) -> Float:
        return self.spline(np.mod(t, self.period), 2)

    def quadrature(self) -> tuple[Float, Float]:
        g, w = self.GAUSS
        a, b = self.knots[:-1, None], self.knots[1:, None]
        return (0.5 * (a + b) + 0.5 * (b - a) * g).ravel(), (0.5 * (b - a) * w).ravel()

    def dense(self, n: int) -> Float:
        m = len(self.knots) - 1
        u = (np.arange(-(-n // m)) + 0.5) / -(-n // m)
        a, b = self.knots[:-1, None], self.knots[1:, None]
        return (a + (b - a) * u).ravel()

    def boundary(self) -> du.Boundary:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # clockwise points are reversed
            return du.PeriodicSpline(self.points)


def _diameter(p: Float) -> float:
    """Largest distance between two of the points (of 500 of them along the hull)."""
    v = p[ConvexHull(p).vertices]
    v = v[:: -(-len(v) // 500)]
    return float(np.linalg.norm(v[:, None] - v[None], axis=2).max())


def _gap(p: Float, q: Float | cKDTree) -> float:
    """Smallest distance between two point sets (the second one may be a tree)."""
    tree = q if isinstance(q, cKDTree) else cKDTree(q)
    return float(tree.query(p)[0].min())


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _fourier(
    rng: np.random.Generator, r0: float, modes: int, kmax: int, amp: float, rmin: float, rho: float
) -> _Fourier:
    """Random modes, damped until ``r >= rmin r0`` and the curvature radius ``>= rho r0``."""
    k = rng.choice(np.arange(2, kmax + 1), size=modes, replace=False).astype(np.float64)
    a = rng.uniform(0.3, 1.0, modes) * amp / np.sqrt(modes)
    phase = rng.uniform(0, 2 * np.pi, modes)
    while True:
        f = _Fourier(r0, k, a, phase)
        t = np.arange(4096) * (2 * np.pi / 4096)
        c = _Polar(np.zeros(2), f)
        if f.r(t).min() >= rmin * r0 and c.min_radius_of_curvature(4096) >= rho * r0:
            return f
        a = 0.85 * a


# ----------------------------------------------------------------------------- kinds
@dataclass
class _Parts:
    container: _Curve
    bodies: list[_Curve]
    boundary: du.Boundary
    description: str
    params: dict[str, Any]
    gaps: list[float] = field(default_factory=list)
    h: float | None = None


def _spline(rng: np.random.Generator, scale: float, ratio: float) -> _Parts:
    while True:
        n = int(rng.integers(6, 15))
        theta = (
            rng.uniform(0, 2 * np.pi) + 2 * np.pi * (np.arange(n) + rng.uniform(-0.3, 0.3, n)) / n
        )
        r = rng.uniform(0.5, 1.3, n)
        centre = rng.uniform(-0.3, 0.3, 2)
        pts = centre + scale * r[:, None] * np.column_stack([np.cos(theta), np.sin(theta)])
        curve = _Spline(pts)
        kappa = curve.curvature()
        if np.abs(kappa).max() > 25 / scale or kappa.min() >= 0:  # too sharp, or no inflection
            continue
        try:
            boundary = curve.boundary()
        except ValueError:  # self-intersecting spline
            continue
        desc = f"spline through {n} points, radii {r.min():.2f}-{r.max():.2f} x {scale:.3g}"
        return _Parts(curve, [], boundary, desc, {"points": pts.tolist()})


def _polar(rng: np.random.Generator, scale: float, ratio: float) -> _Parts:
    modes = int(rng.integers(1, 4))
    f = _fourier(rng, scale, modes, 7, 0.45, 0.3, 0.04)
    centre = rng.uniform(-0.3, 0.3, 2)
    curve = _Polar(centre, f)
    terms = " + ".join(f"{a:.3f} cos({k:.0f}t + {p:.2f})" for k, a, p in zip(f.k, f.a, f.phase))
    desc = f"polar r = {scale:.3g} (1 + {terms}), centre ({centre[0]:.3f}, {centre[1]:.3f})"
    params = {
        "r0": scale,
        "k": f.k.tolist(),
        "a": f.a.tolist(),
        "phase": f.phase.tolist(),
        "center": centre.tolist(),
    }
    return _Parts(curve, [], curve.boundary(), desc, params)


def _ellipse(rng: np.random.Generator, scale: float, ratio: float) -> _Parts:
    aspect = _log_uniform(rng, 1.0, 8.0)
    a = scale * rng.uniform(0.7, 1.3)
    b = a / aspect
    angle = rng.uniform(0, np.pi)
    centre = rng.uniform(-0.5, 0.5, 2)
    curve = _Ellipse(centre, a, b, angle)
    desc = f"ellipse a={a:.4g} b={b:.4g} (aspect {aspect:.2f}), angle {angle:.3f}"
    params = {"a": a, "b": b, "angle": angle, "center": centre.tolist()}
    return _Parts(curve, [], curve.boundary(), desc, params)


def _body(rng: np.random.Generator, size: float) -> tuple[str, Any]:
    """A body shape centred at the origin: ``(kind, factory(centre) -> _Curve)``."""
    kind = str(rng.choice(["circle", "ellipse", "polar"]))
    if kind == "circle":
        return kind, lambda c: _Circle(c, size)
    if kind == "ellipse":
        b, angle = size * rng.uniform(0.4, 1.0), rng.uniform(0, np.pi)
        return kind, lambda c: _Ellipse(c, size, b, angle)
    f = _fourier(rng, size, int(rng.integers(1, 3)), 4, 0.25, 0.6, 0.3)
    return kind, lambda c: _Polar(c, f)


def _multibody(rng: np.random.Generator, scale: float, ratio: float) -> _Parts:
    if rng.random() < 0.5:
        container: _Curve = _Circle(np.zeros(2), scale * rng.uniform(1.3, 1.7))
        cdesc = f"circle R={container.radius:.4g}"  # type: ignore[attr-defined]
    else:
        a = scale * rng.uniform(1.4, 1.8)
        container = _Ellipse(np.zeros(2), a, a * rng.uniform(0.7, 1.0), rng.uniform(0, np.pi))
        cdesc = f"ellipse a={a:.4g} b={container.b:.4g}"  # type: ignore[attr-defined]
    spacing = 2e-3 * scale
    csamp = container.samples(spacing)
    ctree = cKDTree(csamp)
    lo, hi = csamp.min(axis=0), csamp.max(axis=0)
    h = _diameter(csamp) / ratio
    gmin = 0.5 * h
    bodies: list[_Curve] = []
    samples: list[Float] = []
    trees: list[cKDTree] = []
    kinds: list[str] = []

    def valid(body: _Curve, bs: Float, gap: float) -> bool:
        if not container.inside(bs).all():
            return False
        if any(b.inside(bs[:1]).any() or body.inside(s[:1]).any() for b, s in zip(bodies, samples)):
            return False
        return min(_gap(bs, o) for o in [ctree, *trees]) >= gap

    for _ in range(int(rng.integers(1, 4))):
        kind, make = _body(rng, scale * rng.uniform(0.1, 0.4))
        for _attempt in range(50):
            body = make(lo + (hi - lo) * rng.random(2))
            bs = body.samples(spacing)
            if not valid(body, bs, 1.02 * gmin):
                continue
            if rng.random() < 0.5:  # squeeze it towards its nearest neighbour
                moved = _squeeze(body, make, [ctree, *trees], rng.uniform(0.5, 1.0) * h, spacing)
                ms = moved.samples(spacing)
                if valid(moved, ms, gmin):
                    body, bs = moved, ms
            bodies.append(body)
            samples.append(bs)
            trees.append(cKDTree(bs))
            kinds.append(kind)
            break
    if not bodies:
        return _multibody(rng, scale, ratio)
    gaps = [_gap(samples[i], o) for i in range(len(bodies)) for o in [ctree, *trees[:i]]]
    boundary = du.Domain(container.boundary(), [b.boundary() for b in bodies])
    desc = (
        f"{cdesc} minus {len(bodies)} bodies ({', '.join(kinds)}), smallest gap "
        f"{min(gaps):.4g} = {min(gaps) / h:.2f} h"
    )
    params = {"container": cdesc, "bodies": kinds, "centres": [b.center.tolist() for b in bodies]}
    return _Parts(container, bodies, boundary, desc, params, gaps, h)


def _squeeze(
    body: _Curve, make: Any, others: list[cKDTree], target: float, spacing: float
) -> _Curve:
    """``body`` translated so that its gap to the nearest sampled curve is about ``target``."""
    for _ in range(6):
        bs = body.samples(spacing)
        best = min(others, key=lambda o: _gap(bs, o))
        d, j = best.query(bs)
        i = int(np.argmin(d))
        u = (best.data[j[i]] - bs[i]) / d[i]
        body = make(body.center + (d[i] - target) * u)
        if abs(d[i] - target) < 1e-3 * target:
            break
    return body


def _dumbbell(X: float, A: float, p: int, beta: float, w: float, n: int) -> Float:
    t = np.arange(n) * (2 * np.pi / n)
    c = np.cos(t)
    return np.column_stack([X * c, np.sin(t) * (w / 2 + A * c**p * (1 + beta * c))])


def _neck(rng: np.random.Generator, scale: float, ratio: float) -> _Parts:
    """A dumbbell ``(X cos t, sin t (w/2 + A cos^p t (1 + beta cos t)))`` through a spline."""
    X = rng.uniform(1.0, 1.4)
    p = int(rng.choice([2, 4]))
    A = rng.uniform(1.0, 2.0) if p == 2 else rng.uniform(1.3, 2.6)
    beta = rng.uniform(-0.5, 0.5)
    n = 2 * int(rng.integers(18, 25))
    h = _diameter(scale * _dumbbell(X, A, p, beta, 0.0, 512)) / ratio
    w = rng.uniform(0.3, 1.0) * h / scale
    pts = scale * _dumbbell(X, A, p, beta, w, n)
    curve = _Spline(pts)
    dense = curve.point(curve.dense(16384))
    mid = np.abs(dense[:, 0]) < 0.5 * X * scale
    width = _gap(dense[mid & (dense[:, 1] > 0)], dense[mid & (dense[:, 1] < 0)])
    angle, shift = rng.uniform(0, 2 * np.pi), rng.uniform(-0.3, 0.3, 2)
    boundary = du.RigidMotion(curve.boundary(), angle, (0.0, 0.0), shift)
    desc = (
        f"dumbbell X={X * scale:.3g} A={A:.3g} p={p} beta={beta:.2f}, neck width "
        f"{width:.4g} = {width / h:.2f} h, rotated {angle:.2f}"
    )
    params = {
        "points": pts.tolist(),
        "angle": angle,
        "translation": shift.tolist(),
        "neck_width": width,
    }
    return _Parts(curve, [], boundary, desc, params, [width], h)


_MAKERS = {
    "spline": _spline,
    "polar": _polar,
    "ellipse": _ellipse,
    "multibody": _multibody,
    "neck": _neck,
}


def random_domain(seed: int, kind: str | None = None) -> RandomDomain:
    """The random domain of a seed.

    Parameters
    ----------
    seed
        Non-negative integer; everything is drawn from ``numpy.random.default_rng(seed)``.
    kind
        Force a kind (default ``KINDS[seed % len(KINDS)]``).

    Returns
    -------
    The domain, its exact area and a suggested largest mesh size.
    """
    kind = KINDS[seed % len(KINDS)] if kind is None else kind
    if kind not in _MAKERS:
        raise ValueError(f"unknown kind {kind!r}: choose one of {KINDS}")
    rng = np.random.default_rng(seed)
    scale = _log_uniform(rng, 0.5, 2.0)
    ratio = _log_uniform(rng, *RATIO_RANGE)
    parts = _MAKERS[kind](rng, scale, ratio)
    curves = [parts.container, *parts.bodies]
    extent = _diameter(np.concatenate([c.point(c.dense(2048)) for c in curves]))
    h = parts.h if parts.h is not None else extent / ratio
    area = parts.container.area() - sum(b.area() for b in parts.bodies)
    rho = min(c.min_radius_of_curvature() for c in curves)
    feature = min([rho, *parts.gaps])
    desc = (
        f"{parts.description}; h={h:.4g} (extent/h={extent / h:.1f}, h/feature="
        f"{h / feature:.1f}), area {area:.6g}"
    )
    return RandomDomain(
        seed=int(seed),
        kind=kind,
        boundary=parts.boundary,
        exact_area=float(area),
        h=float(h),
        n_curves=len(curves),
        n_pieces=1,
        length=float(sum(c.length() for c in curves)),
        extent=extent,
        min_radius_of_curvature=rho,
        min_gap=float(min(parts.gaps, default=np.inf)),
        min_feature=float(feature),
        description=desc,
        params=dict(parts.params, scale=scale, ratio=ratio),
    )
