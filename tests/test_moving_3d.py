"""MovingDomain on a tetrahedral background: straight (degree-1) geometry re-conformed in place
to a moving surface, one DOLFINx mesh and one set of compiled forms for every step."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from conftest import assert_update_history_free
from dolfinx import fem
from jit_counter import count_jit_compilations
from mesh_checks_3d import active_node_gap

import dolfinx_universal as du

comm = MPI.COMM_WORLD
C = np.array([0.0123, 0.0071, 0.0049])
BOX = [[-1.2, -0.8, -0.8], [1.2, 0.8, 0.8]]


def _positions(n: int) -> list[du.Sphere]:
    return [du.Sphere(C + [0.1 * k, 0.0, 0.0], 0.5) for k in range(n)]


def test_moving_sphere_on_one_background():
    h = 0.125
    md = du.MovingDomain(du.a15_mesh(comm, BOX, h), degree=1)
    volume = fem.form(md.active * ufl.dx(md.mesh))
    area = fem.form(md.immersed_integral(lambda side: 1.0))
    exact_v, exact_a = 4 / 3 * np.pi * 0.5**3, 4 * np.pi * 0.5**2
    with count_jit_compilations() as compiled:
        for sphere in _positions(3):
            report = md.update(sphere)
            v = comm.allreduce(fem.assemble_scalar(volume), op=MPI.SUM)
            a = comm.allreduce(fem.assemble_scalar(area), op=MPI.SUM)
            # the straight mesh's volume and area errors are O(h^2) (0.76 h^2 / R at most in
            # the conforming tests; here R = 0.5)
            assert abs(v - exact_v) / exact_v < 1.6 * h**2
            assert abs(a - exact_a) / exact_a < 3.2 * h**2
            nodes = md.immersed_nodes()
            # nodes on Gamma_h lie on the sphere up to the projection's rounding
            assert len(nodes) == 0 or np.abs(sphere.signed_distance(nodes)).max() < 1e-12
            assert 30.0 <= report.quality["theta_min_deg"]
            assert report.quality["theta_max_deg"] <= 125.0
            assert sum(report.quality["dihedral_histogram"]) == 6 * report.num_active_cells
    assert compiled[0] == 0  # the forms were compiled once, before the steps


def test_update_matches_conform():
    """A step's active cells are the cells conform keeps, with the same vertex positions."""
    bg = du.a15_mesh(comm, BOX, 0.2)
    sphere = _positions(2)[1]
    md = du.MovingDomain(bg, degree=1)
    md.update(sphere)
    cm = du.conform(bg, sphere)
    same, gap = active_node_gap(md, cm, cm.mesh)
    assert same
    # the background's vertex positions after the update equal the conforming mesh's
    assert gap < 1e-14  # the same computation, copied


def test_update_does_not_depend_on_the_previous_steps():
    """Curved tetrahedra: the geometry after a step is that of a fresh MovingDomain updated
    once to the same surface (the previous position's moved cells restored, the bands not
    overlapping)."""
    bg = du.a15_mesh(comm, BOX, 0.2)
    here, there = du.Sphere(C + [0.45, 0.0, 0.0], 0.3), du.Sphere(C - [0.5, 0.0, 0.0], 0.25)
    assert_update_history_free(bg, 2, here, there)


@pytest.mark.parametrize(("degree", "kind"), [(2, "I"), (3, "I~")])
def test_curved_update_matches_curved_mesh(degree, kind):
    """Curved tetrahedra moved in place: after several steps, the nodes of the active cells
    are those curved_mesh gives on the conforming mesh of the last position, the nodes on
    Gamma_h lie on the sphere, and the volume and area converge faster than on straight
    tetrahedra (one set of forms for every step)."""
    bg = du.a15_mesh(comm, BOX, 0.2)
    md = du.MovingDomain(bg, degree=degree, map=kind)
    metadata = {"quadrature_degree": 3 * degree}
    volume = fem.form(md.active * ufl.dx(md.mesh, metadata=metadata))
    area = fem.form(md.immersed_integral(lambda side: 1.0))
    exact_v, exact_a = 4 / 3 * np.pi * 0.5**3, 4 * np.pi * 0.5**2
    with count_jit_compilations() as compiled:
        for sphere in _positions(3):
            report = md.update(sphere)
            v = comm.allreduce(fem.assemble_scalar(volume), op=MPI.SUM)
            a = comm.allreduce(fem.assemble_scalar(area), op=MPI.SUM)
            # measured 1.6e-4 / 7.6e-5 (q = 2), 4.6e-5 / 3.2e-5 (q = 3) at h = 0.2; the
            # straight tetrahedra's bound 1.6 h^2 = 6.4e-2 is 100x larger
            assert abs(v - exact_v) / exact_v < 5e-4
            assert abs(a - exact_a) / exact_a < 3e-4
            nodes = md.immersed_nodes()
            assert len(nodes) == 0 or np.abs(sphere.signed_distance(nodes)).max() < 1e-12
            assert report.min_jacobian_ratio > 0.5  # measured 0.62 (q = 2), 0.94 (q = 3)
    assert compiled[0] == 0
    cm = du.conform(bg, sphere)
    curved = du.curved_mesh(cm, degree, kind)
    same, gap = active_node_gap(md, cm, curved.mesh)
    assert same and gap < 1e-14  # the same computation


def test_from_motion_surfaces():
    """A background for a motion of surfaces: the A15 lattice of the smallest target size
    over the positions covering all of them; every position conforms on it (degree 2)."""
    positions = [du.Ellipsoid(C + [0.15 * k, 0.0, 0.0], [0.5, 0.35, 0.3]) for k in range(3)]
    md = du.MovingDomain.from_motion(comm, positions, 0.5, degree=2, map="I~")
    assert md.refinement_rounds == 0 and not md.steps
    for e in positions:
        report = md.update(e)
        assert report.min_jacobian_ratio > 0 and report.quality["theta_min_deg"] >= 30.0
        nodes = md.immersed_nodes()
        assert len(nodes) == 0 or np.abs(e.signed_distance(nodes)).max() < 1e-12
    lo = np.min(md.mesh.geometry.x, axis=0)
    hi = np.max(md.mesh.geometry.x, axis=0)
    lo, hi = comm.allreduce(lo, op=MPI.MIN), comm.allreduce(hi, op=MPI.MAX)
    assert np.all(lo < C - [0.5, 0.35, 0.3]) and np.all(hi > C + [0.8, 0.35, 0.3])
    with pytest.raises(du.MeshingError, match="more than"):
        du.MovingDomain.from_motion(comm, positions, 0.5, size_factor=200.0)


@pytest.mark.mpi
def test_from_motion_redistributes_the_same_mesh():
    """On several ranks ``from_motion`` builds its A15 background in slabs and redistributes
    it by the graph partitioner: the same background (cell count) and the same conformed
    meshes as on one rank (active cells, extreme angles, proven Jacobian ratio)."""
    from dolfinx_universal.moving.domain import _balanced

    positions = [du.Torus(C + [0.1 * k, 0.0, 0.0], 0.5, 0.25) for k in range(2)]
    mds = [
        du.MovingDomain.from_motion(c, positions, 0.3, degree=2, map="I~")
        for c in (comm, MPI.COMM_SELF)
    ]
    reports = [[md.update(p) for p in positions] for md in mds]
    cells = [md.mesh.topology.index_map(3).size_global for md in mds]
    assert cells[0] == cells[1]
    # Extremes over cells, equal up to a cell's figures computed from its vertices in
    # another order on another partition (a few ulps)
    for mine, ref in zip(*reports, strict=True):
        assert mine.num_active_cells == ref.num_active_cells
        for key in ("theta_min_deg", "theta_max_deg"):
            assert mine.quality[key] == pytest.approx(ref.quality[key], rel=1e-12)
        assert mine.min_jacobian_ratio == pytest.approx(ref.min_jacobian_ratio, rel=1e-12)
    bg = du.a15_mesh(comm, BOX, 0.3)
    assert (_balanced(bg) is bg) == (comm.size == 1)


@pytest.mark.mpi
def test_moving_same_on_any_number_of_ranks():
    bg = du.a15_mesh(comm, BOX, 0.2)
    serial = du.MovingDomain(du.a15_mesh(MPI.COMM_SELF, BOX, 0.2), degree=1)
    md = du.MovingDomain(bg, degree=1)
    for sphere in _positions(2):
        r = md.update(sphere)
        s = serial.update(sphere)
        assert r.num_active_cells == s.num_active_cells
        assert r.quality["theta_min_deg"] == pytest.approx(s.quality["theta_min_deg"], abs=1e-9)
        assert r.quality["dihedral_histogram"] == s.quality["dihedral_histogram"]


@pytest.mark.mpi
def test_curved_moving_same_on_any_number_of_ranks():
    """Degree-3 tetrahedra: the same volume, area and Jacobian bound on any number of ranks
    (the shared nodes of ghost cells synchronised)."""
    exact = []
    for c in (comm, MPI.COMM_SELF):
        md = du.MovingDomain(du.a15_mesh(c, BOX, 0.2), degree=3, map="I~")
        volume = fem.form(md.active * ufl.dx(md.mesh, metadata={"quadrature_degree": 9}))
        area = fem.form(md.immersed_integral(lambda side: 1.0))
        values = []
        for sphere in _positions(2):
            r = md.update(sphere)
            values += [
                c.allreduce(fem.assemble_scalar(volume), op=MPI.SUM),
                c.allreduce(fem.assemble_scalar(area), op=MPI.SUM),
                r.min_jacobian_ratio,
            ]
        exact.append(values)
    assert exact[0] == pytest.approx(exact[1], rel=1e-12)


def test_moving_stokes_concentric_spheres():
    """Taylor-Hood on curved tetrahedra (q = 2) between a sphere of radius a = 0.5 and an
    immersed spherical container of radius b = 1 (no slip): the drag of the translating
    sphere and the torque of the rotating one against their closed forms (Happel & Brenner,
    Low Reynolds number hydrodynamics, 4-22 and 4-24), by the weak residual."""
    from dolfinx_universal.moving.problems import MovingStokes

    a, b = 0.5, 1.0
    lam = a / b
    drag = 6 * np.pi * a / (1 - 9 / 4 * lam + 5 / 2 * lam**3 - 9 / 4 * lam**5 + lam**6)
    drag *= 1 - lam**5
    torque = 8 * np.pi * a**3 / (1 - lam**3)
    C0 = np.zeros(3)  # at h = 0.25 (two cells across the sphere) C inverts a tetrahedron
    md = du.MovingDomain(du.a15_mesh(comm, [[-1.15] * 3, [1.15] * 3], 0.25), degree=2, map="I~")
    x = md.universal.vertex_coordinates
    owned = x[: md.universal._imv.size_local]
    r = np.abs(np.linalg.norm(owned, axis=1) - 0.75)
    best = comm.allreduce((float(r.min(initial=np.inf)), comm.rank), op=MPI.MINLOC)
    point = comm.bcast(owned[np.argmin(r)] if comm.rank == best[1] else None, root=best[1])
    stokes = MovingStokes(md, 1.0, point)
    md.update(du.Domain(du.Sphere(C0, b), [du.Sphere(C0, a)]))
    stokes.solve(boundary_velocity=(1.0, 0.0, 0.0))
    force = stokes.force()
    # measured 2.6e-3 at h = 0.2, 5.7e-4 at h = 0.14 (about h^4)
    assert abs(-force[0] - drag) / drag < 1e-2
    assert np.abs(force[1:]).max() < 1e-3 * drag  # symmetry, up to the lattice
    stokes.solve(angular_velocity=(0.0, 0.0, 1.0))
    t = stokes.torque()
    assert abs(-t[2] - torque) / torque < 1e-2  # measured 1.9e-3 at h = 0.25
    assert np.abs(t[:2]).max() < 1e-3 * torque
    # the container's nodes on Gamma_h are at rest, the sphere's rotate
    u = stokes.wh.sub(0).collapse().x.array.reshape(-1, 3)
    X = stokes.V.tabulate_dof_coordinates()
    on = np.unique(md.immersed_dofs((stokes.W.sub(0), stokes.V))[1] // 3)
    outer = np.linalg.norm(X[on] - C0, axis=1) > 0.75
    assert np.abs(u[on[outer]]).max(initial=0.0) == 0.0
    expected = np.cross([0.0, 0.0, 1.0], X[on[~outer]])
    assert np.abs(u[on[~outer]] - expected).max(initial=0.0) < 1e-12
