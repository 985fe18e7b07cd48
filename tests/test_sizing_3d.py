"""Local feature size of closed surfaces (sizing_3d): shrinking balls against Gamma and
against the samples, on shapes whose medial axes are known."""

from __future__ import annotations

import numpy as np
import pytest

from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.boundaries.motions import RigidMotion
from dolfinx_universal.boundaries.surfaces import Ellipsoid, ImplicitSurface, Sphere, Torus
from dolfinx_universal.sizing.surfaces import (
    SurfaceFeature,
    _searched,
    sample_nearest,
    shrinking_ball_radii,
    surface_feature_size,
    surface_nearest,
    surface_samples,
)

BOTH = ["surface", "samples"]


def _brute_force(x, n, r_max):
    """The largest sample-free tangent balls by definition, ``O(n^2)``:
    ``min |q - p|^2 / (2 |(q - p).n|)`` over the samples ``q`` on each side."""
    d = x[None, :, :] - x[:, None, :]  # q - p
    d2 = (d * d).sum(axis=2)
    dn = (d * n[:, None, :]).sum(axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = d2 / (2 * np.abs(dn))
    out = []
    for side in (-1, 1):
        rs = np.where(side * dn > 0, r, np.inf)
        out.append(np.minimum(rs.min(axis=1), r_max))
    return out


@pytest.mark.parametrize("nearest", BOTH)
def test_sphere(nearest):
    R = 0.8
    f = surface_feature_size(Sphere([0.1, -0.2, 0.3], R), R / 20, nearest=nearest)
    assert isinstance(f, SurfaceFeature)
    n = len(f.points)
    assert f.points.shape == f.normals.shape == (n, 3) and f.feature.shape == (n,)
    assert 4 * np.pi * 400 <= n <= 4 * np.pi * 400 + 1 and (f.labels == 0).all()
    assert not f.points.flags.writeable and not f.feature.flags.writeable
    assert f.spacing == pytest.approx(R / 20, rel=0.1)
    np.testing.assert_allclose(f.normals, (f.points - [0.1, -0.2, 0.3]) / R, atol=1e-12)
    np.testing.assert_allclose(f.feature, R, rtol=1e-9)
    np.testing.assert_allclose(f.r_inside, R, rtol=1e-9)
    assert (f.r_outside == f.r_max).all() and f.r_max == pytest.approx(2 * np.sqrt(3) * R)


@pytest.mark.parametrize("nearest", BOTH)
@pytest.mark.parametrize("c", [1e5, 1e6])
def test_sphere_far_from_the_origin(nearest, c):
    """A unit sphere centred at (c, c, c): its coordinates' rounding (1.5e-11 at 1e5) is
    above the balls' relative tolerance 1e-12 r_max, and a ball tangent at p found p itself
    inside it (feature sizes 0 before, ``ValueError: feature sizes must be positive`` in
    mesh_domain); the radii are those at the origin, to the coordinates' rounding."""
    sf = surface_feature_size(Sphere((c, c, c), 1.0), 0.125, nearest=nearest)
    assert np.allclose(sf.r_inside, 1.0, rtol=0, atol=1e-6 if nearest == "surface" else 0.02)
    assert np.allclose(sf.r_outside, sf.r_max)


@pytest.mark.parametrize("nearest", BOTH)
def test_torus_tube_and_hole(nearest):
    """Inside: the core circle, 0.35 away. Outside: the axis; on the inner equator the ball
    reaches it at R - r = 0.65 (the hole is 1.3 across); the outer equator and the top of
    the tube see nothing (r_max)."""
    f = surface_feature_size(Torus([0, 0, 0], 1.0, 0.35), 0.05, nearest=nearest)
    rho, z = np.hypot(f.points[:, 0], f.points[:, 1]), f.points[:, 2]
    tol = 1e-9 if nearest == "surface" else 2e-3
    np.testing.assert_allclose(f.r_inside, 0.35, rtol=tol)
    np.testing.assert_allclose(f.feature, 0.35, rtol=tol)
    inner = (rho < 0.66) & (np.abs(z) < 0.05)
    assert inner.sum() > 50
    np.testing.assert_allclose(f.r_outside[inner], 0.65, rtol=5e-3)
    assert (f.r_outside >= 0.65 * (1 - 1e-9)).all()
    assert (f.r_outside[rho > 1.3] == f.r_max).all()


@pytest.mark.parametrize("nearest", BOTH)
def test_ellipsoid_tips(nearest):
    """The smallest feature is the smaller radius of curvature c^2 / a at the tips of the
    long axis; the largest is at most the smallest semi-axis."""
    a, b, c = 1.0, 0.7, 0.5
    f = surface_feature_size(Ellipsoid([0, 0, 0], [a, b, c]), 0.04, nearest=nearest)
    k = int(np.argmin(f.feature))
    assert abs(f.points[k, 0]) > 0.99
    tol = 2e-3 if nearest == "surface" else 2e-2
    assert f.feature[k] == pytest.approx(c**2 / a, rel=tol)
    assert f.feature[k] >= c**2 / a * (1 - 1e-9)  # an upper estimate
    assert f.feature.max() == pytest.approx(c, rel=tol)  # the ball of radius c at the centre
    if nearest == "surface":
        assert f.feature.max() <= c * (1 + 1e-9)
    assert (f.r_outside == f.r_max).all()  # convex


def test_spheres_in_a_sphere():
    """Two bodies 0.1 apart inside a container: the gap's feature is 0.05 at the facing
    points, that between a body and the container 0.175; labels follow the components."""
    bodies = [Sphere([-0.35, 0, 0], 0.3), Sphere([0.35, 0, 0], 0.3)]
    d = Domain(Sphere([0, 0, 0], 1.0), bodies)
    f = surface_feature_size(d, 0.02)
    counts = np.bincount(f.labels)
    assert counts.tolist() == [int(np.ceil(4 * np.pi / 0.02**2))] + 2 * [
        int(np.ceil(4 * np.pi * 0.09 / 0.02**2))
    ]
    for k in (1, 2):  # normals out of the domain: into the bodies
        mine = f.labels == k
        towards = (bodies[k - 1].center - f.points[mine]) / 0.3
        np.testing.assert_allclose(f.normals[mine], towards, atol=1e-12)
        assert f.feature[mine].min() == pytest.approx(0.05, rel=1e-2)  # nearest sample
        # across the gap, the ball centred at a + (0.3 + r) u touches the other body when
        # r = D / (2 cos theta) - 0.3 (D = 0.7 between the centres, theta from the axis)
        other = bodies[2 - k].center - bodies[k - 1].center
        cos = -towards @ other / 0.7  # u . (b - a) / D with u = -towards, outward of the body
        facing = np.flatnonzero(mine)[cos > 0.95]
        assert len(facing) > 10
        exact = 0.7 / (2 * cos[cos > 0.95]) - 0.3
        np.testing.assert_allclose(f.r_inside[facing], exact, rtol=1e-9)
        assert f.r_outside[mine].max() == pytest.approx(0.3)  # the body itself
    cont = f.labels == 0
    assert f.feature[cont].min() == pytest.approx(0.175, rel=2e-3)
    assert (f.r_outside[cont] == f.r_max).all()
    assert f.feature.min() >= 0.05 * (1 - 1e-9)


def test_shrinking_balls_among_samples_match_the_definition():
    """With the nearest samples, the shrinking balls are exactly the largest sample-free
    ones (O(n^2) check), for one surface and for components with gaps."""
    for b, s in (
        (Ellipsoid([0, 0, 0], [1.0, 0.7, 0.5]), 0.1),
        (Domain(Sphere([0, 0, 0], 1.0), [Sphere([0.3, 0, 0], 0.5)]), 0.15),
    ):
        x, n, _ = surface_samples(b, s)
        r_max = 3.5
        got = shrinking_ball_radii(x, n, r_max, sample_nearest(x))
        for g, ref in zip(got, _brute_force(x, n, r_max)):
            np.testing.assert_allclose(g, ref, rtol=1e-9)


def test_samples_bound_the_surface_radii():
    """Sample-free balls are at least the Gamma-free ones, by ``r (s / r)^2`` at most."""
    e = Ellipsoid([0, 0, 0], [1.0, 0.7, 0.5], rotation=([1, 2, 3], 0.7))
    x, n, _ = surface_samples(e, 0.05)
    among_samples = shrinking_ball_radii(x, n, 3.0, sample_nearest(x))
    against_gamma = shrinking_ball_radii(x, n, 3.0, surface_nearest(e))
    for s_r, c_r in zip(among_samples, against_gamma):
        assert (s_r >= c_r * (1 - 1e-9)).all()
        assert (s_r - c_r <= 4 * 0.05**2 / c_r).all()


def test_rigid_motion_and_bounding_box_area():
    """A moved surface has the same features; a surface without ``area`` is sampled from
    its bounding box's area (more samples, same features)."""

    class NoArea(Sphere):
        def area(self):
            raise NotImplementedError

    moved = RigidMotion(Sphere([0, 0, 0], 0.5), rotation=([0, 0, 1], 1.0), translation=[1, 2, 3])
    f = surface_feature_size(moved, 0.05)
    np.testing.assert_allclose(f.feature, 0.5, rtol=1e-9)
    s = NoArea([0, 0, 0], 0.5)
    g = surface_feature_size(s, 0.05)
    side = np.diff(s.bounding_box(), axis=0)[0]  # a cube of side about 1
    assert len(g.points) == int(np.ceil(6 * side[0] ** 2 / 0.05**2)) > 4 * np.pi * 0.25 / 0.05**2
    np.testing.assert_allclose(g.feature, 0.5, rtol=1e-9)


def test_failing_projections_fall_back_on_samples():
    """Where ``closest_point`` raises, the chunk takes the nearest samples instead."""

    class Fragile(Sphere):
        def closest_point(self, x):
            x = np.asarray(x)
            if (np.linalg.norm(x - self.center, axis=1) < 0.1).any():
                raise RuntimeError("no converged projection")
            return super().closest_point(x)

    f = surface_feature_size(Fragile([0, 0, 0], 1.0), 0.1, nearest="surface")
    np.testing.assert_allclose(f.feature, 1.0, rtol=1e-9)


def test_implicit_surface_uses_the_samples():
    """An implicit sphere: "auto" takes the samples (its projections are a search)."""
    s = ImplicitSurface(
        lambda x: (x * x).sum(axis=1) - 0.36, lambda x: 2 * x, [[-0.7] * 3, [0.7] * 3]
    )
    assert _searched(s) and _searched(Domain(Sphere([0, 0, 0], 2.0), [RigidMotion(s)]))
    assert not _searched(Domain(Sphere([0, 0, 0], 2.0), [RigidMotion(Sphere([0, 0, 0], 1))]))
    f = surface_feature_size(s, 0.06)
    np.testing.assert_allclose(f.feature, 0.6, rtol=5e-3)
    np.testing.assert_allclose(f.normals, f.points / 0.6, atol=1e-6)


def test_bad_arguments():
    with pytest.raises(ValueError, match="nearest"):
        surface_feature_size(Sphere([0, 0, 0], 1.0), 0.1, nearest="delaunay")
    with pytest.raises(ValueError, match="spacing"):
        surface_feature_size(Sphere([0, 0, 0], 1.0), 0.0)
    from dolfinx_universal import Circle

    with pytest.raises(ValueError, match="surface"):
        surface_feature_size(Circle((0.0, 0.0), 1.0), 0.1)
