# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
# ---

# # Navier–Stokes flow around a rotating ellipse: a steady flow seen from a moving mesh
#
# An ellipse turns at a constant rate inside a circular container filled with a viscous
# fluid. In the frame that turns with the ellipse the flow is steady, so the torque on the
# ellipse is constant in time. Computed in the fixed frame on one background mesh
# conformed to the ellipse at every time step, with the ALE time steps of
# {py:class}`~dolfinx_universal.moving.stepping.TimeStepper`, that torque must stay constant
# over a full turn while the mesh around the ellipse changes at every step, and equal the
# torque of the steady flow computed in the rotating frame on a fixed mesh.
#
# It illustrates how to
#
# - write incompressible Navier–Stokes (Taylor–Hood, curved cells of degree 2) on a
#   {py:class}`~dolfinx_universal.moving.domain.MovingDomain` with the stepper's ALE time
#   derivative of the velocity and its extrapolated velocity for the convection (one linear
#   solve per step, the forms compiled once),
# - impose the rigid velocity of the body and a fixed container on the immersed boundary,
# - compute the torque by the weak residual (reaction) against the rotation field,
# - solve the steady problem in the rotating frame (Coriolis force, Picard iterations).
#
# Run it with
#
# ```bash
# python demos/rotating_ellipse.py [--quick] [--out DIR]
# mpirun -n 2 python demos/rotating_ellipse.py [--quick] [--out DIR]
# ```
#
# (`--quick`: a coarse background and a quarter turn; the full run, a fine background and
# a full turn, takes some minutes on one core). The output folder (default
# `out/rotating_ellipse`) receives `summary.json` and the figures `torque.png` and
# `flow.png`.
#
# ## The problem
#
# The container is the disc of radius $R = 1$; the ellipse has semi-axes $a = 0.5$, $b =
# 0.25$, its centre at the container's centre, and turns at $\omega = 1$; the kinematic
# viscosity is $\nu = 0.0125$, so that $Re = \omega a^2 / \nu = 20$. In the fixed frame,
#
# $$ \partial_t u + (u \cdot \nabla) u - \nabla \cdot (2 \nu \varepsilon(u)) + \nabla p = 0,
#    \quad \nabla \cdot u = 0 \quad \text{in } \Omega(t), $$
#
# with $u = \omega \times x$ on the ellipse and $u = 0$ on the container. In the frame
# turning with the ellipse, the velocity $u' = u - \omega \times x$ is steady:
#
# $$ (u' \cdot \nabla) u' + 2 \omega \times u' - \nabla \cdot (2 \nu \varepsilon(u')) + \nabla
#    p' = 0, \quad \nabla \cdot u' = 0, $$
#
# with $u' = 0$ on the ellipse and $u' = -\omega \times x$ on the container (the
# centrifugal force is a gradient, absorbed in $p'$). The viscous stresses of $u$ and $u'$
# are the same (a rigid rotation has no strain), and the pressures differ by a function of
# $|x|$ whose torque on the ellipse vanishes: the torques are equal. The moving computation
# starts from the steady solution (turned into the fixed frame) on the same background.
#
# ## The scheme
#
# BDF2 in ALE form: the convection is linearised with the extrapolated velocity $u^*$
# (second order), the mesh velocity $w$ enters through the stepper's time derivative, so
# the convecting velocity is $u^* - w$. The torque is the weak residual of the momentum
# equation against the rotation field $\omega \times x$ taken at the ellipse's nodes
# (zero elsewhere).

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
from dolfinx_universal.moving.stepping import TimeStepper

R, A, B = 1.0, 0.5, 0.25  # container radius, ellipse semi-axes
OMEGA = 1.0
NU = 0.0125
DEGREE = 2  # geometry degree (and velocity degree)
LU = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
H = {True: 0.08, False: 0.02}  # background size
STEPS = {
    True: (40, 10),
    False: (200, 200),
}  # (steps per turn, steps computed)  # (steps per turn, steps computed)
PIN = (0.0, -0.8)  # the pressure is pinned at the background vertex nearest to this point


def domain(t: float) -> du.Domain:
    """The fluid at time ``t``: the container minus the ellipse turned by ``omega t``."""
    return du.Domain(du.Circle([0.0, 0.0], R), [du.Ellipse([0.0, 0.0], A, B, angle=OMEGA * t)])


# -

# ## The discrete problem


# +
class Flow:
    """Taylor–Hood P2/P1 on the moving domain: the forms, the conditions, the torque."""

    def __init__(self, comm: MPI.Comm, h: float, dt: float):
        self.md = du.MovingDomain(
            du.equilateral_mesh(comm, [[-1.1, -1.1], [1.1, 1.1]], h), degree=DEGREE
        )
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
        x = ufl.SpatialCoordinate(msh)
        self.x = x
        inner_part = ufl.lt(ufl.dot(x, x), (0.5 * (A + R)) ** 2)  # the ellipse's nodes
        rotation = OMEGA * ufl.as_vector([-x[1], x[0]])
        self.g = self.ts.dirichlet_data(ufl.conditional(inner_part, 1.0, 0.0) * rotation, self.V)
        self._pin()

    def eps(self, u):
        return ufl.sym(ufl.grad(u))

    def momentum(self, u, p, v, q, convecting, rotating: bool = False) -> Any:
        """The momentum and continuity integrand, without the time derivative (and with
        the Coriolis force in the rotating frame)."""
        f = ufl.inner(ufl.grad(u) * convecting, v) + 2 * NU * ufl.inner(self.eps(u), self.eps(v))
        f += -p * ufl.div(v) - q * ufl.div(u)
        if rotating:
            f += 2 * OMEGA * ufl.inner(ufl.as_vector([-u[1], u[0]]), v)
        return f

    def _pin(self) -> None:
        """The pressure pinned to zero at the background vertex nearest :data:`PIN` (far
        from Gamma at every step, so never moved)."""
        comm = self.md.comm
        x = self.Q.tabulate_dof_coordinates()[:, :2]
        n = self.Q.dofmap.index_map.size_local
        d = np.linalg.norm(x[:n] - np.array(PIN), axis=1)
        local = (float(d.min()), comm.rank) if n else (np.inf, comm.rank)
        best = comm.allreduce(local, op=MPI.MIN)
        point = comm.bcast(x[np.argmin(d)] if comm.rank == best[1] else None, root=best[1])
        dofs = fem.locate_dofs_geometrical(
            (self.W.sub(1), self.Q),
            lambda y: np.isclose(y[0], point[0]) & np.isclose(y[1], point[1]),
        )
        self.bc_pressure = fem.dirichletbc(fem.Function(self.Q), dofs, self.W.sub(1))

    def conditions(self, data: fem.Function) -> list[fem.DirichletBC]:
        dofs = self.md.immersed_dofs((self.W.sub(0), self.V))
        return [fem.dirichletbc(data, dofs, self.W.sub(0)), self.bc_pressure]

    def set_rotation_field(self, t: fem.Function) -> None:
        """The rotation field at the velocity nodes on the ellipse, zero elsewhere."""
        t.x.array[:] = 0.0
        blocks = self.md.immersed_dofs(self.V)
        x = self.V.tabulate_dof_coordinates()[blocks, :2]
        on_ellipse = np.einsum("nd,nd->n", x, x) < (0.5 * (A + R)) ** 2
        b = blocks[on_ellipse]
        values = t.x.array.reshape(-1, 2)
        values[b, 0], values[b, 1] = -x[on_ellipse, 1], x[on_ellipse, 0]


# -

# ## The steady flow in the rotating frame


# +
def steady(flow: Flow, tol: float = 1e-11, max_iter: int = 60) -> tuple[float, int]:
    """Picard iterations for the steady rotating-frame flow on the mesh at t = 0; the
    result (turned into the fixed frame) in ``flow.wh``. Returns its torque and the
    number of iterations."""
    md, W = flow.md, flow.W
    (u, p), (v, q) = ufl.TrialFunctions(W), ufl.TestFunctions(W)
    state = fem.Function(W)
    u_old = ufl.split(state)[0]
    a = md.active * flow.momentum(u, p, v, q, u_old, rotating=True) * ufl.dx
    zero = fem.Constant(md.mesh, np.zeros(2))
    L = md.active * ufl.inner(zero, v) * ufl.dx
    problem = MovingLinearProblem(
        md, a, L, u=state, petsc_options_prefix="steady_", petsc_options=LU, active_only=True
    )

    def wall_velocity(x: np.ndarray) -> np.ndarray:  # -omega x x on the container, 0 inside
        outer = x[0] ** 2 + x[1] ** 2 > (0.5 * (A + R)) ** 2
        return np.where(outer, 1.0, 0.0) * np.stack([OMEGA * x[1], -OMEGA * x[0]])

    wall = fem.Function(flow.V)
    wall.interpolate(wall_velocity)
    previous = state.x.array.copy()
    iterations = 0
    while iterations < max_iter:
        iterations += 1
        problem.solve(flow.conditions(wall))
        change = md.comm.allreduce(float(np.abs(state.x.array - previous).max()), op=MPI.MAX)
        previous[:] = state.x.array
        if change < tol:
            break
    uh, ph = ufl.split(state)
    rotation_field = fem.Function(flow.V)
    flow.set_rotation_field(rotation_field)
    residual = -md.active * flow.momentum(uh, ph, rotation_field, 0, uh, rotating=True) * ufl.dx
    torque = md.comm.allreduce(fem.assemble_scalar(fem.form(residual)), op=MPI.SUM)
    # the fixed frame's velocity: u = u' + omega x x
    rigid = fem.Function(flow.V)
    rigid.interpolate(lambda x: np.stack([-OMEGA * x[1], OMEGA * x[0]]))
    V_rows = np.concatenate([np.asarray(r) for r in W.sub(0).collapse()[1]])
    flow.wh.x.array[:] = state.x.array
    flow.wh.x.array[V_rows] += rigid.x.array
    return float(torque), iterations


# -

# ## The turn


# +
def turn(flow: Flow, steps: int) -> dict[str, Any]:
    """Take ``steps`` BDF2 steps from the steady flow; the torque at each step."""
    md, W, ts = flow.md, flow.W, flow.ts
    (u, p), (v, q) = ufl.TrialFunctions(W), ufl.TestFunctions(W)
    u_star = ufl.split(ts.extrapolation)[0]
    F = md.active * (ufl.inner(ts.time_derivative(u, part=0), v)
                     + flow.momentum(u, p, v, q, u_star)) * ufl.dx  # fmt: skip
    problem = MovingLinearProblem(
        md, ufl.lhs(F), ufl.rhs(F), u=flow.wh, petsc_options_prefix="turn_",
        petsc_options=LU, active_only=True,
    )  # fmt: skip
    uh, ph = ufl.split(flow.wh)
    rotation_field = fem.Function(flow.V)
    derivative = ts.time_derivative(uh, part=0)
    reaction = ufl.inner(derivative, rotation_field) + flow.momentum(
        uh, ph, rotation_field, 0, u_star
    )
    torque_form = fem.form(-md.active * reaction * ufl.dx)
    x, n = flow.x, ufl.FacetNormal(md.mesh)
    inner_part = ufl.conditional(ufl.lt(ufl.dot(x, x), (0.5 * (A + R)) ** 2), 1.0, 0.0)

    def moment(side: str) -> Any:  # the z moment of the fluid's traction on the ellipse
        sigma = -ph * ufl.Identity(2) + 2 * NU * flow.eps(uh)
        traction = -ufl.dot(sigma(side), n(side))  # n: out of the fluid
        return inner_part(side) * (x[0](side) * traction[1] - x[1](side) * traction[0])

    surface_form = fem.form(md.immersed_integral(moment))
    ts.initialize(flow.wh)
    times, torques, surface, seconds = [], [], [], []
    for _ in range(steps):
        t0 = time.perf_counter()
        ts.advance(lambda: problem.solve(flow.conditions(flow.g)))
        seconds.append(time.perf_counter() - t0)
        flow.set_rotation_field(rotation_field)
        torque = md.comm.allreduce(fem.assemble_scalar(torque_form), op=MPI.SUM)
        times.append(ts.time)
        torques.append(float(torque))
        surface.append(float(md.comm.allreduce(fem.assemble_scalar(surface_form), op=MPI.SUM)))
    return {"t": times, "torque": torques, "surface_torque": surface,
            "seconds_per_step": float(np.median(seconds)), "timings": ts.timings}  # fmt: skip


# -

# ## Main


# +
def main(argv: Sequence[str] | None = None) -> dict:
    args = demo_options("Navier-Stokes around a rotating ellipse", "out/rotating_ellipse", argv)
    comm = MPI.COMM_WORLD
    t_start = time.perf_counter()
    per_turn, steps = STEPS[args.quick]
    dt = 2 * np.pi / (OMEGA * per_turn)
    flow = Flow(comm, H[args.quick], dt)
    steady_torque, iterations = steady(flow)
    log(comm, f"steady rotating-frame torque {steady_torque:.8f} ({iterations} Picard iterations)")
    run = turn(flow, steps)
    torques = np.array(run["torque"][2:])  # after the start (SDIRK3 steps)
    mean = float(torques.mean())
    drift = float((torques.max() - torques.min()) / abs(mean))
    log(comm, f"torque over the turn: mean {mean:.8f}, drift {drift:.2e}, "
              f"against steady {abs(mean - steady_torque) / abs(steady_torque):.2e}")  # fmt: skip
    if comm.rank == 0:
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 4))
        ax.plot(run["t"], run["torque"], label="moving mesh, BDF2")
        ax.axhline(steady_torque, color="k", ls="--", label="steady, rotating frame")
        ax.set_xlabel("t")
        ax.set_ylabel("torque on the ellipse")
        ax.legend()
        args.out.mkdir(parents=True, exist_ok=True)
        fig.tight_layout()
        fig.savefig(args.out / "torque.png", dpi=150)
        plt.close(fig)
    flow_figure(flow, args.out / "flow.png")
    seconds = comm.allreduce(time.perf_counter() - t_start, op=MPI.MAX)
    results = {
        "torque": mean,
        "torque_drift": drift,
        "steady_torque": steady_torque,
        "steady_iterations": iterations,
        "t": run["t"],
        "torques": run["torque"],
        "surface_torques": run["surface_torque"],
        "seconds_per_step": run["seconds_per_step"],
        "timings": run["timings"],
        "seconds": seconds,
    }
    parameters = {"quick": args.quick, "R": R, "a": A, "b": B, "omega": OMEGA, "nu": NU,
                  "Re": OMEGA * A**2 / NU, "h": H[args.quick], "dt": dt, "steps": steps,
                  "degree": DEGREE, "scheme": "BDF2"}  # fmt: skip
    path = write_summary(comm, args.out, results, parameters=parameters)
    log(comm, f"wrote {path} ({seconds:.0f} s)")
    return results


def flow_figure(flow: Flow, path) -> None:
    from dolfinx_universal.plotting import plot_function, save

    u = fem.Function(flow.V, name="|u|")
    u.interpolate(flow.wh.sub(0))
    fig, ax = plot_function(None, u, active=flow.md.active, title="speed at the end")
    if flow.md.comm.rank == 0:
        save(fig, path)


# -

# +
if __name__ == "__main__":
    main([] if "ipykernel" in sys.modules else None)
# -
