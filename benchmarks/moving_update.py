"""Per-step cost of re-conforming a moving domain on one background, against a Stokes solve.

For a rotating three-blade body in the square [-1, 1]^2 (equilateral backgrounds of about
1e4, 1e5 and 1e6 cells) the script measures, per time step (median over the steps after a
warm-up step):

* ``in place``: :meth:`MovingDomain.update` — classification, projections near Gamma,
  ``M_h`` and checks, curved degree-2 nodes written into the fixed background mesh; the
  forms, dofmaps and matrices of the background are reused;
* ``submesh``: the alternative design — :meth:`UniversalMesh.conform` (a new DOLFINx
  submesh) plus :func:`curved_mesh`, plus creating the P2/P1 spaces and the matrix on the
  new mesh (what every step would then need);
* one Taylor–Hood (P2/P1) Stokes assembly and MUMPS solve on the in-place mesh
  (:class:`~dolfinx_universal.moving.problems.MovingStokes`) (up to 1e5
  cells; at 1e6 cells a direct solve does not fit this machine's time budget).

Run: ``python benchmarks/moving_update.py [--sizes 1e4 1e5 1e6] [--steps 5] [--quick]``; also under
mpirun (timings are the maximum over ranks).
"""

from __future__ import annotations

import argparse
import time

from mpi4py import MPI

import _results
import basix.ufl
import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import create_matrix

import dolfinx_universal as du
from dolfinx_universal.moving.domain import MovingDomain
from dolfinx_universal.moving.problems import MovingStokes

comm = MPI.COMM_WORLD


def propeller() -> du.PolarCurve:
    """A smooth three-blade body, r = 0.2 + 0.2 exp(-sin^2(1.5 t)/0.5)."""

    def r(t):
        return 0.2 + 0.2 * np.exp(-(np.sin(1.5 * t) ** 2) / 0.5)

    def dr(t):
        s, c = np.sin(1.5 * t), np.cos(1.5 * t)
        return 0.2 * np.exp(-(s**2) / 0.5) * (-2 * s * c * 1.5 / 0.5)

    def d2r(t):
        e = 1e-5
        return (dr(t + e) - dr(t - e)) / (2 * e)

    return du.PolarCurve(r, dr, d2r)


def timed(fn, *args):
    """``fn(*args)`` and its wall time, the maximum over the ranks."""
    comm.Barrier()
    t = time.perf_counter()
    out = fn(*args)
    comm.Barrier()
    return out, comm.allreduce(time.perf_counter() - t, op=MPI.MAX)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e4, 1e5, 1e6])
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument(
        "--stokes-max", type=float, default=2e5, help="largest cell count with a Stokes solve"
    )
    parser.add_argument(
        "--quick", action="store_true", help="one small background (1e4 cells) and 2 steps"
    )
    parser.add_argument("--json", help="write the rows as JSON to this file")
    args = parser.parse_args()
    if args.quick:
        args.sizes, args.steps = [1e4], 2
    body = propeller()
    rows = []
    for target in args.sizes:
        h = float(np.sqrt(4.0 / (target * np.sqrt(3) / 4)))
        background, t_bg = timed(du.equilateral_mesh, comm, [[-1, -1], [1, 1]], h)
        ncells = comm.allreduce(background.topology.index_map(2).size_local)
        md, t_setup = timed(MovingDomain, background, 2)
        um = md.universal
        inplace, sub, split, updated = [], [], [], []
        for step in range(args.steps + 1):
            boundary = du.Domain(None, [du.RigidMotion(body, angle=np.radians(3.0 * step))])
            report, t = timed(md.update, boundary)

            def submesh_step(boundary=boundary, um=um):
                cv = du.curved_mesh(um.conform(boundary), 2)
                P2 = basix.ufl.element("Lagrange", "triangle", 2, shape=(2,))
                P1 = basix.ufl.element("Lagrange", "triangle", 1)
                W = fem.functionspace(cv.mesh, basix.ufl.mixed_element([P2, P1]))
                (u, p), (v, q) = ufl.TrialFunctions(W), ufl.TestFunctions(W)
                form = fem.form(
                    (ufl.inner(ufl.grad(u), ufl.grad(v)) - p * ufl.div(v) - q * ufl.div(u)) * ufl.dx
                )
                return create_matrix(form)

            _, t_sub = timed(submesh_step)
            if step:  # the first step is the warm-up
                inplace.append(t), sub.append(t_sub), split.append(report.timings)
                updated.append(report.num_updated_cells)
        med = {
            k: comm.allreduce(float(np.median([s[k] for s in split])), op=MPI.MAX) for k in split[0]
        }
        row = {
            "cells": ncells,
            "h": h,
            "background_s": t_bg,
            "setup_s": t_setup,
            "update_s": float(np.median(inplace)),
            "submesh_s": float(np.median(sub)),
            "updated_cells": int(np.median(updated)),
            "split": med,
            "stokes_s": None,
        }
        if ncells <= args.stokes_max:
            # Body: the rotation omega (-y, x) on Gamma_h; walls: 0; inactive dofs: 0;
            # pressure: 0 at a corner (the library's Taylor-Hood set-up).
            stokes = MovingStokes(md, 0.01, (-1.0, -1.0), petsc_options_prefix="bench_")
            _, t_asm = timed(stokes.assemble, (0.0, 0.0), -2.0)
            _, t_solve = timed(stokes.solve_assembled)
            row["stokes_s"] = t_asm + t_solve
            row["stokes_dofs"] = stokes.W.dofmap.index_map.size_global
        rows.append(row)
    if comm.rank == 0:
        print(f"\nranks: {comm.size}; median of {args.steps} steps after a warm-up step")
        print(
            f"{'cells':>9} {'updated':>8} {'in-place [s]':>12} {'classify':>9} {'project':>8} "
            f"{'map':>7} {'geometry':>8} {'submesh [s]':>11} {'Stokes [s]':>10} "
            f"{'update/Stokes':>13}"
        )
        for r in rows:
            s = r["split"]
            stokes = f"{r['stokes_s']:10.3f}" if r["stokes_s"] else f"{'-':>10}"
            ratio = (
                f"{100 * r['update_s'] / r['stokes_s']:12.1f}%" if r["stokes_s"] else f"{'-':>13}"
            )
            print(
                f"{r['cells']:9d} {r['updated_cells']:8d} {r['update_s']:12.4f} "
                f"{s['classify']:9.4f} {s['project']:8.4f} {s['map']:7.4f} "
                f"{s['geometry']:8.4f} {r['submesh_s']:11.4f} {stokes} {ratio}"
            )
        print(
            "\nin-place / submesh per-step time: "
            + ", ".join(f"{r['cells']}: {r['update_s'] / r['submesh_s']:.2f}" for r in rows)
        )
        if args.json:
            _results.write(args.json, {"steps": args.steps, "rows": rows})


if __name__ == "__main__":
    main()
