"""Tests of the random domains (``random_domains.py``) and of the mesh checker (``mesh_checks.py``).

The checker must pass on meshes from ``conform`` + ``curved_mesh`` on fine equilateral
backgrounds, and fail on deliberately broken ones.
"""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
from conftest import needs_ranks
from dolfinx import mesh as dmesh
from mesh_checks import check_mesh, reference_lattice
from random_domains import KINDS, RATIO_RANGE, RandomDomain, random_domain

import dolfinx_universal as du
from dolfinx_universal.backgrounds.lattice_tri import (
    create_background_mesh,
    equilateral_triangulation,
)

comm = MPI.COMM_WORLD
CENTRE = np.array([0.0123, -0.0234])
DISC = du.Circle(CENTRE, 1.0)


def _shoelace(p: np.ndarray) -> float:
    q = np.roll(p, -1, axis=0)
    return 0.5 * float((p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]).sum())


def _polygon_area(b: du.Boundary, n: int) -> float:
    """Area inside ``b`` from polygons of ``n`` and ``2n`` samples (Richardson: O(n^-4))."""
    if isinstance(b, du.Domain):
        return sum((-1 if body else 1) * _polygon_area(c, n) for c, body in b.components)
    a1, a2 = abs(_shoelace(b.sample(n))), abs(_shoelace(b.sample(2 * n)))
    return (4 * a2 - a1) / 3


def _conformed(d: RandomDomain) -> du.ConformingMesh:
    hb = d.uniform_size()
    return du.conform(du.equilateral_mesh(comm, d.box(4 * hb + 0.05 * d.extent), hb), d.boundary)


def _seed_of(kind: str, max_cells: float = 4e4) -> int:
    """The first seed of ``kind`` whose uniform background has at most ``max_cells`` cells."""
    for seed in range(KINDS.index(kind), 1000, len(KINDS)):
        d = random_domain(seed)
        hb = d.uniform_size()
        box = d.box(4 * hb + 0.05 * d.extent)
        if 2.4 * np.prod(box[1] - box[0]) / hb**2 <= max_cells:
            return seed
    raise AssertionError(f"no small {kind} domain")


# ----------------------------------------------------------------------------- random domains
def test_random_domains_deterministic_and_balanced():
    a, b = random_domain(7), random_domain(7)
    assert a.description == b.description and a.exact_area == b.exact_area and a.h == b.h
    assert random_domain(12).description != random_domain(17).description
    kinds = [random_domain(s).kind for s in range(50)]
    assert all(kinds.count(k) == 10 for k in KINDS)
    assert random_domain(3, kind="neck").kind == "neck"
    with pytest.raises(ValueError, match="unknown kind"):
        random_domain(0, kind="square")


@pytest.mark.parametrize("seeds", [range(0, 40), range(40, 80)])
def test_random_domain_parameters(seeds):
    for seed in seeds:
        d = random_domain(seed)
        ratio = d.extent / d.h
        assert 0.95 * RATIO_RANGE[0] <= ratio <= 1.05 * RATIO_RANGE[1], (d.label, ratio)
        assert 0 < d.min_feature <= d.min_radius_of_curvature
        assert d.n_pieces == 1
        if d.kind == "multibody":
            assert isinstance(d.boundary, du.Domain)
            assert d.n_curves == len(d.boundary.components) in (2, 3, 4)
            assert d.min_gap >= 0.5 * d.h, d.label
        else:
            assert d.n_curves == 1
        if d.kind == "neck":
            assert 0.25 * d.h <= d.min_gap <= 1.05 * d.h, (d.label, d.min_gap / d.h)


@pytest.mark.parametrize("seeds", [range(0, 30), range(30, 60)])
def test_exact_area_matches_the_boundary(seeds):
    """The independent exact areas agree with polygons through the package's curves."""
    for seed in seeds:
        d = random_domain(seed)
        a = _polygon_area(d.boundary, 20000)
        assert abs(a - d.exact_area) <= 1e-9 * d.exact_area, (d.label, a, d.exact_area)


# ----------------------------------------------------------------------------- valid meshes
@pytest.fixture(scope="module", params=KINDS)
def conformed(request):
    d = random_domain(_seed_of(request.param))
    return d, _conformed(d)


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_checker_passes_on_conformed_random_domains(conformed, degree):
    d, cm = conformed
    cv = du.curved_mesh(cm, degree)
    r = check_mesh(
        cv.mesh,
        cv.facet_tags,
        d.boundary,
        d.exact_area,
        n_curves=d.n_curves,
        n_pieces=d.n_pieces,
        outer=False,
        label=f"{d.label} degree={degree}",
    )
    assert r["failures"] == [], d.description
    assert r["n_loops"] == d.n_curves and r["n_pieces"] == 1
    assert r["min_detJ"] > 0 and 0 < r["min_detJ_ratio"] <= 1 + 1e-12
    assert (r["num_curved_cells"] > 0) == (degree > 1)
    assert r["max_node_distance"] < 1e-12 * d.extent  # closest points: rounding only
    # the area error is the boundary defect, of the order of h^(q+1)
    assert abs(r["area_error"] - r["boundary_defect"]) <= 0.05 * r["boundary_defect_abs"] + 1e-11
    assert r["area_rel_error"] < {1: 1e-2, 2: 1e-4, 3: 1e-6, 4: 1e-7}[degree]
    assert r["boundary_length"] == pytest.approx(d.length, rel=1e-2 if degree == 1 else 1e-5)
    # the angles of the straight triangles are those of the package's report
    q = du.quality_report(cm)
    assert r["min_angle_deg"] == pytest.approx(q["theta_min_deg"], abs=1e-6)
    assert r["max_angle_deg"] == pytest.approx(q["theta_max_deg"], abs=1e-6)


def test_lattice_detects_curved_cells():
    """Affine cells are recognised; curved ones get the fine lattice; both give det J."""
    pts = reference_lattice(4)
    assert len(pts) == 15 and np.array_equal(pts[:3], [[0, 0], [1, 0], [0, 1]])
    bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], 0.12)
    cm = du.conform(bg, DISC)
    cv = du.curved_mesh(cm, 3)
    r = check_mesh(cv.mesh, cv.facet_tags, DISC, np.pi, n_curves=1)
    full = check_mesh(cv.mesh, cv.facet_tags, DISC, np.pi, n_curves=1, full_lattice=True)
    ncut = comm.allreduce(int(cm.positively_cut[: cm.mesh.topology.index_map(2).size_local].sum()))
    assert r["num_curved_cells"] == ncut and full["num_curved_cells"] == r["num_cells"]
    # the same per-cell kernels on the same curved cells (affine ones have det J constant)
    assert r["min_detJ_ratio"] == pytest.approx(full["min_detJ_ratio"], abs=1e-14)
    assert r["min_detJ_ratio"] <= cv.min_jacobian_ratio + 1e-3


def test_two_pieces():
    """A union of two discs: two loops, two pieces (the count is checked, not assumed)."""
    c1, r1, c2, r2 = np.array([-0.6, 0.05]), 0.45, np.array([0.55, -0.02]), 0.35

    def f(x):
        return (((x - c1) ** 2).sum(1) - r1**2) * (((x - c2) ** 2).sum(1) - r2**2)

    def grad(x):
        a, b = ((x - c1) ** 2).sum(1) - r1**2, ((x - c2) ** 2).sum(1) - r2**2
        return 2 * (x - c1) * b[:, None] + 2 * (x - c2) * a[:, None]

    two = du.ImplicitCurve(f, grad, bbox=[[-1.1, -0.45], [0.95, 0.5]])
    cm = du.conform(du.equilateral_mesh(comm, [[-1.5, -1], [1.3, 1]], 0.04), two)
    cv = du.curved_mesh(cm, 2)
    area = np.pi * (r1**2 + r2**2)
    r = check_mesh(cv.mesh, cv.facet_tags, two, area, n_curves=2, n_pieces=2)
    assert r["failures"] == [] and r["n_pieces"] == 2 and r["n_loops"] == 2
    bad = check_mesh(cv.mesh, cv.facet_tags, two, area, n_curves=1, n_pieces=1, label="two")
    assert any("2 connected pieces, expected 1" in m for m in bad["failures"])
    assert any("2 loops, expected 1" in m for m in bad["failures"])
    assert all(m.startswith("two: ") for m in bad["failures"])


# ----------------------------------------------------------------------------- broken meshes
@pytest.fixture(scope="module")
def disc_cm():
    return du.conform(du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], 0.1), DISC)


def _interior_cell(msh: dmesh.Mesh) -> int:
    """An owned cell near the centre of the disc (-1 on ranks without one)."""
    dm = msh.geometry.dofmaps[0][: msh.topology.index_map(2).size_local]
    d = np.linalg.norm(msh.geometry.x[dm[:, :3], :2].mean(axis=1) - CENTRE, axis=1)
    return int(np.argmin(d)) if len(d) and d.min() < 0.3 else -1


def _only(failures: list[str], *words: str) -> bool:
    return bool(failures) and all(any(w in m for w in words) for m in failures)


def test_fails_on_curved_cell_inverted_inside(disc_cm):
    """A degree-2 cell whose edge node is pulled towards the opposite vertex: its vertices
    (the straight triangle) are unchanged, det J < 0 near a vertex only."""
    cv = du.curved_mesh(disc_cm, 2)
    msh = cv.mesh
    assert check_mesh(msh, cv.facet_tags, DISC, np.pi, n_curves=1)["failures"] == []
    c = _interior_cell(msh)
    if c >= 0:
        dm = msh.geometry.dofmaps[0]
        x = msh.geometry.x
        m, v2 = dm[c, 5], dm[c, 2]  # node 5: midpoint of edge 2 = (v0, v1), opposite v2
        x[m] += 0.8 * (x[v2] - x[m])
    r = check_mesh(msh, cv.facet_tags, DISC, np.pi, n_curves=1)
    assert r["min_detJ"] < 0 and r["min_detJ_ratio"] < 0
    assert any("det J <= 0" in m for m in r["failures"]), r["failures"]


def test_fails_on_inverted_straight_cell(disc_cm):
    """A vertex pushed across the opposite edge of its triangle (degree 1)."""
    cv = du.curved_mesh(disc_cm, 1)
    msh = cv.mesh
    c = _interior_cell(msh)
    if c >= 0:
        dm = msh.geometry.dofmaps[0]
        x = msh.geometry.x
        x[dm[c, 0]] += 1.5 * (0.5 * (x[dm[c, 1]] + x[dm[c, 2]]) - x[dm[c, 0]])
    r = check_mesh(msh, cv.facet_tags, DISC, np.pi, n_curves=1)
    assert any("det J <= 0" in m for m in r["failures"]), r["failures"]
    assert any("area" in m for m in r["failures"]), "the folded cells overlap their neighbours"


@pytest.mark.skipif(comm.size > 1, reason="one triangulation on one rank")
def test_fails_on_reversed_cell():
    """A background cell given clockwise: the mesh is geometrically fine, the orientation is
    not consistent, det J < 0 in that cell only."""
    x, cells = equilateral_triangulation([[-1.5, -1.5], [1.5, 1.5]], 0.1)
    k = int(np.argmin(np.linalg.norm(x[cells].mean(axis=1) - CENTRE, axis=1)))
    cells[k] = cells[k, ::-1]
    bg = create_background_mesh(comm, x, cells)
    cv = du.curved_mesh(du.conform(bg, DISC), 3)
    r = check_mesh(cv.mesh, cv.facet_tags, DISC, np.pi, n_curves=1)
    assert _only(r["failures"], "1 cells with det J <= 0"), r["failures"]
    assert r["min_detJ_ratio"] == pytest.approx(-1.0)


def test_fails_on_node_off_gamma(disc_cm):
    """An edge node of an immersed facet moved by 1e-7 along the normal."""
    cv = du.curved_mesh(disc_cm, 3)
    msh = cv.mesh
    facets = cv.facet_tags.find(du.IMMERSED)
    if len(facets):
        node = dmesh.entities_to_geometry(msh, 1, facets[:1])[0, 2]
        x = msh.geometry.x
        x[node, :2] += 1e-7 * (x[node, :2] - CENTRE)
    r = check_mesh(msh, cv.facet_tags, DISC, np.pi, n_curves=1)
    assert _only(r["failures"], "from Gamma"), r["failures"]
    assert r["max_node_distance"] == pytest.approx(1e-7, rel=1e-3)


@pytest.mark.parametrize("degree", [1, 3])
def test_fails_on_dropped_body(degree):
    """The mesh of the container alone, checked against the container minus a body."""
    body = du.Circle((0.3, 0.1), 0.25)
    holed = du.Domain(DISC, [body])
    area = np.pi * (1 - 0.25**2)
    bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], 0.05)
    good = du.curved_mesh(du.conform(bg, holed), degree)
    r = check_mesh(good.mesh, good.facet_tags, holed, area, n_curves=2)
    assert r["failures"] == [] and r["n_loops"] == 2
    cv = du.curved_mesh(du.conform(bg, DISC), degree)
    r = check_mesh(cv.mesh, cv.facet_tags, holed, area, n_curves=2)
    assert any("1 loops, expected 2" in m for m in r["failures"]), r["failures"]
    assert any(m.startswith("area") for m in r["failures"]), r["failures"]


def test_fails_on_wrong_area(disc_cm):
    cv = du.curved_mesh(disc_cm, 3)
    r = check_mesh(cv.mesh, cv.facet_tags, DISC, np.pi * (1 + 1e-6), n_curves=1)
    assert _only(r["failures"], "area"), r["failures"]
    r = check_mesh(cv.mesh, cv.facet_tags, DISC, np.pi, n_curves=1, tol_area=1e-12)
    assert _only(r["failures"], "area"), r["failures"]


def test_fails_on_bad_tags(disc_cm):
    """Exterior facets left untagged; an interior facet tagged IMMERSED."""
    cv = du.curved_mesh(disc_cm, 2)
    msh, tags = cv.mesh, cv.facet_tags
    keep = tags.indices[2:] if comm.rank == 0 else tags.indices
    values = tags.values[2:] if comm.rank == 0 else tags.values
    cut = dmesh.meshtags(msh, 1, keep, values)
    r = check_mesh(msh, cut, DISC, np.pi, n_curves=1)
    assert any("exterior facets carry no tag" in m for m in r["failures"]), r["failures"]
    assert any("not a set of closed simple curves" in m for m in r["failures"])
    msh.topology.create_connectivity(1, 2)
    exterior = dmesh.exterior_facet_indices(msh.topology)
    nf = msh.topology.index_map(1).size_local
    interior = np.setdiff1d(np.arange(nf, dtype=np.int32), exterior)[:1]
    idx = np.concatenate([tags.indices, interior]).astype(np.int32)
    val = np.concatenate([tags.values, np.full(len(interior), du.IMMERSED)]).astype(np.int32)
    order = np.argsort(idx)
    extra = dmesh.meshtags(msh, 1, idx[order], val[order])
    r = check_mesh(msh, extra, DISC, np.pi, n_curves=1)
    assert any("interior facets are tagged IMMERSED" in m for m in r["failures"]), r["failures"]
    assert any("from Gamma" in m for m in r["failures"])
    r = check_mesh(msh, tags, DISC, np.pi, n_curves=1, outer=True)
    assert _only(r["failures"], "OUTER"), r["failures"]


def _checked(c: MPI.Comm) -> dict[str, dict]:
    out = {}
    for seed, degree in ((3, 2), (0, 3), (1, 1)):
        d = random_domain(seed)
        hb = d.uniform_size()
        bg = du.equilateral_mesh(c, d.box(5 * hb), hb)
        cv = du.curved_mesh(du.conform(bg, d.boundary), degree)
        r = check_mesh(cv.mesh, cv.facet_tags, d.boundary, d.exact_area, n_curves=d.n_curves)
        out[f"{d.label} degree={degree}"] = {k: v for k, v in r.items() if not k.endswith("_at")}
    return out


@pytest.mark.mpi
@needs_ranks(2)
def test_checks_agree_in_parallel():
    ref, got = _checked(MPI.COMM_SELF), _checked(MPI.COMM_WORLD)
    assert ref.keys() == got.keys()
    for case, r in ref.items():
        g = got[case]
        assert r["failures"] == g["failures"] == [], case
        for k in ("num_cells", "num_curved_cells", "n_loops", "n_pieces", "n_immersed_facets"):
            assert r[k] == g[k], (case, k)
        # the same mesh: sums in another order, nodes computed by another rank (rounding,
        # ~1e-15 relative); abs: a floor for values near 0
        for k in ("area", "boundary_defect", "boundary_length", "min_detJ_ratio", "min_angle_deg"):
            assert g[k] == pytest.approx(r[k], rel=1e-9, abs=1e-13), (case, k)


def test_gamma_h_loops_match_a_graph_search():
    """The loops of Gamma_h labelled by pointer doubling on oriented edges are the
    components of scipy's graph search, labels and order included; edges that are not
    oriented tail to head (a node with two edges out) take scipy's route."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from dolfinx_universal.conforming.checks_tri import _loops

    rng = np.random.default_rng(0)
    for trial in range(60):
        sizes = rng.integers(3, 80, size=rng.integers(1, 6))
        ids = rng.permutation(100000)[: sizes.sum()]
        edges, o = [], 0
        for k in sizes:
            cycle = ids[o : o + k]
            o += k
            edges += [(cycle[i], cycle[(i + 1) % k]) for i in range(k)]
        g = np.array(edges, dtype=np.int64)[rng.permutation(len(edges))]
        if trial % 3 == 0:  # some edges reversed
            flip = rng.random(len(g)) < 0.3
            g[flip] = g[flip][:, ::-1]
        nodes, inv = np.unique(g, return_inverse=True)
        inv = inv.reshape(-1, 2)
        graph = coo_matrix((np.ones(len(inv)), (inv[:, 0], inv[:, 1])), (len(nodes),) * 2)
        count, label = connected_components(graph, directed=False)
        got = _loops(g)
        assert got[0] == count == len(sizes)
        np.testing.assert_array_equal(got[1], label[inv[:, 0]])
