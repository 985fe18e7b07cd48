# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
# ---

# # Flow around a cylinder (DFG 2D-1) on a universal mesh
#
# The steady benchmark of Schäfer & Turek (1996, "Benchmark computations of laminar flow
# around a cylinder"), set up in the DFG priority programme and since then the usual
# check of a flow solver (the FEniCSx tutorial solves its time-dependent case 2D-3). A
# channel $[0, 2.2] \times [0, 0.41]$ contains a cylinder of radius $R = 0.05$ centred at
# $(0.2, 0.2)$; the fluid ($\rho = 1$, $\nu = 10^{-3}$) obeys the steady incompressible
# Navier–Stokes equations
#
# $$ -\nu \Delta u + (u \cdot \nabla) u + \nabla p = 0, \qquad \operatorname{div} u = 0, $$
#
# with the parabolic inflow $u = (4 U_{\max} y (0.41 - y) / 0.41^2, 0)$, $U_{\max} = 0.3$,
# on $x = 0$, no slip on the walls $y = 0, 0.41$ and on the cylinder, and the do-nothing
# condition $\nu \partial_n u - p n = 0$ on the outflow $x = 2.2$. The mean inflow velocity
# is $U = 2 U_{\max} / 3 = 0.2$ and, with the diameter $D = 0.1$, $\mathrm{Re} = U D / \nu =
# 20$: the flow is steady, with a small recirculation behind the cylinder and a lift that
# is not zero because the cylinder sits $0.005$ below the channel's centre line.
#
# The quantities of interest are the drag and lift coefficients and the pressure
# difference between the front and the back of the cylinder,
#
# $$ c_D = \frac{2 F_D}{\rho U^2 D}, \qquad c_L = \frac{2 F_L}{\rho U^2 D}, \qquad
#    \Delta p = p(0.15, 0.2) - p(0.25, 0.2), $$
#
# $(F_D, F_L) = \int_S (\rho \nu \nabla u - p I)\, \nu_S\, ds$, the force of the fluid on
# the cylinder $S$ ($\nu_S$ the cylinder's outward normal, into the fluid). Their
# high-accuracy values, listed on the FEATFLOW benchmark page of the case ("DFG flow
# around cylinder, laminar case (Re=20)", featflow.de), which refers to the high-order
# computations of Nabh (1998, Heidelberg preprint 42/98) and of John & Matthies (2001,
# "Higher-order finite element discretizations in a benchmark problem for incompressible
# flows", IJNMF 37), are
#
# $$ c_D = 5.57953523384, \qquad c_L = 0.010618948146, \qquad \Delta p = 0.11752016697. $$
#
# ## The discretisation
#
# * **Mesh.** {py:func}`dolfinx_universal.mesh_domain` meshes the fluid domain
#   `Domain(None, [Circle((0.2, 0.2), 0.05)])` in the box of the channel: the box boundary
#   is the background's boundary (facet tag `OUTER`), the cylinder is immersed (tag
#   `IMMERSED`); the background is a graded acute quadtree mesh, fine near the cylinder
#   (size $R$ / `size_factor`) and of size `h` far from it, conformed to the circle by
#   moving a few vertices, and curved: the boundary nodes of the degree-$q$ triangles lie on
#   the exact circle ($q = 2$, and $q = 3$ as a variant). Level $\ell$ halves both sizes of
#   level $\ell - 1$.
# * **Elements.** Taylor–Hood $P_2/P_1$.
# * **Solver.** Newton's method (PETSc SNES through
#   {py:class}`dolfinx.fem.petsc.NonlinearProblem`, the exact Jacobian by UFL, MUMPS LU
#   for each step) from the zero initial guess, to a residual norm below $10^{-11}$.
#   With the do-nothing outflow the pressure is unique (no pin needed).
# * **Forces by the weak residual.** With
#
#   $$ R((u, p); v) = \int_\Omega \nu \nabla u : \nabla v + (u \cdot \nabla) u \cdot v
#      - p \operatorname{div} v \, dx , $$
#
#   Green's formula gives $R((u, p); v) = \int_{\partial\Omega} (\nu \partial_n u - p n)
#   \cdot v\, ds$ ($n$ the outward normal of the fluid, $-\nu_S$ on $S$) for a solution.
#   Taking $v = v_D$, a $P_2$ field equal to $(1, 0)$ at the velocity nodes on the cylinder
#   and zero at every other node, leaves the cylinder only: $F_D = -R((u_h, p_h); v_D)$
#   (John 2004, "Reference values for drag and lift of a two-dimensional time-dependent
#   flow around a cylinder", IJNMF 44). The same with $v_L = (0, 1)$ gives $F_L$. This
#   volume integral converges like the energy error squared, much faster than the
#   surface integral of $\nabla u_h$ and $p_h$.
# * **Pressure difference.** $p_h$ is evaluated at the two points; each point is taken by
#   exactly one rank (the lowest one that owns a cell containing it), so the result does
#   not depend on the partition.
#
# Run with `python demos/dfg_benchmark.py [--quick] [--out DIR]`, also under `mpirun`.
# `--quick` runs the three coarsest levels of both degrees (about 10 s). Written to `DIR`
# (default `out/dfg_benchmark`): `summary.json` (`{"rows": [...]}`, one row per level and
# geometry degree), `fields.png` (velocity magnitude and pressure near the cylinder, on the
# curved mesh), `convergence.png` (errors of $c_D$, $c_L$, $\Delta p$ against the number
# of degrees of freedom).

# +
from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path

from mpi4py import MPI
from petsc4py import PETSc

import basix.ufl
import numpy as np
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from dolfinx.fem.petsc import NonlinearProblem

import dolfinx_universal as du
from dolfinx_universal.demo_support import demo_options, log
from dolfinx_universal.demo_support import point_values as demo_point_values
from dolfinx_universal.plotting import plot_function, save

comm = MPI.COMM_WORLD
length, height = 2.2, 0.41
centre, radius = (0.2, 0.2), 0.05
U_max, nu = 0.3, 1e-3
U_mean, diameter = 2 * U_max / 3, 2 * radius
front, back = (0.15, 0.2), (0.25, 0.2)
reference = {"c_D": 5.57953523384, "c_L": 0.010618948146, "delta_p": 0.11752016697}
# -

# ## The levels
#
# Level 0 has the size $h_0 = 0.08$ far from the cylinder and $R / s_0 = R / 2$ next to it
# (`size_factor` $s$ is the feature size of the boundary, here $R$, over the target size);
# each level halves both, so the graded mesh keeps its shape and the number of cells grows
# about fourfold per level (the quadtree's sizes are powers of two, so the growth from
# level to level varies between 2.6 and 3.7). The number of levels is chosen by
# convergence: at the finest one (level 4, $7 \cdot 10^5$ degrees of freedom) the
# difference to the level below is a few $10^{-7}$ relative for $c_D$ and a few
# $10^{-5}$ for $c_L$, while a level more costs about a minute per Newton step here.


# +
def levels(quick: bool) -> list[tuple[int, int, float, float]]:
    """``(level, geometry degree, h, size_factor)`` of every row of the study."""
    h0, s0 = 0.08, 2.0
    n = 3 if quick else 5
    rows = [(lv, 2, h0 / 2**lv, s0 * 2**lv) for lv in range(n)]
    rows += [(lv, 3, h0 / 2**lv, s0 * 2**lv) for lv in range(n)]
    return rows


# -

# ## One level
#
# The mesh, the spaces and the boundary conditions (walls and inflow on the `OUTER`
# facets located by their coordinates, no slip on the `IMMERSED` ones), the residual and
# Newton's method, the forces and the pressure difference.


# +
def channel_mesh(h: float, size_factor: float, degree: int) -> du.MeshedDomain:
    """The curved universal mesh of the channel minus the cylinder."""
    domain = du.Domain(container=None, bodies=[du.Circle(centre, radius)])
    return du.mesh_domain(
        comm,
        domain,
        h,
        degree=degree,
        box=[[0.0, 0.0], [length, height]],
        size_factor=size_factor,
    )


def inflow(x: np.ndarray) -> np.ndarray:
    """The parabolic inflow profile at points ``x (3, n)``."""
    return np.vstack([4 * U_max * x[1] * (height - x[1]) / height**2, np.zeros(x.shape[1])])


def point_values(f: fem.Function, points: np.ndarray) -> np.ndarray:
    """``f`` at ``points (n, 3)``, each point taken by exactly one rank (collective; see
    :func:`~dolfinx_universal.demo_support.point_values`); the result is the same on every
    rank. Curved cells are tested against the convex hull of their
    nodes, which at a convex body covers the strip between each curved edge and its chord:
    a point on the exact circle is found even where the discrete boundary misses it by the
    interpolation error, and ``f`` is extrapolated there (a tiny distance). Raises on every
    rank if a point lies in no cell."""
    values = demo_point_values([f], points)[0][:, 0]
    if np.isnan(values).any():
        raise RuntimeError(f"points {points[np.isnan(values)].tolist()} lie in no cell")
    return values


def solve_level(level: int, degree: int, h: float, size_factor: float) -> tuple[dict, fem.Function]:
    """Mesh, solve and post-process one level: the summary row and the solution."""
    t0 = time.perf_counter()
    md = channel_mesh(h, size_factor, degree)
    msh, tags = md.mesh, md.facet_tags
    P2 = basix.ufl.element("Lagrange", msh.basix_cell(), 2, shape=(2,))
    P1 = basix.ufl.element("Lagrange", msh.basix_cell(), 1)
    W = fem.functionspace(msh, basix.ufl.mixed_element([P2, P1]))
    V, _ = W.sub(0).collapse()

    # Dirichlet data: inflow on x = 0, zero on the walls and the cylinder.
    msh.topology.create_connectivity(1, 2)
    outer = tags.find(du.OUTER)
    mid = dmesh.compute_midpoints(msh, 1, outer)
    at_inflow = np.isclose(mid[:, 0], 0.0)
    at_wall = np.isclose(mid[:, 1], 0.0) | np.isclose(mid[:, 1], height)
    u_in, u_zero = fem.Function(V), fem.Function(V)
    u_in.interpolate(inflow)
    cylinder = tags.find(du.IMMERSED)
    on_cylinder = fem.locate_dofs_topological((W.sub(0), V), 1, cylinder)
    bcs = [
        fem.dirichletbc(
            u_in, fem.locate_dofs_topological((W.sub(0), V), 1, outer[at_inflow]), W.sub(0)
        ),
        fem.dirichletbc(
            u_zero, fem.locate_dofs_topological((W.sub(0), V), 1, outer[at_wall]), W.sub(0)
        ),
        fem.dirichletbc(u_zero, on_cylinder, W.sub(0)),
    ]

    # The residual (test functions (v, q)) and its derivative: Newton's method.
    w = fem.Function(W)
    u, p = ufl.split(w)
    v, q = ufl.TestFunctions(W)
    nu_c = fem.Constant(msh, PETSc.ScalarType(nu))

    def momentum(v):
        return (
            nu_c * ufl.inner(ufl.grad(u), ufl.grad(v)) + ufl.inner(ufl.grad(u) * u, v)
        ) * ufl.dx - p * ufl.div(v) * ufl.dx

    F = momentum(v) - q * ufl.div(u) * ufl.dx
    problem = NonlinearProblem(
        F,
        w,
        bcs=bcs,
        petsc_options_prefix=f"dfg_{level}_{degree}_",
        petsc_options={
            "snes_type": "newtonls",
            "snes_linesearch_type": "none",
            "snes_atol": 1e-11,
            "snes_rtol": 1e-12,
            "snes_stol": 0.0,
            "snes_max_it": 20,
            "ksp_type": "preonly",
            "pc_type": "lu",
            "pc_factor_mat_solver_type": "mumps",
        },
    )
    problem.solve()
    snes = problem.solver
    reason, iterations = snes.getConvergedReason(), snes.getIterationNumber()
    residual = snes.getFunctionNorm()
    if reason <= 0:
        raise RuntimeError(f"Newton's method failed at level {level}: reason {reason}")

    # The forces from the weak residual with v = v_D, v_L on the cylinder nodes.
    tests = [fem.Function(V), fem.Function(V)]
    for i, test in enumerate(tests):  # unrolled dofs: component i at the dofs = i (mod 2)
        test.x.array[on_cylinder[1][on_cylinder[1] % 2 == i]] = 1.0
    scale = -2.0 / (U_mean**2 * diameter)
    c_D, c_L = (
        scale * comm.allreduce(fem.assemble_scalar(fem.form(momentum(test))), op=MPI.SUM)
        for test in tests
    )
    p_h = w.sub(1).collapse()
    p_front, p_back = point_values(p_h, np.array([[*front, 0.0], [*back, 0.0]]))
    seconds = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
    Q, _ = W.sub(1).collapse()
    n_dofs = sum(S.dofmap.index_map.size_global * S.dofmap.index_map_bs for S in (V, Q))
    row = {
        "level": level,
        "n_cells": msh.topology.index_map(2).size_global,
        "n_dofs": int(n_dofs),
        "geometry_degree": degree,
        "c_D": float(c_D),
        "c_L": float(c_L),
        "delta_p": float(p_front - p_back),
        "newton_iterations": int(iterations),
        "time_s": float(seconds),
    }
    log(
        comm,
        f"{level:5d} {degree:2d} {row['n_cells']:8d} {row['n_dofs']:8d} {c_D:14.10f} "
        f"{c_L:14.10f} {row['delta_p']:14.10f} {iterations:3d} ({residual:.1e}) {seconds:7.1f}",
    )
    return row, w


# -

# ## Figures
#
# The velocity magnitude and the pressure near the cylinder, drawn on the curved cells of
# level 2 (degree 2; coarse enough for the cells to show): the field reaches the exact
# circle (red). Then the relative errors of the three quantities against the number of
# degrees of freedom, for both geometry degrees.


# +
def figures(out: Path, rows: list[dict], shown: fem.Function) -> None:
    """``fields.png`` (collective) and ``convergence.png`` (rank 0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    u_h, p_h = shown.sub(0).collapse(), shown.sub(1).collapse()
    u_h.name, p_h.name = "u", "p"
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8)) if comm.rank == 0 else (None, [None] * 2)
    circle = du.Circle(centre, radius)
    for ax, f, title in ((axes[0], u_h, "velocity magnitude"), (axes[1], p_h, "pressure")):
        plot_function(
            ax,
            f,
            boundary=circle,
            show_mesh=True,
            title=title,
            inset=(0.13, 0.13, 0.27, 0.27),
            inset_loc="upper right",
        )
        if ax is not None:
            ax.set_xlim(0.05, 0.6)
            ax.set_ylim(0.0, height)
            ax.set_aspect("equal")
    save(fig, out / "fields.png")
    if comm.rank != 0:
        return

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    for ax, key in zip(axes, reference):
        for degree, style in ((2, "o-"), (3, "s--")):
            sel = [r for r in rows if r["geometry_degree"] == degree]
            err = [abs(r[key] - reference[key]) / abs(reference[key]) for r in sel]
            ax.loglog([r["n_dofs"] for r in sel], err, style, label=f"geometry degree {degree}")
        ax.set_xlabel("degrees of freedom")
        ax.set_title(f"{key}: |error| / reference")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    save(fig, out / "convergence.png")


# -

# ## What it gives
#
# The full run (geometry degree 2; relative errors against the reference values; seconds
# per level, meshing included, on a 2-core machine shared with other jobs, so noisy):
#
# | level | cells | dofs | $c_D$ | $c_L$ | $\Delta p$ | err $c_D$ | err $c_L$ | err $\Delta p$ | s |
# |---|---|---|---|---|---|---|---|---|---|
# | 0 | 2033 | 9446 | 5.5826431 | -0.00021830 | 0.116706 | +5.6e-04 | -1.0e+00 | -6.9e-03 | 0 |
# | 1 | 5249 | 24173 | 5.5792184 | 0.01030390 | 0.117140 | -5.7e-05 | -3.0e-02 | -3.2e-03 | 1 |
# | 2 | 13126 | 59997 | 5.5795008 | 0.01063156 | 0.117180 | -6.2e-06 | +1.2e-03 | -2.9e-03 | 1 |
# | 3 | 42486 | 193037 | 5.5795391 | 0.01061862 | 0.117600 | +7.0e-07 | -3.1e-05 | +6.8e-04 | 5 |
# | 4 | 155267 | 702414 | 5.5795376 | 0.01061917 | 0.117520 | +4.2e-07 | +2.1e-05 | -3.7e-06 | 21 |
#
# The finest level matches the drag to $4 \cdot 10^{-7}$ and the lift to
# $2 \cdot 10^{-5}$ relative (the check below asks for $10^{-4}$ and $10^{-2}$), with five Newton
# steps at every level; the whole study, both degrees, takes 1 to 2.5 minutes on one
# core here, depending on the load (40 s to 75 s on two). The
# lift, a small difference of large pressure and viscous forces, is the last to settle:
# at level 0 (cells of $R/2$ at the cylinder) even its sign is wrong. Degree-3 geometry
# changes $c_D$ by about $10^{-4}$ relative at level 0, $5 \cdot 10^{-6}$ at level 1 and
# $10^{-9}$ at level 4 (and $c_L$ by less than $10^{-7}$ there): from level 1 on, the
# error of the $P_2/P_1$ solution dominates that of the degree-2 boundary. One level
# more (level 5, $2.7 \cdot 10^6$ degrees of freedom, about six minutes; run once, not
# part of the study) gave errors of $+1.1 \cdot 10^{-7}$, $+1.3 \cdot 10^{-6}$ and
# $-3.0 \cdot 10^{-5}$: drag and lift keep converging to the
# published values; $\Delta p$, a point value of the $P_1$ pressure on the boundary,
# converges more slowly and less regularly.
#
# ## The study


# +
def main(argv: Sequence[str] | None = None) -> dict:
    """Run the study (``argv``: ``--quick``, ``--out DIR``); return the summary."""
    args = demo_options("DFG 2D-1 flow around a cylinder", "out/dfg_benchmark", argv)
    t_start = time.perf_counter()
    log(
        comm,
        f"{'level':>5} {'q':>2} {'cells':>8} {'dofs':>8} {'c_D':>14} {'c_L':>14} "
        f"{'delta_p':>14} {'Newton':>12} {'s':>7}",
    )
    rows, shown = [], None
    for spec in levels(args.quick):
        row, w = solve_level(*spec)
        rows.append(row)
        if spec[:2] == (2, 2):
            shown = w
    assert shown is not None
    summary = {"rows": rows}
    if comm.rank == 0:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    figures(args.out, rows, shown)
    log(comm, "relative errors against the reference values:")
    for r in rows:
        errors = ", ".join(f"{k} {(r[k] - reference[k]) / reference[k]:+.2e}" for k in reference)
        log(comm, f"  level {r['level']}, q = {r['geometry_degree']}: {errors}")
    log(comm, f"total {time.perf_counter() - t_start:.1f} s")
    # Checks: Newton converged quadratically (it raises otherwise), and the finest degree-2
    # level meets the targets: c_D to 1e-4 and c_L to 1e-2 relative (quick mode: the loose
    # bounds of its coarse levels, 1e-4, 3e-2 and 3e-2 with delta_p).
    assert all(r["newton_iterations"] <= 8 for r in rows)
    finest = [r for r in rows if r["geometry_degree"] == 2][-1]
    bounds = (
        {"c_D": 1e-4, "c_L": 3e-2, "delta_p": 3e-2} if args.quick else {"c_D": 1e-4, "c_L": 1e-2}
    )
    for key, bound in bounds.items():
        assert abs(finest[key] - reference[key]) < bound * reference[key], (key, finest)
    return summary


if __name__ == "__main__":
    main()
# -
