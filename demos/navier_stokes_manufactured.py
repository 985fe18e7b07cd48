# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
# ---

# # Navier–Stokes with a manufactured solution on a moving domain: orders in space and time
#
# An ellipse turns and sways inside a circular container; the fluid between them is
# governed by the incompressible Navier–Stokes equations with a body force chosen so that
# a known smooth flow is the exact solution. The flow is computed on one fixed background
# mesh conformed to the ellipse at every time step (a universal mesh): cells enter the
# fluid behind the ellipse's tips and leave it ahead of them. Comparing with the exact
# solution measures the orders of convergence of Taylor–Hood elements on curved cells in
# space, and of the ALE time steps of
# {py:class}`~dolfinx_universal.moving.stepping.TimeStepper` with the extrapolated
# (semi-implicit) convection in time.
#
# It illustrates how to
#
# - write the body force and the boundary data of a manufactured solution in UFL from the
#   exact solution and the stepper's time variable (`ts.time_variable`), so that
#   `ufl.diff` gives its time derivative,
# - impose a time-dependent velocity on both parts of the immersed boundary (the moving
#   ellipse and the container) with `ts.dirichlet_data`,
# - handle the pressure of a pure-Dirichlet velocity problem: pinned at one vertex for the
#   solve, compared up to its mean on the fluid domain,
# - measure the orders in space (P2/P1, degree-2 geometry) and in time (BDF1-3).
#
# Run it with
#
# ```bash
# python demos/navier_stokes_manufactured.py [--quick] [--out DIR]
# mpirun -n 2 python demos/navier_stokes_manufactured.py [--quick] [--out DIR]
# ```
#
# (`--quick`: coarse backgrounds and few steps, under a minute; the full run takes about
# ten minutes on one core). The output folder (default `out/navier_stokes_manufactured`)
# receives `summary.json` and the figures `solution.png`, `space.png` and `time.png`.
#
# ## The problem
#
# The container is the disc of radius $R = 1$; the ellipse has semi-axes $a = 0.5$,
# $b = 0.25$, its centre at $(0.1 \sin t, 0)$, and is turned by the angle $\omega t$ with
# $\omega = 1$ (as in the demo `rotating_ellipse.py`). In the fluid $\Omega(t)$,
#
# $$ \partial_t u + (u \cdot \nabla) u - \nabla \cdot (2 \nu \varepsilon(u)) + \nabla p = f,
#    \quad \nabla \cdot u = 0 \quad \text{in } \Omega(t), \qquad u = g \text{ on }
#    \partial \Omega(t), $$
#
# with $\nu = 0.1$, and $f$, $g$ and the initial velocity taken from the exact solution
#
# $$ u = \left(\frac{\partial \psi}{\partial x_2}, -\frac{\partial \psi}{\partial x_1}
#    \right), \quad \psi = \tfrac12 \sin(2 x_1 + t) \cos(1.5 x_2 - 0.7 t), \qquad
#    p = \sin(x_1 - 0.8 t) \cos(1.2 x_2) + 0.5\, x_1 x_2 , $$
#
# divergence-free as the curl of a stream function, with $f = \partial_t u + (u \cdot
# \nabla) u - \nabla \cdot (2 \nu \varepsilon(u)) + \nabla p$ differentiated by UFL. The
# velocity is given on the whole boundary, so the pressure is determined up to a constant:
# the discrete pressure is pinned to zero at a background vertex far from both boundaries
# (as in `rotating_ellipse.py`), and its error is measured after subtracting the mean of
# $p_h - p$ over $\Omega(T)$. The exact velocity is divergence-free in the whole plane, so
# its flux through the discrete boundary vanishes and the pin only absorbs the flux of the
# interpolated boundary data, which is of the order of the interpolation error.
#
# ## The scheme
#
# Taylor–Hood P2/P1 on cells of geometry degree 2. BDF-$p$ in ALE form (the stepper's
# time derivative holds $-\nabla u \cdot w$ with the mesh velocity $w$), with the
# convecting velocity extrapolated from the previous steps to the scheme's order $p$, so
# that each step is one linear solve with the forms compiled once:
#
# $$ \int_{\Omega_h} \left( \frac{\alpha u - h}{\Delta t} + \nabla u \, (u^* - w) \right)
#    \cdot v + 2 \nu\, \varepsilon(u) : \varepsilon(v) - p \nabla \cdot v - q \nabla \cdot
#    u = \int_{\Omega_h} f(t_{n+1}) \cdot v . $$
#
# BDF2 and BDF3 start with one and two steps of ESDIRK3 (given the exact $\partial_t u$ at
# $t = 0$). Within a Runge–Kutta stage the stepper's extrapolated velocity is the previous
# stage's value, of first order only: with it, each start step makes a local error
# $O(\Delta t^2)$, which the run keeps until the viscosity damps it. Measured on the
# background of size 0.04 to $T = 0.1$ with BDF3 and $\Delta t = 0.02, 0.01, 0.005$: the
# velocity's $L^2$ errors are $1.2 \cdot 10^{-4}$, $2.9 \cdot 10^{-5}$, $8.5 \cdot 10^{-6}$
# (order 2) with the extrapolation in the start steps, against $4.95 \cdot 10^{-6}$ for all
# three (the space error) when their convection is implicit. The demo therefore takes it
# implicit: Picard iterations on each stage of the start steps (the stage's solution
# becomes the convecting velocity until it changes by less than $10^{-11}$, five to eight
# iterations); the BDF steps afterwards take the extrapolation, one solve each.

# +
from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from typing import Any

from mpi4py import MPI

import basix.ufl
import numpy as np
import ufl
from dolfinx import fem

import dolfinx_universal as du
from dolfinx_universal.demo_support import demo_options, log, write_summary
from dolfinx_universal.moving.problems import MovingLinearProblem
from dolfinx_universal.moving.stepping import SCHEMES, TimeStepper

R, A, B = 1.0, 0.5, 0.25  # container radius, ellipse semi-axes
OMEGA = 1.0  # the ellipse's rate of turn
SWAY = 0.1  # the amplitude of its centre's motion along x
NU = 0.1
DEGREE = 2  # geometry degree (and velocity degree)
BOX = [[-1.1, -1.1], [1.1, 1.1]]
LU = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
PIN = (0.0, -0.8)  # the pressure is pinned at the background vertex nearest to this point
PICARD_TOL, PICARD_MAX = 1e-11, 30  # the start steps' implicit convection
INTEGRATORS = ("BDF1", "BDF2", "BDF3")


def motion(t: float) -> du.Domain:
    """The fluid at time ``t``: the container minus the ellipse, turned by ``omega t``
    and moved to ``(0.1 sin t, 0)``."""
    ellipse = du.Ellipse([SWAY * np.sin(t), 0.0], A, B, angle=OMEGA * t)
    return du.Domain(du.Circle([0.0, 0.0], R), [ellipse])


def exact(x: Any, t: Any) -> tuple[Any, Any]:
    """The exact velocity (the curl of a stream function) and pressure, as UFL
    expressions of the coordinates and the time."""
    psi = 0.5 * ufl.sin(2 * x[0] + t) * ufl.cos(1.5 * x[1] - 0.7 * t)
    u = ufl.as_vector([ufl.grad(psi)[1], -ufl.grad(psi)[0]])
    p = ufl.sin(x[0] - 0.8 * t) * ufl.cos(1.2 * x[1]) + 0.5 * x[0] * x[1]
    return u, p


# -

# ## The discrete problem
#
# One mixed space holds $(u, p)$; the stepper is given the whole of it and takes the time
# derivative of its velocity part (`part=0`). The velocity is prescribed at the nodes of
# the immersed facets, on the ellipse and on the container alike: `ts.dirichlet_data`
# interpolates the exact velocity at the step's time on the step's nodes. The pressure pin
# is a background vertex that no step moves: it is far from both boundaries.


# +
def eps(u: Any) -> Any:
    return ufl.sym(ufl.grad(u))


def momentum(u: Any, p: Any, v: Any, q: Any, convecting: Any) -> Any:
    """The momentum and continuity integrand without the time derivative."""
    f = ufl.inner(ufl.grad(u) * convecting, v) + 2 * NU * ufl.inner(eps(u), eps(v))
    return f - p * ufl.div(v) - q * ufl.div(u)


def pressure_pin(W: fem.FunctionSpace, Q: fem.FunctionSpace) -> fem.DirichletBC:
    """``p = 0`` at the pressure dof nearest :data:`PIN` (one vertex on all ranks)."""
    comm = W.mesh.comm
    x = Q.tabulate_dof_coordinates()[:, :2]
    n = Q.dofmap.index_map.size_local
    d = np.linalg.norm(x[:n] - np.array(PIN), axis=1)
    best = comm.allreduce((float(d.min()) if n else np.inf, comm.rank), op=MPI.MIN)
    point = comm.bcast(x[np.argmin(d)] if comm.rank == best[1] else None, root=best[1])
    dofs = fem.locate_dofs_geometrical(
        (W.sub(1), Q), lambda y: np.isclose(y[0], point[0]) & np.isclose(y[1], point[1])
    )
    return fem.dirichletbc(fem.Function(Q), dofs, W.sub(1))


def navier_stokes(
    comm: MPI.Comm, h: float, dt: float, T: float, scheme: str, keep: bool = False
) -> dict[str, Any]:
    """Solve to ``T`` with P2/P1 (geometry degree 2) on the background of size ``h``;
    return the errors at ``T`` on ``Omega(T)`` and the timings."""
    md = du.MovingDomain(du.equilateral_mesh(comm, BOX, h), degree=DEGREE)
    md.update(motion(0.0))
    msh = md.mesh
    cell = msh.basix_cell()
    P2 = basix.ufl.element("Lagrange", cell, 2, shape=(2,))
    P1 = basix.ufl.element("Lagrange", cell, 1)
    W = fem.functionspace(msh, basix.ufl.mixed_element([P2, P1]))
    V, V_rows = W.sub(0).collapse()
    Q, Q_rows = W.sub(1).collapse()
    ts = TimeStepper(md, W, motion, 0.0, dt, scheme)
    x, t = ufl.SpatialCoordinate(msh), ts.time_variable
    u_ex, p_ex = exact(x, t)
    du_dt = ufl.diff(u_ex, t)
    f = du_dt + ufl.grad(u_ex) * u_ex - ufl.div(2 * NU * eps(u_ex)) + ufl.grad(p_ex)

    (u, p), (v, q) = ufl.TrialFunctions(W), ufl.TestFunctions(W)
    u_star = ufl.split(ts.extrapolation)[0]
    dx = ufl.dx(metadata={"quadrature_degree": 8})
    F = md.active * (ufl.inner(ts.time_derivative(u, part=0), v)
                     + momentum(u, p, v, q, u_star) - ufl.inner(f, v)) * dx  # fmt: skip
    wh = fem.Function(W, name="flow")
    problem = MovingLinearProblem(
        md, ufl.lhs(F), ufl.rhs(F), u=wh, petsc_options_prefix="nsm_",
        petsc_options=LU, active_only=True,
    )  # fmt: skip
    g = ts.dirichlet_data(u_ex, V)
    pin = pressure_pin(W, Q)
    start_steps = SCHEMES[scheme] - 1  # taken by ESDIRK3
    step = 0
    picard: list[int] = []  # the iterations of each start stage

    def solve() -> fem.Function:
        g_dofs = md.immersed_dofs((W.sub(0), V))  # the ellipse's and the container's
        bcs = [fem.dirichletbc(g, g_dofs, W.sub(0)), pin]
        problem.solve(bcs)
        if step >= start_steps:
            return wh
        iterations = 0  # a Runge–Kutta stage: its convection made implicit
        while iterations < PICARD_MAX:
            iterations += 1
            previous = wh.x.array.copy()
            ts.extrapolation.x.array[:] = previous
            problem.solve(bcs)
            change = comm.allreduce(float(np.abs(wh.x.array - previous).max()), op=MPI.MAX)
            if change < PICARD_TOL:
                break
        picard.append(iterations)
        return wh

    def interpolated(u_expr: Any, p_expr: Any) -> fem.Function:
        """A function of ``W`` with the velocity ``u_expr`` and the pressure ``p_expr``."""
        out = fem.Function(W)
        for expr, space, rows in ((u_expr, V, V_rows), (p_expr, Q, Q_rows)):
            part = fem.Function(space)
            part.interpolate(fem.Expression(expr, space.element.interpolation_points))
            out.x.array[rows] = part.x.array
        return out

    wh.x.array[:] = interpolated(u_ex, p_ex).x.array
    ts.initialize(wh, interpolated(du_dt, ufl.diff(p_ex, t)))
    t0 = time.perf_counter()
    for step in range(int(round(T / dt))):  # noqa: B007  (solve reads it)
        ts.advance(solve)
    seconds = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)

    uh, ph = ufl.split(wh)
    dxe = ufl.dx(metadata={"quadrature_degree": 8})

    def integral(integrand: Any) -> float:
        local = fem.assemble_scalar(fem.form(md.active * integrand * dxe))
        return float(comm.allreduce(local, op=MPI.SUM))

    e = uh - u_ex
    shift = integral(ph - p_ex) / integral(fem.Constant(msh, 1.0))  # the pressures' offset
    result = {
        "h": h,
        "dt": dt,
        "T": T,
        "scheme": scheme,
        "velocity_L2": np.sqrt(integral(ufl.inner(e, e))),
        "velocity_H1": np.sqrt(integral(ufl.inner(ufl.grad(e), ufl.grad(e)))),
        "pressure_L2": np.sqrt(integral((ph - p_ex - shift) ** 2)),
        "divergence_L2": np.sqrt(integral(ufl.div(uh) ** 2)),
        "picard_iterations": picard,
        "cells": msh.topology.index_map(2).size_global,
        "dofs": W.dofmap.index_map.size_global * W.dofmap.index_map_bs,
        "seconds": seconds,
        "timings": {a: comm.allreduce(b, op=MPI.MAX) for a, b in ts.timings.items()},
    }
    if keep:
        result["objects"] = (md, wh, V)
    return result


# -

# ## Studies
#
# *Space*: three backgrounds, each halving the size, with BDF3 and a time step small
# enough that the time error stays far below the space error. *Time*: BDF1-3 on the
# finest background, halving the time step. Rates are those of the finest pair; the time
# rate of an integrator is that of the velocity's $L^2$ error. The time errors are measured
# on a mesh whose own (space) error does not vanish: where an integrator's time error comes
# near it, the error stops falling at the order. With BDF3 at the smallest steps this
# happens to the velocity's $H^1$ error first (the space error of the background of size
# 0.02 is about $2 \cdot 10^{-4}$ in $H^1$, $3 \cdot 10^{-5}$ for the pressure and
# $6 \cdot 10^{-7}$ for the velocity in $L^2$).


# +
def rate(a: float, b: float, ratio: float) -> float:
    """The order between errors ``a`` (coarse) and ``b`` (fine), refined by ``ratio``."""
    return float(np.log(a / b) / np.log(ratio))


SPACE = {True: ((0.08, 0.04), 0.01, 0.1), False: ((0.08, 0.04, 0.02), 0.005, 0.2)}  # h, dt, T
TIME = {True: (0.04, (0.1, 0.05), 0.4), False: (0.02, (0.2, 0.1, 0.05, 0.025), 1.0)}  # h, dt, T
FIELDS = ("velocity_L2", "velocity_H1", "pressure_L2")


def _line(r: dict) -> str:
    return (
        f"u L2 {r['velocity_L2']:.3e}, u H1 {r['velocity_H1']:.3e}, "
        f"p L2 {r['pressure_L2']:.3e} ({r['seconds']:.1f} s)"
    )


def space_study(comm: MPI.Comm, quick: bool) -> tuple[list[dict], list[dict], Any]:
    sizes, dt, T = SPACE[quick]
    rows = [navier_stokes(comm, h, dt, T, "BDF3", keep=h == sizes[-1]) for h in sizes]
    for r in rows:
        log(comm, f"h={r['h']}: {_line(r)}")
    kept = rows[-1].pop("objects")
    a, b = rows[-2], rows[-1]
    rates = [{"k": 2, **{k: rate(a[k], b[k], a["h"] / b["h"]) for k in FIELDS}}]
    log(comm, "space rates: " + ", ".join(f"{k} {rates[0][k]:.2f}" for k in FIELDS))
    return rows, rates, kept


def time_study(comm: MPI.Comm, quick: bool) -> tuple[list[dict], list[dict]]:
    h, dts, T = TIME[quick]
    runs, rates = [], []
    for scheme in INTEGRATORS:
        rows = [navier_stokes(comm, h, dt, T, scheme) for dt in dts]
        for r in rows:
            log(comm, f"{scheme} dt={r['dt']}: {_line(r)}")
        a, b = rows[-2], rows[-1]
        orders = {k: rate(a[k], b[k], a["dt"] / b["dt"]) for k in FIELDS}
        rates.append(
            {
                "integrator": scheme,
                "order": SCHEMES[scheme],
                "rate": orders["velocity_L2"],
                **orders,
            }
        )
        log(comm, f"{scheme}: velocity L2 rate {rates[-1]['rate']:.2f}")
        runs += rows
    return runs, rates


# -

# ## Figures


# +
def solution_figure(kept: Any, T: float, path) -> None:
    """The speed at the final time on the finest background of the space study."""
    from dolfinx_universal.plotting import boundary_polyline, plot_function, save

    md, wh, V = kept
    speed = fem.Function(V, name="|u|")
    speed.interpolate(wh.sub(0))
    fig, ax = plot_function(
        None, speed, active=md.active, label="$|u_h|$", title=f"velocity at t = {T}"
    )
    if md.comm.rank == 0:
        for t in np.linspace(0.0, T, 3)[:-1]:
            line = boundary_polyline(motion(t).bodies[0])
            ax.plot(line[:, 0], line[:, 1], "--", color="0.5", lw=0.8)
        save(fig, path)


def space_figure(runs: list[dict], path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    hs = np.array([r["h"] for r in runs])
    for key, label, marker, slope in (
        ("velocity_L2", "$u$, $L^2$", "o-", 3),
        ("velocity_H1", "$u$, $H^1$", "s-", 2),
        ("pressure_L2", "$p$, $L^2$", "^-", 2),
    ):
        e = np.array([r[key] for r in runs])
        (line,) = ax.loglog(hs, e, marker, label=label)
        ax.loglog(
            hs, e[-1] * (hs / hs[-1]) ** slope, ":", color=line.get_color(), label=f"slope {slope}"
        )
    ax.set_xlabel("background size h")
    ax.set_ylabel("error at T")
    ax.set_title("P2/P1, q = 2, BDF3")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def time_figure(runs: list[dict], path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, key, title in zip(
        axes, ("velocity_L2", "pressure_L2"), ("velocity, $L^2$", "pressure, $L^2$"), strict=True
    ):
        for scheme in INTEGRATORS:
            rows = [r for r in runs if r["scheme"] == scheme]
            dts = np.array([r["dt"] for r in rows])
            e = np.array([r[key] for r in rows])
            (line,) = ax.loglog(dts, e, "o-", label=scheme)
            slope = SCHEMES[scheme]
            ax.loglog(
                dts,
                e[0] * (dts / dts[0]) ** slope,
                ":",
                color=line.get_color(),
                label=f"slope {slope}",
            )
        ax.set_xlabel("time step")
        ax.set_ylabel("error at T")
        ax.set_title(title)
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
    args = demo_options(
        "Navier-Stokes with a manufactured solution on a moving domain",
        "out/navier_stokes_manufactured",
        argv,
    )
    comm = MPI.COMM_WORLD
    t_start = time.perf_counter()
    space_runs, space_rates, kept = space_study(comm, args.quick)
    solution_figure(kept, SPACE[args.quick][2], args.out / "solution.png")
    del kept
    time_runs, time_rates = time_study(comm, args.quick)
    if comm.rank == 0:
        space_figure(space_runs, args.out / "space.png")
        time_figure(time_runs, args.out / "time.png")
    seconds = comm.allreduce(time.perf_counter() - t_start, op=MPI.MAX)
    results = {
        "space_rates": space_rates,
        "time_rates": time_rates,
        "space_runs": space_runs,
        "time_runs": time_runs,
        "seconds": seconds,
    }
    parameters = {
        "quick": args.quick,
        "R": R,
        "a": A,
        "b": B,
        "omega": OMEGA,
        "sway": SWAY,
        "nu": NU,
        "degree": DEGREE,
        "box": BOX,
        "space": SPACE[args.quick],
        "time": TIME[args.quick],
        "integrators": list(INTEGRATORS),
        "pressure_pin": PIN,
    }
    reference = {
        "psi": "0.5 sin(2 x + t) cos(1.5 y - 0.7 t)",
        "u": "(d psi / dy, -d psi / dx)",
        "p": "sin(x - 0.8 t) cos(1.2 y) + 0.5 x y (up to a constant)",
        "space_orders": {"velocity_L2": 3, "velocity_H1": 2, "pressure_L2": 2},
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
