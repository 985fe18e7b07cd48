"""Equilateral background meshes and their uniform refinement."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from conftest import needs_ranks
from dolfinx import fem
from dolfinx import mesh as dmesh

import dolfinx_universal as du
from dolfinx_universal.backgrounds import lattice_tri as bg
from dolfinx_universal.backgrounds.lattice_tri import equilateral_triangulation
from dolfinx_universal.conforming.classify import cell_diameters, interior_angles, signed_areas

comm = MPI.COMM_WORLD


def canonical_cells(msh: dmesh.Mesh) -> np.ndarray | None:
    """All owned cells of a distributed mesh as rows ``(x0, y0, x1, y1, x2, y2)``, vertices
    sorted inside each row, rows sorted: the same array for the same mesh on any number of
    ranks (on rank 0; None elsewhere)."""
    nc = msh.topology.index_map(2).size_local
    p = msh.geometry.x[msh.geometry.dofmaps[0][:nc]][:, :, :2]
    order = np.lexsort((p[:, :, 1], p[:, :, 0]), axis=1)
    rows = np.take_along_axis(p, order[:, :, None], axis=1).reshape(nc, 6)
    gathered = msh.comm.gather(rows, root=0)
    if msh.comm.rank:
        return None
    rows = np.concatenate(gathered)
    return rows[np.lexsort(rows.T[::-1])]


def check_shared_facet_ghosts(msh: dmesh.Mesh, serial: dmesh.Mesh) -> None:
    """Ghost cells are exactly the cells sharing a facet with an owned cell: every facet of
    an owned cell has both its cells on the rank unless it is on the boundary, and every
    ghost cell shares a facet with an owned cell."""
    counts = []
    for m in (msh, serial):
        topo = m.topology
        topo.create_connectivity(2, 1)
        topo.create_connectivity(1, 2)
        nc = topo.index_map(2).size_local
        c2f = topo.connectivity(2, 1).array.reshape(-1, 3)
        f2c = topo.connectivity(1, 2)
        ncell = np.diff(f2c.offsets)
        facets = np.unique(c2f[:nc])
        counts.append(m.comm.allreduce(int((ncell[facets] == 1).sum())))  # boundary facets
        touches = np.zeros(len(ncell), dtype=bool)
        touches[c2f[:nc].ravel()] = True  # facets of owned cells
        assert touches[c2f[nc:]].any(axis=1).all()
    assert counts[0] == counts[1]


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
    inside = (cross >= -1e-12).all(axis=2).any(axis=1)  # on an edge: 0 up to rounding
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


def reference_equilateral(box, h):
    """The row-by-row construction that :func:`equilateral_triangulation` vectorises."""
    (x0, y0), (x1, y1) = np.asarray(box, dtype=np.float64)
    dy = h * np.sqrt(3.0) / 2.0
    n = max(int(np.ceil((x1 - x0) / h - 1e-12)), 1)
    nrows = max(int(np.ceil((y1 - y0) / dy - 1e-12)), 1) + 1
    counts = np.where(np.arange(nrows) % 2 == 0, n + 1, n + 2)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rows = np.repeat(np.arange(nrows), counts)
    i = np.arange(counts.sum()) - start[rows]
    x = np.column_stack([x0 + i * h - (rows % 2) * 0.5 * h, y0 + rows * dy])
    cells = []
    ie, io = np.arange(n + 1), np.arange(n + 2)
    for j in range(nrows - 1):
        if j % 2 == 0:
            e, o = start[j] + ie, start[j + 1] + io
            cells += [
                np.column_stack([e[:-1], e[1:], o[1:-1]]),
                np.column_stack([e, o[1:], o[:-1]]),
            ]
        else:
            o, e = start[j] + io, start[j + 1] + ie
            cells += [
                np.column_stack([o[:-1], o[1:], e]),
                np.column_stack([o[1:-1], e[1:], e[:-1]]),
            ]
    return x, np.concatenate(cells)


@pytest.mark.parametrize(
    "box, h", [([[-1, -0.5], [2, 1]], 0.07), ([[0, 0], [1, 1]], 1), ([[0, 0], [1, 0.01]], 0.5)]
)
def test_equilateral_parts(box, h):
    """The strips of any number of parts, in order, are the serial triangulation, bitwise."""
    x, cells = equilateral_triangulation(box, h)
    xr, cr = reference_equilateral(box, h)
    assert np.array_equal(x, xr) and np.array_equal(cells, cr)
    x0, y0, dy, n, nrows = bg._equilateral_layout(box, h)
    for k in (2, 3, 7, nrows + 2):  # more parts than strips: some are empty
        parts = [
            bg._equilateral_part(
                x0, y0, float(h), dy, n, nrows, r * (nrows - 1) // k, (r + 1) * (nrows - 1) // k
            )
            for r in range(k)
        ]
        assert np.array_equal(np.concatenate([p[0] for p in parts]), x)
        assert np.array_equal(np.concatenate([p[1] for p in parts]), cells)


@pytest.mark.mpi
@needs_ranks(2)
@pytest.mark.parametrize("box, h", [([[-1, -0.5], [2, 1]], 0.05), ([[0, 0], [1, 1]], 0.6)])
def test_equilateral_mesh_distributed(box, h):
    """Built in parallel, the same cells (bitwise coordinates) as on one rank, no graph
    partitioning (each rank owns its strip of rows) and shared-facet ghosts; the same after
    a uniform refinement."""
    msh = du.equilateral_mesh(comm, box, h)
    serial = du.equilateral_mesh(MPI.COMM_SELF, box, h)
    a, b = canonical_cells(msh), canonical_cells(serial)
    if comm.rank == 0:
        assert a.shape == b.shape and np.array_equal(a, b)
    x0, y0, dy, n, nrows = bg._equilateral_layout(box, h)
    strips = (comm.rank + 1) * (nrows - 1) // comm.size - comm.rank * (nrows - 1) // comm.size
    assert msh.topology.index_map(2).size_local == strips * (2 * n + 1)
    check_shared_facet_ghosts(msh, serial)
    # Uniform refinement keeps the partition and rebuilds the ghosts: the same mesh again.
    fine, fine_serial = du.refine_uniform(msh), du.refine_uniform(serial)
    a, b = canonical_cells(fine), canonical_cells(fine_serial)
    if comm.rank == 0:
        assert a.shape == b.shape and np.array_equal(a, b)
    assert fine.topology.index_map(2).size_local == 4 * msh.topology.index_map(2).size_local
    check_shared_facet_ghosts(fine, fine_serial)
