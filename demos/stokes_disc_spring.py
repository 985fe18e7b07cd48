# # A rigid disc on a spring in Stokes flow, on one universal mesh
#
# A rigid disc is tied by a spring to a point of the inflow wall of a channel and carried
# downstream by a shear flow until the drag balances the spring, the fluid-structure example of
# Rangarajan & Lew (2014, IJNME). The channel
# is the boundary of ONE graded background triangulation; at every time step the same
# background is conformed to the fluid domain $\Omega(t) = \text{channel} \setminus
# \overline{D(t)}$ by moving a few vertices near the disc (a universal mesh: one triangulation for
# every position of the domain), with
# curved degree-2 triangles whose boundary nodes lie on the exact circle. Connectivity,
# dofmaps, the sparsity pattern and the compiled forms are built once and reused at every
# step.
#
# ## The problem
#
# The channel is $0 \le x \le L$, $|y| \le L/2$, $L = 1$ (the origin at the middle of its
# left side). The fluid (viscosity $\mu = 0.01$) obeys the quasi-static Stokes equations
#
# $$ -\operatorname{div} \sigma(u, p) = 0, \quad \operatorname{div} u = 0 \quad
#    \text{in } \Omega(t), \qquad
#    \sigma(u, p) = -p I + \mu (\nabla u + \nabla u^T), $$
#
# with the shear profile $u = (L - 2|y|)\, e_x$ on $x = 0$ and $x = L$ (flux $L^2/2$ in and
# out), no slip on the walls $y = \pm L/2$, and $u = \dot c$ on the disc $D(t)$ of radius
# $R = L/10$ and centre $c(t)$ (a rigid translation: the disc does not rotate). The
# pressure is fixed by $p = 0$ at the corner $(0, -L/2)$ of the channel, which is always
# fluid; no force depends on this constant ($\oint n\, ds = 0$).
#
# The disc has mass $m = 1$ and is tied to the origin by a linear spring of stiffness
# $k = 1$ and rest length $l_0 = L/4$:
#
# $$ m \ddot c = F_s(c) + F_f, \qquad F_s(c) = -k \Bigl(1 - \frac{l_0}{|c|}\Bigr) c,
#    \qquad F_f = \int_{\partial D} \sigma(u, p)\, \nu\, ds, $$
#
# with $\nu$ the outward normal of the DISC. $F_s$ is the restoring force (it pulls the
# disc back towards the origin when the spring is stretched, $|c| > l_0$); the paper's
# statement of this example prints the opposite sign, an unstable spring that pushes a
# stretched disc
# further out. It also starts the disc at $(0, L/4)$, which puts it across the
# inflow wall; we start from $c_0 = (L/4, L/4)$ at rest.
#
# ## Time stepping: a staggered scheme
#
# With $t_n = n\, \Delta t$, $\Delta t = 0.05$, and $c^n \approx c(t_n)$, each step
#
# 1. conforms the background to the disc at $c^n$ (`md.update`),
# 2. solves the Stokes problem with the disc velocity $v^n$ on $\partial D$,
# 3. computes the fluid force $F^n$ on the disc,
# 4. advances the centre by central differences,
#    $c^{n+1} = 2 c^n - c^{n-1} + \frac{\Delta t^2}{m} \bigl(F_s(c^n) + F^n\bigr)$.
#
# The disc velocity imposed at step $n$ is the backward difference
# $v^n = (c^n - c^{n-1}) / \Delta t$, i.e. the central-difference (leapfrog) velocity at
# $t_{n - 1/2}$: when the Stokes problem is solved, $c^{n+1}$ is not known yet, and this
# is the newest second-order velocity the explicit scheme has. The drag is linear in the
# disc velocity, $F^n = F_0(c^n) - Z(c^n) v^n$, so this choice treats the damping term
# explicitly with a lag of half a step. For an oscillator $m \ddot c = -m\omega^2 c - \zeta
# \dot c$ the scheme has amplification factors of modulus $|z| = (1 - \beta)^{1/2}$,
# $\beta = \zeta \Delta t / m$, per step: the exact decay rate $\zeta / 2m$ of the
# amplitude to first order in $\beta$, and it is stable for $(\omega \Delta t)^2 + 2\beta < 4$
# (here $\zeta \approx 0.17$, $\beta \approx 0.009$, $\omega \Delta t \le 0.05$). Imposing
# the unknown $(c^{n+1} - c^{n-1}) / 2\Delta t$ instead would couple the Stokes solve to
# the update of $c$ (an implicit scheme), which the staggered scheme of the paper avoids. The disc
# starts at rest: $v^0 = 0$ and
# $c^1 = c^0 + \frac{\Delta t^2}{2m} (F_s(c^0) + F^0)$ (the even extension $c^{-1} = c^1$,
# second order).
#
# ## The fluid force, two ways
#
# The forms live on the whole background with the cell indicator $\chi$ of the conforming
# mesh (1 on the fluid triangles, 0 inside the disc), rewritten by `md.update`:
#
# $$ a((u, p), (v, q)) = \int \chi \bigl( 2\mu\, \varepsilon(u) : \varepsilon(v)
#    - p \operatorname{div} v - q \operatorname{div} u \bigr)\, dx = 0, \qquad
#    \varepsilon(u) = \tfrac12 (\nabla u + \nabla u^T), $$
#
# Taylor–Hood $P_2/P_1$ on the degree-2 curved mesh, the degrees of freedom of no fluid
# triangle fixed at zero. $n$ below is the outward normal of the FLUID (on $\Gamma_h$ it
# points into the disc): $\nu = -n$.
#
# * Surface integral on the curved boundary $\Gamma_h$ (`md.immersed_integral`):
#   $F_{\text{surf}} = -\int_{\Gamma_h} \sigma(u_h, p_h)\, n\, ds$.
# * Weak residual (reaction force): Green's formula turns $a((u, p), (w, 0))$ into
#   $\int_{\partial \Omega} \sigma n \cdot w\, ds$, so with $w = \phi_i$, the $P_2$ field
#   equal to $e_i$ at the velocity nodes on $\Gamma_h$ and zero at every other node,
#   $F_{\text{var}, i} = -a((u_h, p_h), (\phi_i, 0))$.
#
# $F_{\text{var}}$ uses the discrete equations, which $(u_h, p_h)$ satisfies exactly; its
# error is a product of two energy-norm errors, $O(h^{2k}) = O(h^4)$ (superconvergence of
# the reaction force), whereas $F_{\text{surf}}$ takes traces of $\nabla u_h$ and $p_h$ on
# the boundary, $O(h^2)$. The convergence study below confirms it: on nested backgrounds
# with $h_{\text{fine}} = 0.018, 0.009, 0.0045$ near the disc, successive differences are
# $2.0 \cdot 10^{-4}$, $3.7 \cdot 10^{-5}$ for $F_{\text{surf}}$ (observed order 2.5) and
# $1.1 \cdot 10^{-5}$, $6 \cdot 10^{-7}$ for $F_{\text{var}}$ (order 4.2), on a force of
# $0.15$: on the background of the run $F_{\text{var}}$ is about 19 times more accurate.
# $F_{\text{surf}}$ also jumps from step to step as the conforming triangles at $\Gamma_h$
# change (its median second difference along the run is about 14 times that of
# $F_{\text{var}}$), and the dynamics integrate the force twice. The dynamics use
# $F^n = F_{\text{var}}$.
#
# Run with `python demos/stokes_disc_spring.py [--quick] [--out DIR]`, also under mpirun.
# `--quick` takes a coarser background and exactly 20 steps. The Stokes set-up is
# {py:class}`dolfinx_universal.moving.problems.MovingStokes`.

# +
from __future__ import annotations

import json
import time
from collections.abc import Sequence

from mpi4py import MPI

import numpy as np
from dolfinx import mesh as dmesh

import dolfinx_universal as du
from dolfinx_universal.backgrounds.graded_tri import graded_mesh
from dolfinx_universal.demo_support import demo_options, log, point_values, write_summary
from dolfinx_universal.moving.domain import MovingDomain
from dolfinx_universal.moving.problems import MovingStokes
from dolfinx_universal.plotting import (
    boundary_polyline,
    field_triangulation,
    gather_cells,
    plot_mesh,
    save,
)

comm = MPI.COMM_WORLD
L, R, mass, stiffness, l0, mu, dt = 1.0, 0.1, 1.0, 1.0, 0.25, 0.01, 0.05
c_start = np.array([L / 4, L / 4])


def spring_force(c: np.ndarray) -> np.ndarray:
    """``F_s(c) = -k (1 - l0/|c|) c``: pulls the disc back when the spring is stretched."""
    return -stiffness * (1.0 - l0 / np.linalg.norm(c)) * c


# -

# ## One graded background for the whole motion
#
# The disc moves between its start and the equilibrium, overshooting it several times
# (the damping is weak). The box `visited` contains every position of the centre (taken
# from a first run, with a margin; checked at the end). The target size is
# $h_{\text{fine}}$ at every point the disc can cover (within $R$ of that box) and grows
# with slope 1 away from it up to $h_{\text{coarse}}$; the quadtree mesher splits a square
# of side $s$ until its longest edge $0.53\, s$ is below the target and balances the tree
# (neighbouring squares differ by at most a factor 2), which grades the mesh. So the fine
# region is tiled by squares of side $1/32$: edges up to $0.017 \approx R/6$ (squares of
# side $1/16$ in the quick mode: $R/3$); the next smaller target, $0.016$, would halve the
# squares and quadruple the cost. Every triangle is acute (angles between 31 and 78
# degrees), so the angle conditions of the universal mesh hold wherever the disc goes, and
# the channel
# walls are the background's boundary. Sizes are local (`local_size=True`): $h$ in $M_h$
# is the size of the triangles around each vertex. This background (7830 triangles) sets
# the cost of a step, about 0.25 s on one core, half of it the $LDL^T$ factorisation:
# the 1065 steps of the run take 4 to 5 minutes.


# +
def sizes(quick: bool) -> tuple[float, float, int]:
    """``(h_fine, h_coarse, max_steps)`` of the run."""
    return (0.036, 0.07, 20) if quick else (0.018, 0.07, 2400)


visited = np.array([[0.24, -0.155], [0.46, 0.26]])  # box of the centre positions (checked)


def target_size(h_fine: float, h_coarse: float):
    """Target edge length at points ``x (n, 2)``: fine where the disc can be."""

    def size(x: np.ndarray) -> np.ndarray:
        gap = np.maximum(np.maximum(visited[0] - x, x - visited[1]), 0.0)
        distance = np.maximum(np.hypot(gap[:, 0], gap[:, 1]) - R, 0.0)
        return np.minimum(h_fine + distance, h_coarse)

    return size


def start_size(h_fine: float, h_coarse: float):
    """Target edge length at points ``x (n, 2)``: fine near the disc at the start only."""

    def size(x: np.ndarray) -> np.ndarray:
        distance = np.maximum(np.abs(np.hypot(*(x - c_start).T) - R) - 3 * h_fine, 0.0)
        return np.minimum(h_fine + distance, h_coarse)

    return size


def channel_background(size) -> dmesh.Mesh:
    """The graded acute background of the channel ``[0, L] x [-L/2, L/2]``."""
    return graded_mesh(comm, [[0.0, -L / 2], [L, L / 2]], size)


# -


# ## The Stokes problem on the moving domain
#
# Everything that does not depend on the disc's position is built once: the spaces, the
# forms (with the indicator $\chi$ = `md.active`), the wall data, the matrix and the
# MUMPS solver (symmetric indefinite $LDL^T$). Each solve conforms the background, fixes
# the inactive degrees of freedom, imposes the disc velocity at the nodes on $\Gamma_h$,
# reassembles into the same matrix and computes both forces.


# +
def wall_velocity(y: np.ndarray) -> np.ndarray:
    """The shear profile ``(L - 2|y|) e_x`` on the inflow and outflow walls, 0 elsewhere."""
    inflow = np.isclose(y[0], 0.0) | np.isclose(y[0], L)
    return np.vstack([np.where(inflow, L - 2 * np.abs(y[1]), 0.0), np.zeros(y.shape[1])])


class DiscInChannel:
    """Stokes flow past a disc of radius ``R`` on one universal background."""

    def __init__(self, background: dmesh.Mesh):
        self.md = MovingDomain(background, degree=2, map="I", local_size=True)
        self.mesh = self.md.mesh
        # The matrix is symmetric (and indefinite): MUMPS LDL^T, half the flops of LU.
        self.stokes = MovingStokes(
            self.md,
            mu,
            (0.0, -L / 2),
            wall_velocity=wall_velocity,
            symmetric=True,
            petsc_options_prefix="disc_",
            petsc_options={
                "ksp_type": "preonly",
                "pc_type": "cholesky",
                "pc_factor_mat_solver_type": "mumps",
            },
        )

    def solve(self, c: np.ndarray, velocity: np.ndarray):
        """Conform to the disc at ``c`` moving with ``velocity``; return ``(F_surf, F_var,
        report, seconds)`` (forces on the disc, ``(2,)`` each; seconds per stage)."""
        stokes = self.stokes
        t0 = time.perf_counter()
        report = self.md.update(du.Domain(None, [du.Circle(c, R)]))
        t1 = time.perf_counter()
        stokes.assemble(velocity)
        t2 = time.perf_counter()
        stokes.solve_assembled()
        t3 = time.perf_counter()
        F_surf, F_var = stokes.surface_force(), stokes.force()
        t4 = time.perf_counter()
        seconds = {"update": t1 - t0, "assemble": t2 - t1, "solve": t3 - t2, "forces": t4 - t3}
        return F_surf, F_var, report, seconds

    def snapshot(self, points: np.ndarray) -> dict:
        """The fluid cells (nodes and kinds: 1 fluid, 2 with an edge on Gamma_h; gathered to
        rank 0) and the velocity at ``points (n, 3)`` (NaN inside the disc)."""
        md, msh = self.md, self.mesh
        kind = md.active_tags.values.astype(np.int8)
        f2c = msh.topology.connectivity(1, 2)
        touching = np.concatenate(
            [f2c.links(f) for f in md.immersed_facets] + [np.empty(0, np.int32)]
        )
        kind[touching[kind[touching] == 1]] = 2
        nodes, kinds = gather_cells(msh, kind)
        # Evaluate u_h in the fluid cells only; each point is found on one rank.
        u_h = self.stokes.wh.sub(0).collapse()
        values = point_values([u_h], points, md.active_cells)[0]
        # |u| on the curved fluid cells (meets the curved disc with no gap)
        speed = field_triangulation(u_h, active=self.md.active)
        return {"nodes": nodes, "kinds": kinds, "velocity": values, "speed": speed}


# -


# ## Which force? A convergence study at the start
#
# The disc at $c_0$, at rest, on a background fine near the disc only (`start_size`) and
# on its uniform refinements (every triangle split into four similar ones: the angles,
# hence the angle conditions, are kept). Successive differences of each force show how
# fast it converges.


# +
def convergence_study(h_fine: float, h_coarse: float) -> tuple[list[dict], float]:
    """Both forces on three nested backgrounds; the relative error of F_surf on the first."""
    study, study_background = [], channel_background(start_size(h_fine, h_coarse))
    for level in range(3):
        fine = du.refine_uniform(study_background, level) if level else study_background
        F_surf, F_var, _, _ = DiscInChannel(fine).solve(c_start, np.zeros(2))
        study.append(
            {
                "level": level,
                "h_fine": h_fine / 2**level,
                "cells": fine.topology.index_map(2).size_global,
                "F_surf": F_surf.tolist(),
                "F_var": F_var.tolist(),
            }
        )
        log(
            comm,
            f"h_fine = {h_fine / 2**level:.5f} ({study[-1]['cells']:6d} cells): "
            f"F_surf = ({F_surf[0]:.8f}, {F_surf[1]:.8f}), F_var = ({F_var[0]:.8f}, "
            f"{F_var[1]:.8f}), |F_surf - F_var| = {np.linalg.norm(F_surf - F_var):.2e}",
        )
    for key in ("F_surf", "F_var"):
        diffs = np.linalg.norm(np.diff([s[key] for s in study], axis=0), axis=1)
        log(
            comm,
            f"{key}: |F(h) - F(h/2)| = {diffs[0]:.2e}, |F(h/2) - F(h/4)| = "
            f"{diffs[1]:.2e}, observed order {np.log2(diffs[0] / diffs[1]):.2f}",
        )
        if key == "F_surf":  # the error of F_surf on the coarsest level, relative
            surf_error = diffs[0] / np.linalg.norm(study[0]["F_var"])
    return study, surf_error


# -


# ## The equilibrium and the damping, estimated before the run
#
# At rest the fluid force is $F_0(c)$; at an equilibrium $F_s(c) + F_0(c) = 0$, so $c$ is
# parallel to $F_0(c)$ and $|c| = l_0 + |F_0(c)|/k$: a fixed-point iteration on
# $c \leftarrow (l_0 + |F_0(c)|/k)\, F_0(c)/|F_0(c)|$ finds it with a few Stokes solves
# ($F_0$ depends weakly on $c$). Two more solves with the disc moving at unit speed give
# the drag matrix $Z$ ($F_f = F_0(c) - Z \dot c$, Stokes flow being linear). Near the
# equilibrium the disc is a weakly damped oscillator with two modes: along the spring,
# $\omega_r^2 = k/m$, and across it, $\omega_\perp^2 = k (1 - l_0/|c|)/m$ (the tension of
# the spring over its length); both amplitudes decay like $e^{-\zeta t/2m}$, $\zeta$ the
# eigenvalues of $Z$. This estimates the time the run needs.
#
# The stopping rule: the speed $|\dot c|$ (central difference at $t_n$) below
# `speed_tol` and the force imbalance $|F_s + F_f|/|F_s| = m |\ddot c| / |F_s|$ below
# `balance_tol`, at the same step. In an oscillation the velocity and the acceleration are
# in quadrature, so together they bound the amplitude $A$ of what is left of it:
# $A^2 \lesssim (|\dot c|/\omega)^2 + (|\ddot c|/\omega^2)^2$, at worst for the slow mode
# $\omega_\perp$. With `speed_tol` $= 10^{-3}$ and `balance_tol` $= 10^{-2}$ that is
# $A \lesssim 4 \cdot 10^{-3}$, a quarter of the mesh size, 4% of $R$. A tolerance at the
# level of the discretisation error of the force ($\sim 10^{-4}$ relative, see the study)
# would need about 50 more time units (1000 more steps) at this decay rate: twice the
# run. We stop at the tolerances above, and check that the disc stopped where the
# fixed-point iteration put the equilibrium.

# +
speed_tol, balance_tol = 1e-3, 1e-2


def equilibrium(problem: DiscInChannel) -> dict:
    """The fixed point ``c_eq``, the drag at rest there, the drag matrix and the expected
    settling time and residual amplitude."""
    t0 = time.perf_counter()
    c_eq = c_start.copy()
    for _ in range(12):
        _, F_0, _, _ = problem.solve(c_eq, np.zeros(2))
        c_new = (l0 + np.linalg.norm(F_0) / stiffness) * F_0 / np.linalg.norm(F_0)
        change, c_eq = np.linalg.norm(c_new - c_eq), c_new
        if change < 1e-7:
            break
    _, F_0, _, _ = problem.solve(c_eq, np.zeros(2))
    Z = np.column_stack([F_0 - problem.solve(c_eq, e)[1] for e in np.eye(2)])
    zeta = np.linalg.eigvalsh(0.5 * (Z + Z.T))
    omega_slow = np.sqrt(stiffness * (1 - l0 / np.linalg.norm(c_eq)) / mass)
    amplitude = np.hypot(
        speed_tol / omega_slow, balance_tol * np.linalg.norm(F_0) / (mass * omega_slow**2)
    )
    t_settle = 2 * mass / zeta.min() * np.log(np.linalg.norm(c_start - c_eq) / amplitude)
    log(
        comm,
        f"equilibrium c = ({c_eq[0]:.5f}, {c_eq[1]:.5f}) (last change {change:.1e}), "
        f"drag at rest F_0 = ({F_0[0]:.6f}, {F_0[1]:.6f})",
    )
    log(
        comm,
        f"drag matrix Z = {np.array2string(Z, precision=4)}, eigenvalues "
        f"{zeta.round(4)}; periods {2 * np.pi / np.sqrt(stiffness / mass):.1f} and "
        f"{2 * np.pi / omega_slow:.1f}; decay time 2m/zeta = {2 * mass / zeta.min():.1f}",
    )
    log(
        comm,
        f"expected: settled (amplitude < {amplitude:.1e}) after t = {t_settle:.0f} "
        f"({t_settle / dt:.0f} steps); set-up {time.perf_counter() - t0:.1f} s",
    )
    return {
        "c_eq": c_eq,
        "F_0": F_0,
        "Z": Z,
        "amplitude": float(amplitude),
        "t_settle": float(t_settle),
    }


def time_stepping(
    problem: DiscInChannel, quick: bool, max_steps: int, grid_points: np.ndarray
) -> dict:
    """The staggered scheme from ``c_start`` at rest until settled (or ``max_steps``)."""
    frame_step = 10 if quick else 40
    c_prev, c = c_start.copy(), c_start.copy()
    trajectory, forces, reports = [], [], []
    timing = {"update": [], "assemble": [], "solve": [], "forces": []}
    log(
        comm,
        f"{'t':>6} {'x':>8} {'y':>8} {'speed':>8} {'F_surf':>19} {'F_var':>19} "
        f"{'|F_surf-F_var|':>14} {'imbalance':>9} {'s/step':>6}",
    )
    t_loop = time.perf_counter()
    for step in range(max_steps + 1):
        t_step = time.perf_counter()
        velocity = (c - c_prev) / dt  # v^n = (c^n - c^{n-1}) / dt (0 at the start)
        F_surf, F_var, report, seconds = problem.solve(c, velocity)
        F_spring = spring_force(c)
        accel = (F_spring + F_var) / mass
        if step == 0:  # at rest: c^{-1} = c^1
            c_next = c + 0.5 * dt**2 * accel
        else:
            c_next = 2 * c - c_prev + dt**2 * accel
        speed = float(np.linalg.norm(c_next - c_prev) / (2 * dt)) if step else 0.0
        imbalance = float(np.linalg.norm(F_spring + F_var) / np.linalg.norm(F_spring))
        trajectory.append([step * dt, *c.tolist()])
        forces.append(
            {
                "t": step * dt,
                "F_surf": F_surf.tolist(),
                "F_var": F_var.tolist(),
                "F_spring": F_spring.tolist(),
                "speed": speed,
                "imbalance": imbalance,
            }
        )
        reports.append(report)
        for key, val in seconds.items():
            timing[key].append(comm.allreduce(val, op=MPI.MAX))
        if step == frame_step:
            frame = dict(problem.snapshot(grid_points), t=step * dt, c=c.copy(), v=velocity)
        settled = step > 0 and speed < speed_tol and imbalance < balance_tol
        if step % (1 if quick else 50) == 0 or settled or step == max_steps:
            log(
                comm,
                f"{step * dt:6.2f} {c[0]:8.5f} {c[1]:8.5f} {speed:8.1e} "
                f"{F_surf[0]:9.6f},{F_surf[1]:9.6f} {F_var[0]:9.6f},{F_var[1]:9.6f} "
                f"{np.linalg.norm(F_surf - F_var):14.2e} {imbalance:9.2e} "
                f"{time.perf_counter() - t_step:6.3f}",
            )
        if (settled and not quick) or step == max_steps:
            break
        c_prev, c = c, c_next
    return {
        "trajectory": trajectory,
        "forces": forces,
        "reports": reports,
        "timing": timing,
        "frame": frame,
        "seconds": time.perf_counter() - t_loop,
    }


# -


# ## Figures
#
# The trajectory (position against time, and the path in the channel with the spring's
# anchor and the disc at the start and at the end); the conforming curved mesh near the
# disc and the flow (speed, streamlines) at an intermediate time; the settling (speed and
# force imbalance).


# +
def figures(out, run: dict, c_eq: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> None:
    """The trajectory, the mesh and the flow at ``run["frame"]``, the settling (rank 0)."""
    trajectory, forces, frame = run["trajectory"], run["forces"], run["frame"]
    GX, GY = np.meshgrid(gx, gy)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    traj = np.array(trajectory)
    fig = plt.figure(figsize=(12, 5))
    ax_x = fig.add_subplot(2, 2, 1)
    ax_y = fig.add_subplot(2, 2, 3, sharex=ax_x)
    ax_p = fig.add_subplot(1, 2, 2)
    ax_x.plot(traj[:, 0], traj[:, 1])
    ax_x.set_ylabel("x")
    ax_y.plot(traj[:, 0], traj[:, 2])
    ax_y.set_ylabel("y")
    ax_y.set_xlabel("t")
    for ax in (ax_x, ax_y):
        ax.grid(True, alpha=0.3)
    ax_p.plot([0, L, L, 0, 0], [-L / 2, -L / 2, L / 2, L / 2, -L / 2], "k", lw=1.5)
    ax_p.plot(traj[:, 1], traj[:, 2], lw=0.8, label="centre")
    theta = np.linspace(0, 2 * np.pi, 200)
    for (cx, cy), style, name in ((traj[0, 1:], "--", "start"), (traj[-1, 1:], "-", "end")):
        ax_p.plot(
            cx + R * np.cos(theta),
            cy + R * np.sin(theta),
            "k",
            ls=style,
            lw=0.8,
            label=f"disc at the {name}",
        )
    ax_p.plot([0, traj[-1, 1]], [0, traj[-1, 2]], color="tab:red", lw=0.8, label="spring")
    ax_p.plot(*c_eq, "x", color="tab:green", label="equilibrium (fixed point)")
    (x0, y0), (x1, y1) = visited
    ax_p.plot(
        [x0, x1, x1, x0, x0],
        [y0, y0, y1, y1, y0],
        ":",
        color="0.5",
        lw=0.8,
        label="box of the centres (fine mesh within R)",
    )
    ax_p.set_aspect("equal")
    ax_p.set_xlim(-0.02, L + 0.02)
    ax_p.set_ylim(-L / 2 - 0.02, L / 2 + 0.02)
    ax_p.legend(loc="lower right", fontsize=8)
    ax_p.set_title("path of the centre")
    save(fig, out / "trajectory.png")

    fig, (ax_m, ax_u) = plt.subplots(1, 2, figsize=(13, 5.5))
    keep = frame["kinds"] > 0
    faces = np.array(["none", "#dbe7f3", "#8fb4d9"], dtype=object)[frame["kinds"][keep]]
    plot_mesh(ax_m, frame["nodes"][keep], 2, facecolors=faces, edgecolor="k", linewidth=0.4)
    circle = boundary_polyline(du.Circle(frame["c"], R), 1000)
    ax_m.plot(circle[:, 0], circle[:, 1], color="tab:red", lw=0.8)
    ax_m.set_xlim(frame["c"][0] - 0.18, frame["c"][0] + 0.18)
    ax_m.set_ylim(frame["c"][1] - 0.18, frame["c"][1] + 0.18)
    ax_m.set_title(f"conforming curved mesh near the disc, t = {frame['t']:g}")
    U = np.ma.masked_invalid(frame["velocity"][:, 0].reshape(GX.shape))
    V = np.ma.masked_invalid(frame["velocity"][:, 1].reshape(GX.shape))
    pts, tri, val = frame["speed"]
    cs = ax_u.tripcolor(pts[:, 0], pts[:, 1], tri, val, shading="gouraud", cmap="viridis")
    fig.colorbar(cs, ax=ax_u, label="|u|")
    ax_u.streamplot(gx, gy, U, V, color="w", density=1.5, linewidth=0.5, arrowsize=0.6)
    ax_u.fill(circle[:, 0], circle[:, 1], color="0.6", zorder=3)
    ax_u.arrow(*frame["c"], *(frame["v"] * 0.5), width=0.006, color="tab:red", zorder=4)
    ax_u.set_aspect("equal")
    ax_u.set_xlim(0, L)
    ax_u.set_ylim(-L / 2, L / 2)
    ax_u.set_title(f"speed and streamlines, t = {frame['t']:g}; disc velocity / 2")
    for ax in (ax_m, ax_u):
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    save(fig, out / "frames.png")

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.semilogy(traj[1:, 0], [f["speed"] for f in forces[1:]], label="speed $|\\dot c|$")
    ax.semilogy(traj[:, 0], [f["imbalance"] for f in forces], label="$|F_s + F_f| / |F_s|$")
    ax.axhline(speed_tol, color="C0", ls=":", lw=0.8)
    ax.axhline(balance_tol, color="C1", ls=":", lw=0.8)
    ax.set_xlabel("t")
    ax.grid(True, alpha=0.3)
    ax.legend()
    save(fig, out / "settling.png")


# -

# ## Summary and checks
#
# * The two force computations agree at every step to three times the error of
#   $F_{\text{surf}}$ estimated by the study (its first successive difference).
# * No triangle is inverted at any step. (That nothing is compiled after the first step,
#   the forms being built once, is checked by `tests/test_moving.py`.)
# * Every centre position lies in the `visited` box, the region where the background is
#   fine.
# * In the default mode, at the end, the spring and the fluid force balance to
#   `balance_tol`, the disc has stopped (`speed_tol`), and it stopped at the equilibrium
#   found before the run, within twice the amplitude bound.
#
# Every bound comes from the run's own estimates (the error of $F_{\text{surf}}$, the
# amplitude left by the stopping rule; the factors 3 and 2 allow for these being estimates
# of an order of magnitude), not from observed values, and each compares quantities at the
# level of the discretisation or of the oscillation ($10^{-4}$ and more), which rounding
# differences between CPUs do not move. The stopping rule itself is checked at the step
# where it stopped, so the checks hold whichever step that is.


# +
def main(argv: Sequence[str] | None = None) -> dict:
    """Run the demo (``argv``: ``--quick``, ``--out DIR``); return the summary's results."""
    args = demo_options("A rigid disc on a spring in Stokes flow", "out/stokes_disc_spring", argv)
    if comm.rank == 0:
        args.out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    h_fine, h_coarse, max_steps = sizes(args.quick)
    study, surf_error = convergence_study(h_fine, h_coarse)
    background = channel_background(target_size(h_fine, h_coarse))
    log(comm, f"background: {background.topology.index_map(2).size_global} triangles")
    problem = DiscInChannel(background)
    eq = equilibrium(problem)
    c_eq, amplitude = eq["c_eq"], eq["amplitude"]
    grid_n = 101 if args.quick else 201
    gx, gy = np.linspace(0, L, grid_n), np.linspace(-L / 2, L / 2, grid_n)
    GX, GY = np.meshgrid(gx, gy)
    grid_points = np.column_stack([GX.ravel(), GY.ravel(), np.zeros(GX.size)])
    run = time_stepping(problem, args.quick, max_steps, grid_points)
    if comm.rank == 0:
        figures(args.out, run, c_eq, gx, gy)

    trajectory, forces, reports = run["trajectory"], run["forces"], run["reports"]
    final = forces[-1]
    results = {
        "dt": dt,
        "steps": len(trajectory) - 1,
        "trajectory": trajectory,
        "final_position": trajectory[-1][1:],
        "final_speed": final["speed"],
        "spring_force_final": final["F_spring"],
        "fluid_force_final": final["F_var"],
    }
    parameters = dict(
        quick=args.quick,
        L=L,
        R=R,
        mass=mass,
        stiffness=stiffness,
        rest_length=l0,
        mu=mu,
        start=c_start.tolist(),
        h_fine=h_fine,
        h_coarse=h_coarse,
        max_steps=max_steps,
        speed_tol=speed_tol,
        balance_tol=balance_tol,
        geometry_degree=2,
        map="I",
        elements="P2/P1 Taylor-Hood",
    )
    reference = dict(
        equilibrium_position=c_eq.tolist(),
        drag_at_rest_equilibrium=eq["F_0"].tolist(),
        drag_matrix=eq["Z"].tolist(),
        amplitude_bound=amplitude,
        settling_time=eq["t_settle"],
    )
    write_summary(comm, args.out, results, parameters=parameters, reference=reference)
    if comm.rank == 0:
        (args.out / "forces.json").write_text(
            json.dumps({"study": study, "steps": forces}, indent=1)
        )
    gaps = [
        np.linalg.norm(np.subtract(f["F_surf"], f["F_var"])) / np.linalg.norm(f["F_var"])
        for f in forces
    ]
    n_inverted = sum(r.quality["n_inverted"] for r in reports)
    min_jacobian = min(r.min_jacobian_ratio for r in reports)
    min_angle = min(r.quality["theta_min_deg"] for r in reports)
    log(
        comm,
        f"distance to the equilibrium of the fixed-point iteration: "
        f"{np.linalg.norm(np.subtract(trajectory[-1][1:], c_eq)):.1e}",
    )
    log(
        comm,
        f"final: t = {trajectory[-1][0]:g}, c = {results['final_position']}, "
        f"speed {final['speed']:.2e}, F_spring = {final['F_spring']}, F_fluid = "
        f"{final['F_var']}, imbalance {final['imbalance']:.2e}",
    )
    log(
        comm,
        f"|F_surf - F_var| / |F_var|: max {max(gaps):.2e}, median "
        f"{np.median(gaps):.2e} (error of F_surf estimated by the study: {surf_error:.1e})",
    )
    if len(forces) > 2:
        rough = {
            key: np.median(np.linalg.norm(np.diff([f[key] for f in forces], n=2, axis=0), axis=1))
            for key in ("F_surf", "F_var")
        }
        log(
            comm,
            f"step-to-step roughness, median |F^(n+1) - 2 F^n + F^(n-1)|: "
            f"F_surf {rough['F_surf']:.1e}, F_var {rough['F_var']:.1e}",
        )
    log(
        comm,
        f"quality over all steps: min angle {min_angle:.2f} deg, min Jacobian ratio "
        f"{min_jacobian:.3f}, inverted {n_inverted}",
    )
    log(
        comm,
        "median seconds per step: "
        + ", ".join(f"{k} {np.median(v):.3f}" for k, v in run["timing"].items())
        + f"; {len(trajectory)} steps in {run['seconds']:.1f} s",
    )
    log(comm, f"total {time.perf_counter() - t_start:.1f} s")

    assert n_inverted == 0 and min_jacobian > 0
    assert max(gaps) < 3 * surf_error, (max(gaps), surf_error)
    positions = np.array(trajectory)[:, 1:]
    assert np.all((positions >= visited[0]) & (positions <= visited[1])), "left the fine region"
    if not args.quick:
        assert final["imbalance"] < balance_tol and final["speed"] < speed_tol, final
        assert np.linalg.norm(positions[-1] - c_eq) < 2 * amplitude
    return results


if __name__ == "__main__":
    main()
# -
