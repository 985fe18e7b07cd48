"""Curved tetrahedra: the 3D blend of the closest-point projection, degree 2-4 DOLFINx meshes,
proven Jacobian bounds, volume and Poisson convergence, the same mesh on 1 and 2 ranks."""

from __future__ import annotations

import dataclasses

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import LinearProblem

import dolfinx_universal as du
from dolfinx_universal.backgrounds.lattice_tet import a15_mesh, bcc_mesh
from dolfinx_universal.curved import maps_tet as _curved_tet
from dolfinx_universal.curved.maps import _curved_cells

comm = MPI.COMM_WORLD
C = np.array([0.0123, 0.0071, 0.0049])  # off the lattice's symmetry planes
SURFACES = {
    "sphere": (du.Sphere(C, 1.0), a15_mesh, 0.3),
    "ellipsoid": (du.Ellipsoid(C, (1.0, 0.7, 0.5)), bcc_mesh, 0.2),
    "torus": (du.Torus(C, 1.0, 0.35), a15_mesh, 0.2),
}
BOX = [[-1.5] * 3, [1.5] * 3]


@pytest.fixture(scope="module")
def conformed():
    cache: dict[str, du.ConformingMesh] = {}

    def get(name: str) -> du.ConformingMesh:
        if name not in cache:
            surface, lattice, h = SURFACES[name]
            cache[name] = du.conform(lattice(comm, BOX, h), surface)
        return cache[name]

    return get


def _volume(msh, degree: int) -> float:
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 3 * degree + 2})
    return comm.allreduce(fem.assemble_scalar(fem.form(1.0 * dx)), op=MPI.SUM)


def _per_cell(cm: du.ConformingMesh, degree: int, kind: str) -> np.ndarray:
    """Node images of every local cell computed from that cell alone, ``(cells, ndofs, 3)``."""
    lam = _curved_tet.reference_nodes(degree)
    nodes = np.einsum("pi,cid->cpd", lam, cm.x[cm.cells])
    curved, cell_map = _curved_cells(cm, degree, kind)
    nodes[curved] = cell_map(cm.cells[curved], cm.x)
    return nodes


@pytest.mark.parametrize("name", list(SURFACES))
@pytest.mark.parametrize("degree", [2, 3, 4])
def test_nodes_on_gamma_and_shared_nodes_agree(conformed, name, degree):
    cm = conformed(name)
    surface = SURFACES[name][0]
    cv = du.curved_mesh(cm, degree, "I")
    msh = cv.mesh
    x, dofmap = msh.geometry.x, msh.geometry.dofmaps[0]
    # Every geometry node on an immersed face lies on Gamma (closest points: rounding).
    faces = cv.facet_tags.find(du.IMMERSED)
    from dolfinx.mesh import entities_to_geometry

    on = np.unique(entities_to_geometry(msh, 2, faces))
    dist = np.linalg.norm(surface.closest_point(x[on]) - x[on], axis=1)
    assert len(on) > 0 and dist.max() < 1e-14
    # Each node computed from every cell that holds it (the blend uses face and edge data
    # only): the same position from all of them, and the one in the mesh. A few ulps of O(1)
    # coordinates (the same points summed in another vertex order).
    nodes = _per_cell(cm, degree, "G")
    ref = np.zeros_like(x)
    ref[dofmap.ravel()] = nodes.reshape(-1, 3)
    assert np.abs(nodes - ref[dofmap]).max() < 2e-15
    assert np.abs(x[dofmap] - nodes).max() < 2e-15
    # Proven valid, the straight cells kept their shape.
    assert cv.min_jacobian_ratio > 0.4


@pytest.mark.parametrize("name", ["sphere", "torus"])
def test_compiled_curved_map_is_numpy_s(conformed, name, monkeypatch):
    """curved_mesh with the C kernels (the affine images, the blend, each distinct point
    projected once, the node writes, the degree-q dofmap) and with the numpy code: bitwise
    the same geometry and dofmap, at q = 2-4 and for the maps I (the background's points
    projected) and I~."""
    from dolfinx_universal.core.compiled import relax_kernels

    cm = conformed(name)
    cases = [(q, kind) for q in (2, 3, 4) for kind in ("I", "I~")]

    def arrays():  # copies: no mesh outlives its call
        out = []
        for q, kind in cases:
            g = du.curved_mesh(cm, q, kind).mesh.geometry
            out.append((g.x.copy(), g.dofmaps[0].copy()))
        return out

    assert relax_kernels() is not None
    compiled = arrays()
    monkeypatch.setenv("DOLFINX_UNIVERSAL_COMPILED", "0")
    assert relax_kernels() is None
    for (x, dofmap), (x_np, dofmap_np), case in zip(compiled, arrays(), cases, strict=True):
        np.testing.assert_array_equal(x, x_np, err_msg=str(case))
        np.testing.assert_array_equal(dofmap, dofmap_np, err_msg=str(case))


def test_distinct_rows():
    """Each set of bitwise equal rows once, in order of appearance; -0.0 and 0.0 differ."""
    from dolfinx_universal.core.arrays import distinct_rows

    rng = np.random.default_rng(3)
    base = rng.random((50, 3))
    base[7] = [0.0, 1.0, 2.0]
    base[8] = [-0.0, 1.0, 2.0]
    x = base[rng.integers(0, 50, 400)]
    first, inverse = distinct_rows(x)
    assert inverse is not None
    np.testing.assert_array_equal(x[first][inverse], x)
    keys = x.view(np.dtype((np.void, 24))).ravel()
    assert len(first) == len(np.unique(keys)) == len(np.unique(keys[first]))
    assert (np.diff(first) > 0).all() and first[0] == 0
    first, inverse = distinct_rows(base)  # all distinct
    assert inverse is None and np.array_equal(first, np.arange(50))


def test_which_cells_curve(conformed):
    """Cells with a positive face and cells touching Gamma_h by an edge are curved (their
    nodes on Gamma_h follow the projection of the straight background points); cells
    touching Gamma at a vertex or not at all stay affine."""
    cm = conformed("torus")
    surface = SURFACES["torus"][0]
    degree = 3
    face, edges = _curved_tet.gamma_entities(cm.mesh, cm.on_gamma, cm.facet_tags.find(du.IMMERSED))
    cells = cm.cells
    lam = _curved_tet.reference_nodes(degree)
    nodes = _per_cell(cm, degree, "G")
    affine = np.einsum("pi,cid->cpd", lam, cm.x[cells])
    curved = edges.any(axis=1)
    assert (face >= 0).sum() > 0 and (curved & (face < 0)).sum() > 0  # both kinds occur
    assert np.array_equal(nodes[~curved], affine[~curved])
    assert (cm.on_gamma[cells[~curved]].sum(axis=1) <= 2).all()
    # Positive faces: pi of the straight background face point, computed here directly.
    xb = cm.background_x
    for d in range(4):
        rows = np.flatnonzero(face == d)
        on_face = np.flatnonzero((lam[:, d] == 0) & (lam.max(axis=1) < 1))
        want = surface.closest_point(
            np.einsum("pi,cid->cpd", lam[on_face], xb[cells[rows]]).reshape(-1, 3)
        )
        assert np.abs(nodes[rows][:, on_face].reshape(-1, 3) - want).max() < 2e-15
    # Edge-only cells: the nodes of their curved edge lie on Gamma, the others do not move
    # off the straight entities they share with affine cells (vertices exact).
    only = np.flatnonzero(curved & (face < 0))
    support = lam > 0
    checked = 0
    for e, (i, j) in enumerate(_curved_tet.LOCAL_EDGES):
        on_edge = np.flatnonzero(support[:, i] & support[:, j] & (support.sum(axis=1) == 2))
        p = nodes[only[edges[only, e]]][:, on_edge].reshape(-1, 3)
        assert np.linalg.norm(surface.closest_point(p) - p, axis=1).max(initial=0) < 1e-14
        checked += len(p)
    assert checked > 0
    assert np.array_equal(nodes[only][:, :4], affine[only][:, :4])


def test_maps_I_G_and_tilde(conformed):
    """I and G interpolate the same blend (as for triangles); I~ and G~ project the faces of
    the straight mesh instead: the same vertices and affine nodes, other nodes on Gamma."""
    cm = conformed("sphere")
    a = du.curved_mesh(cm, 2, "I").mesh.geometry.x
    b = du.curved_mesh(cm, 2, "G").mesh.geometry.x
    t = du.curved_mesh(cm, 2, "I~")
    assert np.array_equal(a, b)
    g, gt = _per_cell(cm, 2, "G"), _per_cell(cm, 2, "G~")
    assert np.array_equal(g[:, :4], gt[:, :4])
    diff = np.abs(g - gt).max(axis=(1, 2))
    assert diff.max() > 1e-6  # the face points really differ
    face, edges = _curved_tet.gamma_entities(cm.mesh, cm.on_gamma, cm.facet_tags.find(du.IMMERSED))
    assert (diff[~edges.any(axis=1)] == 0).all()
    assert t.min_jacobian_ratio > 0.9  # the straight faces: nearly affine


def test_boundary_dof_data(conformed):
    """Boundary dofs of a vector P3 space on the degree-3 sphere: the dofs are their own
    closest points; radial normals; orthonormal tangent bases."""
    cm = conformed("sphere")
    cv = du.curved_mesh(cm, 3, "I")
    V = fem.functionspace(cv.mesh, ("Lagrange", 3, (3,)))
    dofs, y, n, t = du.boundary_dof_data(V, cv)
    x = V.tabulate_dof_coordinates()[dofs]
    assert len(dofs) > 0 and np.abs(y - x).max() < 1e-14
    radial = (x - C) / np.linalg.norm(x - C, axis=1)[:, None]
    assert np.abs(n - radial).max() < 1e-12
    assert t.shape == (len(dofs), 2, 3)
    assert np.abs(np.einsum("nid,nd->ni", t, n)).max() < 1e-12
    assert np.abs(np.einsum("nid,njd->nij", t, t) - np.eye(2)).max() < 1e-12


def test_volume_converges():
    """Relative volume error of the unit ball at three sizes: O(h^(q+1)) or better (degree 2
    and 4 nodes superconverge to ~h^4 and ~h^6), against O(h^2) straight."""
    surface = du.Sphere(C, 1.0)
    exact = 4.0 / 3.0 * np.pi
    hs = np.array([0.5, 0.35, 0.25])
    errors: dict[tuple[int, str], list[float]] = {}
    for h in hs:
        cm = du.conform(a15_mesh(comm, [[-1.3] * 3, [1.3] * 3], h), surface)
        errors.setdefault((1, "-"), []).append(abs(_volume(cm.mesh, 1) - exact))
        for degree in (2, 3, 4):
            for kind in ("I", "G~"):
                cv = du.curved_mesh(cm, degree, kind)
                errors.setdefault((degree, kind), []).append(abs(_volume(cv.mesh, degree) - exact))
    rates = {k: np.polyfit(np.log(hs), np.log(v), 1)[0] for k, v in errors.items()}
    assert rates[1, "-"] == pytest.approx(2.0, abs=0.3)
    # Each placement is relaxed differently: the rates scatter by +-0.2 about the trend
    # (measured: q = 2: 4.3 / 3.9, q = 3: 4.1 / 3.9, q = 4: 6.7 / 5.9 for I / G~).
    for (degree, kind), rate in rates.items():
        if degree > 1:
            assert rate > degree + 1 - 0.3, (degree, kind, rates)
    assert max(errors[4, "I"][-1], errors[4, "G~"][-1]) < 1e-3 * errors[1, "-"][-1]


def _poisson_l2(msh, tags) -> float:
    """L2 error of P2 for -div grad u = f, u = 0 on the sphere (the geometry error enters)."""
    V = fem.functionspace(msh, ("Lagrange", 2))
    x = ufl.SpatialCoordinate(msh)
    r2 = sum((x[i] - C[i]) ** 2 for i in range(3))
    u_ex = (1 - r2) * (
        1 + 0.5 * ufl.sin(2 * x[0] + 0.5) * ufl.cos(1.5 * x[1]) * ufl.exp(0.6 * x[2])
    )
    dofs = fem.locate_dofs_topological(V, 2, tags.find(du.IMMERSED))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 8})
    problem = LinearProblem(
        ufl.inner(ufl.grad(u), ufl.grad(v)) * dx,
        -ufl.div(ufl.grad(u_ex)) * v * dx,
        bcs=[fem.dirichletbc(0.0, dofs, V)],
        petsc_options={
            "ksp_type": "preonly",
            "pc_type": "lu",
            "pc_factor_mat_solver_type": "mumps",
        },
        petsc_options_prefix="test_curved_3d_",
    )
    e = problem.solve() - u_ex
    return float(np.sqrt(comm.allreduce(fem.assemble_scalar(fem.form(e * e * dx)), op=MPI.SUM)))


def test_poisson_p2_rate():
    """P2 on the ball at h = 0.35 and 0.25: L2 rate about 3 on degree-2 geometry (measured
    3.0 for I and G~, 2.95 continuing to h = 0.18), about 2 on the straight mesh (1.7 here,
    2.1 to h = 0.18); the curved error 40 times smaller."""
    surface = du.Sphere(C, 1.0)
    hs = [0.35, 0.25]
    straight, curved = [], []
    for h in hs:
        cm = du.conform(a15_mesh(comm, [[-1.2] * 3, [1.2] * 3], h), surface)
        straight.append(_poisson_l2(cm.mesh, cm.facet_tags))
        cv = du.curved_mesh(cm, 2, "I")
        curved.append(_poisson_l2(cv.mesh, cv.facet_tags))
    rate = np.log(np.divide(curved[0], curved[1])) / np.log(hs[0] / hs[1])
    rate_straight = np.log(np.divide(straight[0], straight[1])) / np.log(hs[0] / hs[1])
    assert rate > 2.7 and rate_straight < 2.3
    assert curved[1] < straight[1] / 20


class _Overshoot(du.Sphere):
    """A 'projection' that overshoots inwards away from the vertices (deliberately wrong)."""

    def closest_point(self, x):
        y = super().closest_point(x)
        return y - 0.6 * self.normal(y)


def test_inverted_curved_tetrahedra_are_refused(conformed):
    cm = conformed("sphere")
    bad = dataclasses.replace(cm, boundary=_Overshoot(C, 1.0))
    with pytest.raises(du.MeshingError, match="curved tetrahedra are not proven valid"):
        du.curved_mesh(bad, 2, "I")


def test_min_ratio_threshold(conformed):
    cm = conformed("sphere")
    cv = du.curved_mesh(cm, 3, "G~")
    assert 0.9 < cv.min_jacobian_ratio < 1.0
    with pytest.raises(du.MeshingError, match="not proven valid"):
        du.curved_mesh(cm, 3, "G~", min_ratio=0.999)


def test_degrees_above_the_proofs_limit_are_refused_everywhere(conformed):
    """Degree 6 tetrahedra (MAX_DEGREE is 5 for them) get a clear error from every entry
    point, before any work: one degree more would take 3 s to set up the proof and lose its
    accuracy (test_jacobian)."""
    cm = conformed("sphere")
    match = "geometry degree 6 is above 5, the highest for tetrahedra"
    with pytest.raises(ValueError, match=match):
        du.curved_mesh(cm, 6)
    with pytest.raises(ValueError, match=match):
        du.MovingDomain(cm.background, degree=6)
    with pytest.raises(ValueError, match=match):
        du.mesh_domain(MPI.COMM_WORLD, du.Sphere(C, 0.7), 0.3, degree=6)
    assert du.curved_mesh(cm, 5).degree == 5


def _fingerprint(x: np.ndarray) -> np.ndarray:
    return x[np.lexsort(np.round(x, 9).T[::-1])]


@pytest.mark.mpi
def test_same_curved_mesh_on_any_number_of_ranks():
    torus = du.Torus(C, 1.0, 0.35)
    box = [[-1.5, -1.5, -0.7], [1.5, 1.5, 0.7]]
    cv = du.curved_mesh(du.conform(a15_mesh(comm, box, 0.25), torus), 3, "I")
    ref = du.curved_mesh(du.conform(a15_mesh(MPI.COMM_SELF, box, 0.25), torus), 3, "I")
    n = cv.mesh.geometry.index_map().size_local
    a = _fingerprint(np.concatenate(comm.allgather(cv.mesh.geometry.x[:n])))
    n = ref.mesh.geometry.index_map().size_local
    b = _fingerprint(ref.mesh.geometry.x[:n])
    assert a.shape == b.shape
    # the conforming meshes agree to rounding (test_conform_3d), the curved maps add a few ulps
    assert np.abs(a - b).max() < 1e-10
    assert cv.min_jacobian_ratio == pytest.approx(ref.min_jacobian_ratio, abs=1e-9)
    assert _volume(cv.mesh, 3) == pytest.approx(_volume_self(ref.mesh), rel=1e-12)


def _volume_self(msh) -> float:
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 11})
    return fem.assemble_scalar(fem.form(1.0 * dx))
