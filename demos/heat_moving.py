# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
# ---

# # The heat equation on moving domains: high order in space and time
#
# The heat equation is solved on domains that translate and rotate through one fixed
# background mesh: an ellipse in 2D, a ball and an ellipsoid in 3D. At every time step
# the background is conformed to the domain of that step by moving a few vertices near its
# boundary (a universal mesh, Rangarajan & Lew 2014); cells enter the domain at its front
# and leave it at its back. The time step between two such meshes is the ALE scheme of
# {py:class}`dolfinx_universal.moving.stepping.TimeStepper` (after Gawlik & Lew, "High-order
# finite element methods for moving boundary problems with prescribed boundary
# evolution", CMAME 2014): each step keeps its triangulation fixed over the integrator's
# stencil, the nodes follow smooth paths in time along which the time derivative is taken,
# and the previous solutions are carried onto those paths, extended into the cells that
# have just entered.
#
# It illustrates how to
#
# - write a time-dependent problem on a
#   {py:class}`~dolfinx_universal.moving.domain.MovingDomain` in ordinary UFL with the
#   quantities the stepper provides: the time derivative in ALE form
#   (`ts.time_derivative(u)`, which holds the mesh velocity `ts.w`, the time step `ts.dt`
#   and the previous solutions on the current nodes `ts.history`), the time `ts.t`, and the
#   cell indicator `md.active`; the forms are compiled once for every step,
# - impose Dirichlet, Neumann and Robin conditions on the moving boundary,
# - take steps with BDF of orders 1-3 or the L-stable ESDIRK of order 3,
# - measure the orders in space and time.
#
# Run it with
#
# ```bash
# python demos/heat_moving.py [--quick] [--out DIR]
# mpirun -n 2 python demos/heat_moving.py [--quick] [--out DIR]
# ```
#
# (`--quick`: coarse meshes and few steps, about a minute; the full run takes about 25
# minutes on one core). The output folder (default `out/heat_moving`) receives
# `summary.json` and the figures `solution.png`, `space.png` and `time.png`.
#
# ## The problem
#
# In the domain $\Omega(t)$,
#
# $$ \partial_t u - \Delta u = f \quad \text{in } \Omega(t), \qquad
#    u(\cdot, 0) = u_0, $$
#
# with one of the conditions on the moving boundary $\Gamma(t)$
#
# $$ u = g \quad \text{(Dirichlet)}, \qquad \partial_n u = g_N \quad \text{(Neumann)},
#    \qquad \partial_n u + \beta u = g_R \quad \text{(Robin, } \beta = 2), $$
#
# and $f$, $u_0$, $g$, $g_N$, $g_R$ taken from the exact solution
#
# $$ u(x, t) = \sin(2 x_1 + t) \cos(1.5 x_2 - 0.7 t) + 0.3\, x_1 x_2 $$
#
# (in 3D times $\cos x_3$, plus $0.3\, x_1 x_3$ instead of $0.3\, x_1 x_2$). The domains:
#
# - **ellipse** (2D): semi-axes $0.55, 0.35$, centre $(0.3 \sin t, 0.1 t)$, turned by the
#   angle $0.8 t$, on the equilateral background of $[-1, 1] \times [-0.9, 1]$;
# - **ball** (3D): radius $0.55$, centre $(0.25 \sin t, 0.1 t, 0)$;
# - **ellipsoid** (3D): semi-axes $(0.65, 0.45, 0.35)$ turning about $x_3$ at $0.8$ rad per
#   unit time; both on the A15 background of $[-0.9, 0.9]^2 \times [-0.75, 0.75]$.
#
# ## The scheme
#
# Along a path $x(t)$ of a node, $\frac{d}{dt} u(x(t), t) = \partial_t u + w \cdot \nabla u$
# with the mesh velocity $w = \dot x$. The step to $t_{n+1}$ conforms the background to
# $\Gamma(t_{n+1})$; the nodes that this triangulation takes for the earlier positions of
# $\Gamma$ ({py:meth}`~dolfinx_universal.moving.domain.MovingDomain.nodes_at`) are the
# paths, smooth in time because the triangulation does not change along them. The
# integrator's difference quotient of the dof values along them is
# $\partial_t u + w \cdot \nabla u$, so the form takes
#
# $$ \partial_t u \approx \frac{\alpha u - h}{\Delta t} - \nabla u \cdot w $$
#
# with the coefficient $\alpha$ and the function $h$ (the previous solutions carried onto
# the paths, combined) set by the integrator; $w$ is the same difference quotient of the
# nodes. Where the paths leave the old nodes (vertices that start or stop being snapped
# or relocated, the relaxation's moves, cells entering the domain), the old solution is
# evaluated at the paths' points, continued by the polynomial of the nearest old cell
# outside the old domain. The mesh velocity, the carried solutions and the data of a
# Dirichlet condition are exact to the order of the integrator, so the scheme keeps it.
# Runge–Kutta stages take the Dirichlet data that the method gives the data's own ODE
# along the paths ({py:meth}`~dolfinx_universal.moving.stepping.TimeStepper.dirichlet_data`).

# +
from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from mpi4py import MPI

import numpy as np
import ufl
from dolfinx import fem

import dolfinx_universal as du
from dolfinx_universal.demo_support import demo_options, log, write_summary
from dolfinx_universal.moving.problems import MovingLinearProblem
from dolfinx_universal.moving.stepping import SCHEMES, TimeStepper

BETA = 2.0  # the Robin coefficient
LU = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
INTEGRATORS = [s for s in SCHEMES if s != "SDIRK3"]  # SDIRK3 starts the BDFs


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


MOTIONS: dict[str, Callable[[float], du.Domain]] = {
    "ellipse": lambda t: du.Domain(
        du.Ellipse([0.3 * np.sin(t), 0.1 * t], 0.55, 0.35, angle=0.8 * t)
    ),
    "ball": lambda t: du.Domain(du.Sphere([0.25 * np.sin(t), 0.1 * t, 0.0], 0.55)),
    "ellipsoid": lambda t: du.Domain(
        du.Ellipsoid([0.0, 0.0, 0.0], [0.65, 0.45, 0.35], rotation=rotation_z(0.8 * t))
    ),
}
BOXES = {2: [[-1.0, -0.9], [1.0, 1.0]], 3: [[-0.9, -0.9, -0.75], [0.9, 0.9, 0.75]]}


def background(comm: MPI.Comm, dim: int, h: float):
    """The fixed background: equilateral triangles (2D) or the A15 lattice (3D)."""
    if dim == 2:
        return du.equilateral_mesh(comm, BOXES[2], h)
    return du.a15_mesh(comm, BOXES[3], h)


def exact(x: Any, t: Any, dim: int) -> Any:
    """The exact solution as a UFL expression of the coordinates and the time."""
    u = ufl.sin(2 * x[0] + t) * ufl.cos(1.5 * x[1] - 0.7 * t)
    if dim == 2:
        return u + 0.3 * x[0] * x[1]
    return u * ufl.cos(x[2]) + 0.3 * x[0] * x[2]


# -

# ## One run
#
# The problem is written once in UFL; the stepper's `solve` callback assembles it into
# the same matrix at every stage (the dofs outside the domain are fixed by
# {py:class}`~dolfinx_universal.moving.problems.MovingLinearProblem`) with the Dirichlet
# condition on the dofs of the immersed facets. The errors are measured at the final
# time on $\Omega(T)$.


# +
def heat(
    comm: MPI.Comm,
    case: str,
    h: float,
    k: int,
    dt: float,
    T: float,
    scheme: str,
    bc: str = "dirichlet",
    relax: bool = True,
    keep: bool = False,
) -> dict[str, Any]:
    """Solve the heat equation on ``case`` to ``T`` with P``k`` (geometry degree ``k``)
    on the background of size ``h``; return the errors at ``T`` and the timings."""
    motion = MOTIONS[case]
    dim = 2 if case == "ellipse" else 3
    md = du.MovingDomain(background(comm, dim, h), degree=k, relax=relax)
    md.update(motion(0.0))
    V = fem.functionspace(md.mesh, ("Lagrange", k))
    ts = TimeStepper(md, V, motion, 0.0, dt, scheme)
    x = ufl.SpatialCoordinate(md.mesh)
    u_ex = exact(x, ts.time_variable, dim)
    f = ufl.diff(u_ex, ts.time_variable) - ufl.div(ufl.grad(u_ex))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    F = md.active * (ts.time_derivative(u) * v + ufl.inner(ufl.grad(u), ufl.grad(v))) * ufl.dx
    F -= md.active * f * v * ufl.dx
    n = ufl.FacetNormal(md.mesh)
    flux = ufl.dot(ufl.grad(u_ex), n)
    if bc == "neumann":
        F -= md.immersed_integral(lambda s: flux(s) * v(s))
    elif bc == "robin":
        F += md.immersed_integral(lambda s: (BETA * (u(s) - u_ex(s)) - flux(s)) * v(s))
    uh = fem.Function(V, name="u")
    problem = MovingLinearProblem(
        md,
        ufl.lhs(F),
        ufl.rhs(F),
        u=uh,
        petsc_options_prefix=f"heat_{case}_",
        petsc_options=LU,
        active_only=True,
        restrict_to_active=True,
    )
    g = ts.dirichlet_data(u_ex)

    def solve() -> fem.Function:
        if bc != "dirichlet":
            return problem.solve()
        return problem.solve([fem.dirichletbc(g, md.immersed_dofs(V))])

    u0 = fem.Function(V)
    u0.interpolate(fem.Expression(u_ex, V.element.interpolation_points))
    ts.initialize(u0, ufl.diff(u_ex, ts.time_variable))  # du/dt(0) starts ESDIRK3
    t0 = time.perf_counter()
    for _ in range(int(round(T / dt))):
        ts.advance(solve)
    seconds = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
    e = uh - u_ex
    dx = ufl.dx(metadata={"quadrature_degree": 2 * k + 4})

    def norm(integrand: Any) -> float:
        local = fem.assemble_scalar(fem.form(md.active * integrand * dx))
        return float(np.sqrt(comm.allreduce(local, op=MPI.SUM)))

    result = {
        "case": case,
        "dim": dim,
        "k": k,
        "h": h,
        "dt": dt,
        "T": T,
        "scheme": scheme,
        "bc": bc,
        "relax": relax,
        "L2": norm(e**2),
        "H1": norm(ufl.inner(ufl.grad(e), ufl.grad(e))),
        "cells": md.mesh.topology.index_map(dim).size_global,
        "dofs": V.dofmap.index_map.size_global,
        "seconds": seconds,
        "timings": {a: comm.allreduce(b, op=MPI.MAX) for a, b in ts.timings.items()},
    }
    if keep:
        result["objects"] = (md, uh)
    return result


# -

# ## Studies
#
# *Space*: P1-P3 with geometry of the same degree ($q = k$) on three backgrounds each
# halving the size (2D; in 3D the sizes $0.2, 0.15, 0.1$), with BDF3 and a time step small
# enough that the time error is far below the space error. *Time*: each integrator with
# P3 on a fine background, halving the time step. Rates are those of the finest pair.


# +
def rate(a: float, b: float, ratio: float) -> float:
    """The order between errors ``a`` (coarse) and ``b`` (fine), refined by ``ratio``."""
    return float(np.log(a / b) / np.log(ratio))


SPACE = {  # (case, sizes, dt, T) per mode: quick, full
    True: [("ellipse", (0.2, 0.1), 0.02, 0.1), ("ball", (0.4, 0.3), 0.025, 0.05)],
    False: [("ellipse", (0.1, 0.05, 0.025), 0.005, 0.2), ("ball", (0.2, 0.15, 0.1), 0.01, 0.05)],
}
SPACE_DEGREES = {True: {2: (1, 2, 3), 3: (1, 2)}, False: {2: (1, 2, 3), 3: (1, 2, 3)}}
TIME = {  # (case, h, k, dts, T)
    True: [("ellipse", 0.1, 2, (0.2, 0.1), 0.4), ("ellipsoid", 0.4, 2, (0.2, 0.1), 0.4)],
    False: [
        ("ellipse", 0.025, 3, (0.2, 0.1, 0.05, 0.025), 1.0),
        ("ellipsoid", 0.15, 3, (0.2, 0.1, 0.05), 0.6),
    ],
}


def space_study(comm: MPI.Comm, quick: bool) -> tuple[list[dict], list[dict]]:
    runs, rates = [], []
    for case, sizes, dt, T in SPACE[quick]:
        dim = 2 if case == "ellipse" else 3
        for k in SPACE_DEGREES[quick][dim]:
            rows = [heat(comm, case, h, k, dt, T, "BDF3") for h in sizes]
            for r in rows:
                log(
                    comm,
                    f"{case} P{k} h={r['h']}: L2 {r['L2']:.3e} H1 {r['H1']:.3e} "
                    f"({r['seconds']:.1f} s)",
                )
            a, b = rows[-2], rows[-1]
            ratio = a["h"] / b["h"]
            rates.append(
                {
                    "dim": dim,
                    "case": case,
                    "k": k,
                    "L2": rate(a["L2"], b["L2"], ratio),
                    "H1": rate(a["H1"], b["H1"], ratio),
                }
            )
            runs += rows
    return runs, rates


def time_study(comm: MPI.Comm, quick: bool) -> tuple[list[dict], list[dict]]:
    runs, rates = [], []
    for case, h, k, dts, T in TIME[quick]:
        dim = 2 if case == "ellipse" else 3
        for scheme in INTEGRATORS:
            rows = [heat(comm, case, h, k, dt, T, scheme) for dt in dts]
            for r in rows:
                log(comm, f"{case} {scheme} dt={r['dt']}: L2 {r['L2']:.3e} ({r['seconds']:.1f} s)")
            a, b = rows[-2], rows[-1]
            rates.append(
                {
                    "dim": dim,
                    "case": case,
                    "integrator": scheme,
                    "order": SCHEMES[scheme],
                    "rate": rate(a["L2"], b["L2"], a["dt"] / b["dt"]),
                }
            )
            runs += rows
    return runs, rates


def boundary_study(comm: MPI.Comm, quick: bool) -> list[dict]:
    """Neumann and Robin conditions: P2 on the ellipse, space rates (BDF3)."""
    sizes = (0.2, 0.1) if quick else (0.1, 0.05, 0.025)
    dt, T = (0.02, 0.1) if quick else (0.005, 0.2)
    out = []
    for bc in ("dirichlet", "neumann", "robin"):
        rows = [heat(comm, "ellipse", h, 2, dt, T, "BDF3", bc=bc) for h in sizes]
        a, b = rows[-2], rows[-1]
        out.append(
            {
                "bc": bc,
                "L2": [r["L2"] for r in rows],
                "H1": [r["H1"] for r in rows],
                "L2_rate": rate(a["L2"], b["L2"], 2.0),
                "H1_rate": rate(a["H1"], b["H1"], 2.0),
            }
        )
        log(comm, f"{bc}: L2 rate {out[-1]['L2_rate']:.2f}, H1 rate {out[-1]['H1_rate']:.2f}")
    return out


def relaxation_study(comm: MPI.Comm, quick: bool) -> list[dict]:
    """What the relaxation's moves cost: P2 on the ellipse with and without it."""
    sizes = (0.1,) if quick else (0.1, 0.05, 0.025)
    dt, T = (0.02, 0.1) if quick else (0.005, 0.2)
    out = []
    for relax in (True, False):
        for h in sizes:
            r = heat(comm, "ellipse", h, 2, dt, T, "BDF3", relax=relax)
            out.append({k: r[k] for k in ("relax", "h", "L2", "H1", "seconds", "timings")})
            log(
                comm,
                f"relax={relax} h={h}: L2 {r['L2']:.3e}, transfer {r['timings']['transfer']:.2f} s",
            )
    return out


# -

# ## Figures


# +
def solution_figure(comm: MPI.Comm, quick: bool, path) -> None:
    """The solution at the final time on the conformed mesh, with the domain's earlier
    positions."""
    from dolfinx_universal.plotting import boundary_polyline, plot_function, save

    T = 1.0
    r = heat(comm, "ellipse", 0.1 if quick else 0.05, 2, 0.05, T, "BDF2", keep=True)
    md, uh = r["objects"]
    fig, ax = plot_function(
        None,
        uh,
        active=md.active,
        show_mesh=True,
        label="$u_h(T)$",
        title=f"P2 on the ellipse at t = {T}",
    )
    if comm.rank == 0:
        for t in np.linspace(0.0, T, 5)[:-1]:
            line = boundary_polyline(MOTIONS["ellipse"](t).container)
            ax.plot(line[:, 0], line[:, 1], "--", color="0.5", lw=0.8)
        ax.set_xlim(*np.array(BOXES[2])[:, 0])
        ax.set_ylim(*np.array(BOXES[2])[:, 1])
        save(fig, path)


def space_figure(runs: list[dict], path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, dim in zip(axes, (2, 3), strict=True):
        for k in (1, 2, 3):
            rows = [r for r in runs if r["dim"] == dim and r["k"] == k]
            if not rows:
                continue
            hs = [r["h"] for r in rows]
            ax.loglog(hs, [r["L2"] for r in rows], "o-", label=f"P{k} $L^2$")
            ax.loglog(hs, [r["H1"] for r in rows], "s--", label=f"P{k} $H^1$")
        ax.set_xlabel("background size h")
        ax.set_ylabel("error at T")
        ax.set_title("ellipse (2D)" if dim == 2 else "ball (3D)")
        ax.legend(fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def time_figure(runs: list[dict], path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, case in zip(axes, ("ellipse", "ellipsoid"), strict=True):
        for scheme in INTEGRATORS:
            rows = [r for r in runs if r["case"] == case and r["scheme"] == scheme]
            ax.loglog([r["dt"] for r in rows], [r["L2"] for r in rows], "o-", label=scheme)
        ax.set_xlabel("time step")
        ax.set_ylabel("$L^2$ error at T")
        ax.set_title(f"{case}, P3")
        ax.legend(fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


# -

# ## Main


# +
def main(argv: Sequence[str] | None = None) -> dict:
    """Run the demo (``argv``: ``--quick``, ``--out DIR``); return the summary's results."""
    args = demo_options("The heat equation on moving domains", "out/heat_moving", argv)
    comm = MPI.COMM_WORLD
    t_start = time.perf_counter()
    space_runs, space_rates = space_study(comm, args.quick)
    time_runs, time_rates = time_study(comm, args.quick)
    boundary = boundary_study(comm, args.quick)
    relaxation = relaxation_study(comm, args.quick)
    solution_figure(comm, args.quick, args.out / "solution.png")
    if comm.rank == 0:
        space_figure(space_runs, args.out / "space.png")
        time_figure(time_runs, args.out / "time.png")
    seconds = comm.allreduce(time.perf_counter() - t_start, op=MPI.MAX)
    results = {
        "space_rates": space_rates,
        "time_rates": time_rates,
        "boundary_conditions": boundary,
        "relaxation": relaxation,
        "space_runs": space_runs,
        "time_runs": time_runs,
        "seconds": seconds,
    }
    parameters = {
        "quick": args.quick,
        "space": SPACE[args.quick],
        "space_degrees": {str(d): list(v) for d, v in SPACE_DEGREES[args.quick].items()},
        "time": TIME[args.quick],
        "integrators": INTEGRATORS,
        "robin_beta": BETA,
        "boxes": BOXES,
    }
    reference = {
        "exact_2d": "sin(2 x + t) cos(1.5 y - 0.7 t) + 0.3 x y",
        "exact_3d": "sin(2 x + t) cos(1.5 y - 0.7 t) cos(z) + 0.3 x z",
        "space_orders": "L2: k + 1, H1: k",
        "time_orders": {s: SCHEMES[s] for s in INTEGRATORS},
    }
    path = write_summary(comm, args.out, results, parameters=parameters, reference=reference)
    log(comm, f"wrote {path} ({seconds:.0f} s)")
    return results


# -

# +
if __name__ == "__main__":
    main([] if "ipykernel" in sys.modules else None)
# -
