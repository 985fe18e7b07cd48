# # Optimal high-order convergence on curved universal meshes
#
# Laplace's equation on the unit disc (SPEC §7.2),
#
# $$ -\Delta u = 0 \text{ in } \Omega, \qquad u = e^y \sin x \text{ on } \Gamma, $$
#
# whose exact solution is $u = e^y \sin x$. The disc is immersed in equilateral backgrounds
# (coarsest $h_0 = 5/16$, halved repeatedly); each background is conformed to the disc and
# then curved: the positively cut triangles get a degree-$q$ coordinate element whose nodes
# are the images of the Lagrange nodes under
#
# * `I`: the exactly conforming transfinite blend $G_h$, interpolated at degree $q = k$
#   (the isoparametric map $I_h$);
# * `I~`: the blend through the straight mesh $\tilde G_h$, interpolated at $q = k$;
# * `G`: $G_h$ interpolated at $q = k + 2$ (superparametric: close to the exact $G_h$).
#
# Degree-$k$ Lagrange elements should converge at rate $k+1$ in $L^2$ and $k$ in the $H^1$
# seminorm, for every $k$, with nothing but ordinary UFL forms on the curved mesh.
# Dirichlet data are interpolated at the boundary nodes, which lie exactly on $\Gamma$.
#
# Run with `python demos/poisson_convergence.py [--quick] [--out DIR]`, also under mpirun.
# The full study takes about three minutes on one core.

# +
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from mpi4py import MPI

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import LinearProblem

import dolfinx_universal as du
from dolfinx_universal.plotting import gather_cells, plot_conforming, save

parser = argparse.ArgumentParser(description="Poisson convergence on curved universal meshes")
parser.add_argument("--quick", action="store_true", help="three levels instead of five/six")
parser.add_argument("--out", type=Path, default=Path("out/poisson"), help="output folder")
parser.add_argument("--degrees", type=int, nargs="+", default=[1, 2, 3, 4])
args = parser.parse_args()
comm = MPI.COMM_WORLD
if comm.rank == 0:
    args.out.mkdir(parents=True, exist_ok=True)


def log(*a) -> None:
    if comm.rank == 0:
        print(*a, flush=True)


# -

# ## The solver
#
# Nothing here knows that the mesh came from a universal mesh: a degree-$q$ DOLFINx mesh,
# a Lagrange space of degree $k$, the boundary facets from the facet tags. Errors are
# integrated with a quadrature degree well above the integrand's polynomial degree.

# +
def solve(curved: du.CurvedMesh, k: int) -> tuple[float, float, int]:
    """L2 and H1-seminorm errors of the degree-k solution, and the number of dofs."""
    msh = curved.mesh
    V = fem.functionspace(msh, ("Lagrange", k))
    x = ufl.SpatialCoordinate(msh)
    u_exact = ufl.exp(x[1]) * ufl.sin(x[0])
    u_d = fem.Function(V)
    u_d.interpolate(lambda p: np.exp(p[1]) * np.sin(p[0]))
    dofs = fem.locate_dofs_topological(V, 1, curved.facet_tags.find(du.IMMERSED))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx
    L = fem.Constant(msh, 0.0) * v * ufl.dx
    problem = LinearProblem(
        a, L, bcs=[fem.dirichletbc(u_d, dofs)],
        petsc_options={"ksp_type": "preonly", "pc_type": "lu",
                       "pc_factor_mat_solver_type": "mumps"},
        petsc_options_prefix="poisson_",
    )
    uh = problem.solve()
    dx = ufl.Measure("dx", domain=msh,
                     metadata={"quadrature_degree": 2 * k + 2 * curved.degree + 4})
    e = uh - u_exact
    l2 = np.sqrt(comm.allreduce(fem.assemble_scalar(fem.form(e * e * dx))))
    h1 = np.sqrt(comm.allreduce(
        fem.assemble_scalar(fem.form(ufl.inner(ufl.grad(e), ufl.grad(e)) * dx))))
    return float(l2), float(h1), V.dofmap.index_map.size_global


# -

# ## The study
#
# One background per level, conformed once and curved for every map and degree.

# +
disc = du.Circle((0.0, 0.0), 1.0)
h0 = 5 / 16
maps = [("I", 0), ("I~", 0), ("G", 2)]


def num_levels(k: int) -> int:
    """Five halvings of h0 (six meshes) up to k = 3, four for k = 4 (1.6e5 P4 dofs)."""
    if args.quick:
        return 3
    return 6 if k <= 3 else 5


rows = []
curved_for_figure = {}
t_start = time.perf_counter()
for level in range(max(num_levels(k) for k in args.degrees)):
    h = h0 / 2**level
    background = du.equilateral_mesh(comm, [[-1.2 - 2 * h, -1.2 - 2 * h],
                                            [1.2 + 2 * h, 1.2 + 2 * h]], h)
    cm = du.conform(background, disc)
    n_cells = du.quality_report(cm)["n_cells"]
    for k in args.degrees:
        if level >= num_levels(k):
            continue
        for name, extra in maps:
            curved = du.curved_mesh(cm, k + extra, name)
            l2, h1, ndofs = solve(curved, k)
            rows.append({"map": name, "k": k, "geometry_degree": k + extra, "h": h,
                         "n_cells": n_cells, "L2": l2, "H1": h1})
            log(f"level {level} h={h:.5f} map={name:2s} k={k} q={k + extra} dofs={ndofs:7d} "
                f"L2={l2:.3e} H1={h1:.3e}")
            if level == 0 and name == "I" and k in (2, 3):
                curved_for_figure[k] = (cm, curved)
log(f"study took {time.perf_counter() - t_start:.1f} s")
# -

# ## Rates
#
# The rate between the two finest meshes, and a least-squares fit over the three finest.

# +
rates = []
log(f"\n{'map':>3} {'k':>2} {'L2 rate':>8} {'H1 rate':>8} {'L2 fit':>7} {'H1 fit':>7}")
for name, _ in maps:
    for k in args.degrees:
        sel = [r for r in rows if r["map"] == name and r["k"] == k]
        hs = np.array([r["h"] for r in sel])
        l2 = np.array([r["L2"] for r in sel])
        h1 = np.array([r["H1"] for r in sel])
        r_l2 = float(np.log(l2[-2] / l2[-1]) / np.log(hs[-2] / hs[-1]))
        r_h1 = float(np.log(h1[-2] / h1[-1]) / np.log(hs[-2] / hs[-1]))
        fit_l2 = np.polyfit(np.log(hs[-3:]), np.log(l2[-3:]), 1)[0]
        fit_h1 = np.polyfit(np.log(hs[-3:]), np.log(h1[-3:]), 1)[0]
        rates.append({"map": name, "k": k, "L2_rate": r_l2, "H1_rate": r_h1})
        log(f"{name:>3} {k:2d} {r_l2:8.2f} {r_h1:8.2f} {fit_l2:7.2f} {fit_h1:7.2f}")
# -

# ## Figures
#
# Errors against $h$ for every degree (one panel per map), and close-ups of the curved
# triangles near the boundary for $k = 2$ and $k = 3$ (dots: their geometry nodes).

# +
if comm.rank == 0:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for norm in ("L2", "H1"):
        fig, axes = plt.subplots(1, len(maps), figsize=(5 * len(maps), 4.4), sharey=True)
        for ax, (name, extra) in zip(np.atleast_1d(axes), maps):
            for k in args.degrees:
                sel = [r for r in rows if r["map"] == name and r["k"] == k]
                hs = np.array([r["h"] for r in sel])
                err = np.array([r[norm] for r in sel])
                ax.loglog(hs, err, "o-", color=f"C{k}", label=f"k = {k}")
                order = k + 1 if norm == "L2" else k
                ref = err[-1] * (hs / hs[-1]) ** order
                ax.loglog(hs, ref, ":", color=f"C{k}", lw=0.8)
                ax.annotate(f"{order}", (hs[-1], err[-1]), textcoords="offset points",
                            xytext=(-14, -10), fontsize=8, color=f"C{k}")
            geometry = "q = k" if extra == 0 else f"q = k + {extra}"
            ax.set_title(f"map {name} ({geometry})")
            ax.set_xlabel("h")
            ax.grid(True, which="both", lw=0.3)
        np.atleast_1d(axes)[0].set_ylabel(
            r"$\|u - u_h\|_{L^2}$" if norm == "L2" else r"$|u - u_h|_{H^1}$")
        np.atleast_1d(axes)[0].legend()
        save(fig, args.out / f"convergence_{norm}.png")

for k in sorted(curved_for_figure):
    cm, curved = curved_for_figure[k]
    nodes, cut = gather_cells(curved.mesh, values=cm.positively_cut)
    if comm.rank == 0:
        fig, ax = plt.subplots(figsize=(5.5, 5.5))
    else:
        fig, ax = None, None
    plot_conforming(ax, cm, show_background=False, mesh=curved.mesh, linewidth=0.7,
                    title=f"curved triangles on the coarsest mesh, map I, q = {k}")
    if comm.rank == 0:
        ax.plot(*nodes[cut.astype(bool)].reshape(-1, 2).T, "o", ms=2.5, color="k", zorder=5)
        ax.set_xlim(0.3, 1.05), ax.set_ylim(0.25, 1.0)
        save(fig, args.out / f"closeup_k{k}.png")
# -

# ## Summary and checks
#
# Errors fall with $k$ on every background (p-refinement), and the rates are optimal.

# +
if comm.rank == 0:
    (args.out / "summary.json").write_text(json.dumps({"rows": rows, "rates": rates}, indent=2))
    print(f"wrote {args.out / 'summary.json'}")
for name, _ in maps:
    for h in sorted({r["h"] for r in rows}):
        errs = [r["L2"] for k in args.degrees for r in rows
                if r["map"] == name and r["k"] == k and r["h"] == h]
        assert all(b < a for a, b in zip(errs, errs[1:])), (name, h, errs)
if not args.quick:
    for r in rates:
        assert r["L2_rate"] > r["k"] + 1 - 0.15 and r["H1_rate"] > r["k"] - 0.15, r
# -
