"""Boundaries against slow, obvious references: dense samples + scalar minimisation."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar

from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.boundaries.curves import (
    Circle,
    Ellipse,
    ImplicitCurve,
    PeriodicSpline,
    PolarCurve,
)
from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.boundaries.motions import RigidMotion
from dolfinx_universal.boundaries.numerics import normd
from dolfinx_universal.boundaries.surfaces import Sphere
from dolfinx_universal.core.arrays import norm2

# ----------------------------------------------------------------------------- references


def _rot(v, a):
    c, s = np.cos(a), np.sin(a)
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])


@dataclass
class Ref:
    """A closed counter-clockwise curve ``c(t)``, ``t`` in ``[0, T)``; ``body``: solid inside."""

    c: Callable[[np.ndarray], np.ndarray]
    T: float
    body: bool = False
    n: int = 20000

    def __post_init__(self):
        self.t = np.arange(self.n) * (self.T / self.n)
        self.p = self.c(self.t)

    def project(self, x):
        """Closest points, distances, parameters: nearest dense sample, then Brent.

        Also flags the points with a second local minimum of the distance, away from the
        first, as close as ``1e-6`` (several closest points: only the distance is compared).
        """
        dt = self.T / self.n
        ts = np.empty(len(x))
        self.ambiguous = np.zeros(len(x), dtype=bool)
        for k, xi in enumerate(x):
            ds = np.linalg.norm(self.p - xi, axis=1)
            i = np.argmin(ds)
            local = (ds <= np.roll(ds, 1)) & (ds <= np.roll(ds, -1))
            far = (
                np.abs((np.arange(self.n) - i + self.n // 2) % self.n - self.n // 2) > self.n // 50
            )
            self.ambiguous[k] = (ds[local & far] < ds[i] + 1e-6).any()
            res = minimize_scalar(
                lambda s, xi=xi: ((self.c(np.array([s]))[0] - xi) ** 2).sum(),
                bounds=(self.t[i] - dt, self.t[i] + dt),
                method="bounded",
                options={"xatol": 1e-13},
            )
            ts[k] = res.x
        y = self.c(ts)
        # Brent leaves an error e ~ 1e-8 along the curve: |x - y| would be off by e^2 / (2d)
        # (large for tiny d); the normal component of x - y is off by only e^2 kappa / 2.
        return y, np.abs(((x - y) * self.normal(ts)).sum(axis=1)), ts

    def normal(self, t):
        """Outward normal by central differences of ``c``."""
        e = 1e-6 * self.T
        d = self.c(t + e) - self.c(t - e)
        d /= np.linalg.norm(d, axis=1)[:, None]
        return np.column_stack([d[:, 1], -d[:, 0]])

    def curvature_radius(self):
        e = 1e-4 * self.T
        d1 = (self.c(self.t + e) - self.c(self.t - e)) / (2 * e)
        d2 = (self.c(self.t + e) - 2 * self.p + self.c(self.t - e)) / e**2
        k = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.linalg.norm(d1, axis=1) ** 3
        return 1 / k.max()

    def enclosed(self, x, y, d, t):
        """Strictly inside the curve: ray casting on the dense polygon, or, within 1e-4 of
        the curve (where the polygon is not accurate enough), the side of the normal."""
        a, b = self.p, np.roll(self.p, -1, axis=0)
        px, py = x[:, :1], x[:, 1:]
        cut = (a[:, 1] > py) != (b[:, 1] > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = a[:, 0] + (py - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        ray = (cut & (px < xc)).sum(axis=1) % 2 == 1
        side = ((x - y) * self.normal(t)).sum(axis=1) < 0
        return np.where(d > 1e-4, ray, side)


def reference(refs, x):
    """Closest points, signed distances, outward normals (of Omega) and component index."""
    res = [r.project(x) for r in refs]
    d = np.array([q[1] for q in res])
    k = d.argmin(axis=0)
    ambiguous = np.array([r.ambiguous for r in refs])[k, np.arange(len(x))]
    ds = np.sort(d, axis=0)
    ambiguous |= (ds[1] < ds[0] + 1e-6) if len(refs) > 1 else False
    idx = np.arange(len(x))
    y = np.array([q[0] for q in res])[k, idx]
    t = np.array([q[2] for q in res])[k, idx]
    inside = np.ones(len(x), dtype=bool)
    for r, (yr, dr, tr) in zip(refs, res):
        enc = r.enclosed(x, yr, dr, tr)
        inside &= ~enc if r.body else enc
    n = np.empty_like(x)
    for j, r in enumerate(refs):
        m = k == j
        if m.any():
            n[m] = (-1 if r.body else 1) * r.normal(t[m])
    return y, np.where(inside, -1.0, 1.0) * d.min(axis=0), n, np.where(ambiguous, -1, k)


# ----------------------------------------------------------------------------- cases

TH = np.linspace(0, 2 * np.pi, 12, endpoint=False)
RS = 1 + 0.25 * np.sin(2 * TH) + 0.15 * np.cos(5 * TH)
SPLINE_POINTS = np.column_stack([RS * np.cos(TH), RS * np.sin(TH)])


def spline_ref(points):
    closed = np.vstack([points, points[:1]])
    knots = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    cs = CubicSpline(knots, closed, bc_type="periodic")
    return lambda t: cs(np.mod(t, knots[-1])), knots[-1]


def super_f(y):
    return y[:, 0] ** 4 + 2 * y[:, 1] ** 4 + y[:, 0] ** 2 * y[:, 1] ** 2 - 1


def super_grad(y):
    x, z = y[:, 0], y[:, 1]
    return np.column_stack([4 * x**3 + 2 * x * z**2, 8 * z**3 + 2 * x**2 * z])


def super_hess(y):
    x, z = y[:, 0], y[:, 1]
    return np.stack(
        [np.column_stack([12 * x**2 + 2 * z**2, 4 * x * z]),
         np.column_stack([4 * x * z, 24 * z**2 + 2 * x**2])],
        axis=1,
    )  # fmt: skip


def super_c(t):
    c, s = np.cos(t), np.sin(t)
    r = (c**4 + 2 * s**4 + c**2 * s**2) ** -0.25
    return np.column_stack([r * c, r * s])


def polar_c(t, c=(0.2, -0.1)):
    r = 1 + 0.3 * np.cos(3 * t)
    return np.asarray(c) + np.column_stack([r * np.cos(t), r * np.sin(t)])


def ellipse_c(c, a, b, angle):
    return lambda t: np.asarray(c) + _rot(np.column_stack([a * np.cos(t), b * np.sin(t)]), angle)


def circle_c(c, r):
    return lambda t: np.asarray(c) + r * np.column_stack([np.cos(t), np.sin(t)])


def polar():
    return PolarCurve(
        lambda t: 1 + 0.3 * np.cos(3 * t),
        lambda t: -0.9 * np.sin(3 * t),
        lambda t: -2.7 * np.cos(3 * t),
        center=(0.2, -0.1),
    )


def make_case(name):
    """(boundary, reference components, length scale) of a named case."""
    tau = 2 * np.pi
    if name == "circle":
        return Circle((0.3, -0.2), 1.5), [Ref(circle_c((0.3, -0.2), 1.5), tau)], 1.5
    if name == "ellipse":
        return (
            Ellipse((0.5, 0.2), 1.4, 0.5, 0.6),
            [Ref(ellipse_c((0.5, 0.2), 1.4, 0.5, 0.6), tau)],
            1,
        )
    if name in ("implicit", "implicit_fd"):
        hess = super_hess if name == "implicit" else None
        b = ImplicitCurve(super_f, super_grad, hess, bbox=[[-1.1, -0.9], [1.1, 0.9]])
        return b, [Ref(super_c, tau)], 1.0
    if name == "polar":
        return polar(), [Ref(polar_c, tau)], 1.0
    c, period = spline_ref(SPLINE_POINTS)
    if name == "spline":
        return PeriodicSpline(SPLINE_POINTS), [Ref(c, period)], 1.0
    if name == "rigid":
        ctr, a, shift = np.array([0.3, -0.2]), 0.7, np.array([1.5, 0.5])
        b = RigidMotion(PeriodicSpline(SPLINE_POINTS), a, ctr, shift)
        return b, [Ref(lambda t: ctr + _rot(c(t) - ctr, a) + shift, period)], 1.0
    assert name == "domain"
    bodies = [Circle((-1.2, 0.0), 0.5), Ellipse((1.1, 0.4), 0.8, 0.4, 0.3)]
    refs = [
        Ref(circle_c((0, 0), 3.0), tau),
        Ref(circle_c((-1.2, 0.0), 0.5), tau, body=True),
        Ref(ellipse_c((1.1, 0.4), 0.8, 0.4, 0.3), tau, body=True),
    ]
    return Domain(Circle((0.0, 0.0), 3.0), bodies), refs, 0.5


def near_points(refs, size, rng, n=300):
    """Random points within 0.3 size of the curves, points 1e-8 size from them, far points."""
    pts = []
    for r in refs:
        t = rng.uniform(0, r.T, n // len(refs))
        off = rng.uniform(-0.3, 0.3, len(t)) * size
        off[:20] = np.where(np.arange(20) % 2, 1e-8, -1e-8) * size
        pts.append(r.c(t) + off[:, None] * r.normal(t))
    lo, hi = refs[0].p.min(axis=0), refs[0].p.max(axis=0)
    far = np.array([[5.0, 3.0], [-4.0, -7.0], [0.0, 0.0], [0.3, 0.2], [0.0, 30.0]])
    far = np.vstack([far, lo - 1.0, hi + 0.7, (lo + hi) / 2])
    return np.vstack(pts + [far])


CASES = ["circle", "ellipse", "implicit", "implicit_fd", "polar", "spline", "rigid", "domain"]


@pytest.mark.parametrize("name", CASES)
def test_against_reference(name):
    b, refs, size = make_case(name)
    rng = np.random.default_rng(sum(map(ord, name)))
    x = near_points(refs, size, rng)
    y_ref, phi_ref, n_ref, k_ref = reference(refs, x)

    y = b.closest_point(x)
    phi, y2 = b.project(x)
    s = b.sign(x)
    # Brent's method on the squared distance finds the reference minimiser only to about
    # sqrt(machine eps) (the distance is flat there); the distance itself is second order.
    ok = k_ref >= 0  # the points with a unique closest point
    assert ok.sum() > 0.95 * len(x)
    length = max(r.T for r in refs) / (2 * np.pi)  # scale of the reference parameters
    assert np.abs(y - y_ref)[ok].max() < 1e-7 * length
    assert np.abs(phi - phi_ref).max() < 1e-10 * size
    np.testing.assert_array_equal(y2, y)
    np.testing.assert_array_equal(b.signed_distance(x), phi)
    clear = np.abs(phi_ref) > 1e-9 * size
    np.testing.assert_array_equal(s[clear], np.sign(phi_ref[clear]))
    assert set(np.unique(s)) <= {-1.0, 1.0}
    assert (np.sign(phi)[phi != 0] == s[phi != 0]).all()
    if isinstance(b, Domain):
        np.testing.assert_array_equal(b.component_index(x)[ok], k_ref[ok])

    # exact properties of the projection, independent of the reference's accuracy; their
    # tolerances are rounding of O(size) values (a converged Newton step, a normalisation:
    # a few ulps), at least 45 ulps, far below the reference comparisons above
    nrm = b.normal(y)
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-14)
    assert np.abs(nrm - n_ref)[ok].max() < 1e-6  # finite-difference normals at t_ref
    np.testing.assert_array_equal(b.tangent(y), np.column_stack([-nrm[:, 1], nrm[:, 0]]))
    v = x - y  # along the normal at the closest point
    assert np.abs(v[:, 0] * nrm[:, 1] - v[:, 1] * nrm[:, 0]).max() < 1e-11 * max(size, 1)
    assert np.abs(b.closest_point(y) - y).max() < 1e-12 * size
    assert np.abs(b.signed_distance(y)).max() < 1e-12 * size
    eps = 1e-6 * size  # outward: just outside along +N, inside along -N
    assert (b.sign(y + eps * nrm) == 1).all() and (b.sign(y - eps * nrm) == -1).all()

    # near: a superset of the points within the distance, with a small extra margin
    for dist in (0.0, 0.02 * size, 0.1 * size):
        m = b.near(x, dist)
        assert m[np.abs(phi_ref) <= dist].all()
        assert (np.abs(phi_ref[m]) <= dist + 0.02 * size).all()

    box = b.bounding_box()
    assert box.shape == (2, 2)
    for r in refs:
        assert (r.p >= box[0]).all() and (r.p <= box[1]).all()
        if isinstance(b, (Circle, Ellipse, PolarCurve, PeriodicSpline)):  # tight boxes
            assert np.abs(box - [r.p.min(axis=0), r.p.max(axis=0)]).max() < 0.02 * size

    samples = b.sample(500)
    assert samples.shape == (500, 2)
    assert np.abs(b.signed_distance(samples)).max() < 1e-10 * size
    if len(refs) == 1:  # one closed curve: ordered, roughly equally spaced
        chords = np.linalg.norm(np.roll(samples, -1, axis=0) - samples, axis=1)
        assert chords.max() < 1.2 * chords.min()

    rc = min(r.curvature_radius() for r in refs)
    assert b.min_radius_of_curvature() == pytest.approx(rc, rel=1e-3)


@pytest.mark.parametrize("name", CASES)
def test_empty_and_three_columns(name):
    b = make_case(name)[0]
    e = np.empty((0, 3))
    assert b.sign(e).shape == (0,) and b.signed_distance(e).shape == (0,)
    assert b.closest_point(e).shape == (0, 2) and b.normal(e).shape == (0, 2)
    assert b.near(e, 0.1).shape == (0,) and b.project(e)[1].shape == (0, 2)
    assert b.sample(0).shape == (0, 2) and b.tangent(e).shape == (0, 2)
    with pytest.raises(ValueError, match="distance"):
        b.near(e, -1.0)
    x = np.random.default_rng(1).uniform(-2, 2, (50, 2))
    x3 = np.column_stack([x, np.full(50, 7.0)])
    np.testing.assert_array_equal(b.project(x3)[0], b.project(x)[0])
    for bad, what in ((np.nan, "NaN"), (np.inf, "inf")):
        x3[3, 1] = bad
        with pytest.raises(ValueError, match=f"contains {what} at index 3"):
            b.sign(x3)
        with pytest.raises(ValueError, match=what):
            b.project(x3)
    with pytest.raises(ValueError, match="shape"):
        b.sign(np.zeros(2))


def test_circle_centre_and_closed_forms():
    c = Circle((1.0, 2.0), 0.5)
    np.testing.assert_array_equal(c.closest_point([[1.0, 2.0]]), [[1.5, 2.0]])
    np.testing.assert_array_equal(c.sign([[1.5, 2.0], [1.2, 2.0], [2.0, 2.0]]), [1, -1, 1])
    assert c.signed_distance([[1.0, 2.0]])[0] == -0.5


def test_ellipse_evolute_region():
    """Points near the major axis inside the evolute: two nearest points, found exactly."""
    e = Ellipse((0.0, 0.0), 2.0, 1.0)
    x = np.array([[0.3, 0.0], [0.3, 1e-12], [-0.3, -1e-9], [0.0, 0.0], [1.6, 0.0], [2.0, 0.0]])
    y = e.closest_point(x)
    # closest points of (p, 0) with |p| < (a^2 - b^2)/a: cos t = a p / (a^2 - b^2)
    ct = 2 * np.array([0.3, 0.3, -0.3, 0.0]) / 3
    exact = np.column_stack([2 * np.abs(ct), np.sqrt(1 - ct**2)])
    # Newton on the parameter: 1.9e-15 (9 ulps) measured where the exact value is 0; a wrong
    # branch (the axis vertex, the other nearest point) would be off by O(1).
    np.testing.assert_allclose(np.abs(y[[0, 3]]), exact[[0, 3]], rtol=0, atol=1e-13)
    np.testing.assert_allclose(np.abs(y[1:3]), exact[1:3], atol=1e-8)  # moved off the axis
    # t = 0 is a start sample and a root of the Newton function: exact up to an ulp
    np.testing.assert_allclose(y[4:], [[2.0, 0.0], [2.0, 0.0]], atol=1e-15)
    np.testing.assert_allclose(e.normal(y[4:]), [[1.0, 0.0], [1.0, 0.0]], atol=1e-15)


def test_implicit_orientation_and_bbox():
    b = ImplicitCurve(super_f, super_grad, bbox=[[-1.1, -0.9], [1.1, 0.9]])
    flipped = ImplicitCurve(
        lambda y: -super_f(y), lambda y: -super_grad(y), bbox=[[-1.1, -0.9], [1.1, 0.9]],
        inside_negative=False,
    )  # fmt: skip
    x = np.random.default_rng(2).uniform(-1.5, 1.5, (200, 2))
    np.testing.assert_array_equal(flipped.sign(x), b.sign(x))
    np.testing.assert_allclose(flipped.normal(x), b.normal(x), atol=1e-12)  # negated gradients
    with pytest.raises(ValueError, match="bbox"):
        ImplicitCurve(super_f, super_grad, bbox=[[-0.5, -0.9], [1.1, 0.9]]).sample(10)
    two = ImplicitCurve(  # two disjoint discs: two loops
        lambda y: np.minimum(np.hypot(y[:, 0] - 1, y[:, 1]), np.hypot(y[:, 0] + 1, y[:, 1])) - 0.5,
        lambda y: np.where(
            (y[:, :1] > 0), (y - [1, 0]) / np.hypot(y[:, :1] - 1, y[:, 1:]),
            (y + [1, 0]) / np.hypot(y[:, :1] + 1, y[:, 1:]),
        ),
        bbox=[[-1.6, -0.6], [1.6, 0.6]],
    )  # fmt: skip
    s = two.sample(100)  # on the curve to rounding: Newton steps end below 1e-12 (quadratic)
    assert (s[:, 0] > 0).sum() == 50
    np.testing.assert_allclose(np.hypot(np.abs(s[:, 0]) - 1, s[:, 1]), 0.5, atol=1e-12)
    u = np.array([-0.8, 0.1]) / np.hypot(0.8, 0.1)
    np.testing.assert_allclose(two.closest_point([[0.2, 0.1]]), [[1, 0] + 0.5 * u], atol=1e-12)
    assert two.near(np.array([[0.0, 0.0], [0.45, 0.3]]), 0.45).tolist() == [False, True]


def test_spline_interpolates_and_orientation():
    s = PeriodicSpline(SPLINE_POINTS)
    knots = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(SPLINE_POINTS, axis=0), axis=1))])
    np.testing.assert_allclose(s.point(knots), SPLINE_POINTS, atol=1e-14)  # cubic: a few ulps
    closed = PeriodicSpline(np.vstack([SPLINE_POINTS, SPLINE_POINTS[:1]]))
    np.testing.assert_array_equal(closed.points, s.points)
    with pytest.warns(UserWarning, match="clockwise"):
        cw = PeriodicSpline(SPLINE_POINTS[::-1])
    np.testing.assert_array_equal(cw.points, SPLINE_POINTS[::-1][::-1])
    x = np.random.default_rng(3).uniform(-1.5, 1.5, (100, 2))
    np.testing.assert_array_equal(cw.sign(x), s.sign(x))
    with pytest.raises(ValueError, match="clockwise.*reverse"):
        PeriodicSpline(SPLINE_POINTS[::-1], orientation="ccw")
    with pytest.raises(ValueError, match="orientation"):
        PeriodicSpline(SPLINE_POINTS, orientation="cw")


def test_spline_invalid_points():
    t = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    with pytest.raises(ValueError, match="intersects itself near"):
        PeriodicSpline(np.column_stack([np.sin(t), np.sin(t) * np.cos(t)]))  # figure eight
    p = SPLINE_POINTS.copy()
    p[5] = p[4]
    with pytest.raises(ValueError, match="points 4 and 5 coincide"):
        PeriodicSpline(p)
    with pytest.raises(ValueError, match="at least 4 distinct"):
        PeriodicSpline([[0, 0], [1, 0], [0, 1], [0, 0]])
    p = SPLINE_POINTS.copy()
    p[2, 0] = np.nan
    with pytest.raises(ValueError, match="NaN at index 2"):
        PeriodicSpline(p)


def test_spline_from_file(tmp_path):
    ref = PeriodicSpline(SPLINE_POINTS)
    files = {
        "a.csv": "x,y\n" + "\n".join(f"{x},{y}" for x, y in SPLINE_POINTS.tolist()),
        "b.txt": "# contour\n" + "\n".join(f"{x}  {y}" for x, y in SPLINE_POINTS.tolist()),
        "c.json": json.dumps(SPLINE_POINTS.tolist()),
        "d.json": json.dumps({"points": SPLINE_POINTS.tolist()}),
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
        np.testing.assert_array_equal(PeriodicSpline.from_file(tmp_path / name).points, ref.points)
    (tmp_path / "bad.csv").write_text("x,y\n1,2\nfoo,bar\n")
    with pytest.raises(ValueError, match="foo"):
        PeriodicSpline.from_file(tmp_path / "bad.csv")
    (tmp_path / "bad.json").write_text('{"pts": []}')
    with pytest.raises(ValueError, match="points"):
        PeriodicSpline.from_file(tmp_path / "bad.json")


def test_polar_requires_positive_radius():
    with pytest.raises(ValueError, match="positive"):
        PolarCurve(lambda t: 0.5 + np.cos(t), lambda t: -np.sin(t), lambda t: -np.cos(t))


def test_rigid_motion_moved():
    base = polar()
    m = RigidMotion(base, 0.3, (1.0, 0.0), (0.2, 0.1))
    still = m.moved(0.0, (0.0, 0.0))
    assert still.base is base and still.angle == 0.0
    np.testing.assert_array_equal(still.center, m.center)
    x = np.random.default_rng(4).uniform(-1.5, 1.5, (100, 2))
    # the identity motion: x - c + c rounds by an ulp of |x| <= 1.5 (1e-14: 30 ulps)
    np.testing.assert_allclose(still.closest_point(x), base.closest_point(x), atol=1e-14)
    np.testing.assert_array_equal(still.sign(x), base.sign(x))
    turned = m.moved(np.pi / 2, (0.0, 0.0))  # rotation by 90 degrees about (1, 0)
    y = base.sample(7)
    moved_y = np.column_stack([1.0 - y[:, 1], y[:, 0] - 1.0])
    np.testing.assert_allclose(turned.sample(7), moved_y, atol=1e-14)  # cos(pi/2) = 6e-17: ulps
    np.testing.assert_allclose(turned.normal(moved_y), _rot(base.normal(y), np.pi / 2), atol=1e-12)


def test_rigid_motion_rotation_per_dimension():
    """A planar motion turns by its angle: ``rotation`` (for surfaces) is refused by the
    constructor and by ``moved``; its tangent bases are its tangents turned, as the base's;
    the default centre and translation (two zeros) are the origin of space too."""
    base = polar()
    m = RigidMotion(base, 0.7, (0.5, -0.2), (0.1, 0.3))
    c, s = np.cos(0.7), np.sin(0.7)
    np.testing.assert_array_equal(m.rotation, [[c, -s], [s, c]])
    y = m.sample(40)
    np.testing.assert_array_equal(m.tangent_basis(y), m.tangent(y)[:, None, :])
    np.testing.assert_allclose(np.linalg.norm(m.tangent(y), axis=1), 1.0, atol=1e-14)
    for make in (
        lambda: RigidMotion(base, rotation=((0, 0, 1), 0.1)),
        lambda: m.moved(0.1, rotation=((0, 0, 1), 0.1)),
    ):
        with pytest.raises(ValueError, match="rotation is for surfaces"):
            make()
    solid = RigidMotion(Sphere((0.0, 0.0, 0.0), 1.0), 0.2)  # the planar defaults, in 3D
    np.testing.assert_array_equal(solid.center, np.zeros(3))
    np.testing.assert_array_equal(solid.translation, np.zeros(3))
    assert solid.rotation.shape == (3, 3)
    with pytest.raises(ValueError, match="translation must be three finite numbers"):
        RigidMotion(Sphere((0.0, 0.0, 0.0), 1.0), translation=(1.0, 0.0))


def test_normd_is_norm2_in_the_plane():
    """One norm for curves and surfaces: in the plane, bit for bit the arithmetic of
    ``norm2`` (the meshes of curves stay the same)."""
    v = np.random.default_rng(6).standard_normal((1000, 2)) * np.logspace(-3, 3, 1000)[:, None]
    np.testing.assert_array_equal(normd(v), norm2(v))
    w = np.random.default_rng(7).standard_normal((100, 3))
    np.testing.assert_array_equal(normd(w), np.sqrt(w[:, 0] ** 2 + w[:, 1] ** 2 + w[:, 2] ** 2))


def test_domain_components():
    body = Circle((0.0, 0.0), 0.5)
    d = Domain(None, [body])
    assert d.components == [(body, True)]
    x = np.array([[0.0, 0.0], [0.7, 0.0], [5.0, 5.0]])
    np.testing.assert_array_equal(d.sign(x), [1.0, -1.0, -1.0])
    np.testing.assert_allclose(d.signed_distance(x), [0.5, -0.2, -(50**0.5 - 0.5)])
    np.testing.assert_allclose(d.normal([[0.5, 0.0]]), [[-1.0, 0.0]])
    with pytest.raises(ValueError, match="container or at least one body"):
        Domain()
    with pytest.raises(TypeError):
        Domain(None, [object()])  # type: ignore[list-item]


def test_boundary_is_abstract():
    with pytest.raises(TypeError):
        Boundary()  # type: ignore[abstract]


def test_implicit_newton_failure_is_reported():
    noise = np.random.default_rng(5)

    def noisy_grad(y):  # a wrong gradient: Newton's method cannot settle
        return 2 * y + 1e-3 * noise.standard_normal(y.shape)

    b = ImplicitCurve(lambda y: (y**2).sum(axis=1) - 1, noisy_grad, bbox=[[-1.1, -1.1], [1.1, 1.1]])
    with pytest.raises(RuntimeError, match=r"did not converge for 2 point\(s\), e.g. x=\[0.5"):
        b.closest_point([[0.5, 0.1], [0.1, 0.9]])


@pytest.mark.parametrize("name", ["ellipse", "implicit", "annulus", "spline", "neck"])
def test_window_clearance_is_a_lower_bound(name):
    """Each sample's clearance (which lets the closest-point search skip the k-d tree's ball
    count) is at most its distance to every sample outside its window along its loop, and
    is attained where the nearest such sample is among the neighbours searched: against
    all pairs of samples. ``annulus`` has two loops; ``neck`` comes back within a few
    sample spacings of itself."""
    from dolfinx_universal.boundaries.curve_samples import WINDOWS, window_clearance

    if name == "neck":  # a dumbbell whose waist is 0.004 wide
        t = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
        r = 0.002 + np.abs(np.cos(t)) ** 3
        b: Boundary = PeriodicSpline(np.column_stack([r * np.cos(t), 0.5 * r * np.sin(t)]))
    elif name == "annulus":  # (|x|^2 - 1) (|x|^2 - 1/4) < 0: two circles

        def f(x):
            s = (x**2).sum(axis=1)
            return (s - 1.0) * (s - 0.25)

        def grad(x):
            return (2.0 * (x**2).sum(axis=1) - 1.25)[:, None] * 2.0 * x

        b = ImplicitCurve(f, grad, bbox=[[-1.1, -1.1], [1.1, 1.1]])
    else:
        b = make_case(name)[0]
    samples = b._samples
    if len(samples) == 5:  # ImplicitCurve: (points, tree, prev, next, spacing)
        pts, tree, nxt = samples[0], samples[1], samples[3]
    else:  # ParametricCurve: (parameters, points, tree, prev, next, spacing)
        pts, tree, nxt = samples[1], samples[2], samples[4]
    clears = window_clearance(tree, pts, nxt)
    n = len(pts)
    ends = np.flatnonzero(nxt != np.arange(1, n + 1))
    loop = np.searchsorted(ends, np.arange(n))
    size = np.bincount(loop)[loop]
    assert len(ends) == (2 if name == "annulus" else 1)
    assert len(clears) == len(WINDOWS)
    for w, clear in zip(WINDOWS, clears):
        exact = np.empty(n)
        for rows in np.array_split(np.arange(n), 16):  # all pairs, a block of rows at a time
            step = (np.arange(n)[None, :] - rows[:, None]) % size[rows, None]
            near = (step <= w) | (step >= size[rows, None] - w)
            inside = (loop[None, :] == loop[rows, None]) & near
            d = np.linalg.norm(pts[rows, None, :] - pts[None, :, :], axis=2)
            exact[rows] = np.where(inside, np.inf, d).min(axis=1)
        assert np.all(clear <= exact), w
        assert np.mean(clear == exact) > 0.9, w


@pytest.mark.parametrize("name", ["polar", "spline", "neck"])
def test_projection_starts_change_nothing(name):
    """The closest points found from the sample hints' starts (no k-d tree query where the
    windows prove the nearest sample) are bitwise those of the tree's route, at distances
    from on Gamma to far outside the hints' cells; the starts lie within a few samples of
    the nearest one where they exist, and there are none far away."""
    if name == "neck":  # comes back within a few sample spacings of itself
        t = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
        r = 0.002 + np.abs(np.cos(t)) ** 3
        b = PeriodicSpline(np.column_stack([r * np.cos(t), 0.5 * r * np.sin(t)]))
    else:
        b = make_case(name)[0]
    rng = np.random.default_rng(3)
    on = b.sample(2000)
    _, pts, tree, _, _, spacing = b._samples
    hints = b._hints
    for scale in (0.0, 1e-9, 1e-4, 3 * spacing, 20 * spacing, 0.3, 3.0):
        x = on + scale * rng.standard_normal(on.shape)
        start = hints.starts(x)
        t1, y1 = b._project(x)
        hints.starts = lambda x: np.full(len(x), -1, dtype=np.intp)  # the tree's route
        try:
            t2, y2 = b._project(x)
        finally:
            del hints.starts
        np.testing.assert_array_equal(y1, y2)
        np.testing.assert_array_equal(t1, t2)
        have = start >= 0
        j0 = tree.query(x[have])[1]
        n = len(pts)
        assert (np.abs((start[have] - j0 + n // 2) % n - n // 2) <= 4).mean() > 0.99
        if scale >= 3.0:  # far outside the band of cells
            assert have.mean() < 0.1
    assert (hints.starts(np.array([[np.nan, 0.0], [1e300, 1e300]])) == -1).all()


def test_onto_gamma_curves():
    """``onto_gamma`` on curves: the closest points (bitwise) for the closed-form and
    parametric curves other than :class:`PolarCurve` (``test_onto_gamma_polar``) and their
    wrappers; on an implicit curve Newton's steps along
    ``grad f``: points on Gamma (their own closest points to 1e-12), with the normals
    there, within twice the distance of the candidates from Gamma, not the closest points
    themselves; a point whose zero is out of reach gets its closest point."""
    rng = np.random.default_rng(11)
    for c in (Circle((0.1, 0.0), 0.8), Ellipse((0, 0), 1.0, 0.6, 0.3)):
        y0 = c.sample(200)
        x = y0 + 0.05 * rng.standard_normal(y0.shape)
        for b in (c, RigidMotion(c, angle=0.4), Domain(None, [c])):
            y, n = b.onto_gamma(x)
            y1, n1 = b.closest_normal(x)
            np.testing.assert_array_equal(y, y1)
            np.testing.assert_array_equal(n, n1)
    b = ImplicitCurve(super_f, super_grad, bbox=[[-1.1, -0.9], [1.1, 0.9]])
    y0 = b.sample(300)
    t = b.tangent(y0)
    x = y0 + rng.uniform(0.01, 0.1, (len(y0), 1)) * t  # tangent steps: sliding candidates
    d = np.linalg.norm(x - b.closest_point(x), axis=1)
    for w in (b, RigidMotion(b, angle=0.0), Domain(None, [b])):
        y, n = w.onto_gamma(x)
        yc, nc = w.closest_normal(y)
        np.testing.assert_allclose(yc, y, rtol=0, atol=1e-12)
        np.testing.assert_allclose(n, nc, rtol=0, atol=1e-9)
        assert (np.linalg.norm(y - x, axis=1) <= 2 * d + 1e-12).all()
        assert np.abs(y - b.closest_point(x)).max() > 0  # the cheap path, not the closest point
    far = np.array([[0.0, 0.0], [0.05, 0.02]])  # deep inside: Newton's estimate is far off
    y, n = b.onto_gamma(far)
    y1, n1 = b.closest_normal(far)
    np.testing.assert_array_equal(y, y1)
    np.testing.assert_array_equal(n, n1)


def test_onto_gamma_polar(monkeypatch):
    """``PolarCurve.onto_gamma``: points of Gamma (their own closest points to 1e-12) with
    the normals there, each within ``ONTO_REACH`` times its candidate's distance from the
    tangent line at it, or the candidate's closest point. Tangent steps on a propeller whose
    flanks meet the rays from the pole at grazing angles (cosine down to 0.37) take the ray
    (not the closest point) or, at the flanks, the Newton step onto the normal line; points
    far off take the closest point; a subclass that changes the geometry gets closest
    points."""
    from dolfinx_universal.boundaries.base import ONTO_REACH

    def r(t):
        return 0.12 + 0.38 * np.exp(-(np.sin(1.5 * t) ** 2) / 0.3)

    def dr(t):
        return -0.38 * np.exp(-(np.sin(1.5 * t) ** 2) / 0.3) * 1.5 * np.sin(3 * t) / 0.3

    def d2r(t):
        g, dg = -1.5 * np.sin(3 * t) / 0.3, -4.5 * np.cos(3 * t) / 0.3
        return 0.38 * np.exp(-(np.sin(1.5 * t) ** 2) / 0.3) * (g**2 + dg)

    b = PolarCurve(r, dr, d2r, center=(0.1, -0.05))
    rng = np.random.default_rng(5)
    y0 = b.sample(400)
    t = np.column_stack([-b.normal(y0)[:, 1], b.normal(y0)[:, 0]])
    x = y0 + rng.uniform(-0.02, 0.02, (len(y0), 1)) * t  # tangent steps: sliding candidates
    d = x - b.center
    u = d / np.linalg.norm(d, axis=1)[:, None]
    assert (np.abs((u * b.normal(b.closest_point(x))).sum(axis=1)) < 0.4).any()  # grazing
    far = b.center + np.array([[-1.0, -1.0], [-1.0, 0.8], [0.0, 0.05]])
    calls = []
    closest = PolarCurve.closest_normal
    monkeypatch.setattr(
        PolarCurve, "closest_normal", lambda self, z: (calls.append(len(z)), closest(self, z))[1]
    )
    for w in (b, RigidMotion(b, angle=0.0), Domain(None, [b])):
        for pts, cheap in ((x, True), (far, False)):
            calls.clear()
            y, n = w.onto_gamma(pts)
            num_closest = sum(calls)
            yc, nc = w.closest_normal(y)
            np.testing.assert_allclose(yc, y, rtol=0, atol=1e-12)
            np.testing.assert_allclose(n, nc, rtol=0, atol=1e-9)
            off = pts - y
            near = np.linalg.norm(off, axis=1) <= ONTO_REACH * np.abs((off * n).sum(1)) + 1e-12
            is_closest = np.abs(y - w.closest_point(pts)).max(axis=1) <= 1e-14
            assert (near | is_closest).all()
            if cheap:  # the ray or the Newton step, no closest point (except where the ray
                assert num_closest == 0 and is_closest.mean() < 0.1  # is the normal line)
            else:
                assert num_closest > 0

    class Moved(PolarCurve):
        def closest_point(self, z):
            return super().closest_point(z)

    m = Moved(r, dr, d2r, center=(0.1, -0.05))
    y, n = m.onto_gamma(x)
    y1, n1 = Boundary.closest_normal(m, x)
    np.testing.assert_array_equal(y, y1)
    np.testing.assert_array_equal(n, n1)
