"""mesh_domain: sizing from the geometry, refinement, certificate; no silent wrong mesh."""

from __future__ import annotations

import dataclasses
import warnings

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from conftest import needs_ranks
from dolfinx import fem
from scipy.spatial import cKDTree

import dolfinx_universal as du
from dolfinx_universal.backgrounds.lattice_tri import equilateral_triangulation

comm = MPI.COMM_WORLD


def area(msh) -> float:
    return comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(msh))))


def row_gap_centre(box, h) -> float:
    """A y halfway between two vertex rows of the equilateral background, near 0."""
    x, _ = equilateral_triangulation(box, h)
    rows = np.unique(np.round(x[:, 1], 12))
    k = np.searchsorted(rows, 0.0)
    return 0.5 * (rows[k - 1] + rows[k])


def long_neck(width: float, yc: float = 0.0, L: float = 1.2, beta: float = 2.0):
    """Omega = {(y - yc)^2 < g(x)}, g = (L^2 - x^2)(a + beta x^4): two lobes joined by a neck of
    width ``width`` at x = 0 that stays thin over about 0.3 (an implicit curve), and its area."""
    a = width**2 / (4 * L**2)

    def g(x):
        return (L**2 - x**2) * (a + beta * x**4)

    def dg(x):
        return -2 * x * (a + beta * x**4) + (L**2 - x**2) * 4 * beta * x**3

    curve = du.ImplicitCurve(
        lambda p: (p[:, 1] - yc) ** 2 - g(p[:, 0]),
        lambda p: np.column_stack([-dg(p[:, 0]), 2 * (p[:, 1] - yc)]),
        bbox=[[-L - 0.05, yc - 1.0], [L + 0.05, yc + 1.0]],
        resolution=1024,
    )
    t = (np.arange(20000) + 0.5) * (np.pi / 20000) - np.pi / 2  # x = L sin t
    exact = float(np.sum(2 * np.sqrt(g(L * np.sin(t))) * L * np.cos(t)) * (np.pi / 20000))
    return curve, exact


def polar_area(curve: du.PolarCurve, n: int = 4096) -> float:
    """1/2 oint r^2 dtheta by the trapezoidal rule (exact for trigonometric polynomials)."""
    t = np.arange(n) * (2 * np.pi / n)
    return 0.5 * float(np.mean(curve.r(t) ** 2)) * 2 * np.pi


H = 0.1
BOX = [[-1.8, -1.8], [1.8, 1.8]]


def thin_body_domain() -> tuple[du.Domain, float]:
    yc = row_gap_centre(BOX, H)
    body = du.Ellipse((0.013, yc), 3 * H, 0.27 * H)  # minor axis 0.54 h, between two rows
    return du.Domain(du.Circle((0.0, 0.0), 1.5), [body]), np.pi * (1.5**2 - 0.3 * 0.027)


def test_conform_refuses_a_body_between_lattice_rows():
    domain, _ = thin_body_domain()
    bg = du.equilateral_mesh(comm, BOX, H)
    with pytest.raises(du.MeshingError, match="curve 1 of the boundary.*is lost") as info:
        du.conform(bg, domain)
    pts = info.value.points
    assert len(pts) and np.abs(pts[:, 1]).max() < 0.1  # it names the body
    # A body alone (the background clips the plane) that falls between lattice points.
    lone = du.Domain(None, [domain.bodies[0]])
    with pytest.raises(du.MeshingError, match="lost|no positive edge"):
        du.conform(bg, lone)


def test_conform_refuses_a_split_neck():
    bg = du.equilateral_mesh(comm, BOX, H)
    curve, _ = long_neck(0.3 * H, row_gap_centre(BOX, H))  # between two vertex rows
    with pytest.raises(du.MeshingError, match="split into 2 loops"):
        du.conform(bg, curve)


@pytest.mark.parametrize("degree", [1, 2])
def test_mesh_domain_meshes_the_thin_body(degree):
    domain, exact = thin_body_domain()
    md = du.mesh_domain(comm, domain, 0.2, degree=degree)
    cert = md.certificate
    assert cert.num_loops == 2 and cert.num_pieces == 1
    # Straight: the inscribed polygons miss O(h^2) per unit length; curved: far less.
    tol = 2e-3 if degree == 1 else 1e-5
    assert abs(area(md.mesh) - exact) < tol * exact
    assert cert.min_angle_deg >= cert.min_angle_floor_deg
    assert cert.max_conditioning_angle_deg < 90
    text = str(cert)
    assert "2 closed loop(s)" in text and "proven" in text
    assert cert.background == "graded" and cert.tdim == 2  # the 2D wording, unchanged
    assert f"{cert.num_cells} cells (degree {degree}" in text and "graded background" in text
    assert "  angles in [" in text and "tetrahedra" not in text


def test_mesh_domain_meshes_the_neck():
    curve, exact = long_neck(0.3 * H)
    md = du.mesh_domain(comm, curve, 0.2, degree=2)
    assert md.certificate.num_loops == 1 and md.certificate.num_pieces == 1
    assert abs(area(md.mesh) - exact) < 1e-4 * exact
    # The background was graded: far finer at the neck than the largest size.
    assert md.certificate.h_min < 0.02 < 0.2 == md.certificate.h_max


def test_low_quality_warns_in_conform_and_is_refined_by_mesh_domain():
    # A five-lobed polar curve on a coarse equilateral background: rho / h well below 2.
    r = du.PolarCurve(
        lambda t: 1 + 0.3 * np.cos(5 * t),
        lambda t: -1.5 * np.sin(5 * t),
        lambda t: -7.5 * np.cos(5 * t),
    )
    bg = du.equilateral_mesh(comm, [[-1.6, -1.6], [1.6, 1.6]], 0.08)
    # Without the relaxation the images of M_h have angles well below 25 degrees here.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cm = du.conform(bg, r, min_angle=25.0, relax=False)
    assert cm.moved_angle_range[0] < 25.0
    assert any("below the quality floor of 25 degrees near (" in str(w.message) for w in caught)
    with pytest.raises(du.MeshingError, match="quality floor"):
        du.conform(bg, r, min_angle=25.0, on_low_quality="raise", relax=False)
    # A floor above the natural 10-14 degrees of unrelaxed meshes is reached by refining.
    md = du.mesh_domain(comm, r, 0.3, degree=2, min_angle=14.0, relax=False)
    assert md.certificate.min_angle_deg >= 14.0 and md.certificate.refinement_rounds >= 1
    assert abs(area(md.mesh) - polar_area(r)) < 1e-4
    # The relaxation lifts the same floor without any refinement.
    md = du.mesh_domain(comm, r, 0.3, degree=2, min_angle=25.0)
    assert md.certificate.min_angle_deg >= 25.0 and md.certificate.refinement_rounds == 0


def test_refinement_rounds_repair_an_undersized_background():
    """With the target size equal to the feature size (a third of the default) the first
    background fails the checks without the relaxation; local refinement repairs it in a
    few rounds."""
    r = du.PolarCurve(
        lambda t: 1 + 0.3 * np.cos(5 * t),
        lambda t: -1.5 * np.sin(5 * t),
        lambda t: -7.5 * np.cos(5 * t),
    )
    md = du.mesh_domain(comm, r, 0.3, degree=3, size_factor=0.7, relax=False)
    cert = md.certificate
    assert 1 <= cert.refinement_rounds <= 8 and len(cert.refinements) == cert.refinement_rounds
    assert abs(area(md.mesh) - polar_area(r)) < 1e-5
    assert cert.min_jacobian_ratio > 0
    with pytest.raises(du.MeshingError, match="still failing after 0 local refinements"):
        du.mesh_domain(comm, r, 0.3, degree=3, size_factor=0.7, max_rounds=0, relax=False)


def test_errors_no_size_can_fix():
    with pytest.raises(du.MeshingError, match="overlaps body"):
        du.mesh_domain(
            comm,
            du.Domain(du.Circle((0, 0), 2), [du.Circle((0, 0), 0.5), du.Circle((0.6, 0), 0.3)]),
            0.2,
        )
    with pytest.raises(du.MeshingError, match="leaves the container"):
        du.mesh_domain(comm, du.Domain(du.Circle((0, 0), 1), [du.Circle((0.9, 0), 0.3)]), 0.2)
    with pytest.raises(du.MeshingError, match="leaves the given box"):
        du.mesh_domain(comm, du.Circle((0, 0), 1), 0.2, box=[[-0.5, -2], [2, 2]])
    with pytest.raises(ValueError, match="h must be positive"):
        du.mesh_domain(comm, du.Circle((0, 0), 1), float("nan"))


def test_certificate_prints_the_angle_it_verified():
    """A conditioning angle just below 90 degrees is printed below 90, with the digits that
    takes: never "90.00 deg (< 90 needed)"; tetrahedra need at most 90, and say so."""
    cert = du.mesh_domain(comm, du.Circle((0, 0), 1), 0.5).certificate
    for angle, shown in [(89.9991, "89.9991"), (89.99999999, "89.99999999"), (67.123, "67.12")]:
        text = str(dataclasses.replace(cert, max_conditioning_angle_deg=angle))
        assert f"conditioning angles <= {shown} deg (< 90 needed)" in text
    # Tetrahedra may have right angles at the positive faces (BCC): at most 90 is needed.
    tet = dataclasses.replace(cert, tdim=3, background="graded BCC octree")
    text = str(dataclasses.replace(tet, max_conditioning_angle_deg=90.0))
    assert "conditioning angles <= 90.00 deg (<= 90 needed" in text and "< 90 needed" not in text


@pytest.mark.parametrize("c", [1e5, 1e6])
def test_domains_far_from_the_origin(c):
    """A circle and a sphere centred at (c, c(, c)) mesh as they do at the origin (the
    sphere raised ``feature sizes must be positive`` from 1e5 on)."""
    at_origin = du.mesh_domain(comm, du.Circle((0, 0), 1.0), 0.5).certificate
    cert = du.mesh_domain(comm, du.Circle((c, c), 1.0), 0.5).certificate
    assert cert.num_cells == at_origin.num_cells and cert.refinement_rounds == 0
    cert = du.mesh_domain(comm, du.Sphere((c, c, c), 1.0), 0.5).certificate
    assert cert.num_pieces == 1 and cert.num_loops == 1
    assert cert.min_feature_over_h >= 3.0 * (1 - 1e-6) and cert.min_angle_deg > 30.0


def test_touching_bodies_are_named():
    """Spheres that touch (two bodies; a body and its container) need a size that no
    max_cells allows at the contact: the error names the components and the place, not only
    the cell count (it said "the geometry asks for about 1.3e13 background cells" near an
    unrelated sample)."""
    pairs = [
        (du.Domain(None, [du.Sphere((0, 0, 0), 1), du.Sphere((2, 0, 0), 1)]), "body 0 and body 1"),
        (du.Domain(du.Sphere((0, 0, 0), 2), [du.Sphere((1, 0, 0), 1)]), "the container and body 1"),
    ]
    for domain, names in pairs:
        with pytest.raises(du.MeshingError, match=f"{names} touch or nearly touch") as info:
            du.mesh_domain(comm, domain, 0.5)
        assert "move them apart" in str(info.value) and not info.value.refinable
        contact = np.array([[1.0, 0.0, 0.0]]) * (1 if "body 0" in names else 2)
        assert np.linalg.norm(info.value.points - contact) < 0.1


def test_given_box_channel():
    """A channel (the box) minus a cylinder: the box boundary is the outer boundary."""
    md = du.mesh_domain(
        comm,
        du.Domain(None, [du.Circle((0.2, 0.2), 0.05)]),
        0.05,
        degree=2,
        box=[[0.0, 0.0], [2.2, 0.41]],
    )
    exact = 2.2 * 0.41 - np.pi * 0.05**2
    # q = 2: the area error of the cylinder is O(h^4 / rho^3) per cell, about 1e-7 here
    # (8e-8 for the images of M_h, 1.1e-7 relaxed: vertices slid along Gamma lengthen some
    # of its chords).
    assert abs(area(md.mesh) - exact) < 2e-7
    assert md.certificate.num_loops == 1


def test_parameter_errors():
    bg = du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.2)
    for eta in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="eta must lie in"):
            du.conform(bg, du.Circle((0, 0), 0.5), eta=eta)
    from dolfinx import mesh as dmesh

    line = dmesh.create_unit_interval(comm, 4)
    with pytest.raises(ValueError, match="planar triangle meshes"):
        du.conform(line, du.Circle((0, 0), 0.5))
    cube = dmesh.create_unit_cube(comm, 1, 1, 1)
    with pytest.raises(ValueError, match="a 2D boundary cannot be meshed on a 3D background"):
        du.conform(cube, du.Circle((0, 0), 0.5))
    # A triangle mesh in 3D (a tilted square).
    import basix.ufl

    x = np.array([[-1, -1, 0], [1, -1, 0.5], [1, 1, 0.5], [-1, 1, 0]], dtype=np.float64)
    cells = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    if comm.rank:
        x, cells = x[:0], cells[:0]
    surf = dmesh.create_mesh(
        comm, cells, basix.ufl.element("Lagrange", "triangle", 1, shape=(3,)), x
    )
    with pytest.raises(ValueError, match="triangle mesh in 3D"):
        du.conform(surf, du.Circle((0, 0), 0.5))


def _fingerprint(c: MPI.Comm) -> dict:
    """Rank-independent description of mesh_domain's mesh of a spline domain with a body."""
    t = np.linspace(0, 2 * np.pi, 11, endpoint=False)
    r = 1 + 0.25 * np.cos(3 * t) + 0.1 * np.sin(5 * t)
    spline = du.PeriodicSpline(np.column_stack([r * np.cos(t), r * np.sin(t)]))
    domain = du.Domain(spline, [du.Ellipse((0.1, 0.05), 0.25, 0.06, angle=0.4)])
    md = du.mesh_domain(c, domain, 0.3, degree=3)
    msh = md.mesh
    a = c.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(msh))))
    owned = msh.topology.index_map(2).size_local
    cents = np.concatenate(
        c.allgather(msh.geometry.x[msh.geometry.dofmaps[0][:owned]][:, :, :2].mean(axis=1))
    )
    return {
        "n_cells": msh.topology.index_map(2).size_global,
        "area": a,
        "rounds": md.certificate.refinement_rounds,
        "centroids": cents,  # in the partition's order: compared as a point set
    }


@pytest.mark.mpi
@needs_ranks(2)
def test_same_mesh_on_any_number_of_ranks():
    got, ref = _fingerprint(comm), _fingerprint(MPI.COMM_SELF)
    assert got["n_cells"] == ref["n_cells"] and got["rounds"] == ref["rounds"]
    # The same cells summed in another order: rounding of a sum of n terms (sqrt(n) to n ulps).
    assert got["area"] == pytest.approx(ref["area"], rel=1e-11)
    # Centroids as point sets (one-to-one nearest neighbours; a sort, even on rounded values,
    # could order nodes that differ in the last bits differently): nodes computed by another
    # cell differ by a few ulps (1e-15), a changed mesh by far more than 1e-12.
    a, b = got["centroids"], ref["centroids"]
    assert a.shape == b.shape
    dist, idx = cKDTree(b).query(a)
    assert dist.max(initial=0.0) <= 1e-12 and len(np.unique(idx)) == len(a), dist.max()


class FailsOnRank1(du.Circle):
    def sign(self, x):
        if comm.rank == 1:
            raise KeyError("lookup table")
        return super().sign(x)


@pytest.mark.mpi
@needs_ranks(2)
def test_collective_errors_never_hang():
    """A callback failing on one rank only: the same error on every rank (a hang here is
    caught by the timeout of .ci/test). Per-rank reports merge into one global count."""
    from dolfinx_universal.core.collective import Problem, raise_collective

    bg = du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.1)
    with pytest.raises(du.MeshingError, match="KeyError") as info:
        du.conform(bg, FailsOnRank1((0.0, 0.0), 0.6))
    messages = comm.allgather(str(info.value))
    assert all(m == messages[0] for m in messages)
    with pytest.raises(du.MeshingError) as info:
        raise_collective(
            comm,
            [
                Problem(
                    "{count} cells are bad near {where}",
                    np.array([[float(comm.rank), 0.0]]),
                    comm.rank + 1,
                )
            ],
        )
    n = comm.size
    assert str(info.value).startswith(f"{n * (n + 1) // 2} cells are bad near (0, 0), (1, 0)")
    assert len(info.value.points) == n


def test_leaving_the_background_is_named_alone():
    """A domain crossing the background's boundary: that is the error, not a Gamma_h one."""
    bg = du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.1)
    with pytest.raises(du.MeshingError) as info:
        du.conform(bg, du.Circle((0.9, 0.0), 0.5))
    text = str(info.value)
    assert "leaves the background" in text and "Gamma_h" not in text and "refine" not in text
    assert not info.value.refinable and np.all(np.abs(info.value.points[:, 0]) > 0.99)


def test_curved_mesh_wants_a_conforming_mesh():
    cm = du.conform(du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.2), du.Circle((0, 0), 0.6))
    with pytest.raises(TypeError, match="needs the ConformingMesh returned by conform"):
        du.curved_mesh(cm.mesh, 2)


def _interior_facet_measure(c: MPI.Comm) -> tuple[float, float]:
    """Total length of the interior facets of a curved mesh_domain mesh, and the sum of the
    jumps of a discontinuous field across them (interior facet integrals, collective)."""
    md = du.mesh_domain(c, du.Circle((0.01, 0.02), 1.0), 0.3, degree=2)
    msh = md.mesh
    DG0 = fem.functionspace(msh, ("DG", 0))
    f = fem.Function(DG0)
    f.interpolate(lambda x: np.floor(4 * x[0]))  # jumps across the lines x = k / 4
    length = fem.assemble_scalar(fem.form(1.0 * ufl.dS(msh)))
    jumps = fem.assemble_scalar(fem.form(abs(ufl.jump(f)) * ufl.dS(msh)))
    return c.allreduce(length, op=MPI.SUM), c.allreduce(jumps, op=MPI.SUM)


@pytest.mark.mpi
@needs_ranks(2)
def test_interior_facet_integrals_in_parallel():
    """The meshes have shared-facet ghosts, as DOLFINx needs for ``dS`` integrals (jump
    terms, error indicators, DG forms): the same values as on one rank (rounding of sums
    in another order)."""
    got, ref = _interior_facet_measure(comm), _interior_facet_measure(MPI.COMM_SELF)
    assert got == pytest.approx(ref, rel=1e-12)
