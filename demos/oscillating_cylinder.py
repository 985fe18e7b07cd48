# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
# ---

# # A cylinder oscillating in a channel: Navier–Stokes around a body in prescribed motion
#
# A circular cylinder moves back and forth along the axis of a closed channel filled with
# fluid initially at rest: the benchmark of Wan & Turek ("Direct numerical simulation of
# particulate flow via multigrid FEM techniques and the fictitious boundary method", Int.
# J. Numer. Meth. Fluids 51, 2006; "Fictitious boundary and moving mesh methods for the
# numerical simulation of rigid particulate flows", J. Comput. Phys. 222, 2007). The
# cylinder travels two and a half diameters each way, through one background mesh that is
# conformed to it at every time step; cells enter the fluid in front of it and leave it
# behind. The drag and lift coefficients over time are the output.
#
# It illustrates how to
#
# - write incompressible Navier–Stokes on a
#   {py:class}`~dolfinx_universal.moving.domain.MovingDomain` whose outer boundary is the
#   background's (the channel walls) and whose body is immersed,
# - take BDF2 steps in ALE form with
#   {py:class}`~dolfinx_universal.moving.stepping.TimeStepper` (the mesh velocity, the
#   previous solutions carried onto the current nodes, the extrapolated velocity for the
#   convection: one linear solve per step, forms compiled once),
# - impose the body's time-dependent velocity on the immersed boundary with the stepper's
#   Dirichlet data,
# - compute the force on the body by the weak residual at every step,
# - see where the time of a step goes: the domain's update, the nodes' paths and the
#   transfer of the previous solutions, against the linear solve.
#
# Run it with
#
# ```bash
# python demos/oscillating_cylinder.py [--quick] [--out DIR]
# mpirun -n 2 python demos/oscillating_cylinder.py [--quick] [--out DIR]
# ```
#
# (`--quick`: coarse backgrounds, large steps, to t = 1; the full run computes two
# resolutions to t = 8, some tens of minutes on one core). The output folder (default
# `out/oscillating_cylinder`) receives `summary.json` and the figures `forces.png` and
# `flow.png`. `benchmarks/oscillating_cylinder_vs_gmsh.py` compares the same solver on
# body-fitted gmsh meshes (moved by a harmonic extension, or remeshed at every step).
#
# ## The problem
#
# The channel is $[0, 2.2] \times [0, 0.41]$ with no-slip walls all around; the cylinder
# has diameter $D = 0.1$ and centre
#
# $$ c(t) = (1.1 + A \sin(2 \pi f t),\ 0.2), \qquad A = 0.25,\ f = 0.25, $$
#
# so its velocity $U(t) = 2 \pi f A \cos(2 \pi f t)\, e_x$ is largest, $U_{ref} = 2 \pi f A
# \approx 0.393$, at $t = 0$: the cylinder starts impulsively in a fluid at rest. The
# kinematic viscosity is $\nu = 10^{-3}$ ($Re = U_{ref} D / \nu \approx 39$), the density
# 1. The fluid satisfies
#
# $$ \partial_t u + (u \cdot \nabla) u - \nabla \cdot (2 \nu \varepsilon(u)) + \nabla p = 0,
#    \quad \nabla \cdot u = 0 \quad \text{in } \Omega(t), $$
#
# $u = 0$ on the walls and $u = U(t)$ on the cylinder. The force of the fluid on the
# cylinder, $F = (F_D, F_L)$, gives the coefficients
#
# $$ C_D = \frac{2 F_D}{U_{ref}^2 D}, \qquad C_L = \frac{2 F_L}{U_{ref}^2 D}: $$
#
# the fluid resists the motion, so $C_D < 0$ while the cylinder moves to the right.
#
# ## The scheme
#
# Taylor–Hood $P_2/P_1$ on curved cells of degree 2, BDF2 in ALE form, the convection
# linearised with the velocity extrapolated to the new time
# (second order), so that the convecting velocity is $u^* - w$ with the mesh velocity $w$.
# The start is impulsive: the fluid at rest does not meet the cylinder's velocity. The
# first two steps are taken by BDF1, and the state at rest is used by the first only
# (`ts.initialize(u0, start="BDF")`): a BDF2 formula reaching back to it, or the stages of
# a Runge–Kutta start, would differentiate the jump with the wrong sign.
# The force is the weak residual of the momentum equation (Babuška & Miller's
# post-processing, which converges at the order of the energy norm squared for smooth
# solutions): with $v_i$ the field equal to $e_i$ at the velocity nodes on the cylinder
# and zero at all other nodes,
#
# $$ F_i = -\int_{\Omega(t)} \left( (\partial_t u + (u^* - w) \cdot \nabla u) \cdot v_i
#          + 2 \nu \varepsilon(u) : \varepsilon(v_i) - p \nabla \cdot v_i \right) dx. $$

# +
from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from mpi4py import MPI

import basix.ufl
import numpy as np
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh

import dolfinx_universal as du
from dolfinx_universal.demo_support import demo_options, log, write_summary
from dolfinx_universal.moving.problems import MovingLinearProblem
from dolfinx_universal.moving.stepping import TimeStepper

LENGTH, HEIGHT = 2.2, 0.41  # the channel
D = 0.1  # the cylinder's diameter
AMPLITUDE, FREQUENCY = 0.25, 0.25
Y0 = 0.2  # the height of the cylinder's centre
NU = 1e-3
U_REF = 2 * np.pi * FREQUENCY * AMPLITUDE
LU = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
DEGREE = 2  # geometry degree (and velocity degree)
T_END = {True: 1.0, False: 8.0}
RUNS = {  # (finest size at the cylinder's track, time step) of each resolution
    True: [(D / 2, 0.1), (D / 4, 0.05)],
    False: [(D / 4, 0.02), (D / 8, 0.01)],
}
H_COARSE = 0.05  # the background's size far from the track
GRADING = 0.25  # growth of the background's size per unit distance from the track
PIN = (0.0, 0.0)  # the pressure is pinned at the channel's corner
T_START = 0.5
"""The runs are compared after this time: the impulsive start makes the first steps'
forces of the order of 1/dt (the added mass times the velocity's jump), and the start's
transient differs with the time step."""


def centre(t: float) -> np.ndarray:
    """The cylinder's centre at time ``t``."""
    return np.array([1.1 + AMPLITUDE * np.sin(2 * np.pi * FREQUENCY * t), Y0])


def domain(t: float) -> du.Domain:
    """The fluid at time ``t``: the channel (the background's box) minus the cylinder."""
    return du.Domain(None, [du.Circle(centre(t), D / 2)])


def track_size(h_fine: float) -> Callable[[np.ndarray], np.ndarray]:
    """The background's size at points ``x (n, 2)``: ``h_fine`` on the cylinder's track
    (every position it takes, with eight cells around it: the vertices the conforming
    moves and their neighbours), growing by :data:`GRADING` per unit distance from it up
    to :data:`H_COARSE`."""
    x0, x1 = 1.1 - AMPLITUDE, 1.1 + AMPLITUDE
    reach = D / 2 + 8 * h_fine

    def size(x: np.ndarray) -> np.ndarray:
        dx = np.maximum(np.maximum(x0 - x[:, 0], x[:, 0] - x1), 0.0)
        distance = np.maximum(np.hypot(dx, x[:, 1] - Y0) - reach, 0.0)
        return np.minimum(h_fine + GRADING * distance, H_COARSE)

    return size


def navier_stokes(u, p, v, q, convecting) -> Any:
    """The momentum and continuity integrand without the time derivative: ``u`` convected
    by ``convecting`` (the extrapolated velocity minus the mesh velocity)."""
    eps = ufl.sym
    f = ufl.inner(ufl.grad(u) * convecting, v)
    f += 2 * NU * ufl.inner(eps(ufl.grad(u)), eps(ufl.grad(v)))
    return f - p * ufl.div(v) - q * ufl.div(u)


# -

# ## The background and the discrete problem
#
# The background is a graded acute mesh of the channel
# ({py:func}`~dolfinx_universal.backgrounds.graded_tri.graded_mesh`): the channel's walls are
# its boundary; it is fine along the whole track of the cylinder, so that the mesh around
# the cylinder is the same at every position. The pressure is pinned at a corner of the
# channel (the velocity is given on the whole boundary).


# +
class Flow:
    """Taylor–Hood P2/P1 on the moving channel: the forms, the conditions, the forces."""

    def __init__(self, comm: MPI.Comm, h_fine: float, dt: float):
        background = du.graded_mesh(
            comm, [[0.0, 0.0], [LENGTH, HEIGHT]], track_size(h_fine), root_size=HEIGHT / 4
        )
        self.md = du.MovingDomain(background, degree=DEGREE, local_size=True)
        self.md.update(domain(0.0))
        msh = self.md.mesh
        cell = msh.basix_cell()
        P2 = basix.ufl.element("Lagrange", cell, 2, shape=(2,))
        P1 = basix.ufl.element("Lagrange", cell, 1)
        self.W = fem.functionspace(msh, basix.ufl.mixed_element([P2, P1]))
        self.V, _ = self.W.sub(0).collapse()
        self.Q, _ = self.W.sub(1).collapse()
        self.wh = fem.Function(self.W, name="flow")
        self.ts = TimeStepper(self.md, self.W, domain, 0.0, dt, "BDF2")
        tau = 2 * np.pi * FREQUENCY * self.ts.time_variable
        x = ufl.SpatialCoordinate(msh)
        # the cylinder's velocity (x-independent; the x keeps the data a field of x)
        body = ufl.as_vector([U_REF * ufl.cos(tau) + 0 * x[0], 0 * x[1]])
        self.body_velocity = self.ts.dirichlet_data(body, self.V)
        msh.topology.create_connectivity(1, 2)
        walls = dmesh.exterior_facet_indices(msh.topology)
        self.wall_dofs = fem.locate_dofs_topological((self.W.sub(0), self.V), 1, walls)
        self.zero = fem.Function(self.V)
        self._pin()
        self.n_cells = msh.topology.index_map(2).size_global

    def _pin(self) -> None:
        """The pressure pinned to zero at the background vertex at :data:`PIN`."""
        dofs = fem.locate_dofs_geometrical(
            (self.W.sub(1), self.Q),
            lambda y: np.isclose(y[0], PIN[0]) & np.isclose(y[1], PIN[1]),
        )
        self.bc_pressure = fem.dirichletbc(fem.Function(self.Q), dofs, self.W.sub(1))

    def conditions(self) -> list[fem.DirichletBC]:
        on_cylinder = self.md.immersed_dofs((self.W.sub(0), self.V))
        return [
            fem.dirichletbc(self.zero, self.wall_dofs, self.W.sub(0)),
            fem.dirichletbc(self.body_velocity, on_cylinder, self.W.sub(0)),
            self.bc_pressure,
        ]

    def set_force_fields(self, fields: list[fem.Function]) -> None:
        """``e_x`` and ``e_y`` at the velocity nodes on the cylinder, zero elsewhere."""
        blocks = self.md.immersed_dofs(self.V)
        for i, field in enumerate(fields):
            field.x.array[:] = 0.0
            field.x.array[2 * blocks + i] = 1.0

    def n_dofs(self) -> int:
        """The unknowns of the active cells (velocity and pressure), over all ranks."""
        cells = self.md.active_cells
        count = 0
        for space, bs in ((self.V, 2), (self.Q, 1)):
            dofs = np.unique(space.dofmap.list[cells])
            owned = dofs[dofs < space.dofmap.index_map.size_local]
            count += bs * self.md.comm.allreduce(owned.size, op=MPI.SUM)
        return count


# -

# ## The time steps
#
# One form for every step: the stepper's time derivative of the velocity in ALE form (it
# holds the mesh velocity and the carried previous solutions), the convection by the
# extrapolated velocity. The problem keeps its matrix and its sparsity, and solves only
# for the unknowns of the active cells (`active_only`).


# +
def simulate(flow: Flow, t_end: float) -> dict[str, Any]:
    """BDF2 steps from rest to ``t_end``; the force coefficients at every step."""
    md, W, ts = flow.md, flow.W, flow.ts
    (u, p), (v, q) = ufl.TrialFunctions(W), ufl.TestFunctions(W)
    u_star = ufl.split(ts.extrapolation)[0]
    F = md.active * (ufl.inner(ts.time_derivative(u, part=0), v)
                     + navier_stokes(u, p, v, q, u_star)) * ufl.dx  # fmt: skip
    problem = MovingLinearProblem(
        md, ufl.lhs(F), ufl.rhs(F), u=flow.wh, petsc_options_prefix="cylinder_",
        petsc_options=LU, active_only=True,
    )  # fmt: skip
    uh, ph = ufl.split(flow.wh)
    fields = [fem.Function(flow.V) for _ in range(2)]
    forms = [
        fem.form(-md.active * (ufl.inner(ts.time_derivative(uh, part=0), e)
                               + navier_stokes(uh, ph, e, 0, u_star)) * ufl.dx)
        for e in fields
    ]  # fmt: skip
    ts.initialize(flow.wh, start="BDF")  # the fluid at rest; an impulsive start
    scale = 2.0 / (U_REF**2 * D)
    times, c_D, c_L, seconds, moving = [], [], [], [], []
    while ts.time < t_end - 1e-9:
        before = ts.timings["update"] + ts.timings["nodes"] + ts.timings["transfer"]
        t0 = time.perf_counter()
        ts.advance(lambda: problem.solve(flow.conditions()))
        seconds.append(time.perf_counter() - t0)
        moving.append(ts.timings["update"] + ts.timings["nodes"] + ts.timings["transfer"] - before)
        flow.set_force_fields(fields)
        force = [md.comm.allreduce(fem.assemble_scalar(f), op=MPI.SUM) for f in forms]
        times.append(ts.time)
        c_D.append(float(scale * force[0]))
        c_L.append(float(scale * force[1]))
    return {"t": times, "c_D": c_D, "c_L": c_L, "seconds": seconds, "moving_seconds": moving,
            "timings": dict(ts.timings)}  # fmt: skip


# -

# ## Main
#
# Two resolutions, the second with half the background's size and half the time step; the
# finest run's coefficients are the demo's output, their difference to the coarser run's
# an estimate of the coarser run's error.


# +
def main(argv: Sequence[str] | None = None) -> dict:
    args = demo_options("Oscillating cylinder in a channel", "out/oscillating_cylinder", argv)
    comm = MPI.COMM_WORLD
    t_start = time.perf_counter()
    t_end = T_END[args.quick]
    runs, flow = [], None
    for h_fine, dt in RUNS[args.quick]:
        flow = Flow(comm, h_fine, dt)
        run = simulate(flow, t_end)
        steps = len(run["t"])
        timings = {k: comm.allreduce(v, op=MPI.MAX) for k, v in run["timings"].items()}
        total = comm.allreduce(float(np.sum(run["seconds"])), op=MPI.MAX)
        moving = timings["update"] + timings["nodes"] + timings["transfer"]
        run.update(h_fine=h_fine, dt=dt, n_cells=flow.n_cells, n_dofs=flow.n_dofs(),
                   seconds_per_step=total / steps, moving_share=moving / total,
                   timings=timings)  # fmt: skip
        log(comm, f"h {h_fine:.4f}, dt {dt}: {flow.n_cells} cells, {run['n_dofs']} dofs, "
                  f"{steps} steps, {total / steps:.3f} s a step ({100 * moving / total:.1f} % "
                  f"update, paths and transfer); C_D in [{min(run['c_D']):.4f}, "
                  f"{max(run['c_D']):.4f}], C_L in [{min(run['c_L']):.4f}, "
                  f"{max(run['c_L']):.4f}]")  # fmt: skip
        runs.append(run)
    assert flow is not None
    fine, coarse = runs[-1], runs[0]
    stride = round(coarse["dt"] / fine["dt"])
    after = np.array(coarse["t"]) >= T_START - 1e-9
    differences = {
        key: float(np.max(np.abs(np.array(fine[key])[stride - 1 :: stride] - coarse[key])[after]))
        for key in ("c_D", "c_L")
    }
    log(comm, f"largest difference between the two runs for t >= {T_START}: "
              f"C_D {differences['c_D']:.4f}, C_L {differences['c_L']:.4f}")  # fmt: skip
    if comm.rank == 0:
        force_figure(runs, args.out / "forces.png")
    flow_figure(flow, args.out / "flow.png")
    seconds = comm.allreduce(time.perf_counter() - t_start, op=MPI.MAX)
    results = {
        "t": fine["t"],
        "c_D": fine["c_D"],
        "c_L": fine["c_L"],
        "runs": [{k: r[k] for k in RUN_KEYS} for r in runs],
        "coarse_difference": differences,
        "seconds": seconds,
    }
    parameters = {"quick": args.quick, "length": LENGTH, "height": HEIGHT, "D": D,
                  "amplitude": AMPLITUDE, "frequency": FREQUENCY, "nu": NU, "U_ref": U_REF,
                  "t_end": t_end, "degree": DEGREE, "scheme": "BDF2",
                  "runs": RUNS[args.quick], "ranks": comm.size}  # fmt: skip
    path = write_summary(comm, args.out, results, parameters=parameters)
    log(comm, f"wrote {path} ({seconds:.0f} s)")
    return results


RUN_KEYS = ("h_fine", "dt", "n_cells", "n_dofs", "seconds_per_step", "moving_share", "timings",
            "c_D", "c_L")  # fmt: skip
"""What the summary keeps of each run."""


def force_figure(runs: list[dict], path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    for run, style in zip(runs, ("--", "-"), strict=False):
        label = f"$h = D/{D / run['h_fine']:.0f}$, $\\Delta t = {run['dt']}$"
        axes[0].plot(run["t"], run["c_D"], style, lw=1, label=label)
        axes[1].plot(run["t"], run["c_L"], style, lw=1, label=label)
    # the impulsive start's first steps (C_D of the order of 1/dt) outside the frame
    later = [np.array(r["c_D"])[np.array(r["t"]) >= T_START] for r in runs]
    low, high = min(v.min() for v in later), max(v.max() for v in later)
    axes[0].set_ylim(low - 0.15 * (high - low), high + 0.15 * (high - low))
    first = runs[-1]["c_D"][0]
    axes[0].set_title(f"first step: $C_D = {first:.1f}$ (the impulsive start)", fontsize=9)
    axes[0].set_ylabel("$C_D$")
    axes[1].set_ylabel("$C_L$")
    axes[1].set_xlabel("t")
    axes[0].legend()
    for ax in axes:
        ax.grid(alpha=0.3)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def flow_figure(flow: Flow, path) -> None:
    from dolfinx_universal.plotting import plot_function, save

    u = fem.Function(flow.V, name="|u|")
    u.interpolate(flow.wh.sub(0))
    fig, ax = plot_function(None, u, active=flow.md.active,
                            title=f"speed at t = {flow.ts.time:g}")  # fmt: skip
    if flow.md.comm.rank == 0:
        save(fig, path)


# -

# +
if __name__ == "__main__":
    main([] if "ipykernel" in sys.modules else None)
# -
