"""Time steps on moving domains: the nodes' paths, the transfer between meshes, the orders.

The exact solution of :func:`_linear_run` is linear in space, which isoparametric Lagrange
spaces hold exactly: the error is the integrators' alone, so their orders show on coarse
meshes, with the domain translating and rotating through the background (cells enter and
leave at every step).
"""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from conftest import needs_ranks
from dolfinx import fem
from jit_counter import count_jit_compilations

import dolfinx_universal as du
from dolfinx_universal.moving.problems import MovingLinearProblem
from dolfinx_universal.moving.stepping import (
    ESDIRK3,
    SCHEMES,
    SDIRK3,
    TimeStepper,
    derivative_weights,
)
from dolfinx_universal.moving.transfer import NodeTransfer

comm = MPI.COMM_WORLD


def _ellipse(t: float) -> du.Domain:
    """An ellipse translating and rotating through the background."""
    return du.Domain(du.Ellipse([0.3 * np.sin(2 * t), 0.2 * t], 0.55, 0.4, angle=t))


def _moving(degree: int, relax: bool = True, h: float = 0.1, c=comm) -> du.MovingDomain:
    bg = du.equilateral_mesh(c, [[-1.0, -0.9], [1.0, 1.0]], h)
    return du.MovingDomain(bg, degree=degree, relax=relax)


def _gap(a, b) -> float:
    return comm.allreduce(float(np.abs(a - b).max(initial=0.0)), op=MPI.MAX)


@pytest.mark.parametrize("relax", [False, True])
@pytest.mark.parametrize("degree", [1, 2, 3])
def test_paths_pass_through_the_current_nodes(degree, relax):
    """For the step's own boundary the paths are the mesh's nodes: bitwise without the
    relaxation (the same formulas), to rounding with it (its vertices on Gamma are
    projected again)."""
    md = _moving(degree, relax)
    md.update(_ellipse(0.0))
    md.update(_ellipse(0.1))
    x = md.nodes_at([_ellipse(0.1)])[0]
    gap = _gap(x, md.mesh.geometry.x[:, :2])
    assert gap == 0.0 if not relax else gap < 1e-14


def test_paths_are_smooth_in_time():
    """Third differences of the paths over steps dt shrink like dt^3 (here by 7.9 when dt
    halves; a kink or a jump of a node would keep them of order dt or 1)."""
    md = _moving(2)
    md.update(_ellipse(0.3))
    diffs = []
    for dt in (0.02, 0.01):
        X = md.nodes_at([_ellipse(0.3 - k * dt) for k in range(4)])
        diffs.append(_gap(X[0] - 3 * X[1] + 3 * X[2], X[3]))
    assert diffs[0] / diffs[1] > 6.0, diffs


def test_paths_hold_vertices_whose_projection_jumps():
    """A vertex pushed inwards near the medial axis has its closest point jump to the
    other side of a thin ellipse; its path is held where it is instead."""

    def thin(t: float) -> du.Domain:  # within a relaxation radius of the medial axis
        return du.Domain(du.Ellipse([0.3 * np.sin(2 * t), 0.2 * t], 0.55, 0.35))

    md = _moving(1, relax=False)
    md.update(thin(0.275))
    X = md.nodes_at([thin(0.25 + k * 0.00625) for k in range(5)])
    # cubic through four positions predicts the fifth to O(dt^4)
    tau = np.array([0.0, 2.0, 3.0, 4.0])
    w = [
        np.prod([(1.0 - tau[m]) / (tau[j] - tau[m]) for m in range(4) if m != j]) for j in range(4)
    ]
    pred = sum(wj * X[j] for wj, j in zip(w, [0, 2, 3, 4], strict=True))
    assert _gap(pred, X[1]) < 1e-5


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_transfer_carries_linear_functions_exactly(degree):
    """Isoparametric spaces hold linear functions: carried across a step, with the cells
    that enter the domain (extension from the nearest old cell), they stay exact; dofs of
    cells that neither moved nor entered keep their values bitwise."""
    md = _moving(degree)
    V = fem.functionspace(md.mesh, ("Lagrange", degree))
    transfer = NodeTransfer(md.mesh, md.universal.cell_vertices, V)
    md.update(_ellipse(0.0))
    u = fem.Function(V)
    u.interpolate(lambda x: 1.0 + 2.0 * x[0] - 3.0 * x[1])
    x0, a0 = md.mesh.geometry.x[:, :2].copy(), md.active_mask.copy()
    md.update(_ellipse(0.08))
    x1, a1 = md.mesh.geometry.x[:, :2].copy(), md.active_mask.copy()
    assert comm.allreduce(int((a1 & ~a0).sum())) > 0  # cells entered
    carried = transfer.carry(u.x.array, x0, a0, x1, a1)
    exact = fem.Function(V)
    exact.interpolate(lambda x: 1.0 + 2.0 * x[0] - 3.0 * x[1])
    active = np.unique(V.dofmap.list[md.active_cells])
    assert _gap(carried[active], exact.x.array[active]) < 1e-12
    moved = transfer.moved_cells(x0, a0, x1, a1)
    kept = np.setdiff1d(active, V.dofmap.list[moved].ravel())
    assert np.array_equal(carried[kept], u.x.array[kept])


def test_slopes_carry_with_the_change_of_velocity():
    """A slope along paths moving at w_old becomes slope + (w_new - w_old) . grad u along
    paths moving at w_new: exact for a linear u, a linear slope and a linear w_old."""
    md = _moving(2)
    V = fem.functionspace(md.mesh, ("Lagrange", 2))
    transfer = NodeTransfer(md.mesh, md.universal.cell_vertices, V)
    md.update(_ellipse(0.0))
    u, k = fem.Function(V), fem.Function(V)
    u.interpolate(lambda x: 2.0 * x[0] - 3.0 * x[1])
    k.interpolate(lambda x: 0.5 + x[0])
    x0, a0 = md.mesh.geometry.x[:, :2].copy(), md.active_mask.copy()
    w0 = np.column_stack([0.1 + 0.2 * x0[:, 1], -0.3 * x0[:, 0]])
    md.update(_ellipse(0.05))
    x1, a1 = md.mesh.geometry.x[:, :2].copy(), md.active_mask.copy()
    w1 = np.full_like(x1, 0.25)
    out = transfer.carry_slope(k.x.array, u.x.array, w0, x0, a0, x1, w1, a1)
    p = V.tabulate_dof_coordinates()[:, :2]
    w0_at = np.column_stack([0.1 + 0.2 * p[:, 1], -0.3 * p[:, 0]])
    want = 0.5 + p[:, 0] + (0.25 - w0_at) @ np.array([2.0, -3.0])
    dofs = np.unique(V.dofmap.list[md.active_cells])
    assert _gap(out[dofs], want[dofs]) < 1e-11


def test_derivative_weights_are_the_bdf_coefficients():
    dt = 0.1
    for order, coefficients in {
        1: [1, -1],
        2: [1.5, -2, 0.5],
        3: [11 / 6, -3, 1.5, -1 / 3],
    }.items():
        c = derivative_weights([1.0 - j * dt for j in range(order + 1)], 1.0) * dt
        assert np.allclose(c, coefficients, atol=1e-13)
    # variable steps: exact derivative of a cubic at the first node
    tau = np.array([1.0, 0.93, 0.81, 0.74])
    c = derivative_weights(tau, 1.0)
    assert c @ (tau**3 - 2 * tau) == pytest.approx(3.0 - 2.0, abs=1e-11)


def test_runge_kutta_tableaux():
    """Both methods: order 3 (Butcher's conditions), stiffly accurate, L-stable; ESDIRK3
    has stage order 2."""
    for A, c in (SDIRK3, ESDIRK3):
        b = A[-1]
        assert np.allclose(A.sum(axis=1), c, atol=1e-14)
        assert np.allclose([b.sum(), b @ c, b @ c**2, b @ A @ c], [1, 1 / 2, 1 / 3, 1 / 6])
        s = len(c)
        stability = 1 + -1e8 * b @ np.linalg.solve(np.eye(s) + 1e8 * A, np.ones(s))
        assert abs(stability) < 1e-6
    A, c = ESDIRK3
    assert np.allclose(A @ c, c**2 / 2, atol=1e-14)


def _linear_run(
    scheme: str,
    dt: float,
    T: float = 0.6,
    c=comm,
    static: bool = False,
    jit: list | None = None,
    start: str | None = None,
) -> float:
    """The largest L2 error over the steps of the heat equation with a solution linear in
    space (P1, Dirichlet data on the moving ellipse)."""
    motion = (lambda t: _ellipse(0.0)) if static else _ellipse
    md = _moving(1, c=c)
    md.update(motion(0.0))
    V = fem.functionspace(md.mesh, ("Lagrange", 1))
    ts = TimeStepper(md, V, motion, 0.0, dt, scheme)
    x, t = ufl.SpatialCoordinate(md.mesh), ts.time_variable
    exact = ufl.sin(3 * t) + ufl.cos(2 * t) * x[0] + 0.5 * ufl.sin(2 * t) * x[1]
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    F = md.active * (ts.time_derivative(u) * v + ufl.inner(ufl.grad(u), ufl.grad(v))) * ufl.dx
    F -= md.active * ufl.diff(exact, t) * v * ufl.dx
    uh = fem.Function(V)
    problem = MovingLinearProblem(
        md, ufl.lhs(F), ufl.rhs(F), u=uh, petsc_options_prefix=f"linear_{scheme}_",
        petsc_options={"ksp_type": "preonly", "pc_type": "lu"}, active_only=True,
    )  # fmt: skip
    g = ts.dirichlet_data(exact)
    u0 = fem.Function(V)
    u0.interpolate(fem.Expression(exact, V.element.interpolation_points))
    ts.initialize(u0, None if start else ufl.diff(exact, t), start=start)
    error = fem.form(md.active * (uh - exact) ** 2 * ufl.dx)
    worst = 0.0
    for n in range(int(round(T / dt))):
        with count_jit_compilations() as compiled:
            ts.advance(lambda: problem.solve([fem.dirichletbc(g, md.immersed_dofs(V))]))
        if jit is not None and n > 0:
            jit.append(compiled[0])
        worst = max(worst, np.sqrt(c.allreduce(fem.assemble_scalar(error), op=MPI.SUM)))
    return worst


@pytest.mark.parametrize("scheme", ["BDF3", "ESDIRK3"])
def test_steps_compile_nothing(scheme):
    """After the first step (which compiles the Dirichlet data's expressions), steps only
    set constants, functions and nodes: no form or expression is compiled again."""
    jit: list[int] = []
    _linear_run(scheme, 0.1, T=0.4, jit=jit)
    assert jit == [0, 0, 0]


@pytest.mark.parametrize("scheme", ["BDF1", "BDF2", "BDF3"])
def test_bdf_orders_on_a_moving_domain(scheme):
    """BDF-p converges at order p (within 0.2; measured 0.99, 1.95, 2.97) while cells
    enter and leave and the relaxation moves vertices at every step."""
    e = [_linear_run(scheme, dt) for dt in (0.05, 0.025)]
    assert abs(np.log2(e[0] / e[1]) - SCHEMES[scheme]) < 0.2, e


def test_bdf2_started_by_bdf1_keeps_order_two():
    """``start="BDF"``: BDF2's first two steps by implicit Euler (local errors O(dt^2))
    keep the global order 2: the largest error over the steps converges at least at
    order 2 - 0.2 (measured 2.27: the start's errors, of order 2 with a larger constant,
    are part of it)."""
    e = [_linear_run("BDF2", dt, start="BDF") for dt in (0.05, 0.025)]
    assert np.log2(e[0] / e[1]) > 1.8, e
    with pytest.raises(ValueError, match="start"):
        _linear_run("BDF2", 0.05, T=0.05, start="Euler")


def test_esdirk_order():
    """ESDIRK3: order 3 on a fixed domain (measured 3.96 in this norm); on the moving
    domain it falls towards its stage order 2 (measured 2.13; SDIRK3, stage order 1:
    1.84): the order reduction of Runge–Kutta methods on stiff problems with
    time-dependent boundary data, here the moving boundary's."""
    e = [_linear_run("ESDIRK3", dt, static=True) for dt in (0.1, 0.05)]
    assert np.log2(e[0] / e[1]) > 2.8, e
    e = [_linear_run("ESDIRK3", dt) for dt in (0.05, 0.025)]
    assert np.log2(e[0] / e[1]) > 1.8, e


@pytest.mark.mpi
@needs_ranks(2)
def test_stepping_is_the_same_on_any_number_of_ranks():
    """The error history on all ranks equals the serial one (each rank computes that on
    its own): the paths, transfers and solves do not depend on the partition."""
    parallel = _linear_run("BDF2", 0.05, T=0.3)
    serial = _linear_run("BDF2", 0.05, T=0.3, c=MPI.COMM_SELF)
    assert parallel == pytest.approx(serial, rel=1e-9)


def test_active_forms_keep_interior_facet_couplings():
    """MovingLinearProblem(active_only=True) with a bilinear term on Gamma (a Robin
    condition) solves the same system as the plain forms: the matrix keeps the couplings
    of the facets' two cells."""
    md = _moving(2)
    md.update(_ellipse(0.0))
    V = fem.functionspace(md.mesh, ("Lagrange", 2))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    x = ufl.SpatialCoordinate(md.mesh)
    F = md.active * (u * v + ufl.inner(ufl.grad(u), ufl.grad(v)) - x[0] * v) * ufl.dx
    F += md.immersed_integral(lambda s: (2.0 * u(s) - x[1]) * v(s))
    solutions = []
    for active_only in (False, True):
        problem = MovingLinearProblem(
            md, ufl.lhs(F), ufl.rhs(F), petsc_options_prefix=f"robin_{active_only}_",
            petsc_options={"ksp_type": "preonly", "pc_type": "lu"}, active_only=active_only,
        )  # fmt: skip
        solutions.append(problem.solve().x.array.copy())
    assert _gap(solutions[0], solutions[1]) < 1e-10
