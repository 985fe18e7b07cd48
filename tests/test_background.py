"""Equilateral background meshes and their uniform refinement."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from dolfinx import fem

import dolfinx_universal as du
from dolfinx_universal.background import equilateral_triangulation
from dolfinx_universal.classify import cell_diameters, interior_angles, signed_areas

comm = MPI.COMM_WORLD


@pytest.mark.parametrize("h", [0.3, 0.07])
def test_equilateral_triangulation(h):
    box = np.array([[-1.0, -0.5], [2.0, 1.0]])
    x, cells = equilateral_triangulation(box, h)
    assert np.allclose(np.degrees(interior_angles(x, cells)), 60.0)
    assert np.allclose(cell_diameters(x, cells), h)
    assert np.all(signed_areas(x, cells) > 0)  # counter-clockwise
    assert len(np.unique(np.round(x / h, 9), axis=0)) == len(x)  # no duplicate vertices
    # Conforming: every edge in one or two triangles, boundary edges form one closed loop.
    e = np.sort(np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]]), axis=1)
    _, count = np.unique(e, axis=0, return_counts=True)
    assert set(count) == {1, 2}
    # The box is covered: its corners and random points lie in some triangle.
    pts = np.vstack(
        [
            box,
            [[box[0, 0], box[1, 1]], [box[1, 0], box[0, 1]]],
            np.random.default_rng(0).uniform(box[0], box[1], (200, 2)),
        ]
    )
    p = x[cells]
    d = p[:, [1, 2, 0]] - p
    rel = pts[:, None, None, :] - p[None]
    cross = d[None, ..., 0] * rel[..., 1] - d[None, ..., 1] * rel[..., 0]
    inside = (cross >= -1e-12).all(axis=2).any(axis=1)
    assert inside.all()


def test_distributed_mesh_and_refinement():
    msh = du.equilateral_mesh(comm, [[0, 0], [1, 1]], 0.2)
    assert comm.allreduce(msh.topology.index_map(2).num_ghosts) > 0 or comm.size == 1
    area = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(msh))))
    n = comm.allreduce(msh.topology.index_map(2).size_local)
    assert area == pytest.approx(n * np.sqrt(3) / 4 * 0.04)
    fine = du.refine_uniform(msh, 2)
    assert comm.allreduce(fine.topology.index_map(2).size_local) == 16 * n
    fine.topology.create_connectivity(2, 0)
    c2v = fine.topology.connectivity(2, 0).array.reshape(-1, 3)
    v2n = np.empty(
        fine.topology.index_map(0).size_local + fine.topology.index_map(0).num_ghosts,
        dtype=np.int32,
    )
    v2n[c2v] = fine.geometry.dofmaps[0]
    x = fine.geometry.x[v2n, :2]
    assert np.allclose(np.degrees(interior_angles(x, c2v)), 60.0)
    assert np.allclose(cell_diameters(x, c2v), 0.05)
    assert comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(fine)))) == pytest.approx(area)
    if comm.size > 1:
        assert comm.allreduce(fine.topology.index_map(2).num_ghosts) > 0


def test_bad_box():
    with pytest.raises(ValueError, match="box"):
        equilateral_triangulation([[0, 0], [0, 1]], 0.1)
    with pytest.raises(ValueError, match="h > 0"):
        equilateral_triangulation([[0, 0], [1, 1]], -0.1)
