"""Curved maps G_h, G~_h and their interpolants; degree-k DOLFINx meshes; Poisson rates."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import LinearProblem
from mesh_checks import curved_triangle_nodes

import dolfinx_universal as du
from dolfinx_universal.curved.maps import jacobian_ratio
from dolfinx_universal.curved.maps_tri import map_nodes, reference_nodes, transfinite_map

comm = MPI.COMM_WORLD
CENTRE = np.array([0.0123, -0.0234])


@pytest.fixture(scope="module")
def disc():
    bg = du.equilateral_mesh(comm, [[-1.6, -1.6], [1.6, 1.6]], 0.15)
    return du.conform(bg, du.Circle(CENTRE, 1.0))


def _pc_data(cm):
    cells = cm.cells[cm.positively_cut]
    k = np.argmin(cm.sign[cells], axis=1)
    rows = np.arange(len(cells))
    u, v, w = cells[rows, (k + 1) % 3], cells[rows, (k + 2) % 3], cells[rows, k]
    return u, v, w


def test_blend_on_edges_and_vertices(disc):
    cm = disc
    u, v, w = _pc_data(cm)
    y, b = cm.x, cm.background_x
    t = np.linspace(0, 1, 11)
    pi = cm.boundary.closest_point
    # Positive edge (l_w = 0): G_h = pi(l_u u + l_v v), on the circle.
    lam = np.column_stack([t, 1 - t, 0 * t])
    g = transfinite_map(lam, b[u], b[v], y[u], y[v], y[w], pi)
    ref = pi(
        (t[None, :, None] * b[u][:, None] + (1 - t[None, :, None]) * b[v][:, None]).reshape(-1, 2)
    ).reshape(g.shape)
    # The same projections, blended with weights 0 and 1: a few ulps of O(1) values (1e-14 =
    # 45 ulps), here and below.
    assert np.abs(g[:, 1:-1] - ref[:, 1:-1]).max() < 1e-14
    assert np.abs(np.linalg.norm(g - CENTRE, axis=2) - 1.0).max() < 1e-14
    # Vertex limits are exact.
    assert np.array_equal(g[:, 0], y[v]) and np.array_equal(g[:, -1], y[u])
    # The two other edges are affine between the vertex images.
    for lam, a, c in (
        (np.column_stack([t, 0 * t, 1 - t]), u, w),
        (np.column_stack([0 * t, t, 1 - t]), v, w),
    ):
        g = transfinite_map(lam, b[u], b[v], y[u], y[v], y[w], pi)
        lin = t[None, :, None] * y[a][:, None] + (1 - t[None, :, None]) * y[c][:, None]
        assert np.abs(g - lin).max() < 1e-14


@pytest.mark.parametrize("degree,per_cell", [(2, 1), (3, 4), (4, 7), (5, 12)])
def test_each_cell_projects_the_points_of_its_own_pattern(disc, degree, per_cell):
    """``map_nodes`` projects, for each positively cut triangle, only the edge points of
    its own node pattern (which local vertex is inside), in one call, and gives the nodes of
    ``transfinite_map`` cell by cell (an independent route: every node's own points)."""
    cm = disc
    pc = np.flatnonzero(cm.positively_cut)
    calls: list[int] = []

    def counted(p):
        calls.append(len(p))
        return cm.boundary.closest_point(p)

    nodes = map_nodes(cm.cells, cm.x, cm.background_x, cm.sign, degree, "G", counted)
    assert calls == [per_cell * len(pc)]
    # The inside vertex at each local index occurs: every pattern is exercised.
    k = np.argmin(cm.sign[cm.cells[pc]], axis=1)
    assert set(k.tolist()) == {0, 1, 2}
    lam = reference_nodes(degree)
    u, v, w = _pc_data(cm)
    y, b = cm.x, cm.background_x
    for j in range(3):  # the barycentric points of pattern j: (l_u, l_v, l_w)
        rows = np.flatnonzero(k == j)
        pattern = lam[:, [(j + 1) % 3, (j + 2) % 3, j]]
        ref = transfinite_map(pattern, b[u[rows]], b[v[rows]], y[u[rows]], y[v[rows]],
                              y[w[rows]], cm.boundary.closest_point)  # fmt: skip
        # Nodes on the two straight edges are the affine ones in map_nodes: a few ulps.
        assert np.abs(nodes[pc[rows]] - ref).max() < 1e-14


@pytest.mark.parametrize("degree", [2, 3, 6])
def test_nodes_consistent_and_on_gamma(disc, degree):
    cv = du.curved_mesh(disc, degree, "I")
    x, dofmap = cv.mesh.geometry.x[:, :2], cv.mesh.geometry.dofmaps[0]
    nodes = curved_triangle_nodes(disc, degree, "G")
    # Every cell sees the node values it computed itself: neighbours agree on shared nodes
    # (the same formulas from either side: an ulp or two).
    assert np.abs(x[dofmap] - nodes).max() < 1e-14
    # Every geometry node on an immersed facet lies on Gamma.
    topo = cv.mesh.topology
    topo.create_connectivity(1, 2)
    facets = cv.facet_tags.find(du.IMMERSED)
    V = fem.functionspace(cv.mesh, ("Lagrange", degree))
    dofs = fem.locate_dofs_topological(V, 1, facets)
    r = np.linalg.norm(V.tabulate_dof_coordinates()[dofs, :2] - CENTRE, axis=1)
    assert len(dofs) > 0 and np.abs(r - 1.0).max() < 1e-13  # closest points: rounding only
    assert cv.min_jacobian_ratio > 0.5


def test_boundary_dof_data(disc):
    """Boundary dofs of a vector space: exact closest points (the dofs themselves), normals
    and tangents of the true circle."""
    cv = du.curved_mesh(disc, 2, "I")
    V = fem.functionspace(cv.mesh, ("Lagrange", 2, (2,)))
    dofs, y, n, t = du.boundary_dof_data(V, cv)
    x = V.tabulate_dof_coordinates()[dofs, :2]
    # Closest points of points on the circle, and normalised radii: rounding only.
    assert len(dofs) > 0 and np.abs(y - x).max() < 1e-13
    radial = (x - CENTRE) / np.linalg.norm(x - CENTRE, axis=1)[:, None]
    assert np.abs(n - radial).max() < 1e-12
    assert np.abs(t - np.column_stack([-radial[:, 1], radial[:, 0]])).max() < 1e-12


def test_I_and_Itilde_differ_only_where_expected(disc):
    k = 2
    a, b = curved_triangle_nodes(disc, k, "G"), curved_triangle_nodes(disc, k, "G~")
    pc = disc.positively_cut
    assert np.array_equal(a[~pc], b[~pc])  # affine cells: identical
    assert np.array_equal(a[:, :3], b[:, :3])  # vertices: identical
    u, v, w = _pc_data(disc)
    pi = disc.boundary.closest_point
    y, bx = disc.x, disc.background_x
    # The mid-node of the positive edge: pi((z1 + z2)/2) under I, pi((pi z1 + pi z2)/2) under I~.
    mid_I = pi(0.5 * (bx[u] + bx[v]))
    mid_It = pi(0.5 * (y[u] + y[v]))
    lam = reference_nodes(k)
    cells = disc.cells[pc]
    kk = np.argmin(disc.sign[cells], axis=1)
    # local edge index of the positive edge = index of the opposite (inside) vertex
    node = 3 + kk
    rows = np.arange(len(cells))
    # the same projections of the same points (an ulp or two), against a difference > 1e-8
    assert np.abs(a[pc][rows, node] - mid_I).max() < 1e-14
    assert np.abs(b[pc][rows, node] - mid_It).max() < 1e-14
    assert np.abs(mid_I - mid_It).max() > 1e-8  # they really differ
    # The other edge mid-nodes (affine edges) agree.
    for e in range(3):
        same = kk != e
        assert np.abs(a[pc][rows[same], 3 + e] - b[pc][rows[same], 3 + e]).max() < 1e-14
    assert lam.shape == (6, 3)


def test_jacobian_check_catches_inverted_cell():
    lam = reference_nodes(2)
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    nodes = lam @ tri
    assert jacobian_ratio(nodes[None], 2)[0] == pytest.approx(1.0)
    bulge = nodes.copy()
    bulge[3] += [0.1, 0.1]  # edge 0 (v1-v2) bulges outwards: still valid
    assert jacobian_ratio(bulge[None], 2)[0] > 0
    fold = nodes.copy()
    fold[3] = [-0.1, -0.1]  # the edge mid-node pushed past the opposite vertex: inverted
    assert jacobian_ratio(fold[None], 2)[0] < 0


class _Wavy(du.Circle):
    """A 'projection' that overshoots inwards away from the vertices (deliberately wrong)."""

    def closest_point(self, x):
        y = super().closest_point(x)
        return y - 0.4 * self.normal(y)


def test_curved_mesh_rejects_inverted_cells(disc):
    import dataclasses

    bad = dataclasses.replace(disc, boundary=_Wavy(CENTRE, 1.0))
    with pytest.raises(du.MeshingError, match="not proven valid"):
        du.curved_mesh(bad, 2, "I")


def _poisson_errors(cm, k, geometry_degree, map_):
    cv = du.curved_mesh(cm, geometry_degree, map_)
    msh = cv.mesh
    V = fem.functionspace(msh, ("Lagrange", k))
    x = ufl.SpatialCoordinate(msh)
    u_ex = ufl.exp(x[1]) * ufl.sin(x[0])
    u_d = fem.Function(V)
    u_d.interpolate(lambda p: np.exp(p[1]) * np.sin(p[0]))
    dofs = fem.locate_dofs_topological(V, 1, cv.facet_tags.find(du.IMMERSED))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    problem = LinearProblem(
        ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx,
        fem.Constant(msh, 0.0) * v * ufl.dx,
        bcs=[fem.dirichletbc(u_d, dofs)],
        petsc_options={
            "ksp_type": "preonly",
            "pc_type": "lu",
            "pc_factor_mat_solver_type": "mumps",
        },
        petsc_options_prefix="test_poisson_",
    )
    uh = problem.solve()
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 2 * k + 6})
    e = uh - u_ex
    l2 = np.sqrt(comm.allreduce(fem.assemble_scalar(fem.form(e * e * dx))))
    h1 = np.sqrt(
        comm.allreduce(fem.assemble_scalar(fem.form(ufl.inner(ufl.grad(e), ufl.grad(e)) * dx)))
    )
    return l2, h1


@pytest.mark.parametrize(
    "k, map_, extra",
    [(1, "I", 0), (2, "I", 0), (3, "I", 0), (2, "I~", 0), (1, "G", 2), (2, "G", 2)],
)
def test_poisson_optimal_rates(k, map_, extra):
    """L2 rate k+1 and H1 rate k , fitted over the three finest of four meshes.

    Tolerance 0.15 below the optimal rate: the boundary cuts each level differently, so the
    rates scatter by about +-0.1 before the asymptotic range; a geometric error that spoils
    optimality (e.g. straight interior nodes) costs more than 0.4.
    """
    hs, l2s, h1s = [], [], []
    for level in range(4):
        h = 5 / 16 / 2**level
        bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], h)
        cm = du.conform(bg, du.Circle((0.0, 0.0), 1.0))
        l2, h1 = _poisson_errors(cm, k, k + extra, map_)
        hs.append(h), l2s.append(l2), h1s.append(h1)
    r2 = np.polyfit(np.log(hs[1:]), np.log(l2s[1:]), 1)[0]
    r1 = np.polyfit(np.log(hs[1:]), np.log(h1s[1:]), 1)[0]
    assert r2 > k + 1 - 0.15, (hs, l2s)
    assert r1 > k - 0.15, (hs, h1s)


def test_degrees_above_the_proofs_limit_are_refused(disc):
    """Degree 8 triangles (MAX_DEGREE is 7 for them): a clear error from curved_mesh,
    MovingDomain and mesh_domain, before any work. At degree 15 the proof's rounding had
    reported valid curved triangles of a disc as inverted (test_jacobian gives the reason)."""
    match = "geometry degree 8 is above 7, the highest for triangles"
    with pytest.raises(ValueError, match=match):
        du.curved_mesh(disc, 8)
    with pytest.raises(ValueError, match=match):
        du.MovingDomain(disc.background, degree=8)
    with pytest.raises(ValueError, match=match):
        du.mesh_domain(MPI.COMM_WORLD, du.Circle([0.0, 0.0], 0.5), 0.2, degree=8)
    assert du.curved_mesh(disc, 7).min_jacobian_ratio > 0.5
