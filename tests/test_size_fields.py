"""User size fields of mesh_domain: gmsh-like thresholds and boxes, and adaptive refinement."""

from __future__ import annotations

import pickle

from mpi4py import MPI

import numpy as np
import pytest
from conftest import needs_ranks
from dolfinx import mesh as dmesh
from scipy.spatial import cKDTree

import dolfinx_universal as du
from dolfinx_universal.backgrounds.graded_tri import EDGE_FACTOR

comm = MPI.COMM_WORLD
CYLINDER = du.Circle((0.2, 0.2), 0.05)
CHANNEL = du.Domain(None, [CYLINDER])
BOX = [[0.0, 0.0], [2.2, 0.41]]


def cell_data(msh) -> tuple[np.ndarray, np.ndarray]:
    """Vertex means and longest edges of the owned cells ``(n, gdim)``, ``(n,)``."""
    tdim, gdim = msh.topology.dim, msh.geometry.dim
    n = msh.topology.index_map(tdim).size_local
    xv = msh.geometry.x[msh.geometry.dofmaps[0][:n, : tdim + 1], :gdim]
    diam = np.zeros(n)
    for i in range(tdim + 1):
        for j in range(i + 1, tdim + 1):
            diam = np.maximum(diam, np.linalg.norm(xv[:, i] - xv[:, j], axis=1))
    return xv.mean(axis=1), diam


# ----------------------------------------------------------------------------- the fields
def test_threshold_is_gmsh_ramp():
    """Distance to a circle |r - R| and to points, the ramp of gmsh's Threshold field."""
    f = du.threshold(CYLINDER, 0.01, 0.05, 0.05, 0.45)
    r = np.array([0.05, 0.07, 0.1, 0.3, 0.5, 0.6, 0.0])  # distances to the circle
    x = np.column_stack([0.2 + 0.05 + r, np.full(len(r), 0.2)])
    expected = 0.01 + np.clip((r - 0.05) / 0.4, 0, 1) * 0.04
    assert np.allclose(f(x), expected, rtol=0, atol=1e-15)
    inside = f(np.array([[0.2, 0.2]]))  # the centre: 0.05 from the curve
    assert inside[0] == pytest.approx(0.01)
    g = du.threshold(np.array([[0.0, 0.0], [1.0, 0.0]]), 0.1, 0.3, 0.0, 1.0)
    assert np.allclose(g(np.array([[0.0, 0.5], [0.5, 0.0], [3.0, 0.0]])), [0.2, 0.2, 0.3])
    step = du.threshold(np.zeros((1, 2)), 0.1, 0.3, 0.5, 0.5)  # a jump at 0.5
    assert np.array_equal(step(np.array([[0.4, 0.0], [0.6, 0.0]])), [0.1, 0.3])
    assert np.allclose(pickle.loads(pickle.dumps(f))(x), f(x))


def test_box_size_is_gmsh_box():
    f = du.box_size([[0.0, 0.0], [1.0, 0.5]], 0.01, 0.1, thickness=0.2)
    x = np.array([[0.5, 0.25], [1.1, 0.25], [1.0, 0.7], [1.5, 0.25], [-0.1, -0.1]])
    d = np.array([0.0, 0.1, 0.2, 0.5, np.hypot(0.1, 0.1)])
    assert np.allclose(f(x), 0.01 + np.clip(d / 0.2, 0, 1) * 0.09, rtol=0, atol=1e-15)
    sharp = du.box_size([[0.0, 0.0], [1.0, 0.5]], 0.01, 0.1)
    assert np.array_equal(sharp(x[:2]), [0.01, 0.1])


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: du.threshold(CYLINDER, -1.0, 0.1, 0.0, 1.0), "size_min"),
        (lambda: du.threshold(CYLINDER, 0.1, 0.2, 1.0, 0.5), "dist_max"),
        (lambda: du.threshold(np.zeros((0, 2)), 0.1, 0.2, 0.0, 0.5), "at least one"),
        (lambda: du.box_size([[1.0, 0.0], [0.0, 1.0]], 0.1, 0.2), "lower corner"),
        (lambda: du.box_size([[0.0, 0.0], [1.0, 1.0]], 0.1, 0.2, thickness=-1.0), "dist_max"),
    ],
)
def test_bad_field_parameters(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# ----------------------------------------------------------------------------- mesh_domain
def test_mesh_follows_the_size_field():
    """A threshold around the cylinder and a wake box: no cell away from Gamma is longer
    than the field allows, the mesh is finer than the geometry's own only where the field
    asks for it, and every check of mesh_domain still holds."""
    h = 0.04
    field = du.threshold(CYLINDER, 0.005, h, 0.02, 0.3)
    wake = du.box_size([[0.3, 0.1], [1.2, 0.3]], 0.01, h, thickness=0.1)

    def both(x):
        return np.minimum(field(x), wake(x))

    plain = du.mesh_domain(comm, CHANNEL, h, box=BOX, size_factor=2)
    md = du.mesh_domain(comm, CHANNEL, h, box=BOX, size_factor=2, size_field=both)
    assert md.certificate.num_cells > 2 * plain.certificate.num_cells
    assert md.certificate.min_angle_deg >= 20.0
    mid, diam = cell_data(md.mesh)
    # Cells away from Gamma are background cells: the quadtree keeps every edge below the
    # size sampled at its square (9 samples; the field grows by at most 0.09 per unit
    # length between a sample and the cell: a few percent of the cell).
    far = np.abs(np.linalg.norm(mid - [0.2, 0.2], axis=1) - 0.05) > 0.03
    target = np.minimum(np.minimum(both(mid), h), 0.05 / 2)  # at most the geometry's own
    assert (diam[far] <= both(mid[far]) * (1 + 0.1 * EDGE_FACTOR) + 1e-12).all()
    assert (diam <= target * 4).all()  # nowhere coarser than the quadtree's rounding
    # Where the field asks for nothing finer than h (x > 1.5), the mesh is the plain one.
    pm, pd = cell_data(plain.mesh)
    right = comm.allgather(np.sort(diam[mid[:, 0] > 1.6]))
    right_plain = comm.allgather(np.sort(pd[pm[:, 0] > 1.6]))
    assert np.allclose(np.sort(np.concatenate(right)), np.sort(np.concatenate(right_plain)))


@pytest.mark.parametrize(
    "field, match",
    [
        (lambda x: -np.ones(len(x)), "positive"),
        (lambda x: np.ones((len(x), 2)), "shape"),
        (lambda x: np.full(len(x), np.nan), "positive"),
        (0.1, "callable"),
    ],
)
def test_bad_size_field_is_a_clear_error(field, match):
    with pytest.raises(ValueError, match=match):
        du.mesh_domain(comm, CHANNEL, 0.1, box=BOX, size_field=field)


def test_size_field_asking_too_much_is_refused():
    """A field asking for 1e9 cells: refused by max_cells before any background is built."""
    with pytest.raises(du.MeshingError, match="max_cells"):
        du.mesh_domain(comm, CHANNEL, 0.1, box=BOX, size_field=lambda x: np.full(len(x), 1e-5))
    sphere = du.Sphere((0.0, 0.0, 0.0), 0.5)
    with pytest.raises(du.MeshingError, match="max_cells"):
        du.mesh_domain(comm, sphere, 0.3, size_field=lambda x: np.full(len(x), 1e-4))
    with pytest.raises(ValueError, match="graded background"):
        du.mesh_domain(
            comm, sphere, 0.3, tet_background="a15", size_field=lambda x: np.full(len(x), 0.1)
        )


def test_size_field_on_a_surface():
    """A point source on a sphere's surface: the octree (not A15, which is uniform) is finer
    there, the band stays uniform at the field's smallest value on the sphere."""
    sphere = du.Sphere((0.0, 0.0, 0.0), 0.5)
    point = np.array([[0.5, 0.0, 0.0]])
    md = du.mesh_domain(comm, sphere, 0.3, size_field=du.threshold(point, 0.06, 0.3, 0.05, 0.5))
    assert md.certificate.background == "graded BCC octree"
    assert md.certificate.min_angle_deg >= 20.0
    mid, diam = cell_data(md.mesh)
    near = np.linalg.norm(mid - point, axis=1) < 0.1
    far_out = np.linalg.norm(mid, axis=1) > 1.0  # beyond the band, far from the point
    assert comm.allreduce(near.sum()) > 0
    near_max = comm.allreduce(float(diam[near].max(initial=0.0)), op=MPI.MAX)
    assert near_max <= 0.06 * 1.6  # BCC: longest edge = cube side <= the size
    far_min = comm.allreduce(float(diam[far_out].min(initial=np.inf)), op=MPI.MIN)
    assert far_min > 2 * near_max


# ----------------------------------------------------------------------------- adaptivity
def test_refine_size_halves_the_marked_cells():
    """Marked cells in a window of the channel: one halving there (mean longest edge ratio
    1/2), the cells far from the window unchanged, the field the minimum with the previous
    one, and a second round halves again."""
    h = 0.04
    md = du.mesh_domain(comm, CHANNEL, h, box=BOX, size_factor=2)
    mid, diam = cell_data(md.mesh)

    def window(m):
        return (np.abs(m[:, 0] - 1.5) < 0.1) & (np.abs(m[:, 1] - 0.2) < 0.1)

    field = du.refine_size(md.mesh, np.flatnonzero(window(mid)))
    md2 = du.mesh_domain(comm, CHANNEL, h, box=BOX, size_factor=2, size_field=field)
    mid2, diam2 = cell_data(md2.mesh)

    def mean(values):
        return comm.allreduce(float(values.sum())) / comm.allreduce(len(values))

    ratio = mean(diam2[window(mid2)]) / mean(diam[window(mid)])
    assert 0.4 < ratio < 0.6, ratio
    far = mid2[:, 0] < 0.9  # 0.5 from the window: the field has grown back to h
    old = np.sort(np.concatenate(comm.allgather(diam[mid[:, 0] < 0.9])))
    new = np.sort(np.concatenate(comm.allgather(diam2[far])))
    assert np.allclose(old, new)
    field2 = du.refine_size(md2.mesh, np.flatnonzero(window(mid2)), field)
    x = np.array([[1.5, 0.2], [0.5, 0.2]])
    assert (field2(x) <= field(x)).all() and field2(x)[0] < 0.6 * field(x)[0]
    # the rounds' sources in one set: the minimum of the two rounds' fields, evaluated once
    alone = du.refine_size(md2.mesh, np.flatnonzero(window(mid2)))
    y = np.random.default_rng(2).random((2000, 2)) * [2.2, 0.41]
    assert len(field2.points) == len(field.points) + len(alone.points)
    # both evaluations are within a factor 1.1 below the exact envelope (SizeField's
    # ratio), compared where the fields ask for less than h (above, inf or h: the same)
    both = np.minimum(field(y), alone(y))
    fine = both < h
    assert fine.sum() > 100
    np.testing.assert_allclose(field2(y)[fine], both[fine], rtol=0.1)
    with pytest.raises(ValueError, match="factor"):
        du.refine_size(md.mesh, [0], factor=1.5)
    with pytest.raises(ValueError, match="local cell"):
        du.refine_size(md.mesh, [10**9])


def test_refine_size_mirror_refines_both_halves_alike():
    """``mirror``: the sources of the marked cells above the line y = 0.2 and their images
    below it, with the same sizes; the new background is finer at the images as at the
    marked cells (without ``mirror``: only there); a bad plane is refused."""
    h = 0.04
    md = du.mesh_domain(comm, CHANNEL, h, box=BOX, size_factor=2)
    mid, _ = cell_data(md.mesh)
    marked = np.flatnonzero((np.abs(mid[:, 0] - 1.5) < 0.1) & (mid[:, 1] > 0.25))
    line = ([0.0, 0.2], [0.0, 3.0])  # any length of normal
    field = du.refine_size(md.mesh, marked, mirror=line)
    plain = du.refine_size(md.mesh, marked)
    n = len(plain.points)
    assert n > 0 and len(field.points) == 2 * n
    np.testing.assert_array_equal(field.points[:n], plain.points)
    np.testing.assert_allclose(field.points[n:, 0], plain.points[:, 0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(field.points[n:, 1], 0.4 - plain.points[:, 1], atol=1e-15)
    np.testing.assert_array_equal(field.sizes, np.tile(plain.sizes, 2))
    images = plain.points * [1.0, -1.0] + [0.0, 0.4]
    # both within SizeField's factor 1.1 of the exact envelope, which is symmetric
    np.testing.assert_allclose(field(images), field(plain.points), rtol=0.1)
    # without mirror: no source there, the size grown by the gradation (at least 0.05 away)
    assert (plain(images) > 1.5 * field(images)).all()
    for bad in (([0.0, 0.2], [0.0, 0.0]), ([0.0], [0.0, 1.0]), ([np.nan, 0.2], [0.0, 1.0]), 3):
        with pytest.raises(ValueError, match="mirror"):
            du.refine_size(md.mesh, marked, mirror=bad)


def test_refine_size_below_the_field_it_refines():
    """Where the mesh is coarser than the previous field asks (here a field finer than the
    cells everywhere, as near a curved boundary, where the longest edge around a cell can
    exceed its leaf), the new sources are ``factor`` times the field there, not times the
    cells: an adaptive loop that marks them must change the mesh (it once kept the same
    mesh, marking the same two cells round after round)."""
    md = du.mesh_domain(comm, CHANNEL, 0.04, box=BOX, size_factor=2)
    mid, diam = cell_data(md.mesh)
    marked = np.flatnonzero(np.linalg.norm(mid - [1.5, 0.2], axis=1) < 0.05)
    assert comm.allreduce(len(marked)) > 0

    def fine(x):
        return np.full(len(x), 0.01)  # below every cell's longest edge (about 0.04)

    field = du.refine_size(md.mesh, marked, fine)
    # 0.6 * 0.01 at each source, growing by 0.2 per unit length: below 0.01 at the
    # marked cells' vertex means (the sources themselves)
    assert (field(mid[marked]) <= 0.6 * 0.01 * (1 + 1e-12)).all()


def test_refine_size_on_tetrahedra():
    md = du.mesh_domain(comm, du.Sphere((0.0, 0.0, 0.0), 0.5), 0.3, tet_background="graded")
    mid, diam = cell_data(md.mesh)
    marked = np.flatnonzero(np.linalg.norm(mid - [0.0, 0.0, 0.3], axis=1) < 0.15)
    field = du.refine_size(md.mesh, marked)
    x = np.array([[0.0, 0.0, 0.3], [0.0, 0.0, -1.0]])
    values = field(x)
    local = comm.allreduce(float(diam.max(initial=0.0)), op=MPI.MAX)
    assert values[0] <= 0.7 * local and values[1] > values[0]  # 0.6 L + 0.2 |x - p|
    # mirrored in the plane z = 0: as fine at (0, 0, -0.3) as at (0, 0, 0.3)
    both = du.refine_size(md.mesh, marked, mirror=([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]))
    image = both(np.array([[0.0, 0.0, 0.3], [0.0, 0.0, -0.3]]))
    assert image[1] == pytest.approx(image[0], rel=0.1) and field(-x[:1])[0] > 1.4 * image[1]


@pytest.mark.mpi
@needs_ranks(2)
def test_refine_size_does_not_depend_on_the_partition():
    """Cells marked by a geometric rule: the field and the next mesh are those of one rank."""
    fields, counts = [], []
    for c in (comm, MPI.COMM_SELF):
        md = du.mesh_domain(c, CHANNEL, 0.04, box=BOX, size_factor=2)
        mid, _ = cell_data(md.mesh)
        num = md.mesh.topology.index_map(2)
        mid_all = dmesh.compute_midpoints(
            md.mesh, 2, np.arange(num.size_local + num.num_ghosts, dtype=np.int32)
        )
        marked = np.flatnonzero(np.linalg.norm(mid_all[:, :2] - [0.6, 0.2], axis=1) < 0.15)
        field = du.refine_size(md.mesh, marked)  # ghosts marked too: counted once
        fields.append(field)
        md2 = du.mesh_domain(c, CHANNEL, 0.04, box=BOX, size_factor=2, size_field=field)
        counts.append(md2.mesh.topology.index_map(2).size_global)
    x = np.random.default_rng(1).random((500, 2)) * [2.2, 0.41]
    assert np.allclose(fields[0](x), fields[1](x), rtol=1e-13)
    assert counts[0] == counts[1]
    sources = [f.points for f in fields]
    assert len(sources[0]) == len(sources[1])  # each marked cell once
    assert cKDTree(sources[1]).query(sources[0])[0].max() < 1e-12


@pytest.mark.mpi
@needs_ranks(2)
def test_refine_size_bad_input_on_one_rank_fails_on_every_rank():
    """A bad cell index, a size field that fails, or (for mark_cells) too few indicators,
    on the last rank only: ValueError on every rank (the functions are collective: one rank
    raising alone would leave the others waiting)."""
    md = du.mesh_domain(comm, CHANNEL, 0.04, box=BOX, size_factor=2)
    last = comm.rank == comm.size - 1
    with pytest.raises(ValueError, match="local cell indices"):
        du.refine_size(md.mesh, [10**9] if last else [0])

    def field(x):
        if last:
            raise RuntimeError("no size here")
        return np.full(len(x), 0.05)

    owned = md.mesh.topology.index_map(2).size_local
    with pytest.raises(ValueError, match="the size field failed: RuntimeError: no size here"):
        du.refine_size(md.mesh, np.arange(min(owned, 5)), field)
    # mark_cells: too few indicators on the last rank only
    eta = np.ones(owned - 1 if last else owned)
    with pytest.raises(ValueError, match="one value per owned cell"):
        du.mark_cells(md.mesh, eta, 0.5)


# ----------------------------------------------------------------------------- marking
def test_mark_cells_is_doerfler():
    """The fewest cells holding the fraction of sum eta^2: the marked cells reach it, and
    without the smallest marked one (every cell at the threshold value) they would not."""
    msh = du.mesh_domain(MPI.COMM_SELF, CHANNEL, 0.1, box=BOX).mesh
    n = msh.topology.index_map(2).size_local
    eta = np.random.default_rng(3).random(n) ** 4
    for theta in (0.1, 0.5, 0.9, 1.0):
        marked = du.mark_cells(msh, eta, theta)
        total, got = np.sum(eta**2), np.sum(eta[marked] ** 2)
        assert got >= theta * total * (1 - 1e-12)
        tau = eta[marked].min()
        assert np.array_equal(np.sort(marked), np.flatnonzero(eta >= tau))
        assert got - np.sum(eta[eta == tau] ** 2) < theta * total
    ties = np.ones(n)  # all equal: all marked (none can be told apart)
    assert len(du.mark_cells(msh, ties, 0.3)) == n
    assert len(du.mark_cells(msh, np.zeros(n), 0.5)) == 0  # no error: nothing to refine
    with pytest.raises(ValueError, match="fraction"):
        du.mark_cells(msh, eta, 0.0)
    with pytest.raises(ValueError, match="finite and >= 0"):
        du.mark_cells(msh, -eta, 0.5)
    with pytest.raises(ValueError, match="one value per owned cell"):
        du.mark_cells(msh, eta[:-1], 0.5)


@pytest.mark.mpi
@needs_ranks(2)
def test_mark_cells_does_not_depend_on_the_partition():
    """Indicators that are a function of the cell (its midpoint): the same cells marked."""
    marked_mid = []
    for c in (comm, MPI.COMM_SELF):
        msh = du.mesh_domain(c, CHANNEL, 0.1, box=BOX).mesh
        mid, _ = cell_data(msh)
        eta = np.exp(-20 * np.linalg.norm(mid - [0.3, 0.2], axis=1))
        marked = du.mark_cells(msh, eta, 0.5)
        marked_mid.append(np.concatenate(c.allgather(mid[marked])))
    a, b = marked_mid
    assert len(a) == len(b) and cKDTree(b).query(a)[0].max() < 1e-12
