"""Graded tetrahedral backgrounds: BCC tetrahedra on a 2:1-balanced octree."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from conftest import needs_ranks
from dolfinx import fem
from test_background_tet import (
    canonical_cells,
    check_conforming,
    check_shared_facet_ghosts,
    contains,
    dihedral_angles,
    signed_volumes,
)

import dolfinx_universal as du
from dolfinx_universal.backgrounds import graded_tet as gt

comm = MPI.COMM_WORLD
BOX = np.array([[-1.0, -0.8, -0.9], [1.1, 0.9, 0.7]])
C = np.array([0.0123, 0.0071, 0.0049])


def shell(x: np.ndarray) -> np.ndarray:
    """Small near the sphere of radius 0.5 about (0.2, 0.1, 0), growing away from it."""
    return 0.08 + 0.4 * np.abs(np.linalg.norm(x - [0.2, 0.1, 0.0], axis=1) - 0.5)


def corner(x: np.ndarray) -> np.ndarray:
    """Small at one corner of BOX, on its boundary."""
    return 0.04 + 0.5 * np.linalg.norm(x - BOX[0], axis=1)


CASES = [(shell, 0.5, 0.08), (corner, 0.4, None), (0.3, 0.3, None), (shell, 0.45, 0.04)]


def leaf_sides(x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x[cells][:, :, None] - x[cells][:, None], axis=3).max(axis=(1, 2))


@pytest.mark.parametrize("size, max_size, min_size", CASES)
def test_tetrahedralisation(size, max_size, min_size):
    """Positively oriented, conforming with a closed boundary (the surface of the root cubes,
    whose volume it has), no duplicate or unused vertices, dihedral angles in [45, 120] with
    those above 90 exactly in the half pyramids (two per face against a larger leaf)."""
    x, cells = gt.graded_tetrahedralisation(BOX, size, max_size, min_size)
    assert x.shape[1] == 3 and cells.shape[1] == 4 and cells.dtype == np.int64
    vol = signed_volumes(x, cells)
    assert np.all(vol > 0)
    t = gt._octree(BOX, size, max_size, min_size)
    lv = gt._classify(t)
    root = t.unit * 2.0 ** (t.depth + 1)
    assert vol.sum() == pytest.approx(np.prod(t.n) * root**3, rel=1e-12)
    assert len(cells) == lv.weight.sum()
    d = dihedral_angles(x, cells)
    assert d.min() >= gt.DIHEDRAL_RANGE[0] - 1e-9 and d.max() <= gt.DIHEDRAL_RANGE[1] + 1e-9
    obtuse = d.max(axis=1) > 90 + 1e-9
    assert obtuse.sum() == 2 * (lv.faces == gt._COARSER).sum()
    assert np.allclose(d[obtuse].max(axis=1), 120.0)
    assert set(np.unique(np.round(d, 6)).tolist()) <= {45.0, 60.0, 90.0, 120.0}
    check_conforming(x, cells)
    lo, hi = x.min(axis=0), x.max(axis=0)
    assert np.all(lo <= BOX[0]) and np.all(hi >= BOX[1])
    corners = np.array(np.meshgrid(*BOX.T, indexing="ij")).reshape(3, -1).T
    pts = np.vstack([corners, np.random.default_rng(2).uniform(BOX[0], BOX[1], (8, 3))])
    assert contains(x, cells, pts).all()
    if min_size is not None:  # leaf sides min_size 2^k
        k = np.log2(leaf_sides(x, cells) / min_size)
        assert np.allclose(k[np.isclose(k, np.round(k))], np.round(k[np.isclose(k, np.round(k))]))


def leaf_of(t: gt._Octree, pts: np.ndarray) -> np.ndarray:
    """Level of the leaf containing each point (lattice units), -1 outside the root cubes."""
    out = np.full(len(pts), -1)
    for level, keys in enumerate(t.leaves):
        side = 2 ** (t.depth + 1 - level)
        c = np.floor(pts / side).astype(np.int64)
        lim = np.array(t.n) << level
        ok = np.all((c >= 0) & (c < lim), axis=1)
        k = (c[:, 0] * lim[1] + c[:, 1]) * lim[2] + c[:, 2]
        hit = ok & np.isin(k, keys)
        out[hit] = level
    return out


@pytest.mark.parametrize("size, max_size, min_size", CASES)
def test_octree(size, max_size, min_size):
    """The leaves tile the root cubes; leaves that touch (across a face, an edge or a
    vertex) differ by at most one level; every leaf is at most the size at its centre and
    corners, and its parent was not (unless the balance split it)."""
    t = gt._octree(BOX, size, max_size, min_size)
    lv = gt._classify(t)
    centre = lv.corner + lv.side[:, None] / 2
    assert np.array_equal(leaf_of(t, centre), lv.level)
    dirs = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)])
    for d in dirs[np.any(dirs != 0, axis=1)]:
        probe = centre + d * (lv.side[:, None] / 2 + 0.25)
        nb = leaf_of(t, probe)
        inside = nb >= 0
        assert np.all(np.abs(nb[inside] - lv.level[inside]) <= 1)
    h = gt._size_function(size)
    unit = t.unit
    offs = np.array([(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)])
    pts = np.concatenate([centre[:, None], lv.corner[:, None] + offs * lv.side[:, None, None]], 1)
    hmin = h(t.lo + unit * pts.reshape(-1, 3)).reshape(len(pts), 9).min(axis=1)
    assert np.all(lv.side * unit <= hmin * (1 + 1e-12))
    if min_size is not None:
        assert (lv.side * unit).min() >= min_size * (1 - 1e-12)


def test_uniform_band():
    """With a band size field around a sphere, the tetrahedra within 5 h of it are BCC
    tetrahedra of side h (edges h and h sqrt(3)/2, dihedral angles 60 and 90): no level
    change reaches the band (which stays off the box boundary here); beyond it the sizes
    grow to max_size."""
    h, band = 0.05, 5.0
    pts = du.Sphere(C, 0.45).sample(int(4 * np.pi * 0.45**2 / h**2))
    field = gt.BandSizeField(pts, h, 0.4, band=band, gradation=0.5, margin=h)
    x, cells = gt.graded_tetrahedralisation([C - 1, C + 1], field, 0.4, h)
    dist = np.abs(np.linalg.norm(x - C, axis=1) - 0.45)
    near = (dist[cells] <= band * h).any(axis=1)
    edges = np.linalg.norm(x[cells][:, :, None] - x[cells][:, None], axis=3)
    e = np.sort(edges[near].reshape(-1, 16)[:, [1, 2, 3, 6, 7, 11]], axis=1)
    assert np.allclose(e[:, :4], h * np.sqrt(3) / 2) and np.allclose(e[:, 4:], h)
    d = dihedral_angles(x, cells[near])
    assert np.allclose(np.sort(d, axis=1), [60, 60, 60, 60, 90, 90])
    assert leaf_sides(x, cells).max() == pytest.approx(4 * h)  # graded within the box


def test_band_field():
    """BandSizeField: h inside the band, growing by the gradation beyond, h_max far away;
    the smallest group wins; picklable (the trees are rebuilt)."""
    import pickle

    p = np.array([[0.0, 0, 0], [3.0, 0, 0]])
    f = gt.BandSizeField(p, [0.1, 0.2], 1.0, band=5.0, gradation=0.5, margin=[0.05, 0.0])
    q = np.array([[0.0, 0, 0.55], [0, 0, 0.75], [3, 0, 1.1], [3, 0, 1.3], [0, 0, 50], [1.5, 0, 0]])
    expect = [0.1, 0.2, 0.25, 0.35, 1.0, min(0.1 + 0.5 * 0.95, 0.2 + 0.5 * 0.5)]
    assert np.allclose(f(q), expect)
    g = pickle.loads(pickle.dumps(f))
    assert np.array_equal(g(q), f(q))
    with pytest.raises(ValueError, match="positive"):
        gt.BandSizeField(p, [0.1, -1], 1.0)


@pytest.mark.parametrize("size, max_size, min_size", CASES[:3])
def test_parts(size, max_size, min_size):
    """The parts of any number of ranks, in order, are the serial tetrahedralisation,
    bitwise (more parts than leaves: some are empty); each part holds a contiguous block of
    vertices and about the same number of tetrahedra."""
    x, cells = gt.graded_tetrahedralisation(BOX, size, max_size, min_size)
    t = gt._octree(BOX, size, max_size, min_size)
    lv = gt._classify(t)
    for k in (2, 3, 7) if len(lv.level) > 300 else (2, len(lv.level) + 3):
        parts = gt._leaf_parts(lv, k)
        assert np.all(np.diff(parts) >= 0)
        got = [gt._part(t, lv, parts, r) for r in range(k)]
        assert np.array_equal(np.concatenate([g[0] for g in got]), x)
        assert np.array_equal(np.concatenate([g[1] for g in got]), cells)
        if k < 10:
            counts = np.array([len(g[1]) for g in got])
            assert counts.max() - counts.min() <= 2 * lv.weight.max()


@pytest.mark.parametrize(
    "box, size, max_size, min_size, match",
    [
        ([[0, 0, 0], [1, 1, np.nan]], 0.1, 0.1, None, "finite box"),
        ([[0, 0, 0], [1, 0, 1]], 0.1, 0.1, None, "empty box"),
        ([[0, 0], [1, 1]], 0.1, 0.1, None, r"\[\[xmin"),
        ([[0, 0, 0], [1, 1, 1]], 0.1, 0.0, None, "max_size"),
        ([[0, 0, 0], [1, 1, 1]], 0.1, np.inf, None, "max_size"),
        ([[0, 0, 0], [1, 1, 1]], 0.1, 0.1, 0.2, "min_size"),
        ([[0, 0, 0], [1, 1, 1]], -0.1, 0.5, None, "positive"),
        ([[0, 0, 0], [1, 1, 1]], lambda x: -np.ones(len(x)), 0.5, None, "positive"),
        ([[0, 0, 0], [1e6, 1, 1]], 0.1, 0.1, None, "too many root cubes"),
    ],
)
def test_bad_input(box, size, max_size, min_size, match):
    with pytest.raises(ValueError, match=match):
        gt.graded_tetrahedralisation(box, size, max_size, min_size)


@pytest.mark.mpi
def test_size_function_errors_on_every_rank():
    """A size function failing on some rank's points raises on every rank."""

    def bad(x):
        if np.any(x[:, 0] > 0.9):
            raise RuntimeError("boom")
        return np.full(len(x), 0.2)

    with pytest.raises((ValueError, RuntimeError), match="boom"):
        gt.graded_tet_mesh(comm, [[0, 0, 0], [1, 1, 1]], bad, 0.5)


@pytest.mark.mpi
def test_mesh():
    """The DOLFINx mesh: positively oriented, its volume, local vertex sizes of a graded
    background (the longest edge at each vertex, smoothed)."""
    from dolfinx_universal.backgrounds import lattice_tri as bg

    msh = gt.graded_tet_mesh(comm, BOX, shell, 0.5, 0.08)
    x = msh.geometry.x
    dofs = msh.geometry.dofmaps[0]
    assert np.all(signed_volumes(x, dofs) > 0)
    volume = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(msh))))
    t = gt._octree(BOX, shell, 0.5, 0.08)
    assert volume == pytest.approx(np.prod(t.n) * (t.unit * 2.0 ** (t.depth + 1)) ** 3)
    msh.topology.create_connectivity(3, 0)
    imv = msh.topology.index_map(0)
    c2v = msh.topology.connectivity(3, 0).array.reshape(-1, 4)
    v2n = np.empty(imv.size_local + imv.num_ghosts, dtype=np.int32)
    v2n[c2v] = dofs
    nc = msh.topology.index_map(3).size_local
    hv = bg.vertex_sizes(imv, x[v2n], c2v, nc, True, comm)
    assert comm.allreduce(hv.min(), op=MPI.MIN) == pytest.approx(0.08)
    assert comm.allreduce(hv.max(), op=MPI.MAX) == pytest.approx(0.32)


@pytest.mark.mpi
@needs_ranks(2)
@pytest.mark.parametrize("size, max_size, min_size", CASES[:2])
def test_mesh_distributed(size, max_size, min_size):
    """Built in parallel, bitwise the serial mesh: each local node has the coordinates of its
    input index in the serial tetrahedralisation, the owned cells of all ranks are its cells,
    each rank owns its run of leaves (no graph partitioning), with shared-facet ghosts."""
    x, cells = gt.graded_tetrahedralisation(BOX, size, max_size, min_size)
    msh = gt.graded_tet_mesh(comm, BOX, size, max_size, min_size)
    inp = np.asarray(msh.geometry.input_global_indices, dtype=np.int64)
    assert np.array_equal(msh.geometry.x, x[inp])  # bitwise, ghosts included
    nc = msh.topology.index_map(3).size_local
    mine = inp[msh.geometry.dofmaps[0][:nc]]
    t = gt._octree(BOX, size, max_size, min_size)
    lv = gt._classify(t)
    parts = gt._leaf_parts(lv, comm.size)
    assert len(mine) == lv.weight[parts == comm.rank].sum()
    everything = comm.gather(mine, root=0)
    if comm.rank == 0:
        got = np.concatenate(everything)
        assert np.array_equal(got[np.lexsort(got.T[::-1])], cells[np.lexsort(cells.T[::-1])])
    serial = gt.graded_tet_mesh(MPI.COMM_SELF, BOX, size, max_size, min_size)
    a, b = canonical_cells(msh), canonical_cells(serial)
    if comm.rank == 0:
        assert a.shape == b.shape and np.array_equal(a, b)
    check_shared_facet_ghosts(msh, cells)
    assert comm.allreduce(msh.topology.index_map(3).num_ghosts) > 0


def test_exported():
    assert du.graded_tet_mesh is gt.graded_tet_mesh


# ---------------------------------------------------------------------------------------------
# mesh_domain on the graded background

EXTERIOR = du.Domain(None, [du.Sphere(C, 0.3)])
EXTERIOR_BOX = [[-2.0] * 3, [2.0] * 3]


def test_levels():
    """The finest level is chosen so that the component sizes are levels (base 2^k) as far
    as that saves cells; every size is at most its target."""
    from dolfinx_universal.meshing.plans_tet import _levels

    out = _levels(np.array([0.0634, 0.0333]), np.array([12.6, 0.13]), 5.0, 0.25)
    assert out[0] == pytest.approx(0.0634) and out[1] == pytest.approx(0.0317)
    out = _levels(np.array([0.05, 0.33, 0.09]), np.ones(3), 5.0, 0.25)
    k = np.log2(out / out.min())
    assert np.allclose(k, np.round(k)) and np.all(out <= [0.05, 0.33, 0.09])
    assert np.all(out > 0.5 * np.array([0.05, 0.33, 0.09]))


@pytest.mark.mpi
def test_auto_background():
    """``tet_background="auto"``: the graded octree where it has fewer than half the
    tetrahedra of the A15 background (a small body in a large box), else A15 (a torus
    whose band fills its box)."""
    from dolfinx_universal.meshing.plans_tet import GradedTetPlan as _GradedTetPlan
    from dolfinx_universal.meshing.plans_tet import UniformPlan as _UniformPlan
    from dolfinx_universal.meshing.plans_tet import tet_plan as _tet_plan

    plan = _tet_plan(comm, EXTERIOR, 0.8, 1, EXTERIOR_BOX, 3.0, None, "auto", 5e6)
    assert isinstance(plan, _GradedTetPlan) and plan.top == pytest.approx(8 * plan.base)
    uniform = _UniformPlan.from_graded(plan, EXTERIOR, EXTERIOR_BOX, 3.0)
    assert plan.count(comm) < 0.3 * uniform.count()
    torus = du.Torus(C, 1.0, 0.35)
    plan = _tet_plan(comm, torus, 0.5, 1, None, 3.0, None, "auto", 5e6)
    assert isinstance(plan, _UniformPlan) and plan.size == pytest.approx(0.35 / 3)
    plan = _tet_plan(comm, torus, 0.5, 1, None, 3.0, None, "graded", 5e6)
    assert isinstance(plan, _GradedTetPlan)


@pytest.mark.mpi
def test_auto_falls_back_to_a15():
    """After a refinable failure on the octree that ``auto`` chose (the BCC band left
    inverted tetrahedra at a small spherical hole: fuzz seed 154, a sphere of radius 0.54
    in a superellipsoid, at size 0.08), the next round takes the A15 background of the same
    size where the refined octree would exceed ``max_cells`` (there: both components'
    bands halved, 6.8e6 tetrahedra estimated, the A15 one 2.4e6; mesh_domain raised) or
    have more tetrahedra; else the refined octree. Once only; never for ``"graded"``."""
    from dolfinx_universal.meshing.plans_tet import GradedTetPlan as _GradedTetPlan
    from dolfinx_universal.meshing.plans_tet import UniformPlan as _UniformPlan
    from dolfinx_universal.meshing.plans_tet import tet_plan as _tet_plan

    place = np.array([C + [0.3, 0.0, 0.0]])  # on the sphere
    plan = _tet_plan(comm, EXTERIOR, 0.8, 1, EXTERIOR_BOX, 3.0, None, "auto", 5e6)
    assert isinstance(plan, _GradedTetPlan) and isinstance(plan.alternative, _UniformPlan)
    a15 = plan.alternative
    plan.estimate = lambda: 6e6  # type: ignore[method-assign]  # the refined octree's
    nxt, note = plan.refined(place, comm, 5e6)
    assert nxt is a15 and a15.size == pytest.approx(0.1) and "the A15 uniform background" in note
    # a small body in a large box: the refined octree (4.4e5) is still smaller than A15 (8e5)
    plan = _tet_plan(comm, EXTERIOR, 0.8, 1, EXTERIOR_BOX, 3.0, None, "auto", 5e6)
    nxt, note = plan.refined(place, comm, 5e6)
    assert nxt is plan and note == "" and plan.alternative is None
    assert np.allclose(plan.component_sizes, 0.05)
    plan = _tet_plan(comm, EXTERIOR, 0.8, 1, EXTERIOR_BOX, 3.0, None, "graded", 5e6)
    assert isinstance(plan, _GradedTetPlan) and plan.alternative is None
    plan.estimate = lambda: 6e6  # type: ignore[method-assign]
    assert plan.refined(place, comm, 5e6)[0] is plan  # asked for: kept (check_size refuses)


@pytest.mark.mpi
def test_mesh_domain_graded():
    """A small sphere in a box on the graded background: the mesh is the conforming mesh of
    the octree background (BCC in the band, coarser away from it), its dihedral angles
    within [30, 125] after the relaxation, the surface's vertices on the sphere, the
    volume of the box minus the ball to O(h^2) (on 1-3 ranks)."""
    md = du.mesh_domain(comm, EXTERIOR, 0.8, box=EXTERIOR_BOX)  # auto: graded
    cert = md.certificate
    assert cert.h_min == pytest.approx(0.1) and cert.refinement_rounds == 0
    assert 30.0 <= cert.min_angle_deg and cert.max_angle_deg <= 125.0
    assert cert.num_pieces == 1 and cert.num_loops == 1
    # the certificate names the background used and speaks of tetrahedra
    assert cert.background == "graded BCC octree" and cert.tdim == 3
    text = str(cert)
    assert f"{cert.num_cells} tetrahedra (degree 1) from the graded BCC octree background" in text
    assert "1 closed surface(s), one per surface" in text
    assert "  dihedral angles in [" in text and "triangle" not in text and "loop" not in text
    from dolfinx_universal.meshing.plans_tet import GradedTetPlan as _GradedTetPlan

    plan = _GradedTetPlan.create(comm, EXTERIOR, 0.8, 1, EXTERIOR_BOX, 3.0, None)
    assert cert.num_background_cells == plan.count(comm)
    bg = md.background
    x = bg.geometry.x
    nc = bg.topology.index_map(3).size_local
    sides = leaf_sides(x, bg.geometry.dofmaps[0][:nc])
    assert comm.allreduce(sides.max(initial=0), op=MPI.MAX) == pytest.approx(0.4)  # graded
    assert comm.allreduce(sides.min(initial=1), op=MPI.MIN) == pytest.approx(0.1)
    # Vertices on Gamma, volume.
    msh = md.mesh
    tags = md.facet_tags
    msh.topology.create_connectivity(2, 0)
    f2v = msh.topology.connectivity(2, 0)
    on = np.unique(f2v.array.reshape(-1, 3)[tags.find(du.IMMERSED)])
    r = np.linalg.norm(msh.geometry.x[on] - C, axis=1)
    assert comm.allreduce(np.abs(r - 0.3).max(initial=0), op=MPI.MAX) < 1e-10  # some ranks: none
    volume = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(msh))))
    root_box = 4.0**3  # the 5^3 root cubes of side 0.8 cover the box exactly
    assert abs(volume - (root_box - 4 / 3 * np.pi * 0.3**3)) < 0.8 * 0.1**2 * 4 * np.pi * 0.3**2


@pytest.mark.mpi
def test_plan_refine():
    """A failed check near a component halves that component's size (a level down), with
    denser band sources; the others keep theirs (here no finer band reaches into theirs)."""
    from dolfinx_universal.meshing.plans_tet import GradedTetPlan as _GradedTetPlan

    two = du.Domain(None, [du.Sphere(C - [0.8, 0, 0], 0.3), du.Sphere(C + [1.0, 0, 0], 0.15)])
    plan = _GradedTetPlan.create(comm, two, 0.8, 1, [[-2.0] * 3, [2.0] * 3], 3.0, None)
    assert np.allclose(plan.component_sizes, [0.1, 0.05])
    assert plan.base == pytest.approx(0.05) and plan.top == pytest.approx(0.8)
    n0, m0 = plan.count(comm), len(plan.sources[1][0])
    plan.refine(np.array([C + [1.16, 0.0, 0.0]]))  # just off the small sphere
    assert np.allclose(plan.component_sizes, [0.1, 0.025])
    assert plan.base == pytest.approx(0.025) and plan.top == pytest.approx(0.8)
    assert len(plan.sources[1][0]) > 3 * m0  # resampled one size apart
    assert plan.count(comm) > n0  # the octree was rebuilt
    assert np.allclose(np.unique(plan.sizes()), [0.025, 0.1])


def _torus_in_large_box() -> tuple[du.Torus, np.ndarray, float]:
    """The first torus placement of ``demos/quality_3d.py`` at h = R/4, in a box three
    times its extent (where ``auto`` picks the octree; its BCC band: 29.1 degrees)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng([2019, 2])
    rotation = Rotation.random(random_state=rng).as_matrix()
    period = np.cbrt(4.0) / 4
    u = rng.uniform(0.0, 1.0, 3)
    upright = du.Torus(np.zeros(3), 1.0, 0.35, axis=rotation[:, 2])
    lo, hi = np.asarray(upright.bounding_box())
    box = np.array([1.5 * (lo - hi) + 0.5 * (lo + hi), 1.5 * (hi - lo) + 0.5 * (lo + hi)])
    box[1] += period
    torus = du.Torus(u * period, 1.0, 0.35, axis=rotation[:, 2])
    from dolfinx_universal.sizing.surfaces import surface_feature_size

    factor = 4 * float(surface_feature_size(torus, 0.25).feature.min())
    return torus, box, factor


def test_auto_takes_a15_for_angles():
    """``auto`` conforms the A15 background where the octree it chose gave dihedral angles
    outside ``AUTO_DIHEDRAL`` (the BCC band: 29.1 degrees, A15: 34.4); ``graded`` keeps the
    octree; if A15 fails, the octree's mesh is kept."""
    from dolfinx_universal.meshing import domain as domain

    torus, box, factor = _torus_in_large_box()
    md = du.mesh_domain(comm, torus, 1.0, size_factor=factor, box=box)
    c = md.certificate
    assert c.background == "A15 uniform" and c.refinement_rounds == 1
    assert "graded BCC octree (auto keeps it within (30.0, 125.0))" in c.refinements[0]
    assert 30.0 <= c.min_angle_deg and c.max_angle_deg <= 125.0
    graded = du.mesh_domain(comm, torus, 1.0, size_factor=factor, box=box, tet_background="graded")
    g = graded.certificate
    assert g.background == "graded BCC octree" and g.refinement_rounds == 0
    assert g.min_angle_deg < 30.0  # measured 29.1

    original = domain.conform

    def fail_on_a15(*args, local_size, **kwargs):
        if not local_size:  # the uniform A15 background
            raise du.MeshingError("A15 failed here", np.zeros((1, 3)), refinable=True)
        return original(*args, local_size=local_size, **kwargs)

    domain.conform = fail_on_a15  # type: ignore[assignment]
    try:
        kept = du.mesh_domain(comm, torus, 1.0, size_factor=factor, box=box)
    finally:
        domain.conform = original  # type: ignore[assignment]
    k = kept.certificate
    assert k.background == "graded BCC octree" and k.min_angle_deg == g.min_angle_deg
    assert k.refinement_rounds == 1 and "the octree's mesh kept" in k.refinements[0]
