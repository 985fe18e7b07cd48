# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
# ---

# # Optimal high-order convergence on curved universal meshes
#
# This demo reproduces the convergence study of Rangarajan & Lew (2014) for the Laplace
# equation on a disc: on curved universal meshes, degree-$k$ Lagrange elements converge at
# the optimal rates for every $k$, with nothing but ordinary UFL forms on the curved mesh.
#
# It illustrates how to
#
# - conform a background mesh to a disc with {py:func}`dolfinx_universal.conforming.universal` and
#   curve its boundary triangles with {py:func}`dolfinx_universal.curved_mesh`,
# - solve a problem on the curved DOLFINx mesh with the Dirichlet facets taken from its
#   facet tags,
# - measure the errors and the convergence rates.
#
# Run it with
#
# ```bash
# python demos/poisson_convergence.py [--quick] [--out DIR] [--degrees K [K ...]]
# mpirun -n 2 python demos/poisson_convergence.py [--quick] [--out DIR]
# ```
#
# (same numbers on any number of ranks; `--quick` keeps three levels; the full study takes
# about three minutes on one core). In a notebook, call `main(["--quick"])`. The output
# folder (default `out/poisson`) receives `summary.json` and the figures
# `convergence_L2.png`, `convergence_H1.png`, `closeup_k2.png` and `closeup_k3.png`.
#
# ## The problem
#
# Laplace's equation on the unit disc,
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
# seminorm. Dirichlet data are interpolated at the boundary nodes, which lie exactly on
# $\Gamma$.

# +
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from mpi4py import MPI

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import LinearProblem

import dolfinx_universal as du
from dolfinx_universal.demo_support import demo_options, log, write_summary
from dolfinx_universal.plotting import (
    BOUNDARY_COLOR,
    CUT_FACE,
    KEPT_FACE,
    gather_cells,
    plot_conforming,
    save,
)

H0 = 5 / 16
MAPS = {"I": 0, "I~": 0, "G": 2}  # map -> geometry degree q - k
SOLVER = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
# -

# ## The solver
#
# Nothing here knows that the mesh came from a universal mesh: a degree-$q$ DOLFINx mesh,
# a Lagrange space of degree $k$, the boundary facets from the facet tags. Errors are
# integrated with a quadrature degree $2k + 2q + 4$, well above the integrand's polynomial
# degree.
#
# For $k = 3, 4$ the finest errors (down to $10^{-12}$ with $u$ of size 1) come near the
# round-off floor of the solution itself: the solve, and the assembly before it, are
# backward stable, with errors of relative size $\epsilon$ that the conditioning of the
# stiffness matrix ($O(h^{-2})$) magnifies in the solution. The floor is estimated at every
# solve from its residual: one step of iterative refinement (Higham, *Accuracy and
# Stability of Numerical Algorithms*, 2nd ed., SIAM 2002, ch. 12) solves
# $A\,d = b - A x$ with the same factors, and $d$, the correction it would make, has the
# size of the solution's round-off error (its order of magnitude: the residual is itself
# rounded, and the rounding of the assembled $A$ and $b$ is magnified by the same
# conditioning). Its norms are `L2_roundoff` and `H1_roundoff` in the summary.


# +
def solve(curved: du.CurvedMesh, k: int) -> tuple[float, float, int, float, float]:
    """L2 and H1-seminorm errors of the degree-k solution, the number of dofs, and the L2
    and H1-seminorm norms of the round-off estimate ``d``."""
    msh = curved.mesh
    comm = msh.comm
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
        a,
        L,
        bcs=[fem.dirichletbc(u_d, dofs)],
        petsc_options=SOLVER,
        petsc_options_prefix="poisson_",
    )
    uh = problem.solve()
    # The round-off estimate: d solves A d = b - A x with the factors of the solve.
    residual = problem.b.duplicate()
    problem.A.mult(problem.x, residual)
    residual.aypx(-1.0, problem.b)
    d = fem.Function(V)
    problem.solver.solve(residual, d.x.petsc_vec)
    d.x.scatter_forward()
    residual.destroy()
    dx = ufl.Measure(
        "dx", domain=msh, metadata={"quadrature_degree": 2 * k + 2 * curved.degree + 4}
    )

    def norms(e) -> tuple[float, float]:
        l2 = comm.allreduce(fem.assemble_scalar(fem.form(e * e * dx)))
        h1 = comm.allreduce(fem.assemble_scalar(fem.form(ufl.inner(ufl.grad(e), ufl.grad(e)) * dx)))
        return float(np.sqrt(l2)), float(np.sqrt(h1))

    l2, h1 = norms(uh - u_exact)
    l2_roundoff, h1_roundoff = norms(d)
    return l2, h1, V.dofmap.index_map.size_global, l2_roundoff, h1_roundoff


# -

# ## The study
#
# One background per level, conformed once and curved for every map and degree. Five
# halvings of $h_0$ (six meshes) up to $k = 3$, four for $k = 4$ (already $1.6 \cdot 10^5$
# P4 dofs); three meshes in quick mode.


# +
def num_levels(k: int, quick: bool) -> int:
    if quick:
        return 3
    return 6 if k <= 3 else 5


def background_box(h: float) -> list[list[float]]:
    """The disc's background: the square of side 2.4 with a margin of two cells."""
    return [[-1.2 - 2 * h, -1.2 - 2 * h], [1.2 + 2 * h, 1.2 + 2 * h]]


def study(comm: MPI.Comm, degrees: Sequence[int], quick: bool):
    """Errors for every level, degree and map; also the coarsest meshes for the figures."""
    disc = du.Circle((0.0, 0.0), 1.0)
    rows, for_figure = [], {}
    t_start = time.perf_counter()
    for level in range(max(num_levels(k, quick) for k in degrees)):
        h = H0 / 2**level
        cm = du.conform(du.equilateral_mesh(comm, background_box(h), h), disc)
        n_cells = du.quality_report(cm)["n_cells"]
        for k in degrees:
            if level >= num_levels(k, quick):
                continue
            for name, extra in MAPS.items():
                curved = du.curved_mesh(cm, k + extra, name)
                l2, h1, ndofs, l2_roundoff, h1_roundoff = solve(curved, k)
                rows.append(
                    {
                        "map": name,
                        "k": k,
                        "geometry_degree": k + extra,
                        "h": h,
                        "n_cells": n_cells,
                        "L2": l2,
                        "H1": h1,
                        "L2_roundoff": l2_roundoff,
                        "H1_roundoff": h1_roundoff,
                    }
                )
                log(
                    comm,
                    f"level {level} h={h:.5f} map={name:2s} k={k} q={k + extra} "
                    f"dofs={ndofs:7d} L2={l2:.3e} H1={h1:.3e} "
                    f"(round-off {l2_roundoff:.0e}, {h1_roundoff:.0e})",
                )
                if level == 0 and name == "I" and k in (2, 3):
                    for_figure[k] = (cm, curved)
    log(comm, f"study took {time.perf_counter() - t_start:.1f} s")
    return rows, for_figure, cm


# -

# ## Rates
#
# The rate between the two finest meshes whose errors are above the round-off floor, and a
# least-squares fit over the three finest such meshes. An error counts as above the floor
# where it exceeds `TRUSTED` $= 1000$ times its round-off estimate $d$: the estimate gives
# the floor within about a factor of 10 (see the solver), so there round-off changes each
# error by at most about 1 %, and a rate between two such errors by at most
# $\log_2(1.01 / 0.99) \approx 0.03$, a fifth of the tolerance of the checks below. Below it
# the errors are round-off, and their ratio says nothing about the discretisation (on
# different CPUs, i.e. different rounding in the BLAS kernels of the factorisation, the
# rate of $k = 4$ between errors of $3 \cdot 10^{-11}$ and $10^{-12}$ moved by half a unit).


# +
TRUSTED = 1000.0


def series(rows: list[dict], name: str, k: int, norm: str):
    """``h``, the errors in ``norm`` and their round-off estimates of one map and degree,
    coarsest first."""
    sel = [r for r in rows if r["map"] == name and r["k"] == k]
    return tuple(np.array([r[key] for r in sel]) for key in ("h", norm, f"{norm}_roundoff"))


def finest_trusted(err: np.ndarray, roundoff: np.ndarray) -> int | None:
    """The finest level ``l`` whose error and that of level ``l - 1`` are above the
    round-off floor (``None``: no such pair)."""
    above = err > TRUSTED * roundoff
    pairs = np.flatnonzero(above[1:] & above[:-1])
    return int(pairs[-1]) + 1 if len(pairs) else None


def convergence_rates(comm: MPI.Comm, rows: list[dict], degrees: Sequence[int]) -> list[dict]:
    rates = []
    log(
        comm,
        f"\n{'map':>3} {'k':>2} {'L2 rate':>8} {'H1 rate':>8} {'L2 fit':>7} {'H1 fit':>7}"
        "  (levels of the rate, L2 / H1)",
    )
    for name in MAPS:
        for k in degrees:
            entry: dict = {"map": name, "k": k}
            for norm in ("L2", "H1"):
                hs, err, roundoff = series(rows, name, k, norm)
                fine = finest_trusted(err, roundoff)
                rate = fit = None
                if fine is not None:
                    rate = float(
                        np.log(err[fine - 1] / err[fine]) / np.log(hs[fine - 1] / hs[fine])
                    )
                    used = slice(max(fine - 2, 0), fine + 1)
                    fit = float(np.polyfit(np.log(hs[used]), np.log(err[used]), 1)[0])
                entry[f"{norm}_rate"] = rate
                entry[f"{norm}_fit"] = fit
                entry[f"{norm}_levels"] = None if fine is None else [fine - 1, fine]
            rates.append(entry)

            def show(x, width):
                return f"{x:{width}.2f}" if x is not None else f"{'-':>{width}}"

            log(
                comm,
                f"{name:>3} {k:2d} {show(entry['L2_rate'], 8)} {show(entry['H1_rate'], 8)} "
                f"{show(entry['L2_fit'], 7)} {show(entry['H1_fit'], 7)}  "
                f"{entry['L2_levels']} / {entry['H1_levels']}",
            )
    return rates


# -

# ## Figures
#
# Errors against $h$ for every degree (one panel per map) with reference lines of the
# optimal slopes, and close-ups of the curved triangles near the boundary for $k = 2$ and
# $k = 3$ (dots: their geometry nodes). The figures are drawn on rank 0 with matplotlib's
# object interface (no pyplot state, no backend to choose); `plot_conforming` and
# `gather_cells` are collective.


# +
def convergence_figure(rows: list[dict], degrees: Sequence[int], norm: str, path: Path):
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    order = {"L2": 1, "H1": 0}[norm]  # optimal rate k + order
    fig = Figure(figsize=(5 * len(MAPS), 4.6), layout="constrained")
    axes = fig.subplots(1, len(MAPS), sharey=True)
    all_h = sorted({r["h"] for r in rows}, reverse=True)
    for ax, (name, extra) in zip(np.atleast_1d(axes), MAPS.items()):
        for k in degrees:
            hs, err, roundoff = series(rows, name, k, norm)
            ax.loglog(hs, err, "o-", color=f"C{k}", label=f"k = {k}")
            below = err <= TRUSTED * roundoff  # open markers: near the round-off floor
            ax.loglog(hs[below], err[below], "o", color=f"C{k}", mfc="white", zorder=3)
            # The optimal slope through the finest point above the floor; its label at the
            # middle of the line, just above it: inside the axes whatever the data.
            fine = finest_trusted(err, roundoff)
            fine = len(hs) - 1 if fine is None else fine
            ref = err[fine] * (hs / hs[fine]) ** (k + order)
            ax.loglog(hs, ref, ":", color=f"C{k}", lw=1.0)
            mid = np.sqrt(hs[0] * hs[-1])
            ax.annotate(
                f"{k + order}",
                (mid, err[fine] * (mid / hs[fine]) ** (k + order)),
                textcoords="offset points",
                xytext=(0, 8),
                ha="center",
                fontsize=8,
                color=f"C{k}",
                annotation_clip=True,
            )
        geometry = "q = k" if extra == 0 else f"q = k + {extra}"
        ax.set_title(f"map {name} (geometry {geometry})")
        ax.set_xticks(all_h, [f"{h:.3g}" for h in all_h])
        ax.set_xticks([], minor=True)
        ax.set_xlabel("mesh size h")
        ax.grid(True, which="both", lw=0.3)
    axes = np.atleast_1d(axes)
    axes[0].set_ylabel(r"$\|u - u_h\|_{L^2}$" if norm == "L2" else r"$|u - u_h|_{H^1}$")
    handles, _ = axes[0].get_legend_handles_labels()
    rate = "k + 1" if order else "k"
    handles.append(Line2D([], [], ls=":", color="0.3", label=f"slope {rate} (labelled)"))
    handles.append(
        Line2D(
            [], [], ls="", marker="o", mfc="white", color="0.3", label="near the round-off floor"
        )
    )
    axes[0].legend(handles=handles, fontsize=8, loc="lower right")
    save(fig, path)


def closeup_figure(comm: MPI.Comm, k: int, cm, curved, path: Path) -> None:
    nodes, cut = gather_cells(curved.mesh, values=cm.positively_cut)
    fig = ax = None
    if comm.rank == 0:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6, 5.5), layout="constrained")
        ax = fig.subplots()
    plot_conforming(
        ax,
        cm,
        show_background=False,
        mesh=curved.mesh,
        linewidth=0.7,
        title=f"curved triangles of the coarsest mesh, map I, q = {k}",
    )
    if comm.rank == 0:
        from matplotlib.lines import Line2D
        from matplotlib.patches import Patch

        ax.plot(*nodes[cut.astype(bool)].reshape(-1, 2).T, "o", ms=2.5, color="k", zorder=5)
        ax.set_xlim(0.3, 1.05), ax.set_ylim(0.25, 1.0)
        ax.set_xlabel("x"), ax.set_ylabel("y")
        dots = Line2D([], [], ls="", marker="o", ms=2.5, color="k", label="geometry nodes")
        if (legend := ax.get_legend()) is not None:  # plot_conforming's own: add the dots
            handles = [*legend.legend_handles, dots]
            labels = [t.get_text() for t in legend.get_texts()] + [dots.get_label()]
        else:
            handles = [
                Patch(facecolor=KEPT_FACE, edgecolor="k", lw=0.5, label="kept"),
                Patch(facecolor=CUT_FACE, edgecolor="k", lw=0.5, label="positively cut"),
                Line2D([], [], color=BOUNDARY_COLOR, lw=0.8, label=r"$\Gamma$ (exact)"),
                dots,
            ]
            labels = [h.get_label() for h in handles]
        ax.legend(handles, labels, loc="upper right", fontsize=8, framealpha=0.9)
        save(fig, path)


# -

# ## The whole study
#
# `main` runs the study, draws the figures and writes `summary.json`: the errors (`rows`)
# and rates (`rates`), the set-up (`parameters`, with the conforming parameters read back
# from a conforming mesh), the exact solution and optimal rates compared with
# (`reference`), and the versions and number of ranks. `--degrees` restricts the study to
# some polynomial degrees.


# +
def main(argv: Sequence[str] | None = None) -> dict:
    """Run the study (``argv``: command-line options, ``None`` for ``sys.argv``)."""
    extra = argparse.ArgumentParser(add_help=False)
    extra.add_argument("--degrees", type=int, nargs="+", default=[1, 2, 3, 4])
    known, rest = extra.parse_known_args(argv)
    args = demo_options(
        "Poisson convergence on curved universal meshes (also: --degrees K "
        "[K ...], default 1 2 3 4)",
        "out/poisson",
        rest,
    )
    degrees = known.degrees
    comm = MPI.COMM_WORLD

    rows, for_figure, cm = study(comm, degrees, args.quick)
    rates = convergence_rates(comm, rows, degrees)
    if comm.rank == 0:
        for norm in ("L2", "H1"):
            convergence_figure(rows, degrees, norm, args.out / f"convergence_{norm}.png")
    for k, (cm_k, curved) in sorted(for_figure.items()):
        closeup_figure(comm, k, cm_k, curved, args.out / f"closeup_k{k}.png")

    parameters = {
        "quick": args.quick,
        "degrees": list(degrees),
        "domain": "unit disc",
        "background": "equilateral, square of side 2.4 with a margin of 2h",
        "h0": H0,
        "h": [H0 / 2**level for level in range(max(num_levels(k, args.quick) for k in degrees))],
        "levels": {str(k): num_levels(k, args.quick) for k in degrees},
        "maps": {name: f"q = k + {extra}" for name, extra in MAPS.items()},
        "eta": cm.eta,
        "alpha": cm.alpha,
        "R_r_over_h": comm.allreduce(float(np.max(cm.R_r / cm.h, initial=0.0)), op=MPI.MAX),
        "quadrature_degree": "2k + 2q + 4",
        "solver": SOLVER,
        "rate": "between the two finest meshes whose errors exceed TRUSTED times their "
        "round-off estimates; fit: least squares over the three finest such meshes",
        "TRUSTED": TRUSTED,
    }
    reference = {
        "exact_solution": "u = exp(y) sin(x)",
        "optimal_rates": [{"k": k, "L2": k + 1, "H1": k} for k in degrees],
    }
    results = {"rows": rows, "rates": rates}
    path = write_summary(comm, args.out, results, parameters=parameters, reference=reference)
    log(comm, f"wrote {path}")
    check(rows, rates, degrees, args.quick)
    return results


# -

# ## Checks
#
# Errors fall with $k$ on every background (p-refinement): between consecutive degrees by
# a factor of 10 or more (the least on the coarsest background; about 270 at the finest $k = 4$
# level, whose error, $7 \cdot 10^{-13}$, is near the round-off floor), so rounding cannot
# reverse the order. In the
# full study every map and degree has a pair of levels above the round-off floor (see
# `TRUSTED`), and its rates are within 0.15 of the optimal ones or above: a geometry that
# lost an order (e.g. $q < k$, or boundary nodes off $\Gamma$) lowers the $L^2$ and $H^1$
# rates by at least 1/2, while the rates between two levels of a correct
# discretisation differ from the optimal ones by the pre-asymptotic terms of the error,
# $O(h)$ relative to it (observed at the finest pairs: between +0.0 and +0.5), and by
# round-off by at most 0.03.


# +
def check(rows: list[dict], rates: list[dict], degrees: Sequence[int], quick: bool) -> None:
    for name in MAPS:
        for h in sorted({r["h"] for r in rows}):
            errs = [
                r["L2"]
                for k in degrees
                for r in rows
                if r["map"] == name and r["k"] == k and r["h"] == h
            ]
            assert all(b < a for a, b in zip(errs, errs[1:])), (name, h, errs)
    if not quick:
        for r in rates:
            assert r["L2_rate"] is not None and r["H1_rate"] is not None, r
            assert r["L2_rate"] > r["k"] + 1 - 0.15 and r["H1_rate"] > r["k"] - 0.15, r


# -

# +
if __name__ == "__main__":
    main([] if "ipykernel" in sys.modules else None)
# -
