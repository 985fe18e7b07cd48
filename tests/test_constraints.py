"""Normal/tangential constraints by local rotation: exactness, symmetry, MPI, convergence."""

from __future__ import annotations

import dataclasses

from mpi4py import MPI
from petsc4py import PETSc

import basix.ufl
import numpy as np
import pytest
import ufl
from conftest import needs_ranks
from dolfinx import fem

import dolfinx_universal as du
from dolfinx_universal.curved.constraints import SlipConstraint, facet_frames

comm = MPI.COMM_WORLD
CENTRE = (0.0123, -0.0234)
CASES = [
    (component, tangent, map_, degree)
    for component in ("tangential", "normal")
    for tangent, map_, degree in (("true", "I", 2), ("true", "G", 4), ("discrete", "I", 2))
]


def g_value(x: np.ndarray) -> np.ndarray:
    return 0.3 + 0.2 * x[:, 0] - 0.1 * x[:, 1] ** 2


def disc_mesh(
    h: float, map_: str = "I", degree: int = 2, centre=CENTRE, c: MPI.Comm = comm
) -> du.CurvedMesh:
    bg = du.equilateral_mesh(c, [[-1.5, -1.5], [1.5, 1.5]], h)
    return du.curved_mesh(du.conform(bg, du.Circle(centre, 1.0)), degree, map_)


def vector_problem(V: fem.FunctionSpace, load=(1.0, -0.5)):
    """A symmetric positive definite vector problem (Laplacian plus mass)."""
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    f = fem.Constant(V.mesh, np.array(load, dtype=np.float64))
    a = (ufl.inner(ufl.grad(u), ufl.grad(v)) + ufl.inner(u, v)) * ufl.dx
    return a, ufl.inner(f, v) * ufl.dx


def reference_facet_tangents(V: fem.FunctionSpace, curved: du.CurvedMesh):
    """Slow, obvious reference for P2 geometry: for each owned immersed facet, the tangent of
    the quadratic through its three nodes at each node, oriented with the outward normal.
    Returns a list of (block, tangent) pairs."""
    msh = curved.mesh
    msh.topology.create_connectivity(1, 2)
    msh.topology.create_connectivity(2, 1)
    f2c, c2f = msh.topology.connectivity(1, 2), msh.topology.connectivity(2, 1)
    x = msh.geometry.x[:, :2]
    ends = {0: (1, 2), 1: (0, 2), 2: (0, 1)}  # DOLFINx/basix edge numbering
    out = []
    for f in curved.facet_tags.find(du.IMMERSED):
        c = f2c.links(f)[0]
        lf = int(np.flatnonzero(c2f.links(c) == f)[0])
        geo = msh.geometry.dofmaps[0][c]
        dofs = V.dofmap.cell_dofs(c)
        ia, ib = ends[lf]
        xa, xb, xm = x[geo[ia]], x[geo[ib]], x[geo[3 + lf]]
        centroid = x[geo[:3]].mean(axis=0)
        for node, d in ((ia, -3 * xa + 4 * xm - xb), (ib, xa - 4 * xm + 3 * xb), (3 + lf, xb - xa)):
            t = d / np.linalg.norm(d)
            if np.dot([t[1], -t[0]], x[geo[node]] - centroid) < 0:  # normal (t_y, -t_x) outward
                t = -t
            out.append((int(dofs[node]), t))
    return out


def check_case(
    component: str, tangent: str, map_: str, degree: int, h: float = 0.2, mc: MPI.Comm = comm
) -> dict:
    """Solve with a nonzero constraint value; residuals (module and independent) and a norm."""
    curved = disc_mesh(h, map_, degree, c=mc)
    V = fem.functionspace(curved.mesh, ("Lagrange", 2, (2,)))
    slip = SlipConstraint(V, curved, component=component, value=g_value, tangent=tangent)
    a, L = vector_problem(V)
    u = slip.solve(a, L)
    arr = u.x.array.reshape(-1, 2)
    ref = 0.0
    if tangent == "true":
        n_owned = V.dofmap.index_map.size_local
        blocks, _, _, _ = du.boundary_dof_data(V, curved)
        blocks = blocks[blocks < n_owned]
        y = V.tabulate_dof_coordinates()[blocks, :2]
        n = (y - CENTRE) / np.linalg.norm(y - CENTRE, axis=1)[:, None]
        c = n if component == "normal" else np.column_stack([-n[:, 1], n[:, 0]])
        y_closest = CENTRE + n
        ref = np.abs(np.sum(arr[blocks] * c, axis=1) - g_value(y_closest)).max(initial=0.0)
    elif degree == 2:
        xd = V.tabulate_dof_coordinates()[:, :2]
        for b, t in reference_facet_tangents(V, curved):
            c = t if component == "tangential" else np.array([t[1], -t[0]])
            ref = max(ref, abs(arr[b] @ c - g_value(xd[b : b + 1])[0]))
    norm = fem.assemble_scalar(fem.form(ufl.inner(u, u) * ufl.dx))
    single, double = slip.num_constrained
    return {
        "residual": slip.residual(u),
        "reference_residual": mc.allreduce(float(ref), op=MPI.MAX),
        "norm": float(np.sqrt(mc.allreduce(norm))),
        "single": single,
        "double": double,
        "max_u": mc.allreduce(float(np.abs(arr).max()), op=MPI.MAX),
    }


def check_all(c: MPI.Comm = comm) -> dict:
    return {"/".join(map(str, case)): check_case(*case, mc=c) for case in CASES}


@pytest.fixture(scope="module")
def serial_results():
    return check_all()


@pytest.mark.parametrize("case", ["/".join(map(str, c)) for c in CASES])
def test_constraint_exact_at_every_node(serial_results, case):
    r = serial_results[case]
    # The constraint holds to the rounding of the 2x2 rotations (a few ulps of |u|); the
    # reference recomputes it from the true closest points (Newton, to rounding).
    assert r["residual"] < 1e-13 * max(1.0, r["max_u"])
    assert r["reference_residual"] < 1e-12
    if "discrete" in case:
        # The P2 boundary of the I map is only C0: every vertex is doubly constrained.
        assert r["double"] > 20 and r["single"] == r["double"]
    else:
        assert r["double"] == 0 and r["single"] > 40


def test_true_and_discrete_differ(serial_results):
    for component in ("tangential", "normal"):
        true = serial_results[f"{component}/true/I/2"]["norm"]
        disc = serial_results[f"{component}/discrete/I/2"]["norm"]
        sup = serial_results[f"{component}/true/G/4"]["norm"]
        assert abs(true - sup) < 1e-2 * abs(true - disc)


@pytest.mark.mpi
@needs_ranks(2)
def test_ranks_agree():
    serial, parallel = check_all(MPI.COMM_SELF), check_all(comm)
    for case, ref in serial.items():
        got = parallel[case]
        assert got["residual"] < 1e-13 * max(1.0, got["max_u"]), case  # as in serial
        assert got["reference_residual"] < 1e-12, case
        assert (got["single"], got["double"]) == (ref["single"], ref["double"]), case
        # the same discrete problem; the direct solver's rounding differs with the ordering
        assert abs(got["norm"] - ref["norm"]) < 1e-10 * ref["norm"], case


def test_facet_frames_match_reference():
    curved = disc_mesh(0.3)
    V = fem.functionspace(curved.mesh, ("Lagrange", 2, (2,)))
    blocks, normals = facet_frames(V, curved.facet_tags.find(du.IMMERSED))
    got = {}
    for b, n in zip(blocks.ravel(), normals.reshape(-1, 2)):
        got.setdefault(int(b), []).append(np.array([-n[1], n[0]]))
    ref = {}
    for b, t in reference_facet_tangents(V, curved):
        ref.setdefault(b, []).append(t)
    assert got.keys() == ref.keys()
    for b in ref:
        for t in ref[b]:
            assert min(np.linalg.norm(t - s) for s in got[b]) < 1e-12  # unit vectors: ulps


def test_rotated_system_is_symmetric():
    """Mixed space, vector part constrained, scalar part with an ordinary Dirichlet bc."""
    curved = disc_mesh(0.4)
    msh = curved.mesh
    el = basix.ufl.mixed_element(
        [
            basix.ufl.element("Lagrange", "triangle", 2, shape=(2,)),
            basix.ufl.element("Lagrange", "triangle", 2),
        ]
    )
    W = fem.functionspace(msh, el)
    (th, w), (eta, v) = ufl.TrialFunctions(W), ufl.TestFunctions(W)
    a = (
        ufl.inner(ufl.grad(th), ufl.grad(eta)) + ufl.inner(th - ufl.grad(w), eta - ufl.grad(v))
    ) * ufl.dx
    L = v * ufl.dx + eta[0] * ufl.dx
    Q, _ = W.sub(1).collapse()
    facets = curved.facet_tags.find(du.IMMERSED)
    bc = fem.dirichletbc(
        fem.Function(Q), fem.locate_dofs_topological((W.sub(1), Q), 1, facets), W.sub(1)
    )
    for tangent in ("true", "discrete"):
        slip = SlipConstraint(W.sub(0), curved, value=0.1, tangent=tangent)
        A, b = slip.assemble_system(a, L, [bc])
        At = A.duplicate(copy=True)
        At.transpose()
        At.axpy(-1.0, A)
        # R A R^T is symmetric up to rounding: a few ulps of its largest entries
        assert At.norm(PETSc.NormType.INFINITY) < 1e-14 * A.norm(PETSc.NormType.INFINITY)
        At.destroy()
        u = slip.solve(a, L, [bc])
        assert slip.residual(u) < 1e-14  # rotations of |u| <= O(1): a few ulps
        w_bnd = u.x.array[bc.dof_indices()[0]]
        assert np.abs(w_bnd).max(initial=0.0) == 0.0
        for obj in (A, b):
            obj.destroy()
    # A node cannot carry both an ordinary Dirichlet condition and a component constraint.
    V0, _ = W.sub(0).collapse()
    clash = fem.dirichletbc(
        fem.Function(V0), fem.locate_dofs_topological((W.sub(0), V0), 1, facets), W.sub(0)
    )
    with pytest.raises(ValueError, match="coincide"):
        SlipConstraint(W.sub(0), curved).solve(a, L, [clash])


def test_moving_boundary_reuses_compiled_forms():
    """Translate the domain in place: re-assembled compiled forms and rebuilt R give the same
    (translation-invariant) solution, and the constraint still holds."""
    curved = disc_mesh(0.25)
    V = fem.functionspace(curved.mesh, ("Lagrange", 2, (2,)))
    a, L = vector_problem(V)
    a, L = fem.form(a), fem.form(L)
    slip = SlipConstraint(V, curved, value=0.2)
    u0 = slip.solve(a, L).x.array.copy()
    shift = np.array([0.11, -0.07])
    curved.mesh.geometry.x[:, :2] += shift
    moved_circle = du.Circle(np.array(CENTRE) + shift, 1.0)
    moved = dataclasses.replace(
        curved, conforming=dataclasses.replace(curved.conforming, boundary=moved_circle)
    )
    slip.update(moved)
    u1 = slip.solve(a, L)
    assert slip.residual(u1) < 1e-14  # rotations of |u| <= O(1): a few ulps
    assert np.abs(u1.x.array - u0).max() < 1e-10 * np.abs(u0).max()


def test_invalid_arguments():
    curved = disc_mesh(0.4)
    V = fem.functionspace(curved.mesh, ("Lagrange", 2, (2,)))
    with pytest.raises(ValueError, match="component"):
        SlipConstraint(V, curved, component="radial")
    with pytest.raises(ValueError, match="tangent"):
        SlipConstraint(V, curved, tangent="approximate")
    with pytest.raises(ValueError, match="2-vectors"):
        SlipConstraint(fem.functionspace(curved.mesh, ("Lagrange", 2)), curved)


# Manufactured solutions: -div grad u = f on the unit disc, one component imposed strongly
# at the nodes, the other component of the traction (grad u N) weakly on the boundary.
def u_exact(x):
    r2 = x[0] ** 2 + x[1] ** 2
    rot = ufl.cos(x[0] + x[1])  # (-y, x) rot: tangential on the circle
    return ufl.as_vector(
        [
            (1 - r2) * ufl.sin(2 * x[1]) - x[1] * rot + 0.3 * x[0] * ufl.exp(x[1]),
            (1 - r2) * ufl.exp(x[0]) + x[0] * rot + 0.3 * x[1] * ufl.exp(x[1]),
        ]
    )


def u_exact_np(y: np.ndarray) -> np.ndarray:
    x0, x1 = y[:, 0], y[:, 1]
    rot = np.cos(x0 + x1)
    return np.column_stack([-x1 * rot + 0.3 * x0 * np.exp(x1), x0 * rot + 0.3 * x1 * np.exp(x1)])


def manufactured_errors(h: float, component: str) -> tuple[float, float]:
    curved = disc_mesh(h, centre=(0.0, 0.0))
    msh = curved.mesh
    V = fem.functionspace(msh, ("Lagrange", 2, (2,)))
    x = ufl.SpatialCoordinate(msh)
    ue = u_exact(x)
    r = ufl.sqrt(ufl.inner(x, x))
    N, T = x / r, ufl.as_vector([-x[1], x[0]]) / r
    traction = ufl.dot(ufl.grad(ue), N)
    ds = ufl.Measure("ds", msh, subdomain_data=curved.facet_tags)(du.IMMERSED)
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx
    f = -ufl.div(ufl.grad(ue))
    if component == "normal":  # u.N = g strongly, tangential traction weakly (slip)
        L = ufl.inner(f, v) * ufl.dx + ufl.dot(traction, T) * ufl.dot(v, T) * ds

        def g(y):
            return np.sum(u_exact_np(y) * y, axis=1)
    else:  # u.T = g strongly, normal traction weakly
        L = ufl.inner(f, v) * ufl.dx + ufl.dot(traction, N) * ufl.dot(v, N) * ds

        def g(y):
            return np.sum(u_exact_np(y) * np.column_stack([-y[:, 1], y[:, 0]]), axis=1)

    slip = SlipConstraint(V, curved, component=component, value=g)
    uh = slip.solve(a, L)
    assert slip.residual(uh) < 1e-13  # rotations of |u| <= O(1): a few ulps
    dx = ufl.Measure("dx", msh, metadata={"quadrature_degree": 10})
    e = uh - ue
    l2 = comm.allreduce(fem.assemble_scalar(fem.form(ufl.inner(e, e) * dx)))
    h1 = comm.allreduce(fem.assemble_scalar(fem.form(ufl.inner(ufl.grad(e), ufl.grad(e)) * dx)))
    return float(np.sqrt(l2)), float(np.sqrt(h1))


@pytest.mark.parametrize("component", ["normal", "tangential"])
def test_manufactured_convergence(component):
    hs = 0.15 / 2.0 ** np.arange(4)
    errors = np.array([manufactured_errors(h, component) for h in hs])
    rate_l2 = np.polyfit(np.log(hs), np.log(errors[:, 0]), 1)[0]
    rate_h1 = np.polyfit(np.log(hs), np.log(errors[:, 1]), 1)[0]
    print(
        f"{component}: L2 {errors[:, 0]} rate {rate_l2:.2f}; H1 {errors[:, 1]} rate {rate_h1:.2f}"
    )
    assert abs(rate_l2 - 3) < 0.25 and abs(rate_h1 - 2) < 0.25
