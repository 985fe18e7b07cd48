"""Tetrahedral background meshes: the BCC and A15 lattices, serial and built in parallel."""

from __future__ import annotations

import itertools

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from conftest import needs_ranks
from dolfinx import fem
from dolfinx import mesh as dmesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

import dolfinx_universal as du
from dolfinx_universal.backgrounds import lattice_tet as bt
from dolfinx_universal.backgrounds import lattice_tri as bg

comm = MPI.COMM_WORLD

LATTICES = {
    "bcc": (bt.bcc_tetrahedralisation, bt.bcc_mesh, bt._bcc_layout, bt._bcc_part),
    "a15": (bt.a15_tetrahedralisation, bt.a15_mesh, bt._a15_layout, bt._a15_part),
}
ANGLES = {"bcc": (60.0, 90.0), "a15": (53.1, 78.5)}
BOX = np.array([[-0.5, -0.25, 0.1], [0.6, 0.35, 0.75]])


def signed_volumes(x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """``det[x1 - x0, x2 - x0, x3 - x0] / 6`` of each tetrahedron, shape ``(m,)``."""
    p = x[cells]
    return np.linalg.det(p[:, 1:] - p[:, :1]) / 6.0


def dihedral_angles(x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """The 6 dihedral angles (degrees) of each tetrahedron, shape ``(m, 6)``."""
    p = x[cells]
    out = []
    for a, b in itertools.combinations(range(4), 2):
        c, d = (k for k in range(4) if k not in (a, b))
        e = p[:, b] - p[:, a]
        n1, n2 = np.cross(e, p[:, c] - p[:, a]), np.cross(e, p[:, d] - p[:, a])
        cos = (n1 * n2).sum(1) / np.linalg.norm(n1, axis=1) / np.linalg.norm(n2, axis=1)
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.array(out).T


def faces(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct faces (sorted vertex triples) and the number of cells of each."""
    f = np.concatenate(
        [cells[:, [1, 2, 3]], cells[:, [0, 2, 3]], cells[:, [0, 1, 3]], cells[:, :3]]
    )
    return np.unique(np.sort(f, axis=1), axis=0, return_counts=True)


def check_conforming(x: np.ndarray, cells: np.ndarray) -> None:
    """Every face in one or two cells; the boundary faces form a closed 2-manifold surface
    (every boundary edge in exactly two boundary faces, the boundary faces around each
    boundary vertex one connected fan) that is connected and a sphere (Euler characteristic
    2); no duplicate or unused vertices."""
    f, count = faces(cells)
    assert set(count.tolist()) == {1, 2}
    bnd = f[count == 1]
    e = np.concatenate([bnd[:, [0, 1]], bnd[:, [1, 2]], bnd[:, [0, 2]]])
    edges, inv, ecount = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    assert np.all(ecount == 2)
    # Corners (face, vertex), node 3 face + position: joined across each boundary edge at
    # both its ends.
    nf = len(bnd)
    fid = np.tile(np.arange(nf), 3)
    order = np.argsort(inv.ravel(), kind="stable")
    fa, fb = fid[order][0::2], fid[order][1::2]  # the two faces of each edge
    r, c = [], []
    for k in (0, 1):
        v = edges[:, k, None]
        r.append(3 * fa + (bnd[fa] == v).argmax(axis=1))
        c.append(3 * fb + (bnd[fb] == v).argmax(axis=1))
    r, c = np.concatenate(r), np.concatenate(c)
    g = coo_matrix((np.ones(len(r)), (r, c)), shape=(3 * nf, 3 * nf))
    nfans, _ = connected_components(g, directed=False)
    nbv = len(np.unique(bnd))
    assert nfans == nbv  # one fan per boundary vertex: no pinched vertex
    # One connected sphere.
    fg = coo_matrix((np.ones(len(fa)), (fa, fb)), shape=(nf, nf))
    assert connected_components(fg, directed=False)[0] == 1
    assert nbv - len(edges) + nf == 2
    used = np.zeros(len(x), dtype=bool)
    used[cells] = True
    assert used.all()
    assert len(np.unique(x, axis=0)) == len(x)


def contains(x: np.ndarray, cells: np.ndarray, pts: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """Whether each point lies in some tetrahedron, shape ``(len(pts),)``."""
    p = x[cells]
    inv = np.linalg.inv(np.transpose(p[:, 1:] - p[:, :1], (0, 2, 1)))  # (m, 3, 3)
    out = np.zeros(len(pts), dtype=bool)
    for i, q in enumerate(pts):
        lam = np.einsum("mij,mj->mi", inv, q - p[:, 0])
        bary = np.column_stack([1.0 - lam.sum(1), lam])
        out[i] = bool((bary >= -tol).all(axis=1).any())
    return out


@pytest.mark.parametrize("name", ["bcc", "a15"])
@pytest.mark.parametrize(
    "box, h",
    [(BOX, 0.11), ([[0, 0, 0], [1, 1, 1]], 0.4), ([[0, 0, 0], [1, 0.05, 1]], 2.0)],
)
def test_tetrahedralisation(name, box, h):
    """Positive orientation, dihedral angles, edge lengths, conforming with a closed boundary,
    covers the box, the volume of the covered block."""
    build = LATTICES[name][0]
    box = np.asarray(box, dtype=np.float64)
    x, cells = build(box, h)
    assert x.shape[1] == 3 and cells.shape[1] == 4 and cells.dtype == np.int64
    vol = signed_volumes(x, cells)
    assert np.all(vol > 0)
    lo, hi = ANGLES[name]
    d = dihedral_angles(x, cells)
    assert d.min() >= lo - 1e-6 and d.max() <= hi + 1e-6
    edges = np.linalg.norm(x[cells][:, :, None] - x[cells][:, None], axis=3)
    if name == "bcc":
        assert np.allclose(np.unique(np.round(d, 6)), [60.0, 90.0])
        assert np.allclose(np.unique(np.round(edges[edges > 0] / h, 9)), [np.sqrt(3) / 2, 1.0])
        n = np.maximum(np.ceil((box[1] - box[0]) / h - 1e-12), 1)
        # The cubes plus a pyramid of volume h^3 / 6 on each boundary face of the grid.
        expected = h**3 * (n.prod() + (n[0] * n[1] + n[1] * n[2] + n[0] * n[2]) / 3)
    else:
        assert d.min() == pytest.approx(53.130102354, abs=1e-6)
        assert d.max() == pytest.approx(78.463040967, abs=1e-6)
        assert np.allclose(np.unique(np.round(edges[edges > 0] / h, 4)), [0.7937, 0.8874, 0.9721])
        lay = bt._a15_layout(box, h)
        assert len(cells) == 46 * np.prod(lay.n)
        expected = np.prod(lay.n) * (4 * lay.q) ** 3
    assert vol.sum() == pytest.approx(expected, rel=1e-12)
    check_conforming(x, cells)
    # The box is covered: its corners, edge midpoints and random points lie in some cell.
    corners = np.array(list(itertools.product(*box.T)))
    mids = (corners[:, None] + corners[None]).reshape(-1, 3) / 2
    pts = np.vstack([corners, mids, np.random.default_rng(1).uniform(box[0], box[1], (100, 3))])
    assert contains(x, cells, pts).all()


def test_a15_template_rederived():
    """The stored A15 template is the Delaunay tetrahedralisation of the sites (Qhull on a
    3x3x3 block, the tetrahedra with centroid in the central cell) and a periodic tiling."""
    from scipy.spatial import Delaunay

    cells = np.array(list(itertools.product(range(-1, 2), repeat=3)))
    pts = (4 * cells[:, None, :] + bt.A15_SITES[None]).reshape(-1, 3)
    site, cell = np.tile(np.arange(8), len(cells)), np.repeat(cells, 8, axis=0)
    simp = Delaunay(pts.astype(np.float64)).simplices
    cen = pts[simp].sum(axis=1)  # 4 x centroid, in quarters: in [0, 16) for the central cell
    simp = simp[np.all((cen >= 0) & (cen < 16), axis=1)]
    derived = np.concatenate([site[simp][..., None], cell[simp]], axis=2)

    def canonical(t):
        return sorted(tuple(sorted(map(tuple, tet))) for tet in np.asarray(t).tolist())

    assert canonical(derived) == canonical(bt.A15_TETS)
    # A valid periodic tiling.
    t = bt.A15_TETS
    assert t.shape == (46, 4, 4)
    p = (bt.A15_SITES[t[..., 0]] + 4 * t[..., 1:]).astype(np.float64) / 4  # cell side 1
    flat = p.reshape(-1, 3)
    idx = np.arange(len(flat)).reshape(-1, 4)
    vol = signed_volumes(flat, idx)
    assert np.all(vol > 0) and vol.sum() == pytest.approx(1.0, rel=1e-14)
    d = dihedral_angles(flat, idx)
    assert d.min() >= 53.1 and d.max() <= 78.5
    # Every face of the periodic tiling (up to translation) is in exactly two tetrahedra.
    keys = []
    for tet in t.tolist():
        for drop in range(4):
            f = sorted(tuple(v) for k, v in enumerate(tet) if k != drop)
            o = np.array(f[0][1:])
            keys.append(tuple((s, *(np.array(off) - o).tolist()) for s, *off in f))
    _, count = np.unique(np.array(keys).reshape(len(keys), -1), axis=0, return_counts=True)
    assert np.all(count == 2)
    assert np.abs(t[..., 1:]).max() <= 1  # vertices in neighbouring cells only
    reach = np.abs(p - p.mean(axis=1, keepdims=True)).max() * 4
    assert reach == bt._A15_REACH


@pytest.mark.parametrize("name", ["bcc", "a15"])
@pytest.mark.parametrize("box, h", [(BOX, 0.07), ([[0, 0, 0], [1, 1, 1]], 1.5)])
def test_parts(name, box, h):
    """The slabs of any number of parts, in order, are the serial tetrahedralisation, bitwise
    (more parts than layers: some are empty)."""
    build, _, layout, part = LATTICES[name]
    x, cells = build(box, h)
    lay = layout(box, h)
    for k in (2, 3, 7, lay.n[2] + 2):
        parts = [part(lay, r, k) for r in range(k)]
        assert np.array_equal(np.concatenate([p[0] for p in parts]), x)
        assert np.array_equal(np.concatenate([p[1] for p in parts]), cells)
        # Each part supplies a contiguous block of vertices that its cells (and its
        # neighbours') refer to: every vertex index is in range.
        assert all(p[1].max(initial=0) < len(x) for p in parts)


@pytest.mark.parametrize("name", ["bcc", "a15"])
@pytest.mark.parametrize(
    "box, h, match",
    [
        ([[0, 0, 0], [1, 1, np.nan]], 0.1, "finite box"),
        ([[0, 0, 0], [1, 1, np.inf]], 0.1, "finite box"),
        ([[0, 0, 0], [1, 1, 1]], 0.0, "h > 0"),
        ([[0, 0, 0], [1, 1, 1]], -0.1, "h > 0"),
        ([[0, 0, 0], [1, 1, 1]], np.inf, "h > 0"),
        ([[0, 0, 0], [1, 0, 1]], 0.1, "empty box"),
        ([[0, 0, 1], [1, 1, 0.5]], 0.1, "empty box"),
        ([[0, 0], [1, 1]], 0.1, r"\[\[xmin, ymin, zmin\]"),
    ],
)
def test_bad_input(name, box, h, match):
    build, mesh = LATTICES[name][:2]
    with pytest.raises(ValueError, match=match):
        build(box, h)
    with pytest.raises(ValueError, match=match):
        mesh(MPI.COMM_SELF, box, h)


@pytest.mark.mpi
def test_create_mesh_cell_type():
    """create_mesh and create_background_mesh take tetrahedra; other widths are refused."""
    x, cells = bt.bcc_tetrahedralisation([[0, 0, 0], [1, 1, 1]], 0.5)
    msh = bg.create_background_mesh(comm, x, cells)
    assert msh.topology.cell_type == dmesh.CellType.tetrahedron and msh.geometry.dim == 3
    assert comm.allreduce(msh.topology.index_map(3).size_local) == len(cells)
    if comm.size > 1:
        assert comm.allreduce(msh.topology.index_map(3).num_ghosts) > 0
    with pytest.raises(ValueError, match="shape"):
        bg.create_mesh(MPI.COMM_SELF, np.zeros((1, 5), dtype=np.int64), x)
    with pytest.raises(ValueError, match="shape"):  # on every rank, not only on root
        bg.create_background_mesh(comm, x, np.zeros((1, 5), dtype=np.int64))
    with pytest.raises(ValueError, match="cell_type"):
        bg.create_mesh(MPI.COMM_SELF, cells, x, cell_type="quadrilateral")


@pytest.mark.mpi
@pytest.mark.parametrize("name", ["bcc", "a15"])
def test_mesh(name):
    """The DOLFINx mesh: positively oriented cells, volume, cell diameters and vertex sizes."""
    _, mesh, *_ = LATTICES[name]
    h = 0.2
    msh = mesh(comm, BOX, h)
    assert msh.topology.cell_type == dmesh.CellType.tetrahedron and msh.geometry.dim == 3
    x = msh.geometry.x
    dofs = msh.geometry.dofmaps[0]
    assert np.all(signed_volumes(x, dofs) > 0)
    volume = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(msh))))
    nc = msh.topology.index_map(3).size_local
    assert volume == pytest.approx(comm.allreduce(signed_volumes(x, dofs[:nc]).sum()), rel=1e-12)
    # vertex_sizes: the longest edge (h for BCC, 0.97 h for A15), uniform.
    msh.topology.create_connectivity(3, 0)
    imv = msh.topology.index_map(0)
    c2v = msh.topology.connectivity(3, 0).array.reshape(-1, 4)
    v2n = np.empty(imv.size_local + imv.num_ghosts, dtype=np.int32)
    v2n[c2v] = dofs
    longest = h if name == "bcc" else 0.9721 * h
    for local in (False, True):
        hv = bg.vertex_sizes(imv, x[v2n], c2v, nc, local, comm)
        assert hv.shape == (len(v2n),)
        assert np.allclose(hv, longest, rtol=1e-4)


def canonical_cells(msh: dmesh.Mesh) -> np.ndarray | None:
    """All owned cells as rows of their 4 vertex coordinates (vertices sorted in each row,
    rows sorted), on rank 0 (None elsewhere)."""
    nc = msh.topology.index_map(3).size_local
    p = msh.geometry.x[msh.geometry.dofmaps[0][:nc]]
    order = np.lexsort((p[:, :, 2], p[:, :, 1], p[:, :, 0]), axis=1)
    rows = np.take_along_axis(p, order[:, :, None], axis=1).reshape(nc, 12)
    gathered = msh.comm.gather(rows, root=0)
    if msh.comm.rank:
        return None
    rows = np.concatenate(gathered)
    return rows[np.lexsort(rows.T[::-1])]


def check_shared_facet_ghosts(msh: dmesh.Mesh, cells: np.ndarray) -> None:
    """Every facet of an owned cell has all its cells on the rank (as many boundary facets
    as the serial ``cells``), and every ghost cell shares a facet with an owned cell."""
    topo = msh.topology
    topo.create_connectivity(3, 2)
    topo.create_connectivity(2, 3)
    nc = topo.index_map(3).size_local
    c2f = topo.connectivity(3, 2).array.reshape(-1, 4)
    ncell = np.diff(topo.connectivity(2, 3).offsets)
    owned_facets = np.unique(c2f[:nc])
    bnd = msh.comm.allreduce(int((ncell[owned_facets] == 1).sum()))
    _, count = faces(cells)
    assert bnd == int((count == 1).sum())
    touches = np.zeros(len(ncell), dtype=bool)
    touches[c2f[:nc].ravel()] = True
    assert touches[c2f[nc:]].any(axis=1).all()


@pytest.mark.mpi
@needs_ranks(2)
@pytest.mark.parametrize("name", ["bcc", "a15"])
@pytest.mark.parametrize("box, h", [(BOX, 0.06), ([[0, 0, 0], [1, 1, 1]], 0.9)])
def test_mesh_distributed(name, box, h):
    """Built in parallel, bitwise the serial mesh: each local node has the coordinates of its
    input index in the serial tetrahedralisation, the owned cells (as input indices) of all
    ranks are its cells; each rank owns its slab of layers (no graph partitioning), with
    shared-facet ghosts."""
    build, mesh, layout, part = LATTICES[name]
    x, cells = build(box, h)
    msh = mesh(comm, box, h)
    inp = np.asarray(msh.geometry.input_global_indices, dtype=np.int64)
    assert np.array_equal(msh.geometry.x, x[inp])  # bitwise, ghosts included
    nc = msh.topology.index_map(3).size_local
    mine = inp[msh.geometry.dofmaps[0][:nc]]
    assert len(mine) == len(part(layout(box, h), comm.rank, comm.size)[1])
    everything = comm.gather(mine, root=0)
    if comm.rank == 0:
        got = np.concatenate(everything)
        assert np.array_equal(got[np.lexsort(got.T[::-1])], cells[np.lexsort(cells.T[::-1])])
    serial = mesh(MPI.COMM_SELF, box, h)
    a, b = canonical_cells(msh), canonical_cells(serial)
    if comm.rank == 0:
        assert a.shape == b.shape and np.array_equal(a, b)
    check_shared_facet_ghosts(msh, cells)
    assert comm.allreduce(msh.topology.index_map(3).num_ghosts) > 0


def test_exported():
    assert du.bcc_mesh is bt.bcc_mesh and du.a15_mesh is bt.a15_mesh
