"""The degree-q geometry of ``curved_mesh`` (``_lagrange.lagrange_geometry``) is DOLFINx's.

Against ``dolfinx.fem.interpolate_geometry`` of the same (distorted) meshes of triangles and
tetrahedra: every cell's nodes agree to 1e-15 (a node is the affine image of its reference
point, computed in another order: a few ulps of coordinates below 2); nodes shared by cells
are shared the same way (the same number of nodes, and equal node numbers on one side
exactly where they are equal on the other); under MPI every global node has one position
on all ranks holding it, and the integral of ``|x|^2`` is DOLFINx's.
"""

from __future__ import annotations

from mpi4py import MPI

import basix
import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh

from dolfinx_universal.core.lagrange import lagrange_geometry

DEGREES = {"triangle": (1, 2, 3, 4, 5, 7), "tetrahedron": (1, 2, 3, 4, 5)}


def distorted(cell: str, mode: dmesh.GhostMode = dmesh.GhostMode.shared_facet) -> dmesh.Mesh:
    """A unit square (cube) mesh with its vertices moved: cells of different shapes."""
    comm = MPI.COMM_WORLD
    msh = (
        dmesh.create_unit_square(comm, 9, 7, ghost_mode=mode)
        if cell == "triangle"
        else dmesh.create_unit_cube(comm, 5, 4, 4, ghost_mode=mode)
    )
    x = msh.geometry.x
    x[:, 0] += 0.02 * np.sin(7.0 * x[:, 1])
    x[:, 1] += 0.02 * np.sin(5.0 * x[:, 0])
    return msh


def both(msh: dmesh.Mesh, degree: int) -> tuple[dmesh.Mesh, dmesh.Mesh]:
    """DOLFINx's geometry and the package's, of degree q."""
    ce = fem.coordinate_element(msh.topology.cell_type, degree, basix.LagrangeVariant.gll_warped)
    return fem.interpolate_geometry(msh, ce), lagrange_geometry(msh, ce)


@pytest.mark.mpi
@pytest.mark.parametrize("mode", [dmesh.GhostMode.shared_facet, dmesh.GhostMode.none])
@pytest.mark.parametrize("cell", list(DEGREES))
def test_the_geometry_is_dolfinx_interpolated_one(cell, mode):
    msh = distorted(cell, mode)
    for degree in DEGREES[cell]:
        theirs, ours = both(msh, degree)
        a, b = theirs.geometry, ours.geometry
        np.testing.assert_allclose(
            b.x[b.dofmaps[0]], a.x[a.dofmaps[0]], rtol=0, atol=1e-15, err_msg=f"q={degree}"
        )
        assert b.index_map().size_global == a.index_map().size_global
        assert b.index_map().size_local + b.index_map().num_ghosts == len(b.x)
        pairs = np.unique(np.column_stack([a.dofmaps[0].ravel(), b.dofmaps[0].ravel()]), axis=0)
        assert len(np.unique(pairs[:, 0])) == len(np.unique(pairs[:, 1])) == len(pairs)
        assert b.cmaps[0].degree == degree and b.dim == a.dim == msh.geometry.dim
        integrals = [
            msh.comm.allreduce(fem.assemble_scalar(fem.form(ufl.inner(x, x) * ufl.dx)), op=MPI.SUM)
            for x in (ufl.SpatialCoordinate(theirs), ufl.SpatialCoordinate(ours))
        ]
        assert abs(integrals[1] - integrals[0]) < 1e-14


@pytest.mark.mpi
@pytest.mark.parametrize("mode", [dmesh.GhostMode.shared_facet, dmesh.GhostMode.none])
@pytest.mark.parametrize("cell", list(DEGREES))
def test_each_global_node_has_one_position(cell, mode):
    """The ghost nodes carry their owners' numbers: a global node, one point on all ranks
    (with ghost cells, and without: then only vertices, edges and faces are shared)."""
    comm = MPI.COMM_WORLD
    msh = distorted(cell, mode)
    for degree in DEGREES[cell]:
        geometry = both(msh, degree)[1].geometry
        imap = geometry.index_map()
        n = imap.size_local + imap.num_ghosts
        numbers = imap.local_to_global(np.arange(n, dtype=np.int32))
        g = np.concatenate(comm.allgather(numbers))
        x = np.concatenate(comm.allgather(geometry.x[:n]))
        order = np.argsort(g, kind="stable")
        g, x = g[order], x[order]
        first = np.searchsorted(g, g)
        np.testing.assert_array_equal(x, x[first], err_msg=f"q={degree}")
        assert len(np.unique(g)) == imap.size_global == comm.allreduce(imap.size_local)


@pytest.mark.mpi
@pytest.mark.parametrize("cell", list(DEGREES))
def test_compiled_nodes_are_numpy_s(cell, monkeypatch):
    """The entity nodes and the dofmap from the C kernels and from the numpy code: bitwise
    the same (the same sums in the same order), owned and ghost, at every degree."""
    from dolfinx_universal.core.compiled import relax_kernels

    msh = distorted(cell)

    def geometry(degree):
        g = both(msh, degree)[1].geometry
        return g.x.copy(), g.dofmaps[0].copy(), np.array(g.input_global_indices)

    assert relax_kernels() is not None
    compiled = [geometry(degree) for degree in DEGREES[cell]]
    monkeypatch.setenv("DOLFINX_UNIVERSAL_COMPILED", "0")
    assert relax_kernels() is None
    for degree, arrays in zip(DEGREES[cell], compiled, strict=True):
        for a, b in zip(arrays, geometry(degree), strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"q={degree}")


@pytest.mark.mpi
@pytest.mark.parametrize("cell", list(DEGREES))
def test_ranks_without_cells(cell):
    """A mesh whose cells all lie on rank 0 (a submesh of rank 0's cells)."""
    msh = distorted(cell)
    tdim = msh.topology.dim
    mine = np.arange(msh.topology.index_map(tdim).size_local if msh.comm.rank == 0 else 0)
    sub = dmesh.create_submesh(msh, tdim, mine.astype(np.int32))[0]
    for degree in (2, 3):
        theirs, ours = both(sub, degree)
        a, b = theirs.geometry, ours.geometry
        assert len(b.dofmaps[0]) == len(mine)
        np.testing.assert_allclose(b.x[b.dofmaps[0]], a.x[a.dofmaps[0]], rtol=0, atol=1e-15)
        assert b.index_map().size_global == a.index_map().size_global


def test_only_straight_simplices():
    """A curved or a quadrilateral mesh is refused (its nodes are not vertices)."""
    msh = distorted("triangle")
    curved, _ = both(msh, 2)
    with pytest.raises(ValueError, match="degree-2 mesh of triangles"):
        lagrange_geometry(curved, curved.geometry.cmaps[0])
    quads = dmesh.create_unit_square(MPI.COMM_WORLD, 2, 2, dmesh.CellType.quadrilateral)
    with pytest.raises(ValueError, match="quadrilaterals"):
        lagrange_geometry(quads, quads.geometry.cmaps[0])
