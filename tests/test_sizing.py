"""Feature sizes and size fields against exact values and brute-force references."""

from __future__ import annotations

import pickle
import time

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from dolfinx_universal.boundaries.curves import (
    Circle,
    Ellipse,
    ImplicitCurve,
    PeriodicSpline,
    PolarCurve,
)
from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.boundaries.motions import RigidMotion
from dolfinx_universal.sizing.fields import (
    FEATURE_DIVISOR,
    CurveSamples,
    SizeField,
    curve_samples,
    feature_divisor,
    feature_size,
    medial_radius,
    size_field,
    target_sizes,
)

# ----------------------------------------------------------------------------- references


def discrete_radii(samples: CurveSamples, r_max: float) -> tuple[np.ndarray, np.ndarray]:
    """The definition, over all pairs: min over q of |q - p|^2 / (2 |(q - p).n|) per side."""
    p, n = samples.points, samples.normals
    r_in, r_out = np.full(len(p), r_max), np.full(len(p), r_max)
    for c in range(0, len(p), 256):
        v = p[None, :, :] - p[c : c + 256, None, :]
        vv = (v * v).sum(axis=2)
        vn = (v * n[c : c + 256, None, :]).sum(axis=2)
        tol = 1e-12 * np.sqrt(vv)
        with np.errstate(divide="ignore", invalid="ignore"):
            g = vv / (2 * np.abs(vn))
        r_in[c : c + 256] = np.minimum(r_max, np.where(vn < -tol, g, np.inf).min(axis=1))
        r_out[c : c + 256] = np.minimum(r_max, np.where(vn > tol, g, np.inf).min(axis=1))
    return r_in, r_out


def continuous_radius(curves, p, n, side, rho=np.inf, m=200_000):
    """Radius of the largest disc tangent at ``p`` (centre ``p + side r n``) free of the curves.

    ``curves``: parametrisations ``c(t)``, ``t`` in ``[0, 1)``; ``rho``: radius of curvature
    at ``p`` if the curve bends towards that side (the limit of the ratio as ``q -> p``).
    Dense samples, then a bounded scalar minimisation around the best one.
    """
    d = side * np.asarray(n)
    best = rho
    for c in curves:
        t = np.arange(m) / m

        def g(tt, c=c):
            v = c(np.atleast_1d(tt)) - p
            vd = v @ d
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(vd > 1e-14, (v * v).sum(axis=1) / (2 * vd), np.inf)

        gt = g(t)
        k = int(np.argmin(gt))
        if np.isfinite(gt[k]):
            res = minimize_scalar(
                lambda s: float(g(s)[0]),
                bounds=(t[k] - 1.5 / m, t[k] + 1.5 / m),
                method="bounded",
                options={"xatol": 1e-14},
            )
            best = min(best, gt[k], res.fun)
    return best


def ellipse_curve(a, b, centre=(0.0, 0.0), angle=0.0):
    cs, sn = np.cos(angle), np.sin(angle)

    def c(t):
        x, y = a * np.cos(2 * np.pi * t), b * np.sin(2 * np.pi * t)
        return np.column_stack([centre[0] + cs * x - sn * y, centre[1] + sn * x + cs * y])

    return c


def circle_curve(centre, radius):
    return ellipse_curve(radius, radius, centre)


def nearest(samples, x):
    return int(np.argmin(np.linalg.norm(samples.points - np.asarray(x), axis=1)))


def two_discs(c1, c2, r):
    """ImplicitCurve of the union of two disjoint discs (Omega = inside exactly one)."""
    c1, c2 = np.asarray(c1, float), np.asarray(c2, float)

    def f(x):
        return ((x - c1) ** 2).sum(1) - r * r, ((x - c2) ** 2).sum(1) - r * r

    def val(x):
        a, b = f(x)
        return a * b

    def grad(x):
        a, b = f(x)
        return 2 * (x - c1) * b[:, None] + 2 * (x - c2) * a[:, None]

    lo = np.minimum(c1, c2) - 1.2 * r
    hi = np.maximum(c1, c2) + 1.2 * r
    return ImplicitCurve(val, grad, bbox=[lo, hi])


def neck(amp=0.7):
    return PolarCurve(
        lambda t: 1 + amp * np.cos(2 * t),
        lambda t: -2 * amp * np.sin(2 * t),
        lambda t: -4 * amp * np.cos(2 * t),
    )


# ----------------------------------------------------------------------------- samples


def test_loops_of_compositions():
    body = RigidMotion(Ellipse((0, 0), 0.4, 0.1), 0.3, translation=(0.5, 0.2))
    d = Domain(Circle((0, 0), 2), [body, Circle((-1, 0), 0.3)])
    loops = d.loops(0.01)
    assert len(loops) == 3
    for q, (b, _) in zip(loops, d.components):
        assert np.abs(b.signed_distance(q)).max() < 1e-9
        assert np.linalg.norm(np.roll(q, -1, axis=0) - q, axis=1).max() <= 0.01
    # RigidMotion of a two-loop ImplicitCurve keeps both loops.
    moved = RigidMotion(two_discs((-1, 0), (1, 0), 0.5), 0.5, translation=(1, 2))
    assert len(moved.loops(0.02)) == 2


def test_curve_samples_structure():
    d = Domain(Circle((0, 0), 2), [Circle((0.5, 0), 0.3), Ellipse((-1, 0), 0.4, 0.1, 0.3)])
    s = curve_samples(d, 0.01)
    assert s.num_curves == 3 and s.offsets.tolist()[0] == 0 and s.offsets[-1] == len(s.points)
    assert s.spacing <= 0.01
    assert np.array_equal(np.bincount(s.labels), np.diff(s.offsets))
    assert s.encloses_domain.tolist() == [True, False, False]
    assert s.expected_pieces == 1
    # labels follow the components; normals point into the bodies (out of Omega)
    for k, (b, body) in enumerate(d.components):
        pk = s.points[s.labels == k]
        assert np.abs(b.signed_distance(pk)).max() < 1e-9
        nb = b.normal(pk)
        assert np.allclose(s.normals[s.labels == k], -nb if body else nb)
    assert not s.points.flags.writeable
    with pytest.raises(ValueError, match="spacing"):
        curve_samples(d, 0.0)


@pytest.mark.parametrize(
    "make, pieces, encloses",
    [
        (lambda: Circle((0.2, 0.1), 0.7), 1, [True]),
        (
            lambda: Domain(Circle((0, 0), 2), [Circle((0.5, 0), 0.3), Circle((-1, 0), 0.3)]),
            1,
            [True, False, False],
        ),
        (lambda: Domain(None, [Ellipse((0, 0), 1, 0.5)]), 1, [False]),
        (lambda: Domain(None, [Circle((-1, 0), 0.5), Circle((1, 0), 0.5)]), 1, [False, False]),
        (lambda: two_discs((-1, 0), (1, 0), 0.5), 2, [True, True]),
        (
            lambda: RigidMotion(two_discs((-1, 0), (1, 0), 0.5), 1.0, translation=(3, 1)),
            2,
            [True, True],
        ),
    ],
)
def test_expected_pieces(make, pieces, encloses):
    s = curve_samples(make(), 0.01)
    assert s.expected_pieces == pieces
    assert sorted(s.encloses_domain.tolist()) == sorted(encloses)


def test_expected_pieces_nested_and_complement():
    # Omega = {r < 0.5} U {1 < r < 2}: curves r = 2 and r = 0.5 enclose it, r = 1 does not.
    def f(x):
        q = (x * x).sum(1)
        return (q - 4) * (q - 1) * (q - 0.25)

    def grad(x):
        q = (x * x).sum(1)
        d = (q - 1) * (q - 0.25) + (q - 4) * (q - 0.25) + (q - 4) * (q - 1)
        return 2 * x * d[:, None]

    s = curve_samples(ImplicitCurve(f, grad, bbox=[[-2.1, -2.1], [2.1, 2.1]]), 0.01)
    assert s.num_curves == 3 and s.expected_pieces == 2
    radius = np.array([np.linalg.norm(s.points[s.labels == k], axis=1).mean() for k in range(3)])
    assert np.allclose(np.sort(radius), [0.5, 1, 2], atol=1e-9)
    assert s.encloses_domain[np.argsort(radius)].tolist() == [True, False, True]
    # the outside of a circle: the far field only
    out = ImplicitCurve(
        lambda x: (x * x).sum(1) - 1,
        lambda x: 2 * x,
        bbox=[[-1.2, -1.2], [1.2, 1.2]],
        inside_negative=False,
    )
    s = curve_samples(out, 0.01)
    assert s.encloses_domain.tolist() == [False] and s.expected_pieces == 1


def test_two_loop_labels():
    s = curve_samples(two_discs((-1, 0.5), (1.2, 0), 0.5), 0.005)
    assert s.num_curves == 2 and set(s.labels.tolist()) == {0, 1}
    for k in range(2):
        pk = s.points[s.labels == k]
        centre = pk.mean(axis=0)
        assert np.allclose(np.linalg.norm(pk - centre, axis=1), 0.5, atol=1e-9)
    assert s.expected_pieces == 2


# ----------------------------------------------------------------------------- medial radius


@pytest.mark.parametrize(
    "make, spacing",
    [
        (lambda: Circle((0.3, 0.1), 0.7), 0.005),
        (lambda: Ellipse((0, 0), 2, 0.5, 0.2), 0.01),
        (lambda: neck(0.7), 0.01),
        (lambda: neck(0.5), 0.005),  # symmetric: co-circular quadruples of samples
        (
            lambda: Domain(
                Circle((0, 0), 2), [Circle((0.5, 0), 0.3), Ellipse((-1, 0), 0.5, 0.05, 0.3)]
            ),
            0.01,
        ),
        (lambda: Domain(None, [Circle((-0.51, 0), 0.5), Circle((0.51, 0), 0.5)]), 0.005),
    ],
)
def test_medial_radius_is_the_discrete_definition(make, spacing):
    """The Delaunay shortcut gives exactly the minimum over all samples."""
    s = curve_samples(make(), spacing)
    r_in, r_out = medial_radius(s, r_max=10.0)
    ref_in, ref_out = discrete_radii(s, 10.0)
    assert np.allclose(r_in, ref_in, rtol=1e-9, atol=0)
    assert np.allclose(r_out, ref_out, rtol=1e-9, atol=0)


def test_circle():
    R = 0.7
    s, feature = feature_size(Circle((0.3, 0.1), R))
    r_in, r_out = medial_radius(s)
    assert np.allclose(r_in, R, rtol=1e-9)
    assert np.allclose(feature, R, rtol=1e-9)
    diag = np.linalg.norm(s.points.max(0) - s.points.min(0))
    assert np.allclose(r_out, diag)  # nothing outside a convex curve: the cap
    assert np.allclose(medial_radius(s, r_max=5.0)[1], 5.0)


def test_ellipse_exact_values_and_reference():
    a, b, ang, c0 = 2.0, 0.5, 0.3, (0.1, -0.2)
    e = Ellipse(c0, a, b, ang)
    s, feature = feature_size(e)
    r_in, r_out = medial_radius(s)
    h = s.spacing
    cs, sn = np.cos(ang), np.sin(ang)
    tip = np.array(c0) + a * np.array([cs, sn])
    top = np.array(c0) + b * np.array([-sn, cs])
    i, j = nearest(s, tip), nearest(s, top)
    assert abs(r_in[i] - b * b / a) <= 2e-3 * b * b / a
    assert abs(r_in[j] - b) <= 1e-3 * b  # the disc of radius b about the centre
    assert abs(feature.min() - b * b / a) <= 1e-3 * b * b / a
    assert np.all(r_out > 0.99 * np.linalg.norm(s.points.max(0) - s.points.min(0)))
    # everywhere: 0 <= r - r_c <= r_c (s / r_c)^2 / 8, r_c by brute force
    curve = ellipse_curve(a, b, c0, ang)
    rng = np.random.default_rng(1)
    for k in rng.choice(len(s.points), 25, replace=False):
        p, n = s.points[k], s.normals[k]
        t = np.arctan2(*(np.array([[cs, sn], [-sn, cs]]) @ (p - c0) / [a, b])[::-1])
        rho = (a * a * np.sin(t) ** 2 + b * b * np.cos(t) ** 2) ** 1.5 / (a * b)
        ref = continuous_radius([curve], p, n, -1, rho)
        assert -1e-9 * ref <= r_in[k] - ref <= ref * (h / ref) ** 2 / 8 + 1e-9 * ref, (k, r_in[k])


def test_two_circles_gap():
    g, R = 0.02, 0.5
    d = Domain(None, [Circle((-R - g / 2, 0), R), Circle((R + g / 2, 0), R)])
    s, feature = feature_size(d)
    r_in, r_out = medial_radius(s)
    assert s.spacing <= g / 2 / 16
    k = nearest(s, (-g / 2, 0))
    assert abs(r_in[k] - g / 2) <= 1e-3 * g / 2
    assert abs(feature.min() - g / 2) <= 1e-3 * g / 2
    assert np.allclose(r_out, R, rtol=1e-9)  # into the bodies: their radius
    # brute force on some samples near the gap
    curves = [circle_curve((-R - g / 2, 0), R), circle_curve((R + g / 2, 0), R)]
    cap = np.linalg.norm(s.points.max(0) - s.points.min(0))
    for k in np.argsort(np.abs(s.points[:, 0]))[:: len(s.points) // 40][:20]:
        ref = min(continuous_radius(curves, s.points[k], s.normals[k], -1), cap)
        assert -1e-9 * ref <= r_in[k] - ref <= ref * (s.spacing / ref) ** 2 / 16 + 1e-9 * ref


def test_thin_body_in_container():
    a, t, ang, c0 = 0.5, 0.05, 0.4, np.array([0.3, 0.2])
    d = Domain(Circle((0, 0), 2), [Ellipse(c0, a, t, ang)])
    s, feature = feature_size(d)
    r_in, r_out = medial_radius(s)
    cs, sn = np.cos(ang), np.sin(ang)
    tip, side = c0 + a * np.array([cs, sn]), c0 + t * np.array([-sn, cs])
    i, j = nearest(s, tip), nearest(s, side)
    assert abs(r_out[i] - t * t / a) <= 2e-3 * t * t / a  # into the body at the tip
    assert abs(r_out[j] - t) <= 1e-3 * t  # half the thickness
    assert abs(feature.min() - t * t / a) <= 2e-3 * t * t / a
    # on the container: at most its radius inside, nothing outside (the cap)
    cont = s.labels == 0
    assert np.all(r_in[cont] <= 2 * (1 + 1e-9))
    diag = np.linalg.norm(s.points.max(0) - s.points.min(0))
    # the cap, to an ulp: np.linalg.norm goes through BLAS ddot, which OpenBLAS's SkylakeX
    # kernel evaluates with a fused multiply-add (8 % of 2-vectors differ by an ulp there)
    assert np.allclose(r_out[cont], diag, rtol=1e-12, atol=0)


def test_polar_neck():
    amp = 0.7
    c = neck(amp)
    s, feature = feature_size(c)
    r_in, r_out = medial_radius(s)
    k = nearest(s, (0, 1 - amp))
    half = 1 - amp  # r(pi/2): the disc of that radius about the pole is inside
    assert abs(r_in[k] - half) <= 1e-3 * half
    # outside: the radius of curvature at the neck, (r^2 + r'^2)^1.5 / |r^2 + 2r'^2 - r r''|
    r, r2 = 1 - amp, 4 * amp
    rho = r**3 / abs(r * r - r * r2)
    assert abs(r_out[k] - rho) <= 2e-3 * rho

    def curve(t):
        th = 2 * np.pi * t
        rr = 1 + amp * np.cos(2 * th)
        return np.column_stack([rr * np.cos(th), rr * np.sin(th)])

    ref = continuous_radius([curve], s.points[k], s.normals[k], +1, rho)
    assert abs(r_out[k] - ref) <= 2e-3 * ref
    assert feature.min() == pytest.approx(min(rho, half), rel=2e-3)


def test_straight_parts_give_no_tiny_radii():
    """A stadium sampled exactly (straight sides): radii only from the geometry."""
    L, R, m = 2.0, 0.3, 400
    xs = np.linspace(-L / 2, L / 2, m, endpoint=False)
    th = np.linspace(-np.pi / 2, np.pi / 2, 200, endpoint=False)
    parts = [
        np.column_stack([xs, np.full(m, -R)]),
        np.column_stack([L / 2 + R * np.cos(th), R * np.sin(th)]),
        np.column_stack([-xs, np.full(m, R)]),
        np.column_stack([-L / 2 - R * np.cos(th), -R * np.sin(th)]),
    ]
    normals = [
        np.tile([0.0, -1.0], (m, 1)),
        np.column_stack([np.cos(th), np.sin(th)]),
        np.tile([0.0, 1.0], (m, 1)),
        np.column_stack([-np.cos(th), -np.sin(th)]),
    ]
    p, n = np.concatenate(parts), np.concatenate(normals)
    s = CurveSamples(
        p, n, np.zeros(len(p), np.intp), np.array([0, len(p)]), 1, np.array([True]), 1, 0.01
    )
    r_in, r_out = medial_radius(s, r_max=100.0)
    assert np.allclose(r_in, R, rtol=1e-9)
    flat = np.abs(np.abs(p[:, 1]) - R) < 1e-15  # the sides (y = +-R exactly), arc ends (ulps)
    assert np.all(r_out[flat] == 100.0)


def test_rigid_motion_invariance():
    base = neck(0.5)
    moved = RigidMotion(base, 0.7, center=(0.2, 0.1), translation=(3, -1))
    s0, s1 = curve_samples(base, 0.005), curve_samples(moved, 0.005)
    assert len(s0.points) == len(s1.points)
    r0, r1 = medial_radius(s0, 100.0), medial_radius(s1, 100.0)
    assert np.allclose(r0, r1, rtol=1e-9)
    assert feature_size(moved)[1].min() == pytest.approx(feature_size(base)[1].min(), rel=1e-3)


def test_touching_or_overlapping_bodies_raise():
    for dx in (0.9, 1.0):  # overlapping, touching
        d = Domain(Circle((0, 0), 3), [Circle((0, 0), 0.5), Circle((dx, 0.0), 0.5)])
        with pytest.raises(ValueError, match="overlapping|feature of size"):
            feature_size(d, max_samples=2**15)
    # a narrow but resolvable gap refines instead
    d = Domain(Circle((0, 0), 3), [Circle((0, 0), 0.5), Circle((1.01, 0.0), 0.5)])
    s, f = feature_size(d, max_samples=2**17)
    assert f.min() == pytest.approx(0.005, rel=2e-3)
    with pytest.raises(ValueError, match="smaller spacing"):
        feature_size(d, spacing=0.01)


def test_touching_bodies_are_named():
    """Where the feature that cannot be resolved is a contact between two components of a
    Domain, the error names them and the place."""
    d = Domain(None, [Circle((0, 0), 1), Circle((2, 0), 1)])
    with pytest.raises(ValueError, match=r"body 0 and body 1 touch or nearly touch near \(1, "):
        feature_size(d, 0.01)
    d = Domain(Circle((0, 0), 3), [Circle((0, 0), 0.5), Circle((1.0, 0.0), 0.5)])
    with pytest.raises(ValueError, match=r"body 1 and body 2 touch or nearly touch near \(0.5, "):
        feature_size(d, 0.01)


def test_feature_size_timings():
    pts = np.array(
        [
            [1, 0],
            [0.8, 0.6],
            [0.3, 0.9],
            [-0.2, 1.1],
            [-0.7, 0.8],
            [-1, 0.3],
            [-1.1, -0.2],
            [-0.8, -0.7],
            [-0.3, -0.6],
            [0, -0.2],
            [0.4, -0.8],
            [0.9, -0.5],
        ]
    )
    spline = PeriodicSpline(pts)
    t = time.perf_counter()
    s, f = feature_size(spline)
    t1 = time.perf_counter() - t
    assert f.min() >= 16 * s.spacing
    d = Domain(
        Circle((0, 0), 2),
        [
            Circle((0.5, 0), 0.3),
            Ellipse((-1, 0), 0.5, 0.05, 0.3),
            RigidMotion(Circle((0, 1), 0.3), 0.1, translation=(0, 0.2)),
        ],
    )
    t = time.perf_counter()
    sd, fd = feature_size(d)
    t2 = time.perf_counter() - t
    assert fd.min() == pytest.approx(0.05**2 / 0.5, rel=2e-3)
    print(
        f"\nfeature_size: PeriodicSpline(12 points) {len(s.points)} samples {t1:.3f} s, "
        f"min feature {f.min():.4g}; Domain(container + 3 bodies) {len(sd.points)} samples "
        f"{t2:.3f} s, min feature {fd.min():.4g}"
    )


# ----------------------------------------------------------------------------- targets


def test_target_sizes():
    f = np.array([0.3, 0.03, 3.0])
    assert np.allclose(target_sizes(f, 0.5, 1), np.minimum(0.5, f / 3))
    assert np.allclose(target_sizes(f, 0.5, 2), np.minimum(0.5, f / 3))
    assert np.allclose(target_sizes(f, 0.5, 3), np.minimum(0.5, f / 4))
    assert np.allclose(target_sizes(f, 0.5, 5), np.minimum(0.5, f / FEATURE_DIVISOR[3]))
    assert np.allclose(target_sizes(f, 0.5, 1, factor=10), np.minimum(0.5, f / 10))
    assert feature_divisor(4) == 4.0
    with pytest.raises(ValueError):
        target_sizes(f, 0.5, 0)
    with pytest.raises(ValueError):
        target_sizes(-f, 0.5, 1)


# ----------------------------------------------------------------------------- size fields


def exact_field(x, p, s, h_max, g):
    out = np.full(len(x), h_max)
    for c in range(0, len(x), 512):
        d = np.linalg.norm(x[c : c + 512, None, :] - p[None], axis=2)
        out[c : c + 512] = np.minimum(h_max, (s[None] + g * d).min(axis=1))
    return out


def test_size_field_against_brute_force():
    rng = np.random.default_rng(0)
    p = rng.uniform(-1, 1, (3000, 2))
    s = np.exp(rng.uniform(np.log(1e-3), np.log(0.3), len(p)))
    h_max, g = 0.2, 0.2
    field = SizeField(p, s, h_max, g)
    x = np.concatenate([rng.uniform(-1.5, 1.5, (4000, 2)), p[:500]])
    H, E = field(x), exact_field(x, p, s, h_max, g)
    # (1 + 1e-12): the same min of s_i + g |x - p_i| evaluated another way differs by ulps
    assert np.all(H <= E * (1 + 1e-12)) and np.all(H >= E / 1.1 * (1 - 1e-12))
    assert np.all(H <= h_max) and np.all(H > 0)
    assert np.all(field(p) <= s)
    # Lipschitz
    y = x + rng.normal(scale=0.05, size=x.shape)
    assert np.all(np.abs(field(y) - H) <= g * np.linalg.norm(y - x, axis=1) * (1 + 1e-9) + 1e-15)
    # a finer ratio is closer
    fine = SizeField(p, s, h_max, g, ratio=1.01)(x)
    assert np.all(fine <= E * (1 + 1e-12)) and np.all(fine >= E / 1.01 * (1 - 1e-12))


def test_size_field_at_sources_of_lipschitz_data():
    rng = np.random.default_rng(2)
    p = rng.uniform(0, 1, (2000, 2))
    s = 0.01 + 0.1 * np.abs(np.sin(3 * p[:, 0]) * p[:, 1])  # Lipschitz 0.3 < ... no domination
    field = SizeField(p, s, 1.0, gradation=0.5)
    H = field(p)
    assert np.all(H <= s) and np.all(H >= s / 1.1)


def test_size_field_combinations_and_pickle():
    rng = np.random.default_rng(3)
    p = rng.uniform(-1, 1, (500, 2))
    s = rng.uniform(0.01, 0.1, len(p))
    field = SizeField(p, s, 0.3, 0.2)
    spots = np.array([[0.0, 0.0], [2.0, 2.0]])
    ref = field.refined(spots, 0.001)
    assert len(ref.points) == len(p) + 2 and ref.gradation == 0.2
    x = rng.uniform(-2, 2, (2000, 2))
    assert np.all(ref(x) <= field(x))
    assert np.all(ref(spots) <= 0.001) and np.all(ref(spots) >= 0.001 / 1.1)
    exact = exact_field(x, np.vstack([p, spots]), np.concatenate([s, [0.001, 0.001]]), 0.3, 0.2)
    assert np.all(ref(x) <= exact * (1 + 1e-12)) and np.all(ref(x) >= exact / 1.1)  # (ulps)
    other = SizeField(spots, [0.002, 0.5], 0.25, gradation=0.5)
    both = field.minimum(other)
    assert both.h_max == 0.25 and both.gradation == 0.5
    assert np.allclose(both(x), np.minimum(field(x), other(x)), rtol=0.1)
    assert np.all(both(x) <= np.minimum(field(x), other(x)) * 1.1)
    back = pickle.loads(pickle.dumps(both))
    assert np.array_equal(back(x), both(x))
    # sequences of arrays; sizes above h_max change nothing
    f2 = size_field([p[:200], p[200:]], [s[:200], s[200:]], 0.3)
    assert np.array_equal(f2(x), field(x))
    f3 = SizeField(p, np.full(len(p), 1.0), 0.3)
    assert np.all(f3(x) == 0.3)
    with pytest.raises(ValueError):
        SizeField(p, -s, 0.3)
    with pytest.raises(ValueError):
        SizeField(p, s[:-1], 0.3)


def test_size_field_speed():
    """1e5 sources on the feature samples of a domain, 2e5 query points (times printed; the
    speed itself is measured in the benchmarks)."""
    d = Domain(Circle((0, 0), 2), [Circle((0.5, 0), 0.3), Ellipse((-1, 0), 0.5, 0.05, 0.3)])
    samples, feature = feature_size(d)
    rng = np.random.default_rng(4)
    x = rng.uniform(-2.1, 2.1, (200_000, 2))
    sub = rng.choice(len(x), 500, replace=False)  # against the brute-force field
    lines = []
    for h_max, m in ((0.1, len(x)), (0.5, 50_000)):
        sizes = target_sizes(feature, h_max, 2)
        t = time.perf_counter()
        field = SizeField(samples.points, sizes, h_max)
        field(x[:1])
        t0 = time.perf_counter()
        H = field(x[:m])
        t1 = time.perf_counter()
        E = exact_field(x[sub], samples.points, sizes, h_max, 0.2)
        assert np.all(H <= h_max) and H.min() >= sizes.min() / 1.1
        Hs = field(x[sub])
        assert np.all(Hs <= E * (1 + 1e-12)) and np.all(Hs >= E / 1.1)  # (1e-12: ulps)
        lines.append(
            f"h_max {h_max}: {len(samples.points)} sources (sizes >= {sizes.min():.3g}), "
            f"build {t0 - t:.3f} s, {m:.0e} points {t1 - t0:.3f} s"
        )
    # the worst case for nearest queries: points around the centre of a circle of sources
    t = np.arange(100_000) * (2 * np.pi / 100_000)
    ring = np.column_stack([np.cos(t), np.sin(t)])
    field = SizeField(ring, np.full(len(ring), 0.01), 1.0)
    y = rng.uniform(-0.7, 0.7, (100_000, 2))
    t0 = time.perf_counter()
    H = field(y)
    t1 = time.perf_counter()
    E = 0.01 + 0.2 * (1 - np.linalg.norm(y[:2000], axis=1))
    assert np.all(H[:2000] <= E * (1 + 1e-12)) and np.all(H[:2000] >= E / 1.1)  # (ulps)
    lines.append(f"1e5 sources of size 0.01 on a unit circle, 1e5 points inside: {t1 - t0:.3f} s")
    print("\nsize_field: " + "; ".join(lines))


def test_small_tree_queries_start_no_thread(monkeypatch):
    """``kd_query`` answers as ``cKDTree.query`` does, and starts threads only for large
    queries in a one-process run: scipy starts Python threads for every threaded query, and
    the size field of a ``mesh_domain`` call makes dozens of small ones (before, their
    threads took more than half of the call)."""
    import threading

    from mpi4py import MPI

    from scipy.spatial import cKDTree

    from dolfinx_universal.core import arrays as _geometry

    started = []
    start = threading.Thread.start

    def counted(self):
        started.append(self)
        return start(self)

    monkeypatch.setattr(threading.Thread, "start", counted)
    rng = np.random.default_rng(3)
    tree = cKDTree(rng.random((500, 2)))
    x = rng.random((2000, 2))
    expected = tree.query(x, distance_upper_bound=0.1)
    got = _geometry.kd_query(tree, x, distance_upper_bound=0.1)
    assert not started
    assert all(np.array_equal(a, b) for a, b in zip(got, expected, strict=True))
    d = Domain(Circle((0, 0), 2), [Circle((0.5, 0), 0.3), Ellipse((-1, 0), 0.5, 0.05, 0.3)])
    samples, feature = feature_size(d)
    field = SizeField(samples.points, target_sizes(feature, 0.1, 2), 0.1)
    field(rng.uniform(-2.1, 2.1, (5000, 2)))
    assert not started
    monkeypatch.setattr(_geometry, "THREADED_QUERY", 1000)
    got = _geometry.kd_query(tree, x, distance_upper_bound=0.1)
    assert all(np.array_equal(a, b) for a, b in zip(got, expected, strict=True))
    if MPI.COMM_WORLD.size > 1:  # the ranks occupy the cores
        assert not started
