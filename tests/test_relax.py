"""Vertex relaxation after M_h: quality targets, Gamma kept, curved maps conforming, MPI."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from conftest import ROOT, needs_ranks
from dolfinx import fem
from mesh_checks import curved_triangle_nodes
from random_domains import random_domain

import dolfinx_universal as du
from dolfinx_universal.cells.tri import interior_angles
from dolfinx_universal.conforming.relax import relax_vertices
from dolfinx_universal.conforming.relax_common import (
    SubVertices,
    coordinate_priority,
    movable_vertices,
    vertex_colours,
)
from dolfinx_universal.conforming.relax_tri import (
    ACTIVE_BELOW,
    ACTIVE_RATIO,
    _star_quality,
    shape_quality,
)

CENTRE = (0.0137, -0.0071)
BOX = [[-1.3, -1.3], [1.3, 1.3]]


def _circle(comm, n, relax, box=BOX):
    bg = du.equilateral_mesh(comm, box, 1.0 / n)
    return du.conform(bg, du.Circle(CENTRE, 1.0), relax=relax)


@pytest.fixture(scope="module")
def circle24():
    return {r: _circle(MPI.COMM_WORLD, 24, r) for r in (False, True)}


def _propeller_demo():
    """The module ``demos/stokes_propeller.py`` (its propeller and graded background)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "_propeller", ROOT / "demos" / "stokes_propeller.py"
    )
    assert spec is not None and spec.loader is not None
    demo = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(demo)
    return demo


def _reference_quality(p, a, b, orient):
    """Plain reference: angles and radii from their textbook formulas, one triangle at a time."""
    out = []
    for pi, ai, bi, oi in zip(p, a, b, orient):
        u, v = ai - pi, bi - pi
        if oi * (u[0] * v[1] - u[1] * v[0]) <= 0:
            out.append(-1.0)
            continue
        x = np.array([pi, ai, bi])
        ang = interior_angles(x, np.array([[0, 1, 2]]))[0]
        e = np.array([np.linalg.norm(x[(k + 1) % 3] - x[k]) for k in range(3)])
        area = 0.5 * abs(u[0] * v[1] - u[1] * v[0])
        ratio = (e.prod() / (4 * area)) / (area / (0.5 * e.sum()))  # R / r
        out.append(min(np.sin(ang.min()) / np.sin(np.radians(40)), (2 / ratio) / (2 / 2.6)))
    return np.array(out)


def test_shape_quality_matches_reference():
    rng = np.random.default_rng(3)
    p, a, b = rng.normal(size=(3, 300, 2))
    orient = np.sign(rng.normal(size=300))
    q = shape_quality(p, a, b, orient)
    ref = _reference_quality(p, a, b, orient)
    ok = ref > -1
    assert ok.any() and (~ok).any()
    assert np.allclose(q, ref, rtol=1e-12, atol=1e-14)  # two formulas: a few ulps, O(1) values
    # Equilateral: the radius term (1.3) is below the angle term (sin 60 / sin 40 = 1.35).
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, np.sqrt(3) / 2]])
    assert shape_quality(tri[0], tri[1], tri[2], 1.0) == pytest.approx(1.3, rel=1e-14)  # ulps
    # A degenerate triangle (two coincident corners) is rejected like an inverted one.
    assert shape_quality(np.zeros(2), np.zeros(2), np.ones(2), 1.0) == -1.0


def test_sweep_kernel_matches_shape_quality():
    """The sweeps' kernel is shape_quality of counter-clockwise triangles, to rounding."""
    rng = np.random.default_rng(5)
    p, a, b = rng.normal(size=(3, 500, 2))
    lab = np.linalg.norm(b - a, axis=1)
    k = _star_quality(p[:, 0], p[:, 1], a[:, 0], a[:, 1], b[:, 0], b[:, 1], lab)
    ref = shape_quality(p, a, b, np.ones(500))
    assert (k < 0).sum() > 100 and (k > 0).sum() > 100  # both orientations occur
    assert np.allclose(k, ref, rtol=1e-12, atol=1e-14)  # a few ulps apart, O(1) values


def test_same_set_same_mesh():
    """The propeller demo's threefold propeller at 0 and +-120 degrees is the same set given
    through another parametrisation: on its graded background (quick sizes) the relaxed
    meshes agree to rounding. Decisions on exact comparisons of near-tied candidate
    qualities (argmax, strict gain) made them differ by 2.8e-3 (a step) at a few vertices."""
    demo = _propeller_demo()
    comm = MPI.COMM_WORLD
    md = du.MovingDomain(
        demo.background_mesh(comm, *demo.sizes(True)[:2]), 2, map="I", local_size=True
    )
    x = []
    for angle in (0.0, -120.0, 120.0):
        md.update(du.Domain(None, [du.RigidMotion(demo.propeller, angle=np.radians(angle))]))
        x.append(md.mesh.geometry.x.copy())
    gap = max(float(np.abs(x[0] - xk).max()) for xk in x[1:])
    assert comm.allreduce(gap, op=MPI.MAX) < 1e-12  # rounding of the projections: ~2e-15


def test_priority_is_a_function_of_coordinates():
    x = np.random.default_rng(0).uniform(-1, 1, size=(5000, 2))
    p = coordinate_priority(x)
    assert np.all((p >= 0) & (p < 1)) and len(np.unique(p)) == len(p)
    perm = np.random.default_rng(1).permutation(len(x))
    assert np.array_equal(coordinate_priority(x[perm]), p[perm])


def test_colours_are_independent_sets():
    msh = du.equilateral_mesh(MPI.COMM_SELF, [[0, 0], [1, 1]], 0.1)
    msh.topology.create_connectivity(2, 0)
    cells = msh.topology.connectivity(2, 0).array.reshape(-1, 3)
    imv = msh.topology.index_map(0)
    keep = np.arange(imv.size_local) % 5 != 0  # some vertices left uncoloured
    sub = SubVertices(imv, np.flatnonzero(keep))
    local = np.full(imv.size_local, -1)
    local[sub.vertices] = np.arange(len(sub.vertices))
    x = msh.geometry.x[:, :2]
    v2n = np.empty(imv.size_local, dtype=np.int32)
    v2n[cells] = msh.geometry.dofmaps[0]
    colour = vertex_colours(sub, local[cells], coordinate_priority(x[v2n[sub.vertices]]))
    assert colour.min() == 0 and colour.max() < 12
    c = np.where(local[cells] >= 0, colour[np.maximum(local[cells], 0)], -1 - np.arange(3))
    assert np.all((c[:, 0] != c[:, 1]) & (c[:, 1] != c[:, 2]) & (c[:, 0] != c[:, 2]))


@pytest.mark.parametrize("n", [12, 24])
def test_circle_targets(n, circle24):
    """Equilateral backgrounds, R_r = 3h, alpha = 3/4: the targets (min angle >= 40, max
    <= 95, R/r <= 2.6) with a margin: measured 42.5/91.9/2.47 at h/R = 1/12 and
    40.9/93.4/2.53 at 1/24, from 30.2/104.4/3.15 and 21.9/114.9/4.24 without relaxation
    (vertices stop at 5 % above the targets, ACTIVE_BELOW, and slides may not lengthen
    Gamma_h beyond h, GAMMA_EDGE_MAX, hence the small margin)."""
    cms = circle24 if n == 24 else {r: _circle(MPI.COMM_WORLD, n, r) for r in (False, True)}
    off, on = (du.quality_report(cms[r]) for r in (False, True))
    assert on["n_inverted"] == 0 and on["min_area_ratio"] > 0
    assert on["theta_min_deg"] >= 40.4 and on["theta_max_deg"] <= 94.0 and on["q_max"] <= 2.58
    assert on["theta_min_deg"] > off["theta_min_deg"] + 10
    assert on["n_cells"] == off["n_cells"] and on["n_positively_cut"] == off["n_positively_cut"]


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5, 6, 7])
def test_random_domains(seed):
    """Random smooth domains (tests/random_domains.py) on equilateral backgrounds at
    rho / h = 2: the minimum angle rises to >= 30 degrees (target 20; measured 38.0-42.5
    over these seeds, from 19.4-29.0 without relaxation)."""
    d = random_domain(seed)
    h = float(min(d.h, d.min_radius_of_curvature / 2, d.min_gap / 8))
    bg = du.equilateral_mesh(MPI.COMM_WORLD, d.box(4 * h), h)
    off, on = (
        du.quality_report(du.conform(bg, d.boundary, relax=r, min_angle=0.0)) for r in (0, 1)
    )
    assert on["n_inverted"] == 0 and on["theta_min_deg"] >= max(30.0, off["theta_min_deg"])


def test_gamma_vertices_stay_on_gamma(circle24):
    off, on = circle24[False], circle24[True]
    assert np.array_equal(on.on_gamma, off.on_gamma)
    g = on.on_gamma
    r = np.linalg.norm(on.x[g] - np.asarray(CENTRE), axis=1)
    # Closest points of the unit circle: rounding only (a few ulps; 1e-13 = 450 ulps), as the
    # distances below (the same projections, relaxed or not).
    assert np.abs(r - 1.0).max() < 1e-13
    # The vertices on Gamma slid (not only snapped), and the curved maps' background
    # positions follow them: pi(background_x) = x there, at the same distance from Gamma.
    slid = np.any(on.x[g] != off.x[g], axis=1)
    assert MPI.COMM_WORLD.allreduce(int(slid.sum())) > 0
    bx = on.background_x[g]
    assert np.abs(on.boundary.closest_point(bx) - on.x[g]).max(initial=0.0) < 1e-13
    dist = np.linalg.norm(bx - on.x[g], axis=1)
    dist0 = np.linalg.norm(off.background_x[g] - off.x[g], axis=1)
    assert np.allclose(dist, dist0, rtol=1e-12, atol=1e-15)
    # Nothing moves away from Gamma: vertices beyond R_r keep their background positions.
    far = ~on.moved
    assert np.array_equal(on.x[far], on.background_x[far])


def _gamma_edge_lengths(cm) -> np.ndarray:
    """Lengths of the (local) edges of Gamma_h over the mesh size."""
    f = cm.facet_tags.find(du.IMMERSED)
    fv = cm.mesh.topology.connectivity(1, 0).array.reshape(-1, 2)[f]
    return np.linalg.norm(cm.x[fv[:, 0]] - cm.x[fv[:, 1]], axis=1) / cm.h[fv].max(axis=1)


@pytest.mark.parametrize("n", [24, 48])
def test_slides_keep_gamma_edges_short(n, circle24):
    """Slides may not lengthen an edge of Gamma_h beyond h (nor beyond its length after M_h,
    if longer): the geometric error of a curved edge grows like its length^(q+1), and
    longer edges cost the q = 4 Poisson study half an order on its finest pair."""
    cms = circle24 if n == 24 else {r: _circle(MPI.COMM_WORLD, n, r) for r in (False, True)}
    comm = MPI.COMM_WORLD
    off = comm.allreduce(_gamma_edge_lengths(cms[False]).max(initial=0.0), op=MPI.MAX)
    on = comm.allreduce(_gamma_edge_lengths(cms[True]).max(initial=0.0), op=MPI.MAX)
    assert on <= max(1.0, off) + 1e-12


def test_only_band_vertices_move():
    """Outside the disc (the box minus the disc): vertices of the box's boundary and beyond
    the band keep their positions; ``movable_vertices`` leaves out the fixed ones."""
    comm = MPI.COMM_WORLD
    bg = du.equilateral_mesh(comm, BOX, 1 / 12)
    dom = du.Domain(None, [du.Circle(CENTRE, 1.0)])
    cms = [du.conform(bg, dom, relax=r) for r in (False, True)]
    cm = cms[1]
    imv = bg.topology.index_map(0)
    c2v = bg.topology.connectivity(2, 0).array.reshape(-1, 3)
    v2n = np.empty(imv.size_local + imv.num_ghosts, dtype=np.int32)
    v2n[c2v] = bg.geometry.dofmaps[0]
    orig = bg.geometry.x[v2n[cm.vertex_map], :2]
    d = np.abs(np.linalg.norm(orig - np.asarray(CENTRE), axis=1) - 1.0)
    outer = np.abs(np.abs(orig) - 1.3).min(axis=1) < 1e-9
    changed = np.any(cm.x != orig, axis=1)
    assert comm.allreduce(int(changed.sum())) > 0 and comm.allreduce(int(outer.sum())) > 0
    assert not changed[outer].any() and not changed[d > 3 / 12 + 1e-9].any()
    q = [du.quality_report(c) for c in cms]
    assert q[1]["theta_min_deg"] > q[0]["theta_min_deg"] + 10 and q[1]["n_inverted"] == 0
    n = imv.size_local + imv.num_ghosts
    sign = -np.ones(n)
    band = np.arange(n, dtype=np.int32)
    keep = np.ones(n, dtype=bool)
    fixed = np.arange(0, n, 3, dtype=np.int32)
    movable = movable_vertices(imv, sign, band, ~keep, keep, fixed)
    assert not movable[fixed].any()
    if comm.size == 1:
        assert movable.sum() == n - len(fixed)


@pytest.mark.parametrize("degree", [2, 3])
def test_curved_maps_conform_after_relaxation(circle24, degree):
    """Shared nodes agree, nodes on Gamma_h lie on Gamma, det J > 0 and the disc's area is
    exact to the order of the geometry (error ~ h^(2q): below 1e-6 at q = 2, 1e-8 at q = 3
    for h = 1/24)."""
    cm = circle24[True]
    cv = du.curved_mesh(cm, degree)
    x, dofmap = cv.mesh.geometry.x[:, :2], cv.mesh.geometry.dofmaps[0]
    # every cell computes its nodes with the same formulas: shared nodes agree to an ulp or two
    assert np.abs(x[dofmap] - curved_triangle_nodes(cm, degree, "G")).max() < 1e-14
    V = fem.functionspace(cv.mesh, ("Lagrange", degree))
    cv.mesh.topology.create_connectivity(1, 2)
    dofs = fem.locate_dofs_topological(V, 1, cv.facet_tags.find(du.IMMERSED))
    r = np.linalg.norm(V.tabulate_dof_coordinates()[dofs, :2] - np.asarray(CENTRE), axis=1)
    assert MPI.COMM_WORLD.allreduce(len(dofs)) > 0
    assert np.abs(r - 1.0).max(initial=0.0) < 1e-13  # closest points: rounding only
    assert cv.min_jacobian_ratio > 0.5
    one = fem.Constant(cv.mesh, 1.0)
    area = MPI.COMM_WORLD.allreduce(
        fem.assemble_scalar(fem.form(one * ufl.dx(domain=cv.mesh))), op=MPI.SUM
    )
    assert abs(area - np.pi) < (1e-6 if degree == 2 else 1e-8)


def test_moving_domain_relaxes():
    """MovingDomain relaxes by default: better angles, nodes on Gamma at every step."""
    comm = MPI.COMM_WORLD
    bg = du.equilateral_mesh(comm, BOX, 1 / 12)
    mds = {r: du.MovingDomain(bg, 2, relax=r) for r in (False, True)}
    for step in range(2):
        circle = du.Circle((CENTRE[0] + 0.03 * step, CENTRE[1]), 1.0)
        reps = {r: md.update(circle) for r, md in mds.items()}
        q_off, q_on = reps[False].quality, reps[True].quality
        assert q_on["theta_min_deg"] > q_off["theta_min_deg"] + 5
        assert reps[True].min_jacobian_ratio > 0.5
        md = mds[True]
        V = fem.functionspace(md.mesh, ("Lagrange", 2))
        md.mesh.topology.create_connectivity(1, 2)
        dofs = fem.locate_dofs_topological(V, 1, md.immersed_facets)
        dofs = dofs[dofs < V.dofmap.index_map.size_local]  # (ghost nodes: see moving.py)
        r = np.linalg.norm(V.tabulate_dof_coordinates()[dofs, :2] - circle.center, axis=1)
        assert np.abs(r - 1.0).max(initial=0.0) < 1e-13  # closest points: rounding only


def _vertex_arrays(msh):
    """Triangles by vertex, the vertex index map and the vertex positions of ``msh``."""
    msh.topology.create_connectivity(2, 0)
    cells = msh.topology.connectivity(2, 0).array.reshape(-1, 3)
    imv = msh.topology.index_map(0)
    v2n = np.empty(imv.size_local, dtype=np.int32)
    v2n[cells] = msh.geometry.dofmaps[0]
    return cells, imv, msh.geometry.x[v2n, :2].copy()


def test_relax_vertices_never_lowers_a_star():
    """Each accepted move raises the moving vertex's worst quality: the minimum over the
    triangles never falls, whatever the number of sweeps; vertices not movable stay."""
    msh = du.equilateral_mesh(MPI.COMM_SELF, [[0, 0], [1, 1]], 0.1)
    cells, imv, x0 = _vertex_arrays(msh)
    rng = np.random.default_rng(7)
    inner = np.all((x0 > 0.05) & (x0 < 0.95), axis=1)
    y = x0 + np.where(inner[:, None], rng.uniform(-0.03, 0.03, size=x0.shape), 0.0)
    d1, d2 = y[cells[:, 1]] - y[cells[:, 0]], y[cells[:, 2]] - y[cells[:, 0]]
    orient = np.sign(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])

    def worst(z):
        q = shape_quality(z[cells[:, 0]], z[cells[:, 1]], z[cells[:, 2]], orient)
        return q.min(), np.degrees(interior_angles(z, cells).min())

    history = [worst(y)]
    for sweeps in (1, 3, 6):
        r = relax_vertices(
            MPI.COMM_SELF, imv, lambda p: (p, np.zeros_like(p)), x0, x0, y, cells, inner,
            np.zeros(len(y), dtype=bool), np.zeros_like(y), np.zeros(len(y)),
            np.full(len(y), 0.1), sweeps=sweeps,
        )  # fmt: skip
        history.append(worst(r.y))
        assert np.array_equal(r.y[~inner], y[~inner]) and r.num_sweeps <= sweeps
        assert r.num_moves > 0 and np.array_equal(r.moved, np.any(r.y != x0, axis=1))
    assert all(b[0] >= a[0] for a, b in zip(history, history[1:]))
    assert history[-1][1] > history[0][1] + 5


def _images(cm):
    """Relaxed vertex images keyed by the vertices' original background positions."""
    bg = cm.background
    imv = bg.topology.index_map(0)
    c2v = bg.topology.connectivity(2, 0).array.reshape(-1, 3)
    v2n = np.empty(imv.size_local + imv.num_ghosts, dtype=np.int32)
    v2n[c2v] = bg.geometry.dofmaps[0]
    orig = bg.geometry.x[v2n[cm.vertex_map], :2]
    keys = np.round(orig * 1e9).astype(np.int64)
    return {tuple(k): tuple(v) for k, v in zip(keys, np.column_stack([cm.x, cm.background_x]))}


@pytest.mark.mpi
@needs_ranks(2)
def test_relaxation_independent_of_partition():
    """The relaxed mesh is the same on any number of ranks (positions to 1e-12)."""
    comm = MPI.COMM_WORLD
    t = np.linspace(0, 2 * np.pi, 15, endpoint=False)
    r = 1 + 0.25 * np.cos(3 * t)
    spline = du.PeriodicSpline(np.column_stack([r * np.cos(t), r * np.sin(t)]))
    cases = [(_circle(comm, 24, True), _circle(MPI.COMM_SELF, 24, True))]
    cases.append(
        tuple(du.conform(du.equilateral_mesh(c, BOX, 0.08), spline) for c in (comm, MPI.COMM_SELF))
    )
    for p, s in cases:
        ref = _images(s)
        mine = _images(p)
        diff = max(np.abs(np.subtract(v, ref[k])).max() for k, v in mine.items())
        assert comm.allreduce(diff, op=MPI.MAX) < 1e-12
        qp, qs = du.quality_report(p), du.quality_report(s)
        assert qp["theta_min_deg"] == pytest.approx(qs["theta_min_deg"], abs=1e-9)


def test_vertices_as_good_as_the_background_rest():
    """A vertex is worked on only while its star is below ACTIVE_RATIO times its star's
    worst quality in the background: on a background of 31-59-90 degree triangles (quality
    0.80, below ACTIVE_BELOW) nothing is rated at the background positions, and after a
    perturbation only the stars it spoiled are relaxed, back above that bound."""
    from dolfinx.mesh import create_rectangle

    msh = create_rectangle(MPI.COMM_SELF, [[0.0, 0.0], [1.0, 0.6]], [10, 10])
    cells, imv, x0 = _vertex_arrays(msh)
    inner = np.all((x0 > 0.05) & (x0 < [0.95, 0.55]), axis=1)
    d1, d2 = x0[cells[:, 1]] - x0[cells[:, 0]], x0[cells[:, 2]] - x0[cells[:, 0]]
    orient = np.sign(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    q_bg = shape_quality(x0[cells[:, 0]], x0[cells[:, 1]], x0[cells[:, 2]], orient)
    assert np.allclose(q_bg, q_bg[0]) and 0.75 < q_bg[0] < ACTIVE_BELOW

    def relax(y):
        return relax_vertices(
            MPI.COMM_SELF, imv, lambda p: (p, np.zeros_like(p)), x0, x0, y, cells, inner,
            np.zeros(len(y), dtype=bool), np.zeros_like(y), np.zeros(len(y)),
            np.full(len(y), 0.1),
        )  # fmt: skip

    r = relax(x0.copy())
    assert r.num_sweeps == 0 and r.num_moves == 0 and not r.moved.any()
    # Push one inside vertex most of the way to a neighbour: its star and its neighbours'
    # fall below the bound; the relaxation moves them (and nothing far away) and lifts the
    # worst triangle back above ACTIVE_RATIO times the background's.
    v = np.flatnonzero(inner)[len(np.flatnonzero(inner)) // 2]
    w = cells[np.any(cells == v, axis=1)].ravel()
    w = w[w != v][0]
    y = x0.copy()
    y[v] += 0.6 * (x0[w] - x0[v])
    q = shape_quality(y[cells[:, 0]], y[cells[:, 1]], y[cells[:, 2]], orient)
    assert q.min() < ACTIVE_RATIO * q_bg[0]
    r = relax(y)
    assert r.num_moves > 0
    q = shape_quality(r.y[cells[:, 0]], r.y[cells[:, 1]], r.y[cells[:, 2]], orient)
    assert q.min() >= ACTIVE_RATIO * q_bg[0]
    far = np.linalg.norm(x0 - x0[v], axis=1) > 0.35
    assert not r.moved[far].any()


@pytest.mark.mpi
@needs_ranks(2)
def test_sub_reductions_match_vertex_reduce():
    """``SubVertices.reduce`` (only the shared vertices' rows combined) and
    ``SubVertices.reduce_rows`` (a subset of rows, different on each rank, the others
    neutral) give bitwise the values of ``vertex_reduce`` of the whole array, also when
    called again (the kept vectors return to neutral), on a subset of the vertices of an
    equilateral background split over the ranks."""
    from dolfinx_universal.core.collective import vertex_reduce

    comm = MPI.COMM_WORLD
    imv = du.equilateral_mesh(comm, BOX, 0.05).topology.index_map(0)
    g = imv.local_to_global(np.arange(imv.size_local + imv.num_ghosts, dtype=np.int32))
    sub = SubVertices(imv, np.flatnonzero(g % 7 != 3))
    assert comm.allreduce(len(sub.shared), op=MPI.SUM) > 0  # vertices shared by the ranks
    key = g[sub.vertices].astype(np.float64)  # the same for a vertex on every rank
    calls = ((1, "min"), (5, "min"), (3, "sum"), (16, "max"), (40, "min"), (2, "min"), (3, "sum"))
    for call, (width, op) in enumerate(calls):
        vals = np.cos(0.7 * key[:, None] + comm.rank + 1.3 * call + np.arange(width)[None, :])
        vals = vals[:, 0] if width == 1 else vals  # rank-dependent values
        n = sub.map.size_local
        ghosts = np.arange(n, len(key))
        for rows in (  # rows given per rank; calls in a row: one must not leave values behind
            np.flatnonzero(np.sin(3.1 * key + comm.rank + call) > 0.0),
            ghosts[(ghosts + call) % 2 == 0],  # ghosts only: their owners give nothing
            ghosts[(ghosts + call) % 3 == 0],
        ):
            masked = np.full_like(vals, {"min": np.inf, "max": -np.inf, "sum": 0.0}[op])
            masked[rows] = vals[rows]
            expected = vertex_reduce(sub.map, masked, op)[rows]
            assert np.array_equal(sub.reduce_rows(rows, vals[rows], op), expected)
        assert np.array_equal(sub.reduce(vals, op), vertex_reduce(sub.map, vals, op))


def test_compiled_kernels_match_numpy(monkeypatch):
    """The relaxation's C kernels (``dolfinx_universal.core.compiled``: the ratings, the colour
    passes with their decisions, the candidates) evaluate the numpy code's floating-point
    operations in its order, so the relaxed meshes are bitwise the same (vertices and the
    background positions of the slid ones): on a circle (edges of Gamma_h capped), a spline, the
    propeller (slides by the ray from its pole) in one process, and three steps of a moving
    propeller on its graded background (quick sizes)."""
    from dolfinx_universal.core.compiled import relax_kernels

    assert relax_kernels() is not None  # DOLFINx's C compiler (FFCx's) builds them
    demo = _propeller_demo()
    comm = MPI.COMM_SELF
    t = np.linspace(0, 2 * np.pi, 15, endpoint=False)
    r = 1 + 0.25 * np.cos(3 * t)
    curves = [
        (du.Circle(CENTRE, 1.0), BOX, 0.06),
        (du.PeriodicSpline(np.column_stack([r * np.cos(t), r * np.sin(t)])), BOX, 0.06),
        (
            du.RigidMotion(demo.propeller, 0.3, translation=(0.05, 0.02)),
            [[-0.8] * 2, [0.8] * 2],
            0.02,
        ),
    ]

    def meshes():
        out = []
        for curve, box, h in curves:
            cm = du.conform(du.equilateral_mesh(comm, box, h), curve)
            out.append((cm.x.copy(), cm.background_x.copy()))
        bg = demo.background_mesh(comm, *demo.sizes(True)[:2])
        md = du.MovingDomain(bg, 2, map="I", local_size=True)
        for angle in (0.0, 7.0, 14.0):
            md.update(du.Domain(None, [du.RigidMotion(demo.propeller, angle=np.radians(angle))]))
            out.append((md.mesh.geometry.x.copy(), np.zeros(0)))  # (q = 2 nodes: x's too)
        return out

    compiled = meshes()
    monkeypatch.setenv("DOLFINX_UNIVERSAL_COMPILED", "0")
    assert relax_kernels() is None
    for (xc, bc), (xn, bn) in zip(compiled, meshes(), strict=True):
        np.testing.assert_array_equal(xc, xn)
        np.testing.assert_array_equal(bc, bn)


def test_compiled_ratings_are_numpy_bitwise():
    """The C kernels' ratings are bitwise numpy's (not merely close enough to give the same
    decisions): candidate minima over vertex segments, re-rated star minima and the
    background minima, on a randomly perturbed mesh with inverted and degenerate triangles
    and capped edges between vertices on Gamma."""
    from dolfinx_universal.conforming.relax_tri import _Stars

    msh = du.equilateral_mesh(MPI.COMM_SELF, [[0, 0], [1, 1]], 0.1)
    cells, _, x = _vertex_arrays(msh)
    rng = np.random.default_rng(3)
    y = x + 0.02 * rng.standard_normal(x.shape)
    y[cells[0, 1]] = y[cells[0, 2]] = y[cells[0, 0]]  # a degenerate (flat) triangle
    n = len(y)
    on_gamma = rng.random(n) < 0.3
    verts = np.arange(n, dtype=np.int32)
    stars = _Stars(y, cells, cells, rng.integers(0, 4, n), verts, on_gamma, np.full(n, 0.1))
    assert stars.kernels is not None and stars.any_flat and stars.caps
    cand = y[:, None, :] + 0.08 * rng.standard_normal((n, 17, 2))
    E, row = np.arange(len(stars.ev)), np.arange(n)
    changed = rng.random(n) < 0.5
    stars.star_minima(np.ones(n, dtype=bool), n)
    compiled = [stars.rate_candidates(E, row, cand), stars.background_minima(x, n)]
    y0 = y.copy()
    y[changed] += 0.01
    compiled.append(stars.star_minima(changed, n))
    y[:] = y0
    kernels, stars.kernels = stars.kernels, None
    stars.star_minima(np.ones(n, dtype=bool), n)
    numpy = [stars.rate_candidates(E, row, cand), stars.background_minima(x, n)]
    y[changed] += 0.01
    numpy.append(stars.star_minima(changed, n))
    for c, v in zip(compiled, numpy, strict=True):
        np.testing.assert_array_equal(c, v)
    q = compiled[0]
    assert (q == -1).any() and (q > 0).any()  # inverted and valid candidates both rated
    assert kernels is not None
