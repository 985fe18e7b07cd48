"""Surfaces in 3D (dolfinx_universal.boundaries.surfaces) against dense references.

References: brute force over a dense parametrisation of each surface, refined by
Nelder-Mead on a few points; closed forms (the torus) for the implicit surfaces.
"""

from __future__ import annotations

from collections.abc import Callable

from mpi4py import MPI

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial import cKDTree

from dolfinx_universal import (
    Circle,
    Domain,
    Ellipsoid,
    ImplicitSurface,
    MeshingError,
    RigidMotion,
    Sphere,
    Surface,
    Torus,
    mesh_domain,
)

Float = np.ndarray
Param = Callable[[Float, Float], Float]


# ----------------------------------------------------------------------------- references
def _sphere_param(c: Float, R: Float, e: Float) -> Param:
    """``(theta, phi) -> c + R (e * unit direction)``."""

    def f(t: Float, p: Float) -> Float:
        u = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
        return c + (e * u) @ R.T

    return f


def _torus_param(T: Torus) -> Param:
    t1, t2 = T.frame

    def f(u: Float, v: Float) -> Float:
        rad = T.major + T.minor * np.cos(v)
        return (
            T.center
            + (rad * np.cos(u))[..., None] * t1
            + (rad * np.sin(u))[..., None] * t2
            + (T.minor * np.sin(v))[..., None] * T.axis
        )

    return f


def _quartic_param(t: Float, p: Float) -> Float:
    """The superquadric x^4 + y^4 + z^4 = 1 by directions."""
    u = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    return u / ((u**4).sum(axis=-1) ** 0.25)[..., None]


def _dense(param: Param, spans: tuple[float, float], n: tuple[int, int]) -> tuple[Float, ...]:
    a = (np.arange(n[0]) + 0.5) * (spans[0] / n[0])  # no repeated points at the poles
    b = np.linspace(0, spans[1], n[1], endpoint=False)
    A, B = np.meshgrid(a, b, indexing="ij")
    return A.ravel(), B.ravel(), param(A.ravel(), B.ravel())


def _refine(param: Param, A: Float, B: Float, x: Float, iters: int = 60) -> Float:
    """Distances from ``x (m, 3)`` to ``param``: Newton's method on the parameters of
    ``|param(a, b) - x|^2 / 2`` (derivatives of ``param`` by central differences, step 1e-5;
    gradient steps where the Hessian is not positive definite; halved until the value does
    not increase), all points at once, from ``(A, B) (m,)``."""
    h = 1e-5

    def f(a: Float, b: Float) -> Float:
        return 0.5 * ((param(a, b) - x) ** 2).sum(axis=-1)

    def dot(u: Float, v: Float) -> Float:
        return (u * v).sum(axis=-1)

    for _ in range(iters):
        P = param(A, B)
        pa, pA, pb, pB = param(A + h, B), param(A - h, B), param(A, B + h), param(A, B - h)
        Pa, Pb = (pa - pA) / (2 * h), (pb - pB) / (2 * h)
        Paa, Pbb = (pa - 2 * P + pA) / h**2, (pb - 2 * P + pB) / h**2
        Pab = (param(A + h, B + h) - param(A + h, B - h) - param(A - h, B + h)
               + param(A - h, B - h)) / (4 * h * h)  # fmt: skip
        r = P - x
        g = np.column_stack([dot(r, Pa), dot(r, Pb)])
        haa, hbb = dot(Pa, Pa) + dot(r, Paa), dot(Pb, Pb) + dot(r, Pbb)
        hab = dot(Pa, Pb) + dot(r, Pab)
        det = haa * hbb - hab * hab
        pd = (haa > 0) & (det > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(
                pd[:, None],
                -np.column_stack([hbb * g[:, 0] - hab * g[:, 1], haa * g[:, 1] - hab * g[:, 0]])
                / det[:, None],
                -g,
            )
        f0 = 0.5 * dot(r, r)
        t = np.ones(len(x))
        for _ in range(30):
            bad = ~(f(A + t * step[:, 0], B + t * step[:, 1]) <= f0)
            if not bad.any():
                break
            t[bad] *= 0.5
        t[~(f(A + t * step[:, 0], B + t * step[:, 1]) <= f0)] = 0.0
        A, B = A + t * step[:, 0], B + t * step[:, 1]
    return np.sqrt(2 * f(A, B))


def reference_distances(
    param: Param, spans: tuple[float, float], x: Float, n: tuple[int, int] = (300, 600)
) -> Float:
    """Distances from ``x (m, 3)``: the nearest dense sample, refined by :func:`_refine`."""
    A, B, Y = _dense(param, spans, n)
    d0, k = cKDTree(Y).query(x)
    return np.minimum(_refine(param, A[k], B[k], x), d0)


def scipy_distances(param: Param, spans: tuple[float, float], x: Float) -> Float:
    """As :func:`reference_distances` with scipy's BFGS as the refinement (a few points)."""
    A, B, Y = _dense(param, spans, (300, 600))
    k = cKDTree(Y).query(x)[1]
    out = []
    for i, xi in enumerate(x):

        def f(z: Float, xi: Float = xi) -> float:
            return float(((param(z[:1], z[1:])[0] - xi) ** 2).sum())

        r = minimize(f, [A[k[i]], B[k[i]]], method="BFGS", options={"gtol": 1e-14})
        out.append(np.sqrt(r.fun))
    return np.array(out)


def assert_no_closer_sample(
    param: Param, spans: tuple[float, float], x: Float, d: Float, tol: float = 1e-14
) -> None:
    """No sample of a very dense sampling of the surface is closer to ``x (m, 3)`` than the
    distances ``d (m,)`` minus ``tol`` (the dense distances bound the true ones above)."""
    tree = cKDTree(_dense(param, spans, (500, 1000))[2])
    closer = tree.query_ball_point(x, np.maximum(d - tol, 0.0), return_length=True)
    assert (closer == 0).all(), f"{(closer > 0).sum()} point(s) have a closer dense sample"


def fd_gradient(fn: Callable[[Float], Float], x: Float, h: float = 1e-6) -> Float:
    e = np.eye(3) * h
    return np.column_stack([(fn(x + e[j]) - fn(x - e[j])) / (2 * h) for j in range(3)])


def check_projection(
    S: Surface, x: Float, level: Callable[[Float], Float], fd: int | None = None
) -> None:
    """Closest points on ``level = 0`` to 1e-12, ``x - y`` along the unit outward normal,
    the normal the gradient of the signed distance (at the first ``fd`` points, generic
    ones: most off the medial axis), signs from ``level``."""
    phi, y, n = S.project_normal(x)
    assert phi.shape == (len(x),) and y.shape == n.shape == (len(x), 3)
    assert np.abs(level(y)).max() <= 1e-12
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, atol=1e-14)
    r = x - y
    assert np.abs(np.cross(r, n)).max() <= 1e-10 * (1 + np.abs(r).max())
    np.testing.assert_array_equal(S.sign(x), np.where(level(x) < 0, -1.0, 1.0))
    np.testing.assert_allclose(phi, S.sign(x) * np.linalg.norm(r, axis=1), rtol=0, atol=0)
    # away from Gamma (and its medial axis) grad phi = N(pi(x)): outward, unit
    off = np.abs(phi) > 1e-3
    if fd is not None:
        off[fd:] = False
    g = fd_gradient(S.signed_distance, x[off])
    good = np.linalg.norm(g, axis=1) > 0.999  # kinks (medial axis) excluded
    assert good.mean() > 0.9
    np.testing.assert_allclose(g[good], n[off][good], atol=2e-6)
    np.testing.assert_allclose(S.normal(y), n, atol=1e-12)


def check_near(S: Surface, x: Float) -> None:
    d = np.linalg.norm(x - S.closest_point(x), axis=1)
    for dist in (0.0, 0.05, 0.2, 1.0):
        m = S.near(x, dist)
        assert m[d <= dist].all(), "near() missed a point within the distance"
    per = np.linspace(0, 0.5, len(x))
    assert S.near(x, per)[d <= per].all()
    lb = S.lower_bound(x)
    assert (lb <= d * (1 + 1e-12) + 1e-15).all()
    for cap in (0.0, 0.05, 0.3):  # the bound near() uses: lb where lb <= cap, above cap else
        lw = S._lower_bound_within(x, cap)
        low = lb <= cap
        assert np.array_equal(lw[low], lb[low]) and (lw[~low] > cap).all()
        # near()'s bounds from one computation: the same lower bound; an upper bound of the
        # distance, the same as _upper_bound's, wherever the lower bound is within cap
        lower, upper = S._bounds_within(x, cap)
        assert np.array_equal(lower, lw)
        if upper is not None:
            assert np.array_equal(upper[low], S._upper_bound(x[low]))
            assert (upper[low] >= d[low] * (1 - 1e-12)).all()


RNG = np.random.default_rng(20240611)


def _box_points(S: Surface, m: int, pad: float) -> Float:
    lo, hi = S.bounding_box()
    return RNG.uniform(lo - pad, hi + pad, (m, 3))


# ----------------------------------------------------------------------------- common
def test_interface_basics() -> None:
    assert Circle((0, 0), 1).gdim == 2
    S = Sphere((0, 0, 0), 1)
    assert S.gdim == 3 and S.num_components == 1 and S.euler_characteristic == 2
    assert Torus((0, 0, 0), 2, 1).euler_characteristic == 0
    for s in (S, Ellipsoid((0, 0, 0), (1, 2, 3)), Torus((0, 0, 0), 2, 1)):
        assert s.closest_point(np.empty((0, 3))).shape == (0, 3)
        assert s.sign(np.empty((0, 3))).shape == (0,)
        assert s.signed_distance(np.empty((0, 3))).shape == (0,)
        assert s.near(np.empty((0, 3)), 0.1).shape == (0,)
        with pytest.raises(ValueError, match="NaN"):
            s.closest_point([[0.0, np.nan, 0.0]])
        with pytest.raises(ValueError, match="inf"):
            s.sign([[0.0, 0.0, np.inf]])
        with pytest.raises(ValueError, match=r"\(n, 3\)"):
            s.project([[0.0, 1.0]])
        with pytest.raises(NotImplementedError):
            s.tangent([[1.0, 1.0, 1.0]])
        x = RNG.normal(size=(50, 3)) * 2
        B = s.tangent_basis(x)
        n = s.normal(x)
        assert B.shape == (50, 2, 3)
        np.testing.assert_allclose(
            B @ B.transpose(0, 2, 1), np.tile(np.eye(2), (50, 1, 1)), atol=1e-14
        )
        np.testing.assert_allclose(np.cross(B[:, 0], B[:, 1]), n, atol=1e-14)
        assert s.sample(0).shape == (0, 3)
    with pytest.raises(ValueError):
        Sphere((0, 0), 1)
    with pytest.raises(ValueError):
        Ellipsoid((0, 0, 0), (1, -1, 1))
    with pytest.raises(ValueError, match="minor < major"):
        Torus((0, 0, 0), 1, 1)
    with pytest.raises(ValueError, match="orthogonal"):
        Ellipsoid((0, 0, 0), (1, 2, 3), rotation=np.ones((3, 3)))
    with pytest.raises(ValueError, match="all be curves or all surfaces"):
        Domain(S, [Circle((0, 0), 0.5)])


def test_sphere() -> None:
    S = Sphere((0.3, -0.2, 0.1), 1.3)
    x = np.vstack([_box_points(S, 400, 0.5), S.center, S.sample(20)])
    check_projection(S, x[:-21], lambda y: np.linalg.norm(y - S.center, axis=1) - 1.3)
    np.testing.assert_allclose(S.closest_point(S.center[None]), [S.center + (1.3, 0, 0)])
    y = S.sample(20)
    np.testing.assert_allclose(S.signed_distance(y), 0, atol=1e-15)
    on = [[1.5, 0, 0], [0, -1.5, 0], [0, 0, 1.5], [0.9, 1.2, 0]]
    np.testing.assert_array_equal(Sphere((0, 0, 0), 1.5).sign(on), 1.0)  # on Gamma: outside
    check_near(S, x)
    assert S.min_radius_of_curvature() == 1.3
    np.testing.assert_allclose(S.area(), 4 * np.pi * 1.69)
    lo, hi = S.bounding_box()
    assert (lo <= S.sample(500)).all() and (S.sample(500) <= hi).all()


# ----------------------------------------------------------------------------- ellipsoid
ELLIPSOIDS = [
    Ellipsoid((0.1, 0.2, 0.3), (3, 2, 1)),
    Ellipsoid((0, 0, 0), (1, 2, 0.7), rotation=((1, 1, 1), 0.7)),
    Ellipsoid((0, 0, 0), (1.5, 1.5, 1.5)),  # a sphere
    Ellipsoid((0, 0, -1), (1, 3, 3), rotation=[0.3, -0.2, 0.5]),  # oblate spheroid
    Ellipsoid((0, 0, 0), (2, 0.5, 0.5)),  # prolate spheroid
]


def _slide_candidates(S: Surface, n: int, reach: float) -> tuple[Float, Float]:
    """Points of ``S`` and tangent steps of up to ``reach`` from them: the relaxation's
    sliding candidates."""
    y0 = S.sample(n)
    t = RNG.standard_normal(y0.shape)
    n0 = S.normal(y0)
    t -= (t * n0).sum(axis=1)[:, None] * n0
    t /= np.linalg.norm(t, axis=1)[:, None]
    return y0, y0 + reach * RNG.uniform(0.05, 1.0, (len(y0), 1)) * t


def check_onto(S: Surface, x: Float, scale: float) -> tuple[Float, Float]:
    """``onto_gamma``'s contract at points ``x`` near Gamma: points of Gamma (their own
    closest points to 1e-12 of the size ``scale``: the closest points' tolerance), the
    unit outward normals there, and within twice the distance of ``x`` from Gamma of it
    (a point of Gamma across a feature would be farther). Returns the points and normals."""
    y, n = S.onto_gamma(x)
    yc, nc = S.closest_normal(y)
    np.testing.assert_allclose(yc, y, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(n, nc, rtol=0, atol=1e-9)
    d = np.linalg.norm(x - S.closest_point(x), axis=1)
    assert (np.linalg.norm(y - x, axis=1) <= 2 * d + 1e-12 * scale).all()
    return y, n


def test_onto_gamma() -> None:
    """Closed forms and wrappers of closed forms: the closest points, bitwise. Implicit
    surfaces: along the gradient line, on Gamma; their own closest points where the zero
    on that line is out of reach; the same through RigidMotion and Domain."""
    for S in (Sphere((0.1, 0, 0), 0.8), ELLIPSOIDS[1], Torus((0, 0, 0), 1.0, 0.3)):
        x = _slide_candidates(S, 300, 0.1)[1]
        for B in (S, RigidMotion(S, translation=(0.1, 0.2, 0.3)), Domain(None, [S])):
            y, n = B.onto_gamma(x)
            y0, n0 = B.closest_normal(x)
            np.testing.assert_array_equal(y, y0)
            np.testing.assert_array_equal(n, n0)
    imp = _torus_implicit(1.0, 0.3)
    y0, x = _slide_candidates(imp, 2000, 0.1)
    y, n = check_onto(imp, x, 1.0)
    # Not the closest points, but close to them: the gradient line and the normal through
    # x meet Gamma about (distance) * (curvature) * (distance) apart.
    d = np.linalg.norm(x - imp.closest_point(x), axis=1)
    assert 0 < np.abs(y - imp.closest_point(x)).max() <= 10 * (d * d).max() / 0.3
    moved = RigidMotion(imp, translation=(0.5, 0.0, 0.1), rotation=((0, 0, 1), 0.7))
    xm = moved._from_base(x)
    ym, nm = check_onto(moved, xm, 1.0)
    np.testing.assert_allclose(ym, moved._from_base(y), rtol=0, atol=1e-14)
    inner = Sphere((0, 0, 0), 3.0)  # a container around the torus body
    dom = Domain(inner, [imp])
    yd, nd = check_onto(dom, x, 1.0)
    np.testing.assert_array_equal(yd, y)
    np.testing.assert_array_equal(nd, -n)  # out of Omega: into the body
    # The quartic at the origin: Newton's estimate of the offset is 250, beyond the box;
    # the closest point instead.
    q = _quartic()
    c = np.array([[0.1, 0.0, 0.0], [0.0, 0.0, 0.05]])
    yq, nq = q.onto_gamma(c)
    y0q, n0q = q.closest_normal(c)
    np.testing.assert_array_equal(yq, y0q)
    np.testing.assert_array_equal(nq, n0q)


def _ellipsoid_points(E: Ellipsoid) -> Float:
    e, m = E.semi_axes, E._m
    p = RNG.uniform(-1.4, 1.4, (40, 3)) * e
    q = RNG.uniform(-0.6, 0.6, (8, 3)) * e
    q[:, m] = 0  # the degenerate plane, inside the evolute
    q2 = q.copy()
    q2[:, m] = 1e-13  # just off it
    k = np.arange(9) % 3
    ax = np.zeros((9, 3))
    ax[np.arange(9), k] = np.array([0.3, 0.2, 0.5, 2, 3, 4, -0.1, -1.7, 0.95]) * e[k]
    on = RNG.normal(size=(5, 3))
    on = e * on / np.linalg.norm(on, axis=1)[:, None]  # on Gamma
    return E._world(np.vstack([p, q, q2, ax, on, [[0.0, 0.0, 0.0]]]))


@pytest.mark.parametrize("E", ELLIPSOIDS, ids=range(len(ELLIPSOIDS)))
def test_ellipsoid_against_reference(E: Ellipsoid) -> None:
    x = _ellipsoid_points(E)
    d = np.linalg.norm(x - E.closest_point(x), axis=1)
    param, spans = _sphere_param(E.center, E.rotation, E.semi_axes), (np.pi, 2 * np.pi)
    ref = reference_distances(param, spans, x)
    assert np.max(d - ref) <= 2e-15 * (1 + ref.max())  # never farther than the reference
    assert np.min(d - ref) >= -1e-12  # and the reference is (nearly) as good
    if E is ELLIPSOIDS[0]:  # the reference itself, against scipy on a few points
        i = [0, 7, 45]
        np.testing.assert_allclose(ref[i], scipy_distances(param, spans, x[i]), atol=1e-9)

    def level(y: Float) -> Float:
        p = (y - E.center) @ E.rotation / E.semi_axes
        return (p * p).sum(axis=1) - 1

    check_projection(E, x, level, fd=40)


def test_ellipsoid_dense_and_bounds() -> None:
    E = ELLIPSOIDS[1]
    x = _box_points(E, 3000, 1.0)
    d = np.linalg.norm(x - E.closest_point(x), axis=1)
    param, spans = _sphere_param(E.center, E.rotation, E.semi_axes), (np.pi, 2 * np.pi)
    assert_no_closer_sample(param, spans, x[:1000], d[:1000])
    check_near(E, x)
    assert (E._upper_bound(x) >= d).all()
    assert E.min_radius_of_curvature() == pytest.approx(0.7**2 / 2)
    # area: Carlson's formula against the dense parametrisation
    th, ph = np.linspace(0, np.pi, 801), np.linspace(0, 2 * np.pi, 1601)
    T, P = np.meshgrid(th, ph, indexing="ij")
    a, b, c = E.semi_axes
    J = np.sqrt(
        (b * c * np.sin(T) ** 2 * np.cos(P)) ** 2
        + (a * c * np.sin(T) ** 2 * np.sin(P)) ** 2
        + (a * b * np.sin(T) * np.cos(T)) ** 2
    )
    assert E.area() == pytest.approx(np.trapezoid(np.trapezoid(J, ph, axis=1), th), rel=1e-5)
    lo, hi = E.bounding_box()
    y = E.sample(4000)
    assert y.shape == (4000, 3) and (lo <= y).all() and (y <= hi).all()
    p = (y - E.center) @ E.rotation / E.semi_axes
    np.testing.assert_allclose((p * p).sum(axis=1), 1, atol=1e-14)
    # about uniform: the covering radius of the samples is about their spacing
    dense_pts = _dense(param, spans, (200, 400))[2]
    spacing = np.sqrt(E.area() / len(y))
    assert cKDTree(y).query(dense_pts)[0].max() < 2.5 * spacing


# ----------------------------------------------------------------------------- torus
@pytest.mark.parametrize("axis", [(0, 0, 1), (1, 2, -0.5)])
def test_torus(axis: tuple[float, float, float]) -> None:
    T = Torus((0.2, -0.1, 0.3), 1.0, 0.35, axis=axis)
    param, spans = _torus_param(T), (2 * np.pi, 2 * np.pi)
    x = _box_points(T, 40, 0.4)
    x = np.vstack([x, T.center + 0.3 * T.axis, T.center + 0.6 * T.frame[1]])  # axis, hole
    d = np.linalg.norm(x - T.closest_point(x), axis=1)
    ref = reference_distances(param, spans, x)
    assert np.max(d - ref) <= 2e-15 * (1 + ref.max())
    assert np.min(d - ref) >= -1e-12
    np.testing.assert_allclose(
        T.closest_point(T.center[None]), [T.center + (T.major - T.minor) * T.frame[0]], atol=1e-15
    )  # on the axis: along t1

    def level(y: Float) -> Float:
        dd = y - T.center
        z = dd @ T.axis
        rho = np.linalg.norm(dd - z[:, None] * T.axis, axis=1)
        return np.hypot(rho - T.major, z) - T.minor

    xs = _box_points(T, 1500, 0.5)
    check_projection(T, xs, level)
    d = np.linalg.norm(xs - T.closest_point(xs), axis=1)
    assert_no_closer_sample(param, spans, xs, d)
    check_near(T, xs)
    assert T.min_radius_of_curvature() == 0.35
    assert Torus((0, 0, 0), 1, 0.7).min_radius_of_curvature() == pytest.approx(0.3)
    y = T.sample(3000)
    assert y.shape == (3000, 3)
    np.testing.assert_allclose(level(y), 0, atol=1e-14)
    lo, hi = T.bounding_box()
    assert (lo <= y).all() and (y <= hi).all()
    assert (hi - lo - (y.max(axis=0) - y.min(axis=0)) < 0.05).all()  # tight
    dense_pts = _dense(param, spans, (300, 300))[2]
    assert cKDTree(y).query(dense_pts)[0].max() < 2.5 * np.sqrt(T.area() / len(y))


# ----------------------------------------------------------------------------- implicit
def _torus_implicit(R: float, r: float, genus: int | None = 1, **kw: object) -> ImplicitSurface:
    def phi(x: Float) -> Float:
        return (np.sqrt(x[:, 0] ** 2 + x[:, 1] ** 2) - R) ** 2 + x[:, 2] ** 2 - r**2

    def grad(x: Float) -> Float:
        rho = np.sqrt(x[:, 0] ** 2 + x[:, 1] ** 2)
        f = 2 * (rho - R) / np.maximum(rho, 1e-300)
        return np.column_stack([f * x[:, 0], f * x[:, 1], 2 * x[:, 2]])

    box = [[-R - r - 0.1, -R - r - 0.1, -r - 0.1], [R + r + 0.1, R + r + 0.1, r + 0.1]]
    return ImplicitSurface(phi, grad, box, genus=genus, **kw)  # type: ignore[arg-type]


def test_overridden_normal_is_used() -> None:
    """A subclass that overrides only ``normal`` gets it from ``closest_normal`` (the closed
    forms are bypassed, not recursed into) and keeps the closed-form closest points."""

    for base, args in ((Sphere, ((0.1, 0.0, 0.0), 0.8)), (Torus, ((0.0, 0.1, 0.0), 0.55, 0.3))):

        class Flipped(base):  # type: ignore[valid-type, misc]
            def normal(self, y: Float, base: type = base) -> Float:
                return -base.normal(self, y)

        x = np.random.default_rng(3).uniform(-1.0, 1.0, (50, 3))
        y, n = Flipped(*args).closest_normal(x)
        y0, n0 = base(*args).closest_normal(x)
        np.testing.assert_array_equal(y, y0)
        # The override sees the closest points, not x: the same unit normals up to a few
        # ulps of rounding (a wrong normal is off by O(1)).
        np.testing.assert_allclose(n, -n0, rtol=0.0, atol=1e-14)


def test_implicit_torus_against_closed_form() -> None:
    imp, T = _torus_implicit(1.0, 0.3), Torus((0, 0, 0), 1.0, 0.3)
    assert imp.euler_characteristic == 0 and imp.num_components == 1
    x = _box_points(T, 3000, 0.3)
    rho = np.hypot(x[:, 0], x[:, 1])
    x = x[(rho > 0.05) & (np.hypot(rho - 1, x[:, 2]) > 0.02)]  # unique closest points
    phi, y, n = imp.project_normal(x)
    phit, yt, nt = T.project_normal(x)
    np.testing.assert_allclose(phi, phit, atol=1e-13)
    np.testing.assert_allclose(y, yt, atol=1e-9)
    np.testing.assert_allclose(n, nt, atol=1e-9)
    check_projection(imp, x[:300], lambda y: T.lower_bound(y) * np.sign(T.signed_distance(y)))
    check_near(imp, x)
    assert imp.min_radius_of_curvature() == pytest.approx(0.3, rel=0.01)
    assert _torus_implicit(1.0, 0.3, min_radius_of_curvature=0.25).min_radius_of_curvature() == 0.25
    assert imp.area() == pytest.approx(T.area(), rel=0.03)
    y = imp.sample(2000)
    assert y.shape == (2000, 3)
    np.testing.assert_allclose(T.lower_bound(y), 0, atol=1e-13)
    dense_pts = _dense(_torus_param(T), (2 * np.pi, 2 * np.pi), (300, 300))[2]
    assert cKDTree(y).query(dense_pts)[0].max() < 2.5 * np.sqrt(T.area() / len(y))


def test_implicit_ties_on_the_torus_axis() -> None:
    """Points with a circle of closest points (the axis of the torus) or a sphere of them
    (the centre of a sphere): one of the ties, valid, the same on every call. The
    reduced Hessian is singular along the ties; Newton's step there was rounding over
    1e-8 and drifted along the circle until the iterations ran out (RuntimeError)."""
    z = np.linspace(-2.0, 2.0, 41)
    x = np.column_stack([0 * z, 0 * z, z])
    for R, r, kw in [(1.0, 0.35, {}), (1.0, 0.5, {}), (2.0, 0.3, {"resolution": 48})]:
        imp, T = _torus_implicit(R, r, **kw), Torus((0, 0, 0), R, r)
        y = imp.closest_point(x)
        d, dt = np.linalg.norm(y - x, axis=1), np.linalg.norm(T.closest_point(x) - x, axis=1)
        np.testing.assert_allclose(d, dt, rtol=0, atol=1e-12)
        np.testing.assert_allclose(T.lower_bound(y), 0, atol=1e-12)  # on Gamma
        np.testing.assert_array_equal(imp.closest_point(x), y)  # deterministic
        phi, yn, n = imp.project_normal(x)
        np.testing.assert_allclose(np.abs(phi), dt, atol=1e-12)
        np.testing.assert_allclose(np.cross(x - yn, n), 0, atol=1e-9)  # as _valid
    S = ImplicitSurface(
        lambda p: (p * p).sum(axis=1) - 0.49,
        lambda p: 2 * p,
        [[-1.0] * 3, [1.0] * 3],
        resolution=24,
    )
    y = S.closest_point(np.zeros((1, 3)))
    assert np.linalg.norm(y) == pytest.approx(0.7, abs=1e-12)


def _quartic(**kw: object) -> ImplicitSurface:
    return ImplicitSurface(
        lambda x: (x**4).sum(axis=1) - 1,
        lambda x: 4 * x**3,
        [[-1.1] * 3, [1.1] * 3],
        resolution=40,
        **kw,  # type: ignore[arg-type]
    )


def test_implicit_quartic_against_reference() -> None:
    imp = _quartic()
    x = RNG.uniform(-1.6, 1.6, (40, 3))
    d = np.linalg.norm(x - imp.closest_point(x), axis=1)
    ref = reference_distances(_quartic_param, (np.pi, 2 * np.pi), x)
    assert np.max(d - ref) <= 2e-15 * (1 + ref.max())
    assert np.min(d - ref) >= -1e-12
    xs = RNG.uniform(-1.6, 1.6, (800, 3))
    check_projection(imp, xs, lambda y: (y**4).sum(axis=1) - 1)
    d = np.linalg.norm(xs - imp.closest_point(xs), axis=1)
    assert_no_closer_sample(_quartic_param, (np.pi, 2 * np.pi), xs, d, tol=1e-13)
    check_near(imp, xs)
    assert imp.euler_characteristic == 2


def test_implicit_closest_points_stationary_to_rounding() -> None:
    """Closest points on a surface with flat and strongly curved parts (the quartic, its
    Hessian by differences): ``x - y`` along the normal to rounding, and inputs an ulp
    apart give the same points to rounding. The search used to stop where its distance
    test could no longer see the decrease of the distance (steps of about 1e-8 times the
    square root of the distance): 1.5e-10 along Gamma from the stationary point here (up
    to 2e-9 on the fuzz's random blobs and superellipsoids), different for inputs an ulp
    apart (a curved node computed by two cells, or on two numbers of ranks). 1e-14: about
    30 ulps of the coordinates (|y| <= 1)."""
    imp = _quartic()
    y0 = imp.sample(4000)
    x = y0 + 0.03 * RNG.standard_normal(y0.shape)
    y = imp.closest_point(x)
    n = imp.normal(y)
    r = x - y
    tangential = r - (r * n).sum(axis=1)[:, None] * n
    assert np.linalg.norm(tangential, axis=1).max() < 1e-14
    moved = imp.closest_point(np.nextafter(x, np.inf))
    assert np.abs(moved - y).max() < 1e-14


def test_implicit_ellipsoid_and_errors() -> None:
    E = ELLIPSOIDS[1]

    def phi(x: Float) -> Float:
        p = (x - E.center) @ E.rotation / E.semi_axes
        return (p * p).sum(axis=1) - 1

    def grad(x: Float) -> Float:
        return 2 * ((x - E.center) @ E.rotation / E.semi_axes**2) @ E.rotation.T

    imp = ImplicitSurface(phi, grad, E.bounding_box() * 1.1)
    x = _box_points(E, 2000, 0.5)
    np.testing.assert_allclose(imp.signed_distance(x), E.signed_distance(x), atol=1e-13)
    np.testing.assert_array_equal(imp.sign(x), E.sign(x))
    with pytest.raises(ValueError, match="enlarge"):
        ImplicitSurface(phi, grad, [[-0.5] * 3, [0.5] * 3]).sample(10)
    with pytest.raises(ValueError, match="no zero level set"):
        ImplicitSurface(lambda x: (x * x).sum(axis=1) + 1, grad, [[-1] * 3, [1] * 3]).sample(10)
    with pytest.raises(ValueError, match="bounding_box"):
        ImplicitSurface(phi, grad, [[0, 0], [1, 1]])
    # a genus that disagrees with the surface's: both numbers named
    with pytest.raises(ValueError, match=r"1 component\(s\) and genus 0, but genus = 2 given"):
        _ = ImplicitSurface(phi, grad, E.bounding_box() * 1.1, genus=2).euler_characteristic


# ----------------------------------------------------------------------------- motions
def test_rigid_motion_3d() -> None:
    base = Ellipsoid((0.2, 0.1, -0.3), (1.2, 0.8, 0.5), rotation=((0, 1, 1), 0.4))
    axis, angle = np.array([1.0, -2.0, 0.5]), 0.9
    c, t = np.array([0.5, 0.0, 1.0]), np.array([0.3, -0.7, 0.2])
    M = RigidMotion(base, rotation=(axis, angle), center=c, translation=t)
    R = M.rotation
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(R @ axis, axis, atol=1e-15)
    # the same motion as a rotation vector and as a matrix
    for rot in (axis / np.linalg.norm(axis) * angle, R):
        np.testing.assert_allclose(RigidMotion(base, rotation=rot).rotation, R, atol=1e-15)
    moved = Ellipsoid(c + R @ (base.center - c) + t, base.semi_axes, rotation=R @ base.rotation)
    x = _box_points(moved, 500, 0.5)
    phi, y, n = M.project_normal(x)
    phi2, y2, n2 = moved.project_normal(x)
    np.testing.assert_allclose(y, y2, atol=1e-13)
    np.testing.assert_allclose(phi, phi2, atol=1e-13)
    np.testing.assert_allclose(n, n2, atol=1e-13)
    np.testing.assert_array_equal(M.sign(x), moved.sign(x))
    # moving then projecting == projecting the moved base
    xb = c + (x - c - t) @ R
    np.testing.assert_allclose(y, c + (base.closest_point(xb) - c) @ R.T + t, atol=1e-13)
    np.testing.assert_allclose(M.closest_point(x), y, atol=0)
    np.testing.assert_allclose(M.normal(x), n, atol=1e-15)
    np.testing.assert_allclose(np.cross(*M.tangent_basis(x).transpose(1, 0, 2)), n, atol=1e-14)
    assert M.gdim == 3 and M.euler_characteristic == 2 and M.num_components == 1
    assert M.min_radius_of_curvature() == base.min_radius_of_curvature()
    lo, hi = M.bounding_box()
    s = M.sample(500)
    assert (lo <= s).all() and (s <= hi).all()
    np.testing.assert_allclose(moved.signed_distance(s), 0, atol=1e-14)
    d = np.abs(phi)
    assert M.near(x, 0.2)[d <= 0.2].all()
    # moved(): absolute, same base and centre; angle alone is about the z axis
    M2 = M.moved(translation=(0, 0, 1))
    np.testing.assert_allclose(M2.closest_point(x), base.closest_point(x - (0, 0, 1)) + (0, 0, 1))
    Mz = RigidMotion(base, 0.5)
    np.testing.assert_allclose(Mz.rotation, RigidMotion(base, rotation=((0, 0, 1), 0.5)).rotation)
    with pytest.raises(ValueError, match="not both"):
        RigidMotion(base, 0.5, rotation=(axis, angle))
    with pytest.raises(ValueError, match="surfaces"):
        RigidMotion(Circle((0, 0), 1), rotation=np.eye(3))


# ----------------------------------------------------------------------------- domains
def test_domain_3d() -> None:
    C = Sphere((0, 0, 0), 3.0)
    B1 = Ellipsoid((-1.2, 0, 0), (0.8, 0.5, 0.4), rotation=((0, 0, 1), 0.3))
    B2 = Torus((1.2, 0.2, 0), 0.7, 0.2, axis=(1, 0, 0))
    D = Domain(C, [B1, B2])
    assert D.gdim == 3
    assert D.euler_characteristic == 4 and D.num_components == 3
    x = _box_points(D, 4000, 0.3)
    comps = [C, B1, B2]
    ds = np.array([np.linalg.norm(x - b.closest_point(x), axis=1) for b in comps])
    k = ds.argmin(axis=0)
    inside = (C.sign(x) < 0) & (B1.sign(x) > 0) & (B2.sign(x) > 0)
    np.testing.assert_array_equal(D.sign(x), np.where(inside, -1.0, 1.0))
    phi, y, n = D.project_normal(x)
    np.testing.assert_allclose(np.abs(phi), ds.min(axis=0), atol=1e-15)
    np.testing.assert_array_equal(np.sign(phi), D.sign(x))
    np.testing.assert_array_equal(D.component_index(y), k)
    np.testing.assert_array_equal(D.component_index(x), k)
    for j, b in enumerate(comps):
        m = k == j
        np.testing.assert_allclose(y[m], b.closest_point(x[m]), atol=0)
        np.testing.assert_allclose(n[m], (-1 if j else 1) * b.normal(x[m]), atol=0)  # into bodies
    np.testing.assert_allclose(D.closest_point(x), y, atol=0)
    np.testing.assert_allclose(D.normal(x), n, atol=0)
    np.testing.assert_allclose(np.cross(*D.tangent_basis(x).transpose(1, 0, 2)), n, atol=1e-14)
    for dist in (0.05, 0.3):
        assert D.near(x, dist)[ds.min(axis=0) <= dist].all()
    assert (D.lower_bound(x) <= ds.min(axis=0) + 1e-15).all()
    lo, hi = D.bounding_box()
    np.testing.assert_allclose([lo, hi], C.bounding_box())
    s = D.sample(3000)
    assert 2990 <= len(s) <= 3010
    np.testing.assert_allclose(D.signed_distance(s), 0, atol=1e-14)
    assert D.min_radius_of_curvature() == pytest.approx(min(0.4**2 / 0.8, 0.2))
    # a Domain of bodies only (the whole space) with an implicit body
    D2 = Domain(None, [RigidMotion(_quartic(), rotation=((1, 0, 0), 0.3))])
    x2 = RNG.uniform(-2, 2, (300, 3))
    np.testing.assert_array_equal(D2.sign(x2), -D2.bodies[0].sign(x2))
    np.testing.assert_allclose(D2.normal(x2), -D2.bodies[0].normal(x2))


_C1, _C2, _R = np.array([-0.8, 0.0, 0.1]), np.array([0.7, 0.2, -0.1]), 0.5


def _two_balls(**kw: object) -> ImplicitSurface:
    """Two disjoint balls of radius ``_R`` around ``_C1`` and ``_C2``."""
    c1, c2, r = _C1, _C2, _R

    def phi(x: Float) -> Float:
        return (((x - c1) ** 2).sum(axis=1) - r * r) * (((x - c2) ** 2).sum(axis=1) - r * r)

    def grad(x: Float) -> Float:
        f1, f2 = ((x - c1) ** 2).sum(axis=1) - r * r, ((x - c2) ** 2).sum(axis=1) - r * r
        return 2 * (x - c1) * f2[:, None] + 2 * (x - c2) * f1[:, None]

    return ImplicitSurface(phi, grad, [[-1.4, -0.6, -0.7], [1.3, 0.8, 0.7]], **kw)  # type: ignore[arg-type]


def test_implicit_topology_counted_on_the_grid() -> None:
    """Without ``genus`` and ``num_components`` the surface counts them on its grid (a
    sphere: 1 component of genus 0, a torus: genus 1, two balls: 2 components), and says
    so; numbers given are checked against the counted ones: a ``ValueError`` names both."""
    sphere = ImplicitSurface(
        lambda x: (x * x).sum(axis=1) - 1, lambda x: 2 * x, [[-1.1] * 3, [1.1] * 3]
    )
    assert (sphere.num_components, sphere.genus, sphere.euler_characteristic) == (1, 0, 2)
    assert sphere.topology_counted and sphere.given_topology == (None, None)
    torus = _torus_implicit(1.0, 0.35, genus=None)
    assert (torus.num_components, torus.genus, torus.euler_characteristic) == (1, 1, 0)
    assert torus.topology_counted and torus.counted_topology == (1, 1)
    balls = _two_balls()
    assert (balls.num_components, balls.genus, balls.euler_characteristic) == (2, 0, 4)
    # given and right: kept, and recorded as given
    given = _torus_implicit(1.0, 0.35)
    assert given.genus == 1 and given.given_topology == (None, 1) and not given.topology_counted
    # given and wrong: a clear error at the first use, naming what was given and counted
    x = np.array([[1.0, 0.0, 0.5]])
    with pytest.raises(
        ValueError, match=r"counts 1 component\(s\) and genus 1, but genus = 0 given"
    ):
        _torus_implicit(1.0, 0.35, genus=0).closest_point(x)
    with pytest.raises(
        ValueError, match=r"counts 2 component\(s\) and genus 0, but num_components = 1 given"
    ):
        _ = _two_balls(num_components=1).euler_characteristic
    with pytest.raises(ValueError, match="genus must be an integer >= 0"):
        _torus_implicit(1.0, 0.35, genus=-1)


def test_implicit_counted_topology_gives_the_same_mesh() -> None:
    """Counting the genus changes nothing but where the number comes from: the mesh of a
    surface whose genus is counted is the mesh of the same surface with the genus given."""
    phi = lambda x: x[:, 0] ** 2 + 2 * x[:, 1] ** 2 + 3 * x[:, 2] ** 2 - 1  # noqa: E731
    grad = lambda x: np.stack([2 * x[:, 0], 4 * x[:, 1], 6 * x[:, 2]], axis=1)  # noqa: E731
    box = [[-1.1, -0.8, -0.7], [1.1, 0.8, 0.7]]
    meshes = [
        mesh_domain(MPI.COMM_WORLD, ImplicitSurface(phi, grad, box, **kw), h=0.5).mesh
        for kw in ({"genus": 0, "num_components": 1}, {})
    ]
    np.testing.assert_array_equal(meshes[0].geometry.x, meshes[1].geometry.x)
    np.testing.assert_array_equal(meshes[0].geometry.dofmaps[0], meshes[1].geometry.dofmaps[0])


def test_implicit_grad_checked_against_phi() -> None:
    """A ``grad`` that is not the gradient of ``phi`` (its negative, or its components
    swapped) is a ``ValueError`` naming a point where it disagrees with the differences of
    ``phi`` (it ended in a closest-point ``RuntimeError`` wrapped in a ``MeshingError``)."""
    box = [[-1.1] * 3, [1.1] * 3]

    def phi(x: Float) -> Float:
        return (x * x).sum(axis=1) - 1

    for grad, hint in ((lambda x: -2 * x, "the opposite way"), (lambda x: 2 * x[:, [1, 0, 2]], "")):
        imp = ImplicitSurface(phi, grad, box)
        np.testing.assert_array_equal(imp.sign(np.zeros((1, 3))), [-1.0])  # phi alone: fine
        with pytest.raises(ValueError, match=r"grad disagrees with phi at \(") as info:
            imp.closest_point(np.full((1, 3), 0.5))
        assert hint in str(info.value) and "central differences of phi" in str(info.value)
        with pytest.raises((ValueError, MeshingError), match="grad disagrees with phi"):
            mesh_domain(MPI.COMM_WORLD, imp, h=0.5)


def test_implicit_two_components() -> None:
    c1, c2, r = _C1, _C2, _R
    imp = _two_balls(num_components=2)
    assert imp.euler_characteristic == 4 and imp.num_components == 2
    ref = Domain(None, [Sphere(c1, r), Sphere(c2, r)])
    x = RNG.uniform([-2.5, -1.5, -1.5], [2.5, 1.5, 1.5], (3000, 3))
    phi_i, y, n = imp.project_normal(x)
    phi_r, yr, nr = ref.project_normal(x)
    tie = np.abs(np.linalg.norm(x - c1, axis=1) - np.linalg.norm(x - c2, axis=1)) < 1e-6
    np.testing.assert_allclose(phi_i, -phi_r, atol=1e-13)  # ref's bodies: signs reversed
    np.testing.assert_allclose(y[~tie], yr[~tie], atol=1e-10)
    np.testing.assert_allclose(n[~tie], -nr[~tie], atol=1e-10)
    assert imp.area() == pytest.approx(2 * 4 * np.pi * r * r, rel=0.02)
    assert imp.min_radius_of_curvature() == pytest.approx(r, rel=1e-3)
    check_near(imp, x)


def test_implicit_surface_functions_of_the_wrong_shape_are_named():
    """phi returning (n, 1) or grad returning (n, 2) got numpy's broadcasting message."""
    box = [[-1.0] * 3, [1.0] * 3]
    x = np.array([[0.7, 0.0, 0.0], [0.0, 0.5, 0.1]])
    column = ImplicitSurface(lambda y: (y * y).sum(1, keepdims=True) - 0.49, lambda y: 2 * y, box)
    with pytest.raises(ValueError, match=r"phi returned an array of shape \(2, 1\)"):
        column.sign(x)
    flat = ImplicitSurface(lambda y: (y * y).sum(1) - 0.49, lambda y: 2 * y[:, :2], box)
    with pytest.raises(ValueError, match=r"grad returned an array of shape \(2, 2\)"):
        flat.normal(x)
