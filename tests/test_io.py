"""Checkpoints of curved meshes: VTKHDF round trips of triangles (degrees 1-4) and
tetrahedra (conformed balls, a degree-3 box, curved balls of degrees 2-4), tags, ranks, VTX
output."""

from __future__ import annotations

import shutil

from mpi4py import MPI

import basix
import numpy as np
import pytest
import ufl
from conftest import needs_ranks
from dolfinx import fem
from dolfinx import mesh as dmesh
from dolfinx.io import vtkhdf
from io_cases import C3, cases, fingerprint, tetrahedron_cases
from scipy.spatial import cKDTree

import dolfinx_universal as du
from dolfinx_universal import io as duio

comm = MPI.COMM_WORLD
GLL = int(basix.LagrangeVariant.gll_warped)

# Area: the same polynomial map, re-evaluated GLL -> equispaced -> GLL (each step a few ulps
# times the Lebesgue constant, < 10 up to degree 4) and assembled over re-ordered cells:
# ~1e-15 relative. 1e-12 leaves room for the summation order yet is 1e7 times smaller
# than the 5e-5 of writing GLL-warped nodes as equispaced ones.
AREA_RTOL = 1e-12
NODE_ATOL = 1e-13


@pytest.fixture(scope="module")
def meshes():
    return cases(comm)


def same_points(a: list, b: list, atol: float = NODE_ATOL, dim: int = 2) -> None:
    """The point sets are equal up to ``atol``: one-to-one nearest neighbours (order-free)."""
    a, b = np.asarray(a).reshape(-1, dim), np.asarray(b).reshape(-1, dim)
    assert a.shape == b.shape
    if len(a) == 0:
        return
    dist, idx = cKDTree(b).query(a)
    assert dist.max() <= atol, dist.max()
    assert len(np.unique(idx)) == len(a)


def assert_same(a: dict, b: dict, dim: int = 2) -> None:
    """Two fingerprints (:func:`io_cases.fingerprint`) describe the same mesh and tags."""
    assert a["degree"] == b["degree"]
    assert a["variant"] == b["variant"]
    assert a["num_cells"] == b["num_cells"]
    assert a["area"] == pytest.approx(b["area"], rel=AREA_RTOL)
    same_points(a["nodes"], b["nodes"], dim=dim)
    assert a["tags"].keys() == b["tags"].keys()
    for value in a["tags"]:
        assert a["tags"][value]["count"] == b["tags"][value]["count"]
        same_points(a["tags"][value]["midpoints"], b["tags"][value]["midpoints"], dim=dim)


@pytest.mark.parametrize("name", ["disc1", "disc2", "disc3", "disc4", "holed3"])
def test_round_trip(meshes, mpi_tmp_path, name):
    cv = meshes[name]
    x_before = cv.mesh.geometry.x.copy()
    filename = mpi_tmp_path / f"{name}.vtkhdf"
    duio.write_mesh(filename, cv.mesh, cv.facet_tags)
    assert np.array_equal(cv.mesh.geometry.x, x_before)  # the user's mesh is not touched
    msh, tags = duio.read_mesh(comm, filename)
    assert tags is not None
    a, b = fingerprint(cv.mesh, cv.facet_tags), fingerprint(msh, tags)
    if comm.rank == 0:
        assert_same(a, b)
        assert b["variant"] == GLL
        assert b["tags"]["1"]["count"] > 0
        if name.startswith("disc"):
            # The area error against pi is the curved mesh's own, not the IO's.
            err_a, err_b = abs(a["area"] - np.pi), abs(b["area"] - np.pi)
            assert err_b == pytest.approx(err_a, rel=1e-3, abs=1e-14)
        if name == "disc4":
            assert err_b < 1e-9
        if name == "holed3":
            assert b["tags"]["2"]["count"] > 0


def test_plain_vtkhdf_distorts_gll_nodes(meshes, mpi_tmp_path):
    """The DOLFINx 0.11 behaviour worked around: GLL-warped nodes are read as equispaced."""
    cv = meshes["disc4"]
    filename = mpi_tmp_path / "plain.vtkhdf"
    vtkhdf.write_mesh(str(filename), cv.mesh)
    plain = vtkhdf.read_mesh(comm, str(filename), gdim=2)
    a = fingerprint(plain, _empty_tags(plain))["area"]
    if comm.rank == 0:
        assert abs(a - np.pi) > 1e-6  # if this fails, DOLFINx writes variants correctly now


def _empty_tags(msh):
    from dolfinx import mesh as dmesh

    msh.topology.create_entities(1)
    return dmesh.meshtags(msh, 1, np.zeros(0, np.int32), np.zeros(0, np.int32))


def test_equispaced_variant_and_no_tags(meshes, mpi_tmp_path):
    cv = meshes["disc3"]
    filename = mpi_tmp_path / "m.vtkhdf"
    duio.write_mesh(filename, cv.mesh, cv.facet_tags)
    assert duio.tags_path(filename).exists()
    duio.write_mesh(filename, cv.mesh)  # no tags: the stale sidecar goes
    assert not duio.tags_path(filename).exists()
    msh, tags = duio.read_mesh(comm, filename, variant=basix.LagrangeVariant.equispaced)
    assert tags is None
    assert msh.geometry.cmaps[0].variant == int(basix.LagrangeVariant.equispaced)
    a, b = fingerprint(cv.mesh, _empty_tags(cv.mesh)), fingerprint(msh, _empty_tags(msh))
    if comm.rank == 0:
        assert b["area"] == pytest.approx(a["area"], rel=AREA_RTOL)


def test_sidecar_of_another_mesh(meshes, mpi_tmp_path):
    duio.write_mesh(mpi_tmp_path / "a.vtkhdf", meshes["disc2"].mesh, meshes["disc2"].facet_tags)
    duio.write_mesh(mpi_tmp_path / "b.vtkhdf", meshes["disc1"].mesh)
    if comm.rank == 0:
        shutil.copy(duio.tags_path(mpi_tmp_path / "a.vtkhdf"), mpi_tmp_path / "b.tags.npz")
    comm.barrier()
    with pytest.raises(ValueError, match="does not belong"):
        duio.read_mesh(comm, mpi_tmp_path / "b.vtkhdf")


@pytest.mark.mpi
def test_malformed_sidecar_fails_on_every_rank(meshes, mpi_tmp_path):
    """A sidecar whose header fits but whose rows do not: an error on every rank (rank 0
    alone read the rows, after the header, so the others waited in the scatter)."""
    f = mpi_tmp_path / "m.vtkhdf"
    duio.write_mesh(f, meshes["disc2"].mesh, meshes["disc2"].facet_tags)
    if comm.rank == 0:
        with np.load(duio.tags_path(f)) as d:
            data = dict(d)
        data["vertices"] = data["vertices"][:, :1]
        with open(duio.tags_path(f), "wb") as out:
            np.savez(out, **data)
    comm.barrier()
    with pytest.raises(OSError, match="is malformed"):
        duio.read_mesh(comm, f)


def test_write_fields(meshes, mpi_tmp_path):
    from dolfinx import fem

    msh = meshes["disc4"].mesh
    u = fem.Function(fem.functionspace(msh, ("Lagrange", 4)), name="u")
    u.interpolate(lambda x: x[0] ** 4 - x[1])
    v = fem.Function(fem.functionspace(msh, ("Lagrange", 4)), name="v")
    v.interpolate(lambda x: x[0] * x[1])
    duio.write_fields(mpi_tmp_path / "uv.bp", [u, v])
    w = fem.Function(fem.functionspace(msh, ("Lagrange", 2, (2,))), name="w")
    duio.write_fields(mpi_tmp_path / "w.bp", w)
    comm.barrier()
    assert (mpi_tmp_path / "uv.bp").is_dir() and (mpi_tmp_path / "w.bp").is_dir()
    with pytest.raises(ValueError, match="no functions"):
        duio.write_fields(mpi_tmp_path / "none.bp", [])


@pytest.mark.mpi
@needs_ranks(2)
def test_write_and_read_on_other_rank_counts(mpi_tmp_path):
    """Write on all ranks / read on one, and write on one / read on all: the same meshes and
    tags (fingerprints complete on rank 0)."""
    written = {}
    for name, cv in cases(comm).items():
        duio.write_mesh(mpi_tmp_path / f"all_{name}.vtkhdf", cv.mesh, cv.facet_tags)
        written[name] = fingerprint(cv.mesh, cv.facet_tags)
    assert len(written) == 5
    if comm.rank == 0:
        for name, cv in cases(MPI.COMM_SELF).items():
            duio.write_mesh(mpi_tmp_path / f"one_{name}.vtkhdf", cv.mesh, cv.facet_tags)
    comm.barrier()
    for name in written:
        alone = fingerprint(*duio.read_mesh(MPI.COMM_SELF, mpi_tmp_path / f"all_{name}.vtkhdf"))
        msh, tags = duio.read_mesh(comm, mpi_tmp_path / f"one_{name}.vtkhdf")
        assert comm.allreduce(msh.topology.index_map(2).num_ghosts) > 0  # shared-facet ghosts
        together = fingerprint(msh, tags)
        if comm.rank == 0:
            assert_same(written[name], alone)
            assert_same(written[name], together)
            if name == "disc4":
                assert abs(together["area"] - np.pi) < 1e-9


@pytest.fixture(scope="module")
def tet_meshes():
    return tetrahedron_cases(comm)


@pytest.mark.mpi
@pytest.mark.parametrize("name", ["ball", "hole", "box3"])
def test_tetrahedra_round_trip(tet_meshes, mpi_tmp_path, name):
    """Conformed balls (straight) and a degree-3 box: the same mesh, volume and face tags
    (on 1 rank, and written and read on all ranks under mpirun)."""
    msh0, tags0 = tet_meshes[name]
    filename = mpi_tmp_path / f"{name}.vtkhdf"
    duio.write_mesh(filename, msh0, tags0)
    msh, tags = duio.read_mesh(comm, filename)
    assert tags is not None and tags.dim == 2
    assert msh.topology.dim == 3 and msh.geometry.dim == 3
    a, b = fingerprint(msh0, tags0), fingerprint(msh, tags)
    if comm.rank == 0:
        assert_same(a, b, dim=3)
        assert b["tags"]["1"]["count"] > 0
        if name != "ball":
            assert b["tags"]["2"]["count"] > 0
        if name == "ball":  # the conforming mesh's own O(h^2) volume error
            assert abs(b["area"] / (4 / 3 * np.pi) - 1) < 0.8 * 0.25**2
    # Read alone what all ranks wrote.
    alone = fingerprint(*duio.read_mesh(MPI.COMM_SELF, filename))
    if comm.rank == 0:
        assert_same(a, alone, dim=3)


@pytest.fixture(scope="module")
def curved_tets():
    """Curved tetrahedra (GLL-warped nodes): a ball of degrees 2-4 and a box with a
    spherical hole of degree 3 (OUTER tags too), small."""
    ball = du.conform(du.a15_mesh(comm, [[-1.4] * 3, [1.4] * 3], 0.4), du.Sphere(C3, 1.0))
    out = {f"ball{q}": du.curved_mesh(ball, q) for q in (2, 3, 4)}
    hole = du.conform(
        du.a15_mesh(comm, [[-1.0] * 3, [1.0] * 3], 0.3), du.Domain(None, [du.Sphere(C3, 0.5)])
    )
    out["hole3"] = du.curved_mesh(hole, 3, "I~")
    return out


def _volume(msh) -> float:
    """The volume with a quadrature of degree 3 q (the default one of ``fingerprint`` differs
    by 1e-12 between the same degree-3 mesh on 1 and 2 ranks; this one by 1e-13)."""
    q = msh.geometry.cmaps[0].degree
    dx = ufl.dx(msh, metadata={"quadrature_degree": 3 * q})
    return msh.comm.allreduce(fem.assemble_scalar(fem.form(1.0 * dx)))


@pytest.mark.mpi
@pytest.mark.parametrize("name", ["ball2", "ball3", "ball4", "hole3"])
def test_curved_tetrahedra_round_trip(curved_tets, mpi_tmp_path, name):
    """Degree-q tetrahedra: the nodes read back are the nodes written (to 1e-13: the map
    re-evaluated GLL -> equispaced -> GLL), the volume to 1e-12, the face tags (counts and
    curved midpoints), the nodes on Gamma still on the sphere; written on all ranks, read on
    all and on one."""
    cv = curved_tets[name]
    x_before = cv.mesh.geometry.x.copy()
    filename = mpi_tmp_path / f"{name}.vtkhdf"
    duio.write_mesh(filename, cv.mesh, cv.facet_tags)
    assert np.array_equal(cv.mesh.geometry.x, x_before)  # the user's mesh is not touched
    a = {**fingerprint(cv.mesh, cv.facet_tags), "area": _volume(cv.mesh)}
    for reader in (comm, MPI.COMM_SELF):
        msh, tags = duio.read_mesh(reader, filename)
        assert tags is not None and tags.dim == 2
        assert msh.geometry.cmaps[0].degree == cv.degree
        # every node of an immersed face lies on the sphere after the round trip
        faces = tags.find(du.IMMERSED)
        msh.topology.create_connectivity(2, 3)
        on = np.unique(dmesh.entities_to_geometry(msh, 2, faces))
        x = msh.geometry.x[on]
        r = np.linalg.norm(x - C3, axis=1)
        assert np.abs(r - (1.0 if name.startswith("ball") else 0.5)).max(initial=0.0) < 1e-13
        b = {**fingerprint(msh, tags), "area": _volume(msh)}
        if comm.rank == 0:
            assert_same(a, b, dim=3)
            assert b["variant"] == GLL
            assert b["tags"]["1"]["count"] > 0
            assert (b["tags"]["2"]["count"] > 0) == (name == "hole3")


def test_tetrahedra_sidecar_checks(tet_meshes, meshes, mpi_tmp_path):
    """Tags of the wrong dimension are refused; a triangle sidecar does not fit a tet mesh."""
    msh, tags = tet_meshes["ball"]
    edges = dmesh_meshtags(msh, 1)
    with pytest.raises(ValueError, match="expected 2"):
        duio.write_mesh(mpi_tmp_path / "e.vtkhdf", msh, edges)
    duio.write_mesh(mpi_tmp_path / "tri.vtkhdf", meshes["disc1"].mesh, meshes["disc1"].facet_tags)
    duio.write_mesh(mpi_tmp_path / "tet.vtkhdf", msh)
    if comm.rank == 0:
        shutil.copy(duio.tags_path(mpi_tmp_path / "tri.vtkhdf"), mpi_tmp_path / "tet.tags.npz")
    comm.barrier()
    with pytest.raises(ValueError, match="does not belong"):
        duio.read_mesh(comm, mpi_tmp_path / "tet.vtkhdf")


@pytest.mark.mpi
@pytest.mark.parametrize("dtype", [np.int64, np.float64])
def test_tags_of_owned_and_ghost_facets_any_value_type(meshes, mpi_tmp_path, dtype):
    """Every facet a rank holds after read_mesh, owned or ghost, carries the value written
    for it (found by its midpoint), of the written type: int64 values beyond the int32 range
    and non-integer floats come back exactly (the sidecar's rows travel in parts to the
    ranks that hold the facets, not to every rank)."""
    cv = meshes["holed3"]
    base = cv.facet_tags
    values = base.values.astype(dtype) * (2**40 + 1 if dtype == np.int64 else 0.3)
    tags0 = dmesh.meshtags(cv.mesh, 1, base.indices, values)
    filename = mpi_tmp_path / f"typed_{np.dtype(dtype).name}.vtkhdf"
    duio.write_mesh(filename, cv.mesh, tags0)
    msh, tags = duio.read_mesh(comm, filename)
    assert tags is not None and tags.values.dtype == dtype

    def midpoints(m, facets):
        m.topology.create_connectivity(1, 2)
        return m.geometry.x[dmesh.entities_to_geometry(m, 1, facets), :2].mean(axis=1)

    written = comm.allgather((midpoints(cv.mesh, tags0.indices), tags0.values))
    wx = np.concatenate([w[0] for w in written])
    wv = np.concatenate([w[1] for w in written])
    fmap = msh.topology.index_map(1)
    every = np.arange(fmap.size_local + fmap.num_ghosts, dtype=np.int32)
    dist, near = cKDTree(wx).query(midpoints(msh, every))
    hit = dist < 1e-12  # a facet of the file's tags (midpoints of curved edges agree to 1e-15)
    assert np.array_equal(np.sort(tags.indices), every[hit])
    found = np.empty(len(every), dtype=dtype)
    found[tags.indices] = tags.values
    assert np.array_equal(found[hit], wv[near[hit]])
    if comm.size > 1:  # ghosts among them somewhere
        assert comm.allreduce(int(np.count_nonzero(every[hit] >= fmap.size_local))) > 0


def dmesh_meshtags(msh, dim: int):
    from dolfinx import mesh as dmesh

    msh.topology.create_entities(dim)
    return dmesh.meshtags(msh, dim, np.zeros(1, np.int32), np.ones(1, np.int32))


def _shares(msh) -> list[int]:
    """Owned cells of each rank."""
    return comm.allgather(msh.topology.index_map(msh.topology.dim).size_local)


@pytest.mark.mpi
@pytest.mark.parametrize("name", ["disc1", "disc3", "holed3"])
def test_redistribute_triangles(meshes, name):
    """The same cells, nodes, area and facet tags, the cells shared evenly (DOLFINx's graph
    partitioner balances the cell counts to a few per cent; one cell more for rounding)."""
    cv = meshes[name]
    msh, tags = duio.redistribute(cv.mesh, cv.facet_tags)
    assert tags is not None and tags.dim == 1
    a, b = fingerprint(cv.mesh, cv.facet_tags), fingerprint(msh, tags)
    shares = _shares(msh)
    if comm.rank == 0:
        assert_same(a, b)
        assert max(shares) <= 1.1 * np.mean(shares) + 1, shares
    if comm.size > 1:
        assert comm.allreduce(msh.topology.index_map(2).num_ghosts) > 0  # shared-facet ghosts
    alone, none = duio.redistribute(cv.mesh)
    assert none is None and alone.topology.index_map(2).size_global == a["num_cells"]
    assert tags.name == cv.facet_tags.name and msh.name == cv.mesh.name
    cells = dmesh.meshtags(cv.mesh, 2, np.zeros(0, np.int32), np.zeros(0, np.int32))
    with pytest.raises(ValueError, match="must tag facets"):
        duio.redistribute(cv.mesh, cells)


@pytest.mark.mpi
@pytest.mark.parametrize("name", ["ball3", "hole3"])
def test_redistribute_curved_tetrahedra(curved_tets, name):
    """Degree-3 tetrahedra: the same nodes, volume (to the summation order) and face tags."""
    cm = curved_tets[name]
    msh, tags = duio.redistribute(cm.mesh, cm.facet_tags)
    assert tags is not None and tags.dim == 2
    assert msh.geometry.cmaps[0].degree == 3 and msh.geometry.cmaps[0].variant == GLL
    a, b = fingerprint(cm.mesh, cm.facet_tags), fingerprint(msh, tags)
    va, vb = _volume(cm.mesh), _volume(msh)
    shares = _shares(msh)
    if comm.rank == 0:
        assert_same(a, b, dim=3)
        assert vb == pytest.approx(va, rel=AREA_RTOL)
        assert b["tags"]["1"]["count"] > 0
        assert max(shares) <= 1.1 * np.mean(shares) + 1, shares


@pytest.mark.mpi
@needs_ranks(2)
def test_redistribute_from_one_rank():
    """All cells on rank 0 (the others hold none, as the ranks Gamma does not cross): the
    cells end up shared, the same mesh. (A first version failed on the empty ranks.)"""
    from dolfinx_universal.backgrounds.lattice_tri import create_mesh, layout_partitioner

    square = dmesh.create_unit_square(MPI.COMM_SELF, 6, 6)
    cells = square.geometry.dofmaps[0] if comm.rank == 0 else np.zeros((0, 3), np.int64)
    x = square.geometry.x[:, :2] if comm.rank == 0 else np.zeros((0, 2))
    lopsided = create_mesh(comm, cells, x, layout_partitioner())
    lopsided.topology.create_entities(1)
    lopsided.topology.create_connectivity(1, 2)
    facets = dmesh.exterior_facet_indices(lopsided.topology)
    tags = dmesh.meshtags(lopsided, 1, facets, np.full(len(facets), du.OUTER, dtype=np.int32))
    assert _shares(lopsided)[1:] == [0] * (comm.size - 1)
    msh, even = duio.redistribute(lopsided, tags)
    a, b = fingerprint(lopsided, tags), fingerprint(msh, even)
    shares = _shares(msh)
    if comm.rank == 0:
        assert_same(a, b)
        assert b["tags"][str(du.OUTER)]["count"] == 24 and b["area"] == pytest.approx(
            1.0, rel=1e-14
        )
        assert min(shares) > 0 and max(shares) <= 1.1 * np.mean(shares) + 1, shares
