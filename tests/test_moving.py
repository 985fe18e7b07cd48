"""Moving domains on one background: many rigid motions, in-place geometry, no recompilation."""

from __future__ import annotations

from mpi4py import MPI
from petsc4py import PETSc

import basix.ufl
import numpy as np
import pytest
import ufl
from conftest import assert_update_history_free, needs_ranks
from dolfinx import fem
from dolfinx import mesh as dmesh
from dolfinx.fem.petsc import create_matrix, create_vector
from jit_counter import count_jit_compilations

import dolfinx_universal as du
from dolfinx_universal.moving.domain import MovingDomain, StepReport
from dolfinx_universal.moving.problems import (
    ActiveForm,
    MovingLinearProblem,
    MovingStokes,
    reassemble,
)

comm = MPI.COMM_WORLD


def _max_gap(x: np.ndarray, y: np.ndarray | float) -> float:
    """``max |x - y|`` over every rank's entries: the same on all ranks, so that their
    assertions pass or fail together (no rank left waiting in a collective call)."""
    return comm.allreduce(float(np.abs(x - y).max(initial=0.0)), op=MPI.MAX)


def _body() -> du.Boundary:
    """A smooth non-convex body (closed spline) to move around."""
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    r = 0.35 * (1 + 0.25 * np.cos(3 * t) + 0.1 * np.sin(2 * t))
    return du.PeriodicSpline(np.column_stack([r * np.cos(t), r * np.sin(t)]))


def test_many_rigid_motions_valid_and_on_curve():
    """A body moved to random positions inside a container: every mesh valid, nodes on Gamma."""
    bg = du.equilateral_mesh(comm, [[-1.0, -1.0], [1.0, 1.0]], 0.05)
    md = MovingDomain(bg, degree=3)
    rng = np.random.default_rng(1)
    body = _body()
    area = fem.form(md.active * ufl.dx)
    length = fem.form(md.immersed_integral(lambda s: fem.Constant(md.mesh, 1.0)))
    ref_area = ref_len = None
    for _ in range(12):
        angle = rng.uniform(0, 2 * np.pi)
        shift = rng.uniform(-0.3, 0.3, 2)
        moved = du.RigidMotion(body, angle=angle, translation=shift)
        report = md.update(du.Domain(None, [moved]))
        assert report.quality["n_inverted"] == 0 and report.min_jacobian_ratio > 0.2
        nodes = md.immersed_nodes()
        if len(nodes):
            assert np.abs(moved.signed_distance(nodes)).max() < 1e-10
        # The fluid area and the body's perimeter do not depend on the motion.
        a = comm.allreduce(fem.assemble_scalar(area))
        ell = comm.allreduce(fem.assemble_scalar(length))
        if ref_area is None:
            ref_area, ref_len = a, ell
        assert a == pytest.approx(ref_area, rel=2e-5) and ell == pytest.approx(ref_len, rel=2e-5)
    assert len(md.steps) == 12


def test_update_does_not_depend_on_the_previous_steps():
    """The geometry after a step is that of a fresh MovingDomain updated once to the same
    boundary: every node of the previous step's moved cells is restored (a jump far enough
    that the two bands do not overlap)."""
    bg = du.equilateral_mesh(comm, [[-1.6, -1.0], [1.6, 1.0]], 0.06)
    there = du.Domain(None, [du.RigidMotion(_body(), translation=(-0.75, 0.1))])
    here = du.Domain(None, [du.RigidMotion(_body(), angle=0.4, translation=(0.75, -0.05))])
    assert_update_history_free(bg, 3, here, there)


def test_in_place_equals_submesh_and_no_recompilation():
    """The in-place mesh solves exactly the problem of the extracted conforming mesh."""
    bg = du.equilateral_mesh(comm, [[-1.4, -1.4], [1.4, 1.4]], 0.12)
    k = 2
    md = MovingDomain(bg, degree=k)
    V = fem.functionspace(md.mesh, ("Lagrange", k))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    x = ufl.SpatialCoordinate(md.mesh)
    u_ex = ufl.exp(x[1]) * ufl.sin(x[0])
    a = fem.form(md.active * ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx)
    L = fem.form(fem.Constant(md.mesh, 0.0) * v * ufl.dx)
    uh, u_d = fem.Function(V), fem.Function(V)
    err = fem.form(md.active * (uh - u_ex) ** 2 * ufl.dx)
    A, b = create_matrix(a), create_vector(V)
    ksp = PETSc.KSP().create(comm)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    with count_jit_compilations() as compiled:
        for step in range(3):
            c = (0.1 * np.cos(step), 0.08 * np.sin(2 * step))
            disc = du.Circle(c, 1.0)
            md.update(disc)
            fixed = md.inactive_dofs(V)
            u_d.interpolate(lambda p: np.exp(p[1]) * np.sin(p[0]))
            u_d.x.array[fixed] = 0.0
            bcs = [fem.dirichletbc(u_d, np.union1d(md.immersed_dofs(V), fixed))]
            reassemble(A, b, a, L, bcs)
            ksp.setOperators(A)
            ksp.solve(b, uh.x.petsc_vec)
            uh.x.scatter_forward()
            e_inplace = np.sqrt(comm.allreduce(fem.assemble_scalar(err)))
            # The same problem on the extracted (submesh) conforming curved mesh.
            cv = du.curved_mesh(du.conform(bg, disc), k)
            Vs = fem.functionspace(cv.mesh, ("Lagrange", k))
            us, vs = ufl.TrialFunction(Vs), ufl.TestFunction(Vs)
            gs = fem.Function(Vs)
            gs.interpolate(lambda p: np.exp(p[1]) * np.sin(p[0]))
            dofs = fem.locate_dofs_topological(Vs, 1, cv.facet_tags.find(du.IMMERSED))
            problem = fem.petsc.LinearProblem(
                ufl.inner(ufl.grad(us), ufl.grad(vs)) * ufl.dx,
                fem.Constant(cv.mesh, 0.0) * vs * ufl.dx,
                bcs=[fem.dirichletbc(gs, dofs)],
                petsc_options={
                    "ksp_type": "preonly",
                    "pc_type": "lu",
                    "pc_factor_mat_solver_type": "mumps",
                },
                petsc_options_prefix=f"sub{step}_",
            )
            us_h = problem.solve()
            xs = ufl.SpatialCoordinate(cv.mesh)
            e_sub = np.sqrt(
                comm.allreduce(
                    fem.assemble_scalar(
                        fem.form((us_h - ufl.exp(xs[1]) * ufl.sin(xs[0])) ** 2 * ufl.dx)
                    )
                )
            )
            assert e_inplace == pytest.approx(e_sub, rel=1e-8)
            if step == 0:
                first = compiled[0]
        # Nothing is compiled after the first step: the in-place forms are built once and
        # the submesh forms hit the JIT cache.
        assert compiled[0] == first


def _moving_reports(c: MPI.Comm) -> list:
    bg = du.equilateral_mesh(c, [[-1, -1], [1, 1]], 0.08)
    md = MovingDomain(bg, degree=2)
    out = []
    for a in np.linspace(0, 1, 4):
        r = md.update(du.Domain(None, [du.Ellipse((0.1 * a, 0), 0.5, 0.3, angle=a)]))
        q = r.quality
        out.append((r.num_active_cells, q["n_positively_cut"], q["theta_min_deg"]))
    return out


@pytest.mark.mpi
@needs_ranks(2)
def test_moving_under_mpi():
    got, ref = _moving_reports(comm), _moving_reports(MPI.COMM_SELF)
    assert [g[:2] for g in got] == [r[:2] for r in ref]
    # The same mesh: the angle up to rounding of the positions (a few ulps / h ~ 1e-14
    # degrees), compared with a tolerance: equality after round(., 9) fails when rounding
    # straddles a 9th decimal. A changed mesh (a step >= 1e-2 h) moves angles by far more.
    assert [g[2] for g in got] == pytest.approx([r[2] for r in ref], abs=1e-9)


@pytest.mark.mpi
@needs_ranks(2)
def test_ghost_nodes_on_gamma_under_mpi():
    """Every local copy of a node on Gamma_h lies on Gamma, ghosts included: a rank that has
    only the outside cell of an immersed facet receives the curved node from its owner."""
    bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], 1 / 12)
    md = MovingDomain(bg, 2)
    V = fem.functionspace(md.mesh, ("Lagrange", 2))
    md.mesh.topology.create_connectivity(1, 2)
    for step in range(3):
        circle = du.Circle((0.01 + 0.03 * step, 0.02), 1.0)
        md.update(circle)
        dofs = fem.locate_dofs_topological(V, 1, md.immersed_facets)
        r = np.linalg.norm(V.tabulate_dof_coordinates()[dofs, :2] - circle.center, axis=1)
        assert np.abs(r - 1.0).max(initial=0.0) < 1e-13  # rounding of the projection


def test_graded_background_with_level_changes_near_gamma():
    """A propeller sweeping through quadtree level changes (finer at the tips): the smoothed
    local size keeps every step valid (the raw, jumping size folded triangles there)."""
    from dolfinx_universal.backgrounds.graded_tri import graded_mesh

    def r(t):
        return 0.12 + 0.38 * np.exp(-(np.sin(1.5 * t) ** 2) / 0.3)

    def dr(t):
        s, c = np.sin(1.5 * t), np.cos(1.5 * t)
        return 0.38 * np.exp(-(s**2) / 0.3) * (-2 * s * c * 1.5 / 0.3)

    def d2r(t):
        return (dr(t + 1e-5) - dr(t - 1e-5)) / 2e-5

    def size(p):
        rho = np.linalg.norm(p, axis=1)
        s = np.where((rho > 0.08) & (rho < 0.6), 0.024, 0.1)
        return np.where(np.abs(rho - 0.5) < 0.05, 0.012, s)

    bg = graded_mesh(comm, [[-0.7, -0.7], [0.7, 0.7]], size)
    md = MovingDomain(bg, degree=2, local_size=True)
    prop = du.PolarCurve(r, dr, d2r)
    for angle in np.radians([0.0, 13.0, 31.0, 47.0]):
        report = md.update(du.Domain(None, [du.RigidMotion(prop, angle=-angle)]))
        assert report.quality["n_inverted"] == 0 and report.min_jacobian_ratio > 0.3


def test_from_motion_sizes_one_background_for_every_step():
    """A body rotating and translating in a box: the background is graded along the swept
    band from the geometry, every step of the motion is valid, and a step off the motion
    is refused with the step and the place."""
    body = _body()

    def motion(t: float) -> du.Boundary:
        return du.Domain(None, [du.RigidMotion(body, angle=t, translation=(0.3 * t, 0.0))])

    times = np.linspace(0.0, 1.0, 9)
    md = MovingDomain.from_motion(
        comm, motion, 0.15, times=times, degree=2, box=[[-1.0, -1.0], [1.5, 1.0]]
    )
    assert md.steps == []
    area = fem.form(md.active * ufl.dx)
    ref = 2.5 * 2.0 - comm.allreduce(
        fem.assemble_scalar(fem.form(1.0 * ufl.dx(du.mesh_domain(comm, body, 0.15, degree=2).mesh)))
    )
    for t in times:
        report = md.update(motion(t))
        assert report.quality["n_inverted"] == 0 and report.min_jacobian_ratio > 0
        assert report.quality["theta_min_deg"] >= 10.0
        assert comm.allreduce(fem.assemble_scalar(area)) == pytest.approx(ref, rel=1e-4)
    with pytest.raises(du.MeshingError, match=r"step 9: the boundary leaves the background"):
        md.update(motion(4.0))  # translated by 1.2: out of the box
    with pytest.raises(du.MeshingError, match=r"step 9: .*finer background"):
        md.update(du.Domain(None, [du.RigidMotion(du.Ellipse((0, 0), 0.3, 0.02), angle=1.0)]))
    with pytest.raises(ValueError, match="needs the times"):
        MovingDomain.from_motion(comm, motion, 0.15)


def _taylor_hood(md: MovingDomain):
    P2v = basix.ufl.element("Lagrange", "triangle", 2, shape=(2,))
    P1 = basix.ufl.element("Lagrange", "triangle", 1)
    return fem.functionspace(md.mesh, basix.ufl.mixed_element([P2v, P1]))


def test_immersed_dofs_on_sub_spaces_and_active_tags():
    bg = du.equilateral_mesh(comm, [[-1.0, -1.0], [1.0, 1.0]], 0.1)
    md = MovingDomain(bg, degree=2)
    assert isinstance(md.active_tags, dmesh.MeshTags)
    assert (md.active_tags.values == 0).all()
    W = _taylor_hood(md)
    V, _ = W.sub(0).collapse()
    for c in ((0.0, 0.0), (0.1, -0.05)):
        disc = du.Circle(c, 0.5)
        report = md.update(disc)
        assert isinstance(report, StepReport)
        md.mesh.topology.create_connectivity(1, 2)
        # The same dofs as DOLFINx's locate_dofs_topological on the sub-space and the pair.
        sub = md.immersed_dofs(W.sub(0))
        assert np.array_equal(sub, fem.locate_dofs_topological(W.sub(0), 1, md.immersed_facets))
        pair = md.immersed_dofs((W.sub(0), V))
        assert np.array_equal(pair[0], sub) and len(pair[1]) == len(sub)
        # The velocity nodes on Gamma_h lie on the circle.
        xyz = V.tabulate_dof_coordinates()[pair[1] // 2, :2]
        assert len(xyz) == 0 or np.abs(disc.signed_distance(xyz)).max() < 1e-10
        # The tags are the indicator, recomputed by update.
        tags = md.active_tags
        chi = md.active.x.array[md.active.function_space.dofmap.list[tags.indices, 0]]
        assert np.array_equal(tags.values, chi.astype(np.int32))
        assert np.array_equal(tags.find(1), md.active_cells)
        n_owned = md.mesh.topology.index_map(2).size_local
        assert comm.allreduce(np.count_nonzero(tags.find(1) < n_owned)) == report.num_active_cells
    with pytest.raises(ValueError, match="pair"):
        md.immersed_dofs((W.sub(0), V, V))


def test_moving_linear_problem_equals_manual_reassembly():
    """The library's reassembly into one matrix gives the solution of a system assembled
    from scratch at every step (to 1e-10)."""
    from dolfinx.fem.petsc import apply_lifting, assemble_matrix, assemble_vector, set_bc

    bg = du.equilateral_mesh(comm, [[-1.4, -1.4], [1.4, 1.4]], 0.12)
    md = MovingDomain(bg, degree=2)
    V = fem.functionspace(md.mesh, ("Lagrange", 2))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = fem.form(md.active * ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx)
    L = fem.form(md.active * fem.Constant(md.mesh, 1.0) * v * ufl.dx)
    opts = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
    problem = MovingLinearProblem(
        md, a, L, petsc_options_prefix="mlp_", petsc_options=opts, u=fem.Function(V)
    )
    g = fem.Function(V)
    for step in range(3):
        md.update(du.Circle((0.1 * np.cos(step), 0.08 * np.sin(2 * step)), 1.0))
        g.interpolate(lambda p: 1 + p[0] * p[1])
        bc = fem.dirichletbc(g, md.immersed_dofs(V))
        uh = problem.solve([bc])
        # From scratch: a new matrix, the inactive dofs fixed by hand.
        bcs = [fem.dirichletbc(fem.Function(V), md.inactive_dofs(V)), bc]
        A = assemble_matrix(a, bcs=bcs)
        A.assemble()
        b = assemble_vector(L)
        apply_lifting(b, [a], [bcs])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        set_bc(b, bcs)
        ksp = PETSc.KSP().create(comm)
        ksp.setOperators(A)
        ksp.setType("preonly")
        ksp.getPC().setType("lu")
        ksp.getPC().setFactorSolverType("mumps")
        ref = fem.Function(V)
        ksp.solve(b, ref.x.petsc_vec)
        ref.x.scatter_forward()
        scale = np.abs(ref.x.array).max()
        assert np.abs(uh.x.array - ref.x.array).max() < 1e-10 * scale
        for obj in (ksp, A, b):
            obj.destroy()


@pytest.mark.mpi
def test_active_only_assembly_equals_the_whole_background():
    """``active_only=True`` assembles the cell integrals over the active cells only: the
    same matrix and vector as over every cell (the indicator vanishes on the others),
    also when a later step's domain holds cells outside every earlier one (their entries
    must have kept their place in the matrix: PETSc drops the entries the first assembly
    leaves unset). Both sum the same element tensors in the same cell order; the tolerance
    (1e-13 of the largest entry) only allows the separately compiled kernels to round
    differently."""
    bg = du.equilateral_mesh(comm, [[-1.4, -1.4], [1.4, 1.4]], 0.12)
    md = MovingDomain(bg, degree=2)
    V = fem.functionspace(md.mesh, ("Lagrange", 2))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    chi = md.active
    a = chi * (ufl.inner(ufl.grad(u), ufl.grad(v)) + u * v) * ufl.dx
    L = chi * fem.Constant(md.mesh, 1.0) * v * ufl.dx
    opts = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
    problems = [
        MovingLinearProblem(
            md, a, L, petsc_options_prefix=f"ao{flag}_", petsc_options=opts, active_only=flag
        )
        for flag in (False, True)
    ]
    # A surface integral over Gamma_h (interior facets) and a volume one.
    x = ufl.SpatialCoordinate(md.mesh)
    surface = md.immersed_integral(lambda side: (x[0] + 2 * x[1] ** 2)(side))
    volume = chi * x[0] ** 2 * ufl.dx
    scalars = [(fem.form(surface), ActiveForm(md, surface, on_gamma=True))]
    scalars.append((fem.form(volume), ActiveForm(md, volume)))
    for radius in (0.4, 1.1, 0.7):  # the second domain covers cells the first did not
        md.update(du.Circle((0.05, -0.03), radius))
        for whole, active in scalars:
            value = comm.allreduce(fem.assemble_scalar(whole))
            assert comm.allreduce(fem.assemble_scalar(active.step())) == pytest.approx(
                value, rel=1e-13
            )
        for problem in problems:
            problem.assemble([fem.dirichletbc(fem.Function(V), md.immersed_dofs(V))])
        (r0, c0, v0), (r1, c1, v1) = (p.A.getValuesCSR() for p in problems)  # owned rows
        assert np.array_equal(r0, r1) and np.array_equal(c0, c1)
        np.testing.assert_allclose(v1, v0, rtol=0, atol=1e-13 * np.abs(v0).max())
        b0, b1 = (p.b.array for p in problems)
        np.testing.assert_allclose(b1, b0, rtol=0, atol=1e-13 * np.abs(b0).max())
    with pytest.raises(ValueError, match="must carry the indicator"):
        ActiveForm(md, u * v * ufl.dx)  # nonzero outside the domain: may not skip cells
    with pytest.raises(ValueError, match="must carry the indicator"):
        ActiveForm(md, (x[0] * v)("+") * ufl.dS, on_gamma=True)
    with pytest.raises(ValueError, match="no subdomain id"):
        MovingLinearProblem(
            md, a, chi * v * ufl.ds(1), petsc_options_prefix="ao_ds_", active_only=True
        )
    with pytest.raises(TypeError, match="UFL forms"):
        MovingLinearProblem(
            md,
            fem.form(a),
            fem.form(L),
            petsc_options_prefix="ao_c_",
            u=fem.Function(V),
            active_only=True,
        )


@pytest.mark.mpi
def test_restricted_solve_equals_the_whole_system():
    """``restrict_to_active=True`` (and ``None`` where few unknowns are active) solves the
    submatrix of the active cells' unknowns: the same solution as the whole background's
    system (MUMPS both; 1e-12 of its size allows the two factorisations' rounding), also
    where a condition overlaps the inactive dofs with a nonzero value (the background's
    boundary, outside the domain: it wins there)."""
    bg = du.equilateral_mesh(comm, [[-1.4, -1.4], [1.4, 1.4]], 0.12)
    md = MovingDomain(bg, degree=2)
    V = fem.functionspace(md.mesh, ("Lagrange", 2))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    chi = md.active
    a = chi * ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx
    L = chi * fem.Constant(md.mesh, 1.0) * v * ufl.dx
    opts = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
    problems = [
        MovingLinearProblem(
            md, a, L, petsc_options_prefix=f"rs{flag}_", petsc_options=opts,
            restrict_to_active=flag, active_only=True,
        )
        for flag in (False, True, None)
    ]  # fmt: skip
    g, wall = fem.Function(V), fem.Function(V)
    g.interpolate(lambda p: 1 + p[0] * p[1])
    wall.x.array[:] = 3.0
    fdim = md.mesh.topology.dim - 1
    md.mesh.topology.create_connectivity(fdim, fdim + 1)
    walls = fem.locate_dofs_topological(V, fdim, dmesh.exterior_facet_indices(md.mesh.topology))
    # None restricts where at most half the unknowns are active: at radii 0.9 and 0.8
    # (about a third), not at 1.25 (about two thirds): the KSP switches operators twice.
    for centre, radius in (((0.1, 0.0), 0.9), ((0.05, 0.0), 1.25), ((0.0, 0.1), 0.8)):
        md.update(du.Circle(centre, radius))
        bcs = [fem.dirichletbc(g, md.immersed_dofs(V)), fem.dirichletbc(wall, walls)]
        full, *others = (p.solve(bcs).x.array.copy() for p in problems)
        scale = np.abs(full).max()
        for restricted in others:  # each rank's bound, decided on every rank together
            close = np.abs(restricted - full).max() <= 1e-12 * scale
            assert comm.allreduce(bool(close), op=MPI.LAND)
            wall_wins = np.all(restricted[walls] == 3.0)  # fixed twice: the wall's value wins
            assert comm.allreduce(bool(wall_wins), op=MPI.LAND)


def test_moving_stokes_rigid_translation_and_compiles_once():
    """A disc translating with the walls: the flow is the rigid translation, the force and
    torque vanish, and nothing is compiled after the first step."""
    bg = du.equilateral_mesh(comm, [[-1.0, -1.0], [1.0, 1.0]], 0.1)
    md = MovingDomain(bg, degree=2)
    velocity = np.array([0.3, -0.2])
    stokes = MovingStokes(
        md, 0.01, (-1.0, -1.0), wall_velocity=velocity, petsc_options_prefix="test_stokes_"
    )
    with count_jit_compilations() as compiled:
        for step in range(3):
            md.update(du.Circle((0.1 * step, 0.05), 0.4))
            u_h, p_h = stokes.solve(velocity)
            active = md.inactive_dofs(stokes.V)
            values = u_h.x.array.reshape(-1, 2)
            keep = np.setdiff1d(np.arange(len(values)), active)
            assert np.abs(values[keep] - velocity).max() < 1e-10
            assert np.abs(stokes.force()).max() < 1e-10
            assert abs(stokes.torque()) < 1e-10
            if step == 0:
                first = compiled[0]
        assert compiled[0] == first
    # A rotating disc in fluid at rest: torque against the rotation, no net force.
    stokes = MovingStokes(md, 0.01, (-1.0, -1.0), petsc_options_prefix="test_rot_")
    md.update(du.Domain(None, [du.Circle((0.0, 0.0), 0.4)]))
    stokes.assemble(angular_velocity=1.0)
    stokes.solve_assembled()
    torque, surface = stokes.torque(), stokes.surface_torque()
    assert torque < 0 and surface == pytest.approx(torque, rel=0.05)
    assert np.abs(stokes.force()).max() < 0.15 * abs(torque)  # 0 up to the discretisation


@pytest.mark.mpi
def test_preconditioned_stokes_equals_the_direct_solve():
    """``MovingStokes(preconditioner=True)`` (FGMRES with the Schur factorisation on the
    fields u and p, GAMG on P's velocity block, :data:`ITERATIVE`) gives the direct solve's
    solution, on the submatrix of the active unknowns and on the whole system (the fields
    in either numbering), over steps whose active sets differ; ``set_petsc_options``
    switches the solver and back. Relative residual 1e-13 (not ITERATIVE's 1e-10, whose
    solutions differ from the direct one by up to 1.2e-7 of their size here, 6.7e-8 at
    1e-12 for the whole system): differences of at most 9e-9 on 1 and 3 ranks, so 1e-7
    separates them from a wrong set-up (a direct solver factorising P, or fields in the
    wrong numbering, give O(1) errors or no convergence; a KSP that does not converge
    raises). Maxima over the ranks, so that all of them pass or fail together."""
    from dolfinx_universal.moving.problems import DIRECT, ITERATIVE

    tight = ITERATIVE | {"ksp_rtol": 1e-13}

    bg = du.equilateral_mesh(comm, [[-1.0, -1.0], [1.0, 1.0]], 0.08)
    md = MovingDomain(bg, degree=2)
    direct = MovingStokes(md, 0.5, (-1.0, -1.0), petsc_options_prefix="pc_direct_")
    krylov = [
        MovingStokes(
            md, 0.5, (-1.0, -1.0), preconditioner=True, restrict_to_active=flag,
            petsc_options=tight, petsc_options_prefix=f"pc_krylov{flag}_",
        )
        for flag in (True, False)
    ]  # fmt: skip
    assert not direct.problem.precondition and all(k.problem.precondition for k in krylov)
    for centre, omega in (((0.1, 0.0), 1.0), ((-0.15, 0.1), -0.5)):
        md.update(du.Domain(None, [du.Circle(centre, 0.45)]))
        for stokes in (direct, *krylov):
            stokes.assemble((0.2, -0.1), omega)
            stokes.solve_assembled()
        exact = direct.wh.x.array
        scale = _max_gap(exact, 0.0)
        for stokes in krylov:
            ksp = stokes.problem.solver
            assert ksp.getPC().getType() == "fieldsplit"
            assert len(ksp.getPC().getFieldSplitSubKSP()) == 2
            assert ksp.getIterationNumber() > 0
            assert _max_gap(stokes.wh.x.array, exact) <= 1e-7 * scale
        assert (
            np.abs(krylov[0].force() - direct.force()).max() <= 1e-7 * np.abs(direct.force()).max()
        )
    # Switched to the direct solver (A factorised, not P) and back.
    for options, iterative in ((DIRECT, False), (tight, True)):
        krylov[0].problem.set_petsc_options(options, precondition=iterative)
        krylov[0].assemble((0.2, -0.1), -0.5)
        krylov[0].solve_assembled()
        assert _max_gap(krylov[0].wh.x.array, exact) <= 1e-7 * scale
        assert krylov[0].problem.solver.getPC().getType() == ("fieldsplit" if iterative else "lu")
    with pytest.raises(ValueError, match="preconditioner form P"):
        direct.problem.set_petsc_options(ITERATIVE, precondition=True)
    # Fields out of range on one rank only: the error on every rank (no hang).
    V = fem.functionspace(md.mesh, ("Lagrange", 1))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a, L = md.active * u * v * ufl.dx, md.active * v * ufl.dx
    wrong = [("x", [-1] if comm.rank == 0 else [0])]
    with pytest.raises(ValueError, match="process-local indices of owned unknowns"):
        MovingLinearProblem(md, a, L, petsc_options_prefix="pc_bad_", fields=wrong)


@pytest.mark.mpi
def test_fields_of_a_blocked_space_and_a_compiled_preconditioner():
    """``fields`` on a blocked space (bs = 2: unknowns ``block * 2 + component``) and a
    preconditioner ``P`` given as a UFL form without ``active_only`` (compiled by DOLFINx's
    ``LinearProblem``): the vector Laplacian's components decouple, so a field split by
    component with LU on each solves it in one GMRES iteration, on the submatrix of the
    active unknowns and on the whole system; the same solution as MUMPS on the whole
    system (1e-10 of its size: two factorisations' rounding)."""
    bg = du.equilateral_mesh(comm, [[-1.0, -1.0], [1.0, 1.0]], 0.1)
    md = MovingDomain(bg, degree=2)
    V = fem.functionspace(md.mesh, ("Lagrange", 2, (2,)))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    chi = md.active
    a = chi * ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx
    f = fem.Constant(md.mesh, np.array([1.0, -2.0]))
    L = chi * ufl.inner(f, v) * ufl.dx
    owned = V.dofmap.index_map.size_local
    fields = [(name, 2 * np.arange(owned) + i) for i, name in enumerate("xy")]
    split = {
        "ksp_type": "gmres", "ksp_rtol": 1e-12, "pc_type": "fieldsplit",
        "pc_fieldsplit_type": "additive", "fieldsplit_x_ksp_type": "preonly",
        "fieldsplit_x_pc_type": "lu", "fieldsplit_y_ksp_type": "preonly",
        "fieldsplit_y_pc_type": "lu",
    }  # fmt: skip
    direct = MovingLinearProblem(
        md, a, L, petsc_options_prefix="bs_direct_",
        petsc_options={"ksp_type": "preonly", "pc_type": "lu"},
    )  # fmt: skip
    problems = [
        MovingLinearProblem(
            md, a, L, P=a, fields=fields, restrict_to_active=flag, petsc_options=split,
            petsc_options_prefix=f"bs_split{flag}_",
        )
        for flag in (True, False)
    ]  # fmt: skip
    for centre in ((0.1, 0.0), (-0.2, 0.15)):
        md.update(du.Circle(centre, 0.6))
        bcs = [fem.dirichletbc(np.zeros(2), md.immersed_dofs(V), V)]
        exact = direct.solve(bcs).x.array
        scale = _max_gap(exact, 0.0)
        assert scale > 0.01
        for problem in problems:
            got = problem.solve(bcs).x.array
            assert problem.solver.getIterationNumber() == 1
            assert _max_gap(got, exact) <= 1e-10 * scale
