"""The oscillating cylinder (Wan & Turek) on a universal mesh against two body-fitted
alternatives on gmsh meshes: accuracy of the force coefficients and cost per step.

All three take the same Navier–Stokes discretisation as ``demos/oscillating_cylinder.py``
(Taylor–Hood P2/P1, degree-2 geometry, BDF2 after two BDF1 steps (the impulsive start:
``TimeStepper.initialize(start="BDF")``), the convection by the extrapolated velocity, the
force by the weak residual), with the same time step and about
the same number of unknowns:

* ``universal``: the demo's solver: one graded acute background conformed at every step
  (:class:`~dolfinx_universal.moving.stepping.TimeStepper`);
* ``ALE``: a body-fitted gmsh mesh of the channel at t = 0 whose nodes follow the cylinder
  by a harmonic extension of its displacement (stiffened by the inverse cell area; fixed at
  the channel's ends, sliding along its sides: fixing the sides too folds the cells between
  the cylinder and the walls at this amplitude), the ALE form with the mesh velocity of the
  BDF formula: the classical alternative when the mesh can follow the body;
* ``remesh``: a new gmsh mesh at every step and DOLFINx's non-matching interpolation
  (``interpolate_nonmatching``) of the two previous velocities onto it, the Eulerian form;
  places that were inside the cylinder take its velocity.

The meshes are sized by the demo's background size along the cylinder's track (gmsh's size
callback, scaled so that the gmsh meshes have the universal mesh's number of unknowns).
The reference is the same computation with half the mesh size and half the time step, by
the universal mesh and by the ALE mesh; the errors are the largest differences of C_D and
C_L over ``t >= T_SKIP`` (the impulsive start makes the first steps' forces O(1/dt) in every
method).

The cost of a step is split into the linear solve (assembly and MUMPS) and the rest: the
update and transfer (universal), the mesh motion (ALE), the meshing, spaces, forms and
interpolation (remesh). ``--cells`` adds the universal mesh's split at a background of about
that many cells (a few steps).

Run: ``python benchmarks/oscillating_cylinder_vs_gmsh.py [--quick] [--t-end 4] [--json FILE]``
(serial); ``--large-only --cells 1e5``: only the universal mesh's split.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from mpi4py import MPI

import _results
import basix.ufl
import gmsh
import numpy as np
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from dolfinx.fem.petsc import LinearProblem
from dolfinx.io import gmsh as dgmsh

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "demos"))
import oscillating_cylinder as demo  # noqa: E402

import dolfinx_universal as du  # noqa: E402

comm = MPI.COMM_WORLD
LU = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
T_SKIP = demo.T_START
"""Errors are taken over ``t >= T_SKIP`` (after the impulsive start)."""
SCALE = 2.0 / (demo.U_REF**2 * demo.D)
R = demo.D / 2


def body_velocity(t: float) -> float:
    return demo.U_REF * np.cos(2 * np.pi * demo.FREQUENCY * t)


# ----------------------------------------------------------------------------- gmsh
def gmsh_mesh(c: np.ndarray, h_fine: float, factor: float):
    """The P2 mesh of the channel minus the cylinder at ``c``, sized by the demo's track
    size times ``factor``: ``(mesh, wall facets, cylinder facets, seconds)``."""
    size = demo.track_size(h_fine)
    t0 = time.perf_counter()
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("channel")
    rect = gmsh.model.occ.addRectangle(0, 0, 0, demo.LENGTH, demo.HEIGHT)
    disc = gmsh.model.occ.addDisk(c[0], c[1], 0, R, R)
    fluid, _ = gmsh.model.occ.cut([(2, rect)], [(2, disc)])
    gmsh.model.occ.synchronize()
    gmsh.model.addPhysicalGroup(2, [fluid[0][1]], 1)
    curves = [e[1] for e in gmsh.model.getBoundary(fluid, oriented=False)]
    on_disc = [
        e
        for e in curves
        if np.hypot(*(np.array(gmsh.model.occ.getCenterOfMass(1, e)[:2]) - c)) < 1e-6
    ]
    gmsh.model.addPhysicalGroup(1, [e for e in curves if e not in on_disc], 1)
    gmsh.model.addPhysicalGroup(1, on_disc, 2)
    for name in ("MeshSizeExtendFromBoundary", "MeshSizeFromPoints", "MeshSizeFromCurvature"):
        gmsh.option.setNumber(f"Mesh.{name}", 0)
    gmsh.model.mesh.setSizeCallback(
        lambda dim, tag, x, y, z, lc: float(factor * size(np.array([[x, y]]))[0])
    )  # fmt: skip
    gmsh.model.mesh.generate(2)
    gmsh.model.mesh.setOrder(2)
    data = dgmsh.model_to_mesh(gmsh.model, comm, 0, gdim=2)
    gmsh.finalize()
    tags = data.facet_tags
    return data.mesh, tags.find(1), tags.find(2), time.perf_counter() - t0


def taylor_hood(msh):
    cell = msh.basix_cell()
    P2 = basix.ufl.element("Lagrange", cell, 2, shape=(2,))
    P1 = basix.ufl.element("Lagrange", cell, 1)
    W = fem.functionspace(msh, basix.ufl.mixed_element([P2, P1]))
    V, V_rows = W.sub(0).collapse()
    Q, _ = W.sub(1).collapse()
    return W, V, Q, np.asarray(V_rows)


def n_dofs(msh) -> int:
    msh.topology.create_entities(1)
    return 3 * msh.topology.index_map(0).size_global + 2 * msh.topology.index_map(1).size_global


class BodyFitted:
    """The demo's discretisation on a body-fitted mesh: spaces, conditions, forms, forces."""

    def __init__(self, msh, walls, cylinder, history: int):
        self.msh = msh
        self.W, self.V, self.Q, self.V_rows = taylor_hood(msh)
        W, V = self.W, self.V
        msh.topology.create_connectivity(1, 2)
        self.wall_dofs = fem.locate_dofs_topological((W.sub(0), V), 1, walls)
        self.cyl_dofs = fem.locate_dofs_topological((W.sub(0), V), 1, cylinder)
        pin = fem.locate_dofs_geometrical(
            (W.sub(1), self.Q), lambda y: np.isclose(y[0], 0.0) & np.isclose(y[1], 0.0)
        )
        self.body = fem.Function(V)
        self.bcs = [
            fem.dirichletbc(fem.Function(V), self.wall_dofs, W.sub(0)),
            fem.dirichletbc(self.body, self.cyl_dofs, W.sub(0)),
            fem.dirichletbc(fem.Function(self.Q), pin, W.sub(1)),
        ]
        self.wh = fem.Function(W)
        self.alpha = fem.Constant(msh, 1.0)
        self.dt = fem.Constant(msh, 1.0)
        self.h = fem.Function(V)  # the history (BDF)
        self.u_star = fem.Function(V)  # the extrapolated velocity
        self.w = fem.Function(V)  # the mesh velocity
        (u, p), (v, q) = ufl.TrialFunctions(W), ufl.TestFunctions(W)

        def derivative(u):
            return (self.alpha * u - self.h) / self.dt - ufl.grad(u) * self.w

        F = (ufl.inner(derivative(u), v) + demo.navier_stokes(u, p, v, q, self.u_star)) * ufl.dx
        self.problem = LinearProblem(
            ufl.lhs(F), ufl.rhs(F), u=self.wh, bcs=self.bcs,
            petsc_options_prefix=f"body_fitted_{id(self)}_", petsc_options=LU,
        )  # fmt: skip
        uh, ph = ufl.split(self.wh)
        self.fields = []
        for i in range(2):
            e = fem.Function(V)
            blocks = self.cyl_dofs[1]
            e.x.array[blocks[blocks % 2 == i]] = 1.0
            self.fields.append(e)
        self.force_forms = [
            fem.form(-(ufl.inner(derivative(uh), e)
                       + demo.navier_stokes(uh, ph, e, 0, self.u_star)) * ufl.dx)
            for e in self.fields
        ]  # fmt: skip

    def set_bdf(self, dt: float, previous: list[np.ndarray]) -> None:
        """BDF of the order ``len(previous)`` (1 or 2) with constant steps: the history and
        the extrapolated velocity from the previous velocities (newest first) on this
        mesh's velocity dofs."""
        self.dt.value = dt
        if len(previous) == 1:
            self.alpha.value = 1.0
            self.h.x.array[:] = previous[0]
            self.u_star.x.array[:] = previous[0]
        else:
            self.alpha.value = 1.5
            self.h.x.array[:] = 2 * previous[0] - 0.5 * previous[1]
            self.u_star.x.array[:] = 2 * previous[0] - previous[1]

    def solve(self, t: float) -> np.ndarray:
        """Solve at time ``t``; the new velocity's dofs."""
        self.body.x.array.reshape(-1, 2)[:, 0] = body_velocity(t)
        self.problem.solve()
        self.wh.x.scatter_forward()
        return self.wh.x.array[self.V_rows].copy()

    def forces(self) -> tuple[float, float]:
        """The force coefficients of the last solution."""
        c = [SCALE * fem.assemble_scalar(f) for f in self.force_forms]
        return float(c[0]), float(c[1])


def node_map(space: fem.FunctionSpace, msh) -> np.ndarray:
    """For each dof (block) of ``space`` (P2 on the P2 mesh ``msh``) its geometry node."""
    node = np.empty(space.dofmap.index_map.size_local + space.dofmap.index_map.num_ghosts,
                    dtype=np.int64)  # fmt: skip
    node[space.dofmap.list] = msh.geometry.dofmaps[0]
    x = space.tabulate_dof_coordinates()
    assert np.allclose(x, msh.geometry.x[node]), "P2 dofs and geometry nodes differ"
    return node


# ----------------------------------------------------------------------------- ALE
def ale_run(h_fine: float, factor: float, dt: float, t_end: float) -> dict:
    """The body-fitted mesh at t = 0 moved by the harmonic extension of the cylinder's
    displacement."""
    msh, walls, cylinder, _ = gmsh_mesh(demo.centre(0.0), h_fine, factor)
    # the harmonic extension of a unit displacement of the cylinder, stiffened near it
    S = fem.functionspace(msh, ("Lagrange", 2))
    phi, psi = ufl.TrialFunction(S), ufl.TestFunction(S)
    k = fem.Function(fem.functionspace(msh, ("DG", 0)))  # 1 / the cells' (straight) areas
    v = msh.geometry.x[msh.geometry.dofmaps[0][:, :3], :2]
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    k.x.array[:] = 2.0 / np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    one, zero = fem.Function(S), fem.Function(S)
    one.x.array[:] = 1.0
    msh.topology.create_connectivity(1, 2)
    # the ends x = 0 and x = L stay; nodes on the channel's sides slide along them
    mid = dmesh.compute_midpoints(msh, 1, walls)
    ends = walls[np.isclose(mid[:, 0], 0.0) | np.isclose(mid[:, 0], demo.LENGTH)]
    bcs = [fem.dirichletbc(one, fem.locate_dofs_topological(S, 1, cylinder)),
           fem.dirichletbc(zero, fem.locate_dofs_topological(S, 1, ends))]  # fmt: skip
    extension = LinearProblem(
        k * ufl.inner(ufl.grad(phi), ufl.grad(psi)) * ufl.dx,
        fem.Constant(msh, 0.0) * psi * ufl.dx, bcs=bcs,
        petsc_options_prefix="extension_", petsc_options=LU,
    ).solve()  # fmt: skip
    node = node_map(S, msh)
    shape = np.zeros(len(msh.geometry.x))
    shape[node] = extension.x.array
    X0 = msh.geometry.x[:, :2].copy()

    def nodes(t: float) -> np.ndarray:
        s = demo.AMPLITUDE * np.sin(2 * np.pi * demo.FREQUENCY * t)
        x = X0.copy()
        x[:, 0] += s * shape
        return x

    # the smallest Jacobian determinant relative to the cell's at t = 0 (at the cells'
    # vertices and midpoints), at the extreme positions
    detJ = fem.Expression(ufl.JacobianDeterminant(msh),
                          np.array([[0, 0], [1, 0], [0, 1], [1 / 3, 1 / 3]]))  # fmt: skip
    ncells = msh.topology.index_map(2).size_local
    cells = np.arange(ncells, dtype=np.int32)
    det0 = detJ.eval(msh, cells)
    quality = {}
    for name, t in (("right", 1.0), ("left", 3.0)):
        msh.geometry.x[:, :2] = nodes(t)
        quality[name] = float((detJ.eval(msh, cells) / det0).min())
    msh.geometry.x[:, :2] = X0
    flow = BodyFitted(msh, walls, cylinder, 2)
    Vnode = node_map(flow.V, msh)
    history_x = [X0.copy()]
    previous = [flow.wh.x.array[flow.V_rows].copy()]
    t, out = 0.0, {"t": [], "c_D": [], "c_L": [], "solve_s": [], "other_s": []}
    while t < t_end - 1e-9:
        t0 = time.perf_counter()
        t += dt
        x1 = nodes(t)
        msh.geometry.x[:, :2] = x1
        first = t < 2.5 * dt  # the impulsive start: BDF1, from the state at rest once
        if first:
            w = (x1 - history_x[0]) / dt
        else:
            w = (1.5 * x1 - 2 * history_x[0] + 0.5 * history_x[1]) / dt
        flow.w.x.array[:] = w[Vnode].ravel()
        flow.set_bdf(dt, previous[:1] if first else previous)
        t1 = time.perf_counter()
        u = flow.solve(t)
        t2 = time.perf_counter()
        c_D, c_L = flow.forces()
        previous = [u, *previous][:2]
        history_x = [x1, *history_x][:2]
        out["t"].append(t)
        out["c_D"].append(c_D)
        out["c_L"].append(c_L)
        out["solve_s"].append(t2 - t1)
        out["other_s"].append(t1 - t0)
    out.update(n_dofs=n_dofs(msh), n_cells=msh.topology.index_map(2).size_global,
               min_det_ratio=quality)  # fmt: skip
    return out


# ----------------------------------------------------------------------------- remesh
def remesh_run(h_fine: float, factor: float, dt: float, t_end: float) -> dict:
    """A new mesh at every step; the previous velocities interpolated onto it."""
    msh, walls, cylinder, _ = gmsh_mesh(demo.centre(0.0), h_fine, factor)
    W, V, Q, V_rows = taylor_hood(msh)
    u0 = fem.Function(V)
    past = [(u0, 0.0)]  # (velocity on its mesh, its time), newest first
    t, out = 0.0, {"t": [], "c_D": [], "c_L": [], "solve_s": [], "other_s": [],
                   "mesh_s": [], "interpolate_s": []}  # fmt: skip
    sizes = []
    while t < t_end - 1e-9:
        t0 = time.perf_counter()
        t += dt
        msh, walls, cylinder, mesh_s = gmsh_mesh(demo.centre(t), h_fine, factor)
        flow = BodyFitted(msh, walls, cylinder, 2)
        t1 = time.perf_counter()
        previous = []
        for u_old, t_old in past:
            u_new = fem.Function(flow.V)
            msh_old = u_old.function_space.mesh
            cells = np.arange(msh.topology.index_map(2).size_local, dtype=np.int32)
            data = fem.create_interpolation_data(flow.V, u_old.function_space, cells, 1e-8)
            u_new.interpolate_nonmatching(u_old, cells, data)
            # places inside the cylinder at t_old: its velocity then
            x = flow.V.tabulate_dof_coordinates()[:, :2]
            inside = np.hypot(*(x - demo.centre(t_old)).T) < R * (1 + 1e-8)
            values = u_new.x.array.reshape(-1, 2)
            values[inside] = [body_velocity(t_old), 0.0] if t_old > 0 else 0.0
            previous.append(u_new.x.array.copy())
            del msh_old
        flow.w.x.array[:] = 0.0
        flow.set_bdf(dt, previous[:1] if t < 2.5 * dt else previous)
        t2 = time.perf_counter()
        u = flow.solve(t)
        t3 = time.perf_counter()
        c_D, c_L = flow.forces()
        v = fem.Function(flow.V)
        v.x.array[:] = u
        past = [(v, t), *past][:2]
        sizes.append(n_dofs(msh))
        out["t"].append(t)
        out["c_D"].append(c_D)
        out["c_L"].append(c_L)
        out["solve_s"].append(t3 - t2)
        out["mesh_s"].append(mesh_s)
        out["interpolate_s"].append(t2 - t1)
        out["other_s"].append(t2 - t0)
    out.update(n_dofs=int(np.mean(sizes)), n_dofs_range=[min(sizes), max(sizes)])
    return out


# ----------------------------------------------------------------------------- universal
def universal_run(h_fine: float, dt: float, t_end: float) -> dict:
    flow = demo.Flow(comm, h_fine, dt)
    run = demo.simulate(flow, t_end)
    timings = run["timings"]
    moving = timings["update"] + timings["nodes"] + timings["transfer"]
    total = float(np.sum(run["seconds"]))
    return {"t": run["t"], "c_D": run["c_D"], "c_L": run["c_L"], "n_dofs": flow.n_dofs(),
            "n_cells": flow.n_cells, "seconds": run["seconds"], "timings": timings,
            "moving_seconds": run["moving_seconds"], "moving_share": moving / total}  # fmt: skip


def matched_factor(h_fine: float, target: int) -> float:
    """The factor of gmsh's size field that gives about ``target`` unknowns at t = 0."""
    factor = 1.0
    for _ in range(3):
        msh, *_ = gmsh_mesh(demo.centre(0.0), h_fine, factor)
        factor *= np.sqrt(n_dofs(msh) / target)
    return float(factor)


def errors(run: dict, ref: dict) -> dict:
    """Largest differences of the coefficients over ``t >= T_SKIP``, the reference sampled
    at the run's times (absolute: the coefficients are already scaled; the lift is small,
    the channel being nearly symmetric about the cylinder's path)."""
    t = np.array(run["t"])
    keep = t >= T_SKIP - 1e-9
    out = {}
    for key in ("c_D", "c_L"):
        r = np.interp(t, ref["t"], ref[key])
        out[key] = float(np.abs(np.array(run[key]) - r)[keep].max())
    return out


def per_step(run: dict) -> dict:
    """Median seconds per step (after the first), in the solve and in the rest."""
    if "seconds" in run:  # universal: the stepper's timings
        s = np.array(run["seconds"][1:])
        share = np.sum(run["moving_seconds"][1:]) / np.sum(s)
        return {"step_s": float(np.median(s)), "moving_share": float(share)}
    solve, other = np.array(run["solve_s"][1:]), np.array(run["other_s"][1:])
    total = solve + other
    return {"step_s": float(np.median(total)), "moving_share": float(np.sum(other) / np.sum(total))}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coarse, to t = 0.5")
    parser.add_argument("--t-end", type=float, default=4.0)
    parser.add_argument("--h", type=float, default=demo.D / 4, help="coarse size at the track")
    parser.add_argument("--dt", type=float, default=0.02, help="coarse time step")
    parser.add_argument("--cells", type=float, default=1e5,
                        help="background cells of the cost split (0: none)")  # fmt: skip
    parser.add_argument("--json", help="write the results to this file")
    parser.add_argument("--large-only", action="store_true",
                        help="only the universal mesh's split at --cells")  # fmt: skip
    args = parser.parse_args(argv)
    if args.large_only:
        cost = large_background(args.cells)
        print(f"universal at {cost['n_cells']} cells: {cost['step_s']:.2f} s a step, "
              f"{100 * cost['moving_share']:.1f} % update, paths and transfer")  # fmt: skip
        if args.json:
            _results.write(args.json, {"large": cost})
        return {"large": cost}
    if args.quick:
        args.t_end, args.h, args.dt, args.cells = 0.5, demo.D / 2, 0.05, 0
    rows, runs = {}, {}
    for level, (h, dt) in enumerate([(args.h, args.dt), (args.h / 2, args.dt / 2)]):
        t0 = time.perf_counter()
        uni = universal_run(h, dt, args.t_end)
        factor = matched_factor(h, uni["n_dofs"])
        runs[("universal", level)] = uni
        runs[("ALE", level)] = ale_run(h, factor, dt, args.t_end)
        if level == 0:
            runs[("remesh", level)] = remesh_run(h, factor, dt, args.t_end)
        print(f"level {level}: h {h:.4f}, dt {dt}: {time.perf_counter() - t0:.0f} s", flush=True)
    for method in ("universal", "ALE", "remesh"):
        run = runs[(method, 0)]
        row = {"method": method, "n_dofs": run["n_dofs"], **per_step(run)}
        for ref in ("universal", "ALE"):
            e = errors(run, runs[(ref, 1)])
            row[f"c_D_error_vs_{ref}"], row[f"c_L_error_vs_{ref}"] = e["c_D"], e["c_L"]
        rows[method] = row
    reference_gap = errors(runs[("universal", 1)], runs[("ALE", 1)])
    print(f"{'method':10s} {'dofs':>7s} {'C_D err (uni / ALE ref)':>24s} "
          f"{'C_L err (uni / ALE ref)':>24s} {'s/step':>7s} {'not solve':>9s}")  # fmt: skip
    for row in rows.values():
        print(f"{row['method']:10s} {row['n_dofs']:7d} "
              f"{row['c_D_error_vs_universal']:11.2e} / {row['c_D_error_vs_ALE']:.2e} "
              f"{row['c_L_error_vs_universal']:11.2e} / {row['c_L_error_vs_ALE']:.2e} "
              f"{row['step_s']:7.3f} {100 * row['moving_share']:8.1f}%")  # fmt: skip
    print(f"fine references: universal vs ALE differ by C_D {reference_gap['c_D']:.2e}, "
          f"C_L {reference_gap['c_L']:.2e}")  # fmt: skip
    ale = runs[("ALE", 0)]
    print(f"ALE mesh: smallest det J ratio {ale['min_det_ratio']}")
    cost = None
    if args.cells:
        cost = large_background(args.cells)
        print(f"universal at {cost['n_cells']} cells: {cost['step_s']:.2f} s a step, "
              f"{100 * cost['moving_share']:.1f} % update, paths and transfer")  # fmt: skip
    results = {
        "t_end": args.t_end, "h": args.h, "dt": args.dt, "t_skip": T_SKIP,
        "rows": list(rows.values()), "reference_gap": reference_gap,
        "ale_min_det_ratio": ale["min_det_ratio"], "large": cost,
        "series": {f"{m}_{lv}": {k: r[k] for k in ("t", "c_D", "c_L")}
                   for (m, lv), r in runs.items()},
    }  # fmt: skip
    if args.json:
        _results.write(args.json, results)
    return results


def large_background(cells: float, steps: int = 6) -> dict:
    """The universal step's split on a background of about ``cells`` cells (the BDF steps
    after the first, which compiles and factorises)."""
    h = demo.D / 8
    while True:  # the quadtree's levels: the first size whose background has enough cells
        n = du.graded_mesh(comm, [[0.0, 0.0], [demo.LENGTH, demo.HEIGHT]], demo.track_size(h),
                           root_size=demo.HEIGHT / 4).topology.index_map(2).size_global  # fmt: skip
        if n >= cells:
            break
        h *= 0.8
    flow = demo.Flow(comm, h, 0.01)
    run = demo.simulate(flow, 0.01 * (steps + 1))
    total, moving = np.sum(run["seconds"][1:]), np.sum(run["moving_seconds"][1:])
    return {"n_cells": flow.n_cells, "h": h, "steps": steps, "step_s": total / steps,
            "moving_share": moving / total}  # fmt: skip


if __name__ == "__main__":
    main()
