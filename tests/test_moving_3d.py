"""MovingDomain on a tetrahedral background: straight (degree-1) geometry re-conformed in place
to a moving surface, one DOLFINx mesh and one set of compiled forms for every step."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from dolfinx import fem
from jit_counter import count_jit_compilations

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
    n = md.mesh.topology.index_map(3).size_local
    active = np.sort(md.active_cells[md.active_cells < n])
    kept = np.sort(cm.cell_map[: cm.mesh.topology.index_map(3).size_local])
    assert np.array_equal(active, kept)
    # the background's vertex positions after the update equal the conforming mesh's
    x_md = md.mesh.geometry.x[md.mesh.geometry.dofmaps[0][kept]]
    sub = cm.mesh.geometry.x[cm.mesh.geometry.dofmaps[0][: len(kept)]]
    order = np.argsort(cm.cell_map[: len(kept)])
    assert np.abs(x_md - sub[order]).max() < 1e-14  # the same computation, copied


def test_errors():
    bg = du.a15_mesh(comm, BOX, 0.25)
    with pytest.raises(ValueError, match="curved tetrahedra"):
        du.MovingDomain(bg, degree=2)
    with pytest.raises(ValueError, match="for surfaces build"):
        du.MovingDomain.from_motion(comm, _positions(2), 0.25)


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
