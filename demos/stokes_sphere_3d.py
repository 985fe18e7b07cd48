# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
# ---

# # Stokes drag on a sphere in a spherical container
#
# A rigid sphere of radius $a$ translates with the velocity $U$ through a viscous fluid
# that fills a fixed spherical container of radius $b$. At the centre of the container the
# drag is known in closed form; this demo computes it on curved tetrahedral universal
# meshes with Taylor–Hood elements and measures how fast the computed drag converges to
# it, then moves the sphere off the centre, where no closed form exists, and reports the
# force and how much it still changes from level to level.
#
# It illustrates how to
#
# - mesh the fluid between two surfaces, `Domain(Sphere(c, b), [Sphere(c', a)])`, with
#   curved tetrahedra of degree $q$ by {py:func}`dolfinx_universal.meshing.domain.mesh_domain`, on
#   a uniform background of a given size $h$,
# - tell the two surfaces apart (both are tagged
# {py:data}`dolfinx_universal.conforming.universal.IMMERSED`)
#   by the position of their faces,
# - solve the Stokes problem with $P_2/P_1$ Taylor–Hood elements and pure velocity data:
#   MUMPS with one pinned pressure degree of freedom, or MINRES with a block-diagonal
#   preconditioner (algebraic multigrid on the velocity, the pressure mass matrix) and the
#   constant pressures as the null space, checked against each other,
# - compute the force on the body by the weak residual, as `demos/dfg_benchmark.py` does,
# - draw a clipped view of the mesh with
#   {py:func}`dolfinx_universal.plotting.plot_tetrahedra`.
#
# Run it with
#
# ```bash
# python demos/stokes_sphere_3d.py [--quick] [--out DIR]
# mpirun -n 2 python demos/stokes_sphere_3d.py [--quick] [--out DIR]
# ```
#
# (same meshes and forces on any number of ranks; `--quick` takes two coarse sizes, about
# 20 s on one core; the full run takes about twelve minutes on one core and 4 GB of
# memory). In a notebook, call `main(["--quick"])`. The output folder (default
# `out/stokes_sphere_3d`) receives `summary.json` and the figures `drag_convergence.png`
# and `mesh.png`.
#
# ## The problem
#
# The steady Stokes equations with the viscosity $\mu$,
#
# $$ -\mu \Delta u + \nabla p = 0, \qquad \operatorname{div} u = 0 \qquad \text{in }
#    \Omega = B(0, b) \setminus \overline{B(c, a)}, $$
#
# with no slip on both spheres: $u = U$ on the body $S = \partial B(c, a)$ (a rigid
# translation; in the frame of the body this is the flow past a sphere held fixed in a
# container that moves with $-U$) and $u = 0$ on the container $\partial B(0, b)$. Here $b =
# 1$, $\mu = 1$, $U = (1, 0, 0)$, and $\lambda = a / b = 0.3$ and $0.5$. The pressure is
# defined up to a constant. The force of the fluid on the body is
#
# $$ F = \int_S \sigma(u, p)\, \nu \, ds, \qquad \sigma = \mu (\nabla u + \nabla u^T) - p I,$$
#
# $\nu$ the outward normal of the body, and the drag is $D = -F \cdot U / |U|$.
#
# ## The closed form
#
# With the body at the centre ($c = 0$) the flow is axisymmetric about the direction of
# $U$. In spherical coordinates $(r, \theta)$ about that axis, Stokes' stream function
# $\psi$ ($u_r = \frac{1}{r^2 \sin\theta} \partial_\theta \psi$,
# $u_\theta = -\frac{1}{r \sin\theta} \partial_r \psi$) satisfies $E^4 \psi = 0$, and the
# boundary data, $\psi = \frac12 U r^2 \sin^2\theta$ with its $r$-derivative on $r = a$ and
# $\psi = \partial_r \psi = 0$ on $r = b$, select the separable solutions
#
# $$ \psi = \sin^2\theta \, f(r), \qquad f(r) = A r^4 + B r^2 + C r + \frac{D}{r}, $$
#
# $$ f(a) = \tfrac12 U a^2, \quad f'(a) = U a, \quad f(b) = 0, \quad f'(b) = 0 .$$
#
# Of the four terms only the Stokeslet $C r \sin^2\theta$ carries a force, $F = -8 \pi \mu
# C\, U / |U|$ (the unbounded case, $f = \frac14 U (3 a r - a^3 / r)$, gives Stokes' law
# $6 \pi \mu a U$). Solving the $4 \times 4$ system for $C$ gives
#
# $$ D = 6 \pi \mu a U K(\lambda), \qquad
#    K(\lambda) = \frac{1 - \lambda^5}
#    {1 - \frac94 \lambda + \frac52 \lambda^3 - \frac94 \lambda^5 + \lambda^6}, $$
#
# the wall-correction factor of a sphere at the centre of a spherical container (Cunningham
# 1910, Williams 1915; Haberman & Sayre 1958, David Taylor Model Basin report 1143;
# quoted in Happel & Brenner, "Low Reynolds number hydrodynamics", 1965, chapter 4, the
# sphere in a spherical container). We do not take it on trust: `stream_function_K` below
# solves the $4 \times 4$ system numerically, and it agrees with the formula to rounding
# ($10^{-15}$, `reference.stream_function_check` in the summary). For small $\lambda$,
#
# $$ K(\lambda) = 1 + \tfrac94 \lambda + \tfrac{81}{16} \lambda^2
#    + \tfrac{569}{64} \lambda^3 + O(\lambda^4), $$
#
# Stokes' law with the first wall correction $\frac94 \lambda$ of the method of
# reflections. $K(0.3) = 2.5726381$ and $K(0.5) = 124 / 17 = 7.2941176$: the drag at
# $\lambda = 0.5$ is more than seven times Stokes' value. The finite element drags below
# converge to these values at about the rate 4 (3.9 and 3.6 between the two finest sizes),
# to $6 \cdot 10^{-5}$ and $2 \cdot 10^{-5}$: the last check of the formula.
#
# The off-centre variant moves the body by $0.1\, b$ along $d = (1, 2, 3) / \sqrt{14}$
# ($\lambda = 0.5$, gap between $0.4 b$ and $0.6 b$). By symmetry about the axis $d$ the
# resistance tensor is $\alpha I + \beta\, d d^T$, so $F = -(\alpha U + \beta (d \cdot U)
# d)$: the force lies in the plane of $U$ and $d$, with $F_y / F_z = d_y / d_z = 2/3$,
# which the computed force must reproduce to the discretisation error.

# +
from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from dolfinx.fem.petsc import LinearProblem, create_vector

import dolfinx_universal as du
from dolfinx_universal.demo_support import demo_options, log, write_summary
from dolfinx_universal.plotting import plot_tetrahedra, save

B = 1.0  # container radius
MU = 1.0  # viscosity
U = np.array([1.0, 0.0, 0.0])  # body velocity
RATIOS = (0.3, 0.5)  # a / b, body at the centre
DIRECTION = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)  # off-centre displacement direction
OFFSET = 0.1  # off-centre displacement (times b)
OFF_RATIO = 0.5  # a / b of the off-centre variant
SIZES = {False: (0.24, 0.12, 0.06), True: (0.3, 0.2)}  # h, full and quick runs
LU_MAX_DOFS = 50_000  # MUMPS up to this size, MINRES above
SOLVER_CHECK = {False: (0.5, 0.12), True: (0.5, 0.2)}  # (a / b, h) solved by both solvers
LU = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
MINRES = {
    "ksp_type": "minres",
    "ksp_rtol": 1e-10,
    "ksp_atol": 0.0,
    "ksp_max_it": 1000,
    "pc_type": "fieldsplit",
    "pc_fieldsplit_type": "additive",
    "fieldsplit_0_ksp_type": "preonly",
    "fieldsplit_0_pc_type": "gamg",
    "fieldsplit_0_pc_gamg_threshold": 0.02,
    "fieldsplit_0_mg_levels_ksp_type": "chebyshev",
    "fieldsplit_0_mg_levels_pc_type": "jacobi",
    "fieldsplit_1_ksp_type": "preonly",
    "fieldsplit_1_pc_type": "jacobi",
}


def K(lam: float) -> float:
    """The wall-correction factor of a sphere at the centre of a spherical container."""
    return (1 - lam**5) / (1 - 9 / 4 * lam + 5 / 2 * lam**3 - 9 / 4 * lam**5 + lam**6)


def stream_function_K(lam: float) -> float:
    """``K`` from the stream function: solve the 4x4 system of the no-slip conditions for
    ``f(r) = A r^4 + B r^2 + C r + D / r`` (``a = lam``, ``b = 1``, ``U = 1``) and divide
    the Stokeslet's force ``8 pi C`` by Stokes' ``6 pi a``."""
    a, b = lam, 1.0
    rows = [
        [a**4, a**2, a, 1 / a],
        [4 * a**3, 2 * a, 1.0, -1 / a**2],
        [b**4, b**2, b, 1 / b],
        [4 * b**3, 2 * b, 1.0, -1 / b**2],
    ]
    _, _, C, _ = np.linalg.solve(np.array(rows), [a**2 / 2, a, 0.0, 0.0])
    return 8 * np.pi * C / (6 * np.pi * a)


def exact_drag(lam: float) -> float:
    return 6 * np.pi * MU * (lam * B) * np.linalg.norm(U) * K(lam)


def geometry_estimate(lam: float, da: float, db: float) -> float:
    """The relative change of the exact drag when the radii change by the relative amounts
    ``da`` and ``db`` (first order): ``d ln D = (1 + s) da - s db``, ``s = lam K'/K``."""
    eps = 1e-6
    s = lam * (K(lam + eps) - K(lam - eps)) / (2 * eps) / K(lam)
    return (1 + s) * da - s * db


# -

# ## The meshes
#
# {py:func}`dolfinx_universal.meshing.domain.mesh_domain` sizes its background from the surfaces:
# near them, the local feature size (here the smaller of the radius of curvature and half
# the gap between the spheres) over `size_factor`, at most `h`. Between two spheres this
# gives a nearly uniform size anyway (the feature sizes of the two surfaces are $0.25$ and
# $0.25$ at $\lambda = 0.5$, $0.3$ and $0.35$ at $\lambda = 0.3$): there is nothing to
# grade, and the default (`tet_background="auto"`) itself takes the uniform A15
# background, of size $0.1$ ($\lambda = 0.3$) or $0.083$ ($\lambda = 0.5$) for any larger
# `h`. As in `demos/poisson_3d.py`, the convergence study takes the uniform A15
# background of size exactly $h$ (`tet_background="a15"` and a `size_factor` so small that
# the feature size never binds), which makes $h$ the one parameter of a level; the
# certificate confirms it (`h_min == h`, no refinement round). The sizes are $h = 0.24,
# 0.12, 0.06$ (quick: $0.3, 0.2$); at $h = 0.06$ the meshes have about $2.2 \cdot 10^5$
# tetrahedra and the Stokes problems $10^6$ unknowns.
#
# Both spheres are tagged `IMMERSED`. A face belongs to the body when its midpoint is
# closer to the body's sphere than to the container's.


# +
SIZE_FACTOR = 1e-6  # feature size / size: far below any feature, the size is h


def body_sphere(lam: float, offset: float) -> du.Sphere:
    return du.Sphere(offset * B * DIRECTION, lam * B)


def meshed(comm: MPI.Comm, lam: float, offset: float, h: float, q: int) -> du.MeshedDomain:
    """The uniform curved mesh of the fluid, size ``h``, geometry degree ``q`` (collective)."""
    domain = du.Domain(du.Sphere((0.0, 0.0, 0.0), B), [body_sphere(lam, offset)])
    md = du.mesh_domain(comm, domain, h, degree=q, tet_background="a15", size_factor=SIZE_FACTOR)
    c = md.certificate
    assert c.h_min == h and c.refinement_rounds == 0, (lam, offset, h, q, c)
    return md


def split_surfaces(md: du.MeshedDomain, body: du.Sphere) -> tuple[np.ndarray, np.ndarray]:
    """The local ``IMMERSED`` faces on the body and on the container."""
    faces = md.facet_tags.find(du.IMMERSED)
    mid = dmesh.compute_midpoints(md.mesh, 2, faces)
    to_body = np.abs(np.linalg.norm(mid - body.center, axis=1) - body.radius)
    to_wall = np.abs(np.linalg.norm(mid, axis=1) - B)
    on_body = to_body < to_wall
    return faces[on_body], faces[~on_body]


# -

# ## The discretisation
#
# Taylor–Hood $P_2/P_1$ on the mesh of geometry degree $q = 2$ (the boundary nodes of the
# curved tetrahedra lie on the spheres), in block form: the velocity space $V$ and the
# pressure space $Q$ separately,
#
# $$ a((u, p), (v, q)) = \int_\Omega \mu \nabla u : \nabla v - p \operatorname{div} v -
#    q \operatorname{div} u \, dx = 0 $$
#
# for all $(v, q)$ with $v = 0$ on $\partial\Omega$, with $u_h$ equal to the interpolant of
# the data at the boundary degrees of freedom ($U$ on the body's, 0 on the container's).
# The pressure is determined up to a constant, and the constant is the only kernel: the
# discrete data are compatible, $\int_{\partial\Omega_h} u_h \cdot n\, ds = U \cdot
# \int_{S_h} n\, ds = 0$ on the closed curved surface $S_h$. Two solvers:
#
# * **MUMPS** (up to $5 \cdot 10^4$ unknowns): one pressure degree of freedom is pinned to
#   zero, that of the vertex with the lexicographically largest coordinates (a vertex of
#   the container, the same on any number of ranks), with a zero $(1, 1)$ block to carry
#   the condition. Pinning removes one of the linearly dependent continuity equations, and
#   the solution is the same up to the constant.
# * **MINRES** (above): the preconditioner is block-diagonal, PETSc's algebraic multigrid
#   (GAMG, one V-cycle, Chebyshev–Jacobi smoothing) on the velocity block and Jacobi on the
#   pressure mass matrix scaled by $1 / \mu$, the usual spectrally equivalent Schur
#   complement; the constant pressure vector is given to PETSc as the null space of the
#   matrix. It converges in about 100 iterations at every size (relative residual
#   $10^{-10}$), in 90 s for $10^6$ unknowns on one core, and needs a tenth of the memory
#   of MUMPS (which takes 8.7 GB already at $2.3 \cdot 10^5$ unknowns).
#
# On one level of each run both solvers are used, and the drags agree to
# `solver_check.relative_difference` in the summary ($5 \cdot 10^{-12}$ or less).
#
# ## The force by the weak residual
#
# As in the DFG benchmark: with
#
# $$ R((u, p); v) = \int_\Omega \mu \nabla u : \nabla v - p \operatorname{div} v \, dx ,$$
#
# Green's formula gives $R((u, p); v) = \int_{\partial\Omega} (\mu \partial_n u - p n)
# \cdot v \, ds$ for a solution, $n$ the outward normal of the fluid ($-\nu$ on $S$). With
# $v = v_i$, the $P_2$ field equal to $e_i$ at the velocity nodes on the body and zero at
# every other node, only $S$ remains, and $F_i = -R((u_h, p_h); v_i)$. The traction $\mu
# \partial_n u - p n$ of the Laplacian form is that of $\sigma$ here: on $S$ the velocity is
# constant, so $(\nabla u)^T n = n\, (\partial_n u \cdot n) = n \operatorname{div} u = 0$.
# Since $a((u_h, p_h), (v, q)) = 0$ for every $v$ that vanishes on $\partial\Omega$, the
# value depends only on $v_i$ on the boundary, and it does not depend on the pressure
# constant ($\int_\Omega \operatorname{div} v_i\, dx = e_i \cdot \int_{S_h} n \, ds = 0$,
# $4 \cdot 10^{-16}$ computed). This volume integral converges like the energy error
# squared, $O(h^4)$ for $P_2/P_1$ where the geometry keeps up: much faster than the
# surface integral of $\nabla u_h$ and $p_h$.


# +
def pinned_pressure_dof(Q: fem.FunctionSpace) -> np.ndarray:
    """The owned degree of freedom of the P1 vertex with the lexicographically largest
    coordinates (on its owner; empty on the other ranks). Collective."""
    comm = Q.mesh.comm
    x = Q.tabulate_dof_coordinates()[: Q.dofmap.index_map.size_local]
    best, i = (-np.inf, -np.inf, -np.inf), -1
    if len(x):
        i = int(np.lexsort((x[:, 2], x[:, 1], x[:, 0]))[-1])
        best = tuple(float(c) for c in x[i])
    candidates = comm.allgather(best)
    owner = max(range(comm.size), key=lambda r: (candidates[r], -r))
    return np.array([i] if comm.rank == owner else [], dtype=np.int32)


def solve(md: du.MeshedDomain, body: du.Sphere, solver: str) -> dict:
    """Taylor–Hood solution on ``md``'s mesh and the force of the fluid on ``body``."""
    msh = md.mesh
    comm = msh.comm
    t0 = time.perf_counter()
    V = fem.functionspace(msh, ("Lagrange", 2, (3,)))
    Q = fem.functionspace(msh, ("Lagrange", 1))
    body_faces, wall_faces = split_surfaces(md, body)
    on_body = fem.locate_dofs_topological(V, 2, body_faces)
    on_wall = fem.locate_dofs_topological(V, 2, wall_faces)
    u_body, u_wall = fem.Function(V), fem.Function(V)
    u_body.x.array.reshape(-1, 3)[:] = U
    bcs = [fem.dirichletbc(u_body, on_body), fem.dirichletbc(u_wall, on_wall)]

    mu = fem.Constant(msh, PETSc.ScalarType(MU))
    u, p = ufl.TrialFunction(V), ufl.TrialFunction(Q)
    v, q = ufl.TestFunction(V), ufl.TestFunction(Q)

    def momentum(u, p, v):
        return mu * ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx - p * ufl.div(v) * ufl.dx

    a = [
        [mu * ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx, -p * ufl.div(v) * ufl.dx],
        [-q * ufl.div(u) * ufl.dx, None],
    ]
    zero = fem.Constant(msh, PETSc.ScalarType(0.0))
    L = [ufl.inner(fem.Constant(msh, np.zeros(3)), v) * ufl.dx, zero * q * ufl.dx]
    if solver == "MUMPS":
        a[1][1] = zero * p * q * ufl.dx
        bcs.append(fem.dirichletbc(fem.Function(Q), pinned_pressure_dof(Q)))
        problem = LinearProblem(
            a, L, bcs=bcs, kind="mpi", petsc_options=LU, petsc_options_prefix="st3d_lu_"
        )
    else:
        P = [[a[0][0], None], [None, ufl.inner(p, q) / mu * ufl.dx]]
        problem = LinearProblem(
            a, L, bcs=bcs, P=P, kind="nest", petsc_options=MINRES, petsc_options_prefix="st3d_"
        )
        constant = create_vector([V, Q], kind="nest")
        constant.getNestSubVecs()[0].set(0.0)
        constant.getNestSubVecs()[1].set(1.0)
        constant.normalize()
        problem.A.setNullSpace(PETSc.NullSpace().create(vectors=[constant]))
    u_h, p_h = problem.solve()
    ksp = problem.solver
    reason, iterations = ksp.getConvergedReason(), ksp.getIterationNumber()
    assert reason > 0, f"the {solver} solver did not converge ({reason})"
    t1 = time.perf_counter()

    force = np.zeros(3)
    for i in range(3):
        v_i = fem.Function(V)
        v_i.x.array.reshape(-1, 3)[on_body, i] = 1.0
        residual = fem.assemble_scalar(fem.form(momentum(u_h, p_h, v_i)))
        force[i] = -comm.allreduce(residual, op=MPI.SUM)
    one = fem.Constant(msh, PETSc.ScalarType(1.0))
    volume = comm.allreduce(fem.assemble_scalar(fem.form(one * ufl.dx)), op=MPI.SUM)
    exact_volume = 4 * np.pi / 3 * (B**3 - body.radius**3)
    # The volume inside the discrete body surface S_h: -1/3 of the flux of x - c through it
    # (n, the fluid's normal, points into the body), and the radius of that volume.
    order = np.argsort(body_faces)
    tags = dmesh.meshtags(msh, 2, body_faces[order], np.ones(len(order), dtype=np.int32))
    ds = ufl.Measure("ds", domain=msh, subdomain_data=tags)
    x = ufl.SpatialCoordinate(msh) - ufl.as_vector(body.center.tolist())
    flux = fem.assemble_scalar(fem.form(ufl.dot(x, ufl.FacetNormal(msh)) * ds(1)))
    body_volume = -comm.allreduce(flux, op=MPI.SUM) / 3
    body_radius = (3 * body_volume / (4 * np.pi)) ** (1 / 3)
    container_radius = (3 * (volume + body_volume) / (4 * np.pi)) ** (1 / 3)
    t2 = time.perf_counter()
    seconds = {"solve": t1 - t0, "force": t2 - t1}
    return {
        "dofs": sum(S.dofmap.index_map.size_global * S.dofmap.index_map_bs for S in (V, Q)),
        "solver": solver,
        "iterations": int(iterations),
        "force": force.tolist(),
        "volume_error": (volume - exact_volume) / exact_volume,
        "body_radius_error": body_radius / body.radius - 1,
        "container_radius_error": container_radius / B - 1,
        "seconds": {s: comm.allreduce(t, op=MPI.MAX) for s, t in seconds.items()},
    }


# -

# ## The study
#
# For each case (the body at the centre with $\lambda = 0.3$ and $0.5$, and off the centre
# with $\lambda = 0.5$) and each size: the mesh with $q = 2$ and its solution; at the
# finest size also the mesh with $q = 3$, to show that the geometry is not what limits the
# accuracy. The solver is MUMPS up to $5 \cdot 10^4$ unknowns and MINRES above; at
# $\lambda = 0.5$, $h = 0.12$ (quick: $0.2$) the other solver solves the same problem too.


# +
def cases() -> list[tuple[str, float, float]]:
    """``(name, a / b, offset)`` of every case."""
    return [(f"lambda={lam}", lam, 0.0) for lam in RATIOS] + [("off-centre", OFF_RATIO, OFFSET)]


def study(comm: MPI.Comm, quick: bool) -> tuple[list[dict], dict, dict]:
    """Rows of forces for every case, size and geometry degree; the solver comparison; the
    mesh drawn."""
    rows: list[dict] = []
    check: dict = {}
    drawn: dict = {}
    sizes = SIZES[quick]
    for name, lam, offset in cases():
        body = body_sphere(lam, offset)
        exact = exact_drag(lam) if offset == 0 else None
        for h in sizes:
            for q in (2, 3) if h == sizes[-1] else (2,):
                t0 = time.perf_counter()
                md = meshed(comm, lam, offset, h, q)
                seconds_mesh = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
                n_cells = md.certificate.num_cells
                r = solve(md, body, solver_for(md))
                drag = -float(np.dot(r["force"], U)) / float(np.linalg.norm(U))
                rows.append(
                    {
                        "case": name,
                        "ratio": lam,
                        "offset": offset,
                        "h": h,
                        "q": q,
                        "n_cells": n_cells,
                        "dofs": r["dofs"],
                        "solver": r["solver"],
                        "iterations": r["iterations"],
                        "force": r["force"],
                        "drag": drag,
                        "exact": exact,
                        "rel_error": None if exact is None else (drag - exact) / exact,
                        "volume_error": r["volume_error"],
                        "body_radius_error": r["body_radius_error"],
                        "container_radius_error": r["container_radius_error"],
                        "geometry_estimate": None
                        if exact is None
                        else geometry_estimate(
                            lam, r["body_radius_error"], r["container_radius_error"]
                        ),
                        "seconds": {"mesh": seconds_mesh} | r["seconds"],
                    }
                )
                err = "" if exact is None else f" rel.err={(drag - exact) / exact:+.3e}"
                log(
                    comm,
                    f"{name:11s} h={h:.3f} q={q} cells={n_cells:7d} dofs={r['dofs']:8d} "
                    f"drag={drag:.9f}{err} da/a={r['body_radius_error']:+.1e} "
                    f"({r['solver']}, {r['iterations']} it, "
                    f"{sum(r['seconds'].values()) + seconds_mesh:.1f} s)",
                )
                if offset == 0 and (lam, h) == SOLVER_CHECK[quick] and q == 2:
                    other = "MINRES" if r["solver"] == "MUMPS" else "MUMPS"
                    r2 = solve(md, body, other)
                    drag2 = -float(np.dot(r2["force"], U)) / float(np.linalg.norm(U))
                    check = {
                        "case": name,
                        "h": h,
                        r["solver"]: drag,
                        other: drag2,
                        "relative_difference": abs(drag2 - drag) / abs(drag),
                        "seconds": {r["solver"]: r["seconds"]["solve"]}
                        | {other: r2["seconds"]["solve"]},
                    }
                    log(comm, f"  {other} on the same problem: drag={drag2:.9f} "
                        f"(relative difference {check['relative_difference']:.1e})")  # fmt: skip
                if offset != 0 and h == sizes[0]:
                    drawn = {"h": h, "mesh": md.conforming, "centre": body.center}
    return rows, check, drawn


def solver_for(md: du.MeshedDomain) -> str:
    """MUMPS for small problems, MINRES for large ones (by the number of unknowns)."""
    topology = md.mesh.topology
    topology.create_entities(1)
    vertices, edges = (topology.index_map(d).size_global for d in (0, 1))
    return "MUMPS" if 4 * vertices + 3 * edges <= LU_MAX_DOFS else "MINRES"


# -

# ## Rates and the off-centre variant
#
# For each ratio, the observed rate between consecutive sizes, $\log(e_{l-1} / e_l) /
# \log(h_{l-1} / h_l)$ of the relative drag errors $e_l$ ($q = 2$); the one reported is
# that of the finest pair. Richardson's extrapolation with the rate 4 from the two finest
# levels, $D_\infty = D_l + (D_l - D_{l-1}) / ((h_{l-1} / h_l)^4 - 1)$, is computed for
# every case: where the exact drag is known it shows how far such an estimate can be
# trusted, and for the off-centre body it is the best value we have. For the off-centre
# body: the force at every level, its relative change from the level before, $|F_l -
# F_{l-1}| / |F_l|$, the symmetry checks ($F_y / F_z$ against $2/3$, and the component
# normal to the plane of $U$ and $d$), and the drag relative to the centred body's.


# +
def series(rows: list[dict], case: str, q: int = 2) -> list[dict]:
    """The rows of one case and geometry degree, coarsest first."""
    return sorted((r for r in rows if r["case"] == case and r["q"] == q), key=lambda r: -r["h"])


def richardson(sel: list[dict], key: str = "drag", rate: float = 4.0):
    """Extrapolation of ``key`` (a number or a vector) from the two finest rows."""
    (c, f) = sel[-2:]
    factor = (c["h"] / f["h"]) ** rate - 1
    return (np.asarray(f[key]) + (np.asarray(f[key]) - np.asarray(c[key])) / factor).tolist()


def analyse(comm: MPI.Comm, rows: list[dict]) -> tuple[list[dict], dict]:
    """Rates of the centred cases; the off-centre summary."""
    rates = []
    log(
        comm,
        f"\n{'case':>11} {'finest error':>13} {'rate':>6} {'geometry':>9} {'q=3 error':>10} "
        f"{'geometry':>9} {'Richardson':>11}   (geometry: first-order part of the radii's errors)",
    )
    for name, lam, offset in cases():
        if offset != 0:
            continue
        sel = series(rows, name)
        hs = np.array([r["h"] for r in sel])
        err = np.abs([r["rel_error"] for r in sel])
        pairs = (np.log(err[:-1] / err[1:]) / np.log(hs[:-1] / hs[1:])).tolist()
        fine3 = series(rows, name, q=3)[-1]
        extrapolated = richardson(sel)
        exact = sel[-1]["exact"]
        rates.append(
            {
                "case": name,
                "ratio": lam,
                "rate": pairs[-1],
                "rates": pairs,
                "finest_error": sel[-1]["rel_error"],
                "finest_error_q3": fine3["rel_error"],
                "geometry_effect": (fine3["drag"] - sel[-1]["drag"]) / exact,
                "geometry_estimate": sel[-1]["geometry_estimate"],
                "geometry_estimate_q3": fine3["geometry_estimate"],
                "discretisation_part": sel[-1]["rel_error"] - sel[-1]["geometry_estimate"],
                "discretisation_part_q3": fine3["rel_error"] - fine3["geometry_estimate"],
                "richardson": extrapolated,
                "richardson_error": (extrapolated - exact) / exact,
            }
        )
        r = rates[-1]
        log(
            comm,
            f"{name:>11} {r['finest_error']:+13.3e} {r['rate']:6.2f} "
            f"{r['geometry_estimate']:+9.1e} {r['finest_error_q3']:+10.3e} "
            f"{r['geometry_estimate_q3']:+9.1e} {r['richardson_error']:+11.2e}",
        )

    name = cases()[-1][0]
    sel = series(rows, name)
    forces = np.array([r["force"] for r in sel])
    norms = np.linalg.norm(forces, axis=1)
    changes = (np.linalg.norm(np.diff(forces, axis=0), axis=1) / norms[1:]).tolist()
    normal = np.cross(U, DIRECTION)
    normal /= np.linalg.norm(normal)
    fine, fine3 = sel[-1], series(rows, name, q=3)[-1]
    off = {
        "ratio": OFF_RATIO,
        "offset": OFFSET,
        "direction": DIRECTION.tolist(),
        "h": [r["h"] for r in sel],
        "force": forces.tolist(),
        "drag": [r["drag"] for r in sel],
        "change": changes,
        "Fy_over_Fz": [f[1] / f[2] for f in forces],
        "out_of_plane": (forces @ normal / norms).tolist(),
        "geometry_effect": float(
            np.linalg.norm(np.subtract(fine3["force"], fine["force"])) / norms[-1]
        ),
        "richardson_force": richardson(sel, "force"),
        "richardson_drag": richardson(sel),
        "drag_over_centred": richardson(sel) / exact_drag(OFF_RATIO),
    }
    log(
        comm,
        f"\noff-centre body (a / b = {OFF_RATIO}, offset {OFFSET} b along {DIRECTION.round(4)}):",
    )
    log(comm, f"{'h':>6} {'F_x':>14} {'F_y':>14} {'F_z':>14} {'change':>9} {'F_y/F_z':>9}")
    for i, r in enumerate(sel):
        change = f"{changes[i - 1]:9.2e}" if i else f"{'':9s}"
        log(comm, f"{r['h']:6.3f} {forces[i][0]:14.8f} {forces[i][1]:14.8f} "
            f"{forces[i][2]:14.8f} {change} {off['Fy_over_Fz'][i]:9.6f}")  # fmt: skip
    log(comm, f"q = 3 at the finest size changes F by {off['geometry_effect']:.1e} (relative); "
        f"Richardson drag {off['richardson_drag']:.8f} = {off['drag_over_centred']:.5f} x "
        "the centred one")  # fmt: skip
    return rates, off


# -

# ## Figures
#
# The relative drag errors against $h$ for both ratios ($q = 2$, and $q = 3$ at the finest
# size), with the slope 4 through the finest points; next to them, the off-centre force's
# relative change from the level before. Then a clipped view of the off-centre mesh at the
# coarsest size (the straight conforming tetrahedra under the curved ones), coloured by the
# smallest dihedral angle of each tetrahedron: the body sits off the centre of the
# container.


# +
def convergence_figure(rows: list[dict], off: dict, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11.0, 4.6), layout="constrained")
    ax, ax2 = fig.subplots(1, 2)
    for k, (name, lam, offset) in enumerate(cases()):
        if offset != 0:
            continue
        sel = series(rows, name)
        hs = np.array([r["h"] for r in sel])
        err = np.abs([r["rel_error"] for r in sel])
        ax.loglog(hs, err, "o-", color=f"C{k}", label=rf"$\lambda$ = {lam}, q = 2")
        ax.loglog(hs, err[-1] * (hs / hs[-1]) ** 4, ":", color=f"C{k}", lw=1.0)
        fine3 = series(rows, name, q=3)[-1]
        ax.loglog([fine3["h"]], [abs(fine3["rel_error"])], "s", mfc="none", ms=9,
                  color=f"C{k}", label=rf"$\lambda$ = {lam}, q = 3")  # fmt: skip
    ax.axhline(1e-4, color="0.5", lw=0.8, ls="--")
    ax.set_xlabel("mesh size h")
    ax.set_ylabel("|drag - exact| / exact")
    ax.set_title("centred sphere (dotted: slope 4)")
    ax2.loglog(off["h"][1:], off["change"], "o-", color="C2")
    ax2.set_xlabel("mesh size h")
    ax2.set_ylabel(r"$|F_l - F_{l-1}| / |F_l|$")
    ax2.set_title(rf"off-centre sphere, $\lambda$ = {off['ratio']}: change from the level before")
    for a in (ax, ax2):
        hs = sorted({r["h"] for r in rows})
        a.set_xticks(hs, [f"{h:.3g}" for h in hs])
        a.set_xticks([], minor=True)
        a.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.suptitle("Stokes drag on a sphere in a spherical container (P2/P1, weak residual)")
    save(fig, path)


def mesh_figure(comm: MPI.Comm, drawn: dict, path: Path) -> None:
    fig = ax = None
    if comm.rank == 0:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(7.0, 6.0), layout="constrained")
        ax = fig.add_subplot(projection="3d")
    plot_tetrahedra(
        drawn["mesh"],
        ax,
        view="clipped",
        origin=drawn["centre"],
        elev=15.0,
        azim=-80.0,
        title=f"off-centre sphere in its container, h = {drawn['h']:.3g}, clipped",
    )
    if comm.rank == 0:
        save(fig, path)


# -

# ## The whole study
#
# `main` runs the study, prints the rates and the off-centre force, draws the figures and
# writes `summary.json`: the forces, drags, errors, unknowns, solvers and seconds of every
# solve (`rows`), the rates (`rates`), the off-centre summary (`off_centre`), the two
# solvers on the same problem (`solver_check`), the set-up (`parameters`), the closed form
# with its check by the stream function and the exact drags (`reference`), and the
# versions and number of ranks.


# +
def main(argv: Sequence[str] | None = None) -> dict:
    """Run the study (``argv``: command-line options, ``None`` for ``sys.argv``)."""
    args = demo_options(
        "Stokes drag on a sphere in a spherical container", "out/stokes_sphere_3d", argv
    )
    comm = MPI.COMM_WORLD
    t_start = time.perf_counter()
    rows, solver_check, drawn = study(comm, args.quick)
    rates, off = analyse(comm, rows)
    if comm.rank == 0:
        convergence_figure(rows, off, args.out / "drag_convergence.png")
    mesh_figure(comm, drawn, args.out / "mesh.png")
    seconds = comm.allreduce(time.perf_counter() - t_start, op=MPI.MAX)
    log(comm, f"total {seconds:.1f} s")

    parameters = {
        "quick": args.quick,
        "container_radius": B,
        "viscosity": MU,
        "velocity": U.tolist(),
        "ratios": list(RATIOS),
        "off_centre": {"ratio": OFF_RATIO, "offset": OFFSET, "direction": DIRECTION.tolist()},
        "h": list(SIZES[args.quick]),
        "geometry_degrees": {"all sizes": 2, "finest size": [2, 3]},
        "elements": "Taylor-Hood P2/P1",
        "mesh_domain": {"tet_background": "a15", "size_factor": SIZE_FACTOR, "map": "I~"},
        "solvers": {"MUMPS": LU, "MINRES": MINRES, "lu_max_dofs": LU_MAX_DOFS},
        "pressure": "MUMPS: one dof pinned; MINRES: constant null space",
        "force": "F_i = -R((u_h, p_h); v_i), v_i = e_i at the body's velocity dofs",
        "rate": "between the two finest sizes",
    }
    reference = {
        "K_formula": "(1 - l^5) / (1 - 9/4 l + 5/2 l^3 - 9/4 l^5 + l^6), l = a / b",
        "source": "Cunningham 1910, Williams 1915, Haberman & Sayre 1958; Happel & Brenner "
        "1965, ch. 4",
        "K": {str(lam): K(lam) for lam in (*RATIOS, OFF_RATIO)},
        "drag": {str(lam): exact_drag(lam) for lam in RATIOS},
        "stream_function_check": max(
            abs(stream_function_K(lam) - K(lam)) / K(lam) for lam in (0.01, 0.1, *RATIOS, 0.7)
        ),
    }
    results = {
        "rows": rows,
        "rates": rates,
        "off_centre": off,
        "solver_check": solver_check,
        "seconds": seconds,
    }
    path = write_summary(comm, args.out, results, parameters=parameters, reference=reference)
    log(comm, f"wrote {path}")
    check(results, reference, args.quick)
    return results


# -

# ## Checks
#
# The closed form agrees with the stream-function solution to $10^{-12}$. For both ratios
# the drag error falls from level to level. In the full run the finest relative error is
# below $10^{-4}$ for both ratios, the observed rate between the two finest sizes is above
# 3.3 (4 expected; the A15 lattice is placed afresh at every size, which makes the rates
# a little noisy), and $q = 3$ changes the finest drag by less than $10^{-4}$; in quick
# mode the finest error is below $5 \cdot 10^{-3}$. The two solvers agree to $10^{-8}$.
# The off-centre force lies in the plane of $U$ and $d$ ($F_y / F_z = 2/3$ to $10^{-2}$ at
# the finest size, the normal component below $10^{-3} |F|$ at every size), its change
# from level to level falls (full run: by at least four times from one level to the
# next, as the centred error does from the pre-asymptotic $h = 0.24$ on), and the
# off-centre drag exceeds the centred one (the body is nearer the wall). The checks at
# $10^{-12}$ and $10^{-8}$ compare quantities equal up to rounding ($10^{-15}$) and up to
# the solvers' tolerance (MINRES to a relative residual of $10^{-10}$; measured
# $5 \cdot 10^{-12}$); a wrong closed form or solver is off by $10^{-4}$ or more. The
# other bounds are discretisation errors ($10^{-5}$ and more) that rounding does not move.
#
# ## Results
#
# The full run (one core of a 2-core machine shared with other jobs; seconds per row,
# meshing included; MINRES took 101 to 111 iterations). The exact drags are
# $14.54792559$ ($\lambda = 0.3$) and $68.74543924$ ($\lambda = 0.5$); "geometry" is the
# first-order effect of the discrete radii on the exact drag, $(1 + s)\, \delta a / a -
# s\, \delta b / b$, $s = \lambda K' / K$, with the radii of the volumes enclosed by the
# discrete surfaces:
#
# | $\lambda$ | $h$ | $q$ | unknowns | solver | drag | rel. error | $\delta a / a$ | geometry | s |
# |---|---|---|---|---|---|---|---|---|---|
# | 0.3 | 0.24 | 2 | 18078 | MUMPS | 14.59855237 | +3.48e-03 | -1.4e-03 | -3.1e-03 | 1 |
# | 0.3 | 0.12 | 2 | 135118 | MINRES | 14.56081521 | +8.86e-04 | -1.0e-04 | -2.3e-04 | 10 |
# | 0.3 | 0.06 | 2 | 998340 | MINRES | 14.54877553 | +5.84e-05 | -5.9e-06 | -1.3e-05 | 82 |
# | 0.3 | 0.06 | 3 | 998340 | MINRES | 14.54901142 | +7.46e-05 | +1.3e-06 | +3.0e-06 | 112 |
# | 0.5 | 0.24 | 2 | 17104 | MUMPS | 68.87041642 | +1.82e-03 | -2.1e-04 | -8.7e-04 | 1 |
# | 0.5 | 0.12 | 2 | 126812 | MINRES | 68.76487069 | +2.83e-04 | -1.1e-05 | -4.5e-05 | 9 |
# | 0.5 | 0.06 | 2 | 916544 | MINRES | 68.74709123 | +2.40e-05 | -6.6e-07 | -2.6e-06 | 96 |
# | 0.5 | 0.06 | 3 | 916544 | MINRES | 68.74731462 | +2.73e-05 | +1.5e-07 | +6.2e-07 | 112 |
#
# The finest errors are $5.8 \cdot 10^{-5}$ ($\lambda = 0.3$) and $2.4 \cdot 10^{-5}$
# ($\lambda = 0.5$), below the target $10^{-4}$; the observed rates are 1.97 and 3.92
# ($\lambda = 0.3$), 2.69 and 3.56 ($\lambda = 0.5$): $h = 0.24$ is not yet asymptotic
# ($a / h = 1.25$ and $2$), the finest pair is close to the expected 4. The drag converges
# to the closed form from above, at the expected rate: the formula is confirmed to
# $10^{-5}$. Richardson's extrapolation from the two finest sizes is within $3.3 \cdot
# 10^{-6}$ and $6.8 \cdot 10^{-6}$ of it. MUMPS and MINRES give the same drag at $h =
# 0.12$, $\lambda = 0.5$ ($1.3 \cdot 10^5$ unknowns) to $5 \cdot 10^{-13}$ (21 s and 8 s).
# The lateral force on the centred body, zero by symmetry but not on the unsymmetric
# meshes, is a pure discretisation error: $1.2 \cdot 10^{-4}$ of the drag at $h = 0.24$,
# $1.2 \cdot 10^{-7}$ ($\lambda = 0.3$) and $2.7 \cdot 10^{-8}$ ($\lambda = 0.5$) at $h = 0.06$.
#
# The geometry: the degree-2 surfaces enclose a slightly too small body ($\delta a / a =
# -5.9 \cdot 10^{-6}$ and $-6.6 \cdot 10^{-7}$ at $h = 0.06$, falling like $h^4$ and
# faster); the degree-3 ones are closer and err the other way. The degree-3 drag is not
# more accurate: its error is larger ($7.5 \cdot 10^{-5}$ and $2.7 \cdot 10^{-5}$), because
# the body's too small volume at $q = 2$ lowers the drag and partly cancels the (positive)
# error of the $P_2/P_1$ solution. Subtracting the first-order geometric effect leaves
# $7.163 \cdot 10^{-5}$ ($q = 2$) and $7.161 \cdot 10^{-5}$ ($q = 3$) at $\lambda = 0.3$,
# $2.6664 \cdot 10^{-5}$ and $2.6665 \cdot 10^{-5}$ at $\lambda = 0.5$: the same to
# $3 \cdot 10^{-4}$ of themselves. So the error is that of the Taylor–Hood solution, plus
# a geometric part that the radii's errors explain completely; at $h = 0.06$ this part is
# $-1.3 \cdot 10^{-5}$ (a fifth of the error) and $-2.6 \cdot 10^{-6}$ (a tenth): the
# geometry is not the limit.
#
# The off-centre body ($\lambda = 0.5$, displaced by $0.1 b$ along $(1, 2, 3) / \sqrt{14}$):
#
# | $h$ | unknowns | $F_x$ | $F_y$ | $F_z$ | change | $F_y / F_z$ | s |
# |---|---|---|---|---|---|---|---|
# | 0.24 | 17272 | -69.46940226 | -0.32354962 | -0.48271354 | | 0.670273 | 1 |
# | 0.12 | 126741 | -69.35585637 | -0.32259109 | -0.48361908 | 1.6e-03 | 0.667035 | 9 |
# | 0.06 | 917361 | -69.33821010 | -0.32235708 | -0.48353394 | 2.5e-04 | 0.666669 | 98 |
#
# ($q = 3$ at $h = 0.06$: $F_x = -69.33844078$, a change of $3.3 \cdot 10^{-6}$, 147 s.)
# The level-to-level change falls 6.4 times, as the centred drag's does at $\lambda = 0.5$
# (5.9 times); $F_y / F_z$ reaches $2/3$ to $5 \cdot 10^{-6}$, and
# the component normal to the plane of $U$ and $d$ is $1.3 \cdot 10^{-8} |F|$ at $h = 0.06$.
# Richardson's extrapolation gives the drag $69.33703$ (to about $10^{-5}$, judging by the
# centred cases), $1.0086$ times the centred body's: moving the body by a fifth of the gap
# raises the drag by less than 1 %, and adds a lateral force (normal to $U$) of $0.58$
# (0.8 % of the drag), along the part of $-d$ normal to $U$. In the terms of the
# resistance tensor, $\alpha = 69.176$ for motion normal to $d$ and $\alpha + \beta =
# 71.432$ for motion along $d$ (1.0063 and 1.0391 times the centred value): moving
# towards the nearer wall is resisted more.
#
# The whole full run took 702 s and 3.8 GB (peak resident memory); the quick run about
# 20 s on one core and 30 s on two ranks.


# +
def check(results: dict, reference: dict, quick: bool) -> None:
    assert reference["stream_function_check"] < 1e-12, reference
    for r in results["rates"]:
        errors = [abs(row["rel_error"]) for row in series(results["rows"], r["case"])]
        assert all(b < a for a, b in zip(errors, errors[1:])), (r["case"], errors)
        if quick:
            assert errors[-1] < 5e-3, (r["case"], errors)
        else:
            assert abs(r["finest_error"]) < 1e-4, r
            assert r["rate"] > 3.3, r
            assert abs(r["geometry_effect"]) < 1e-4, r
    assert results["solver_check"]["relative_difference"] < 1e-8, results["solver_check"]
    off = results["off_centre"]
    assert abs(off["Fy_over_Fz"][-1] / (2 / 3) - 1) < 1e-2, off
    assert all(abs(normal) < 1e-3 for normal in off["out_of_plane"]), off
    changes = off["change"]
    assert all(b < a for a, b in zip(changes, changes[1:])), off
    if not quick:
        assert changes[-1] < changes[-2] / 4, off
    assert min(off["drag"]) > reference["drag"][str(OFF_RATIO)], off


# -

# +
if __name__ == "__main__":
    main([] if "ipykernel" in sys.modules else None)
# -
