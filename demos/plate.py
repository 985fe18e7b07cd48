# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
# ---

# # A simply supported Reissner-Mindlin plate: which tangent?
#
# This demo reproduces the simply supported plate example of Rangarajan & Lew (2014): on a
# curved universal mesh, the slip condition $\theta \cdot T = 0$ must be imposed with the
# tangent of the true boundary; with the tangent of the discrete boundary the plate is
# clamped at its boundary vertices and converges to a wrong deflection.
#
# It illustrates how to
#
# - solve a mixed problem on degree-2 and degree-4 curved universal meshes of a disc,
# - impose a tangential condition node by node with
#   {py:class}`dolfinx_universal.curved.constraints.SlipConstraint`,
# - evaluate a function at a point in parallel.
#
# Run it with
#
# ```bash
# python demos/plate.py [--quick] [--out DIR]
# mpirun -n 2 python demos/plate.py [--quick] [--out DIR]
# ```
#
# (same numbers on any number of ranks; `--quick` keeps the two coarsest of the four
# levels). In a notebook, call `main(["--quick"])`. The output folder (default `out/plate`)
# receives `summary.json` and the figures `deflection.png` and `w_center.png`. The log
# lists, per run, the number of boundary nodes with one condition and with two (the
# clamped vertices of the discrete-tangent variant).
#
# ## The problem
#
# A circular plate of radius $R = 3.142$ and thickness $\tau = R/4$, Lamé
# constants $\lambda = \mu = 1$, uniform load $p = 10^{-3}$. The rotations $\theta$ and the
# deflection $w$ minimise
#
# $$ F(\theta, w) = \frac12 \int_\Omega \lambda (\operatorname{tr} \varepsilon(\theta))^2
#    + 2\mu\, \varepsilon(\theta):\varepsilon(\theta)
#    + \frac{6\mu}{\tau^2} \int_\Omega |\theta - \nabla w|^2
#    - \frac{12}{\tau^3} \int_\Omega p\, w $$
#
# subject to $w = 0$ and $\theta \cdot T = 0$ on $\Gamma$ ($T$ the unit tangent). Its first
# variation is the weak form solved below, with equal-order P2 for $\theta$ and $w$ on
# degree-2 (or 4) curved universal meshes of the disc.
#
# The condition $\theta\cdot T = 0$ is imposed node by node with
# {py:class}`dolfinx_universal.curved.constraints.SlipConstraint` (a local rotation of the two
# components of $\theta$ at each boundary node). Three variants:
#
# * `I_true_tangent`: isoparametric map $I_h$ (geometry P2), $T$ = the tangent of the true
#   circle at each boundary node (the nodes lie on the circle);
# * `G_true_tangent`: $G_h$ interpolated at degree 4 (superparametric), true tangent at the
#   closest point of each node;
# * `I_discrete_tangent`: map $I_h$, $T$ = the tangent of the mesh boundary. The P2 boundary
#   is only $C^0$: at each boundary vertex the two facets have different tangents, the
#   condition is imposed for both, and both rotation components are clamped there. This is
#   the classical failure (a relative of the Babuška paradox): the plate is clamped at a
#   growing number of points and converges to a *wrong* deflection.
#
# ## Exact centre deflection
#
# The problem is invariant under rotations about the centre and has a unique solution, so
# $\theta = \phi(r) e_r$ ($\theta\cdot T = 0$ holds everywhere: the tangential condition is
# then also the natural one). With the shear force $q = k(\theta - \nabla w)$,
# $k = 12\mu/\tau^2$, and the load $f = 12 p/\tau^3$, the Euler-Lagrange equations are
# $\operatorname{div} q = f$ and $(\lambda + 2\mu)\nabla \operatorname{div}\theta = q$
# ($\theta$ is a gradient, so $\operatorname{div}\sigma(\theta) = (\lambda+2\mu)
# \nabla\operatorname{div}\theta$). Hence $q_r = f r/2$,
# $\phi = f r^3 / (16(\lambda+2\mu)) + C r/2$, and the free radial moment
# $\lambda \operatorname{div}\theta + 2\mu\phi' = 0$ at $r = R$ gives
# $C = -f R^2 (4\lambda + 6\mu) / (16 (\lambda+2\mu)(\lambda+\mu))$. Integrating
# $w' = \phi - q_r/k$ from $w(R) = 0$,
#
# $$ w(0) = \frac{(3\lambda + 5\mu) f R^4}{64 (\lambda + 2\mu)(\lambda + \mu)}
#    + \frac{f R^2}{4k}: $$
#
# the Kirchhoff value $(5+\nu) f R^4 / (64 (1+\nu) D)$ with $D = \lambda + 2\mu$,
# $\nu = \lambda/(\lambda + 2\mu)$, plus the shear correction. For $\lambda = \mu = 1$ this is
# $p (R^4 + R^2\tau^2)/(4\tau^3)$, and $w(0) = 17 p R = 0.053414$ for $\tau = R/4$.
# The same steps with $\phi(R) = 0$ give the clamped plate,
# $w(0) = f R^4 / (64(\lambda + 2\mu)) + f R^2/(4k) = 0.01571$: the value that the
# discrete-tangent variant drifts towards as more and more boundary points are clamped.


# +
from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

from mpi4py import MPI

import basix.ufl
import numpy as np
import ufl
from dolfinx import fem

import dolfinx_universal as du
from dolfinx_universal.curved.constraints import SlipConstraint
from dolfinx_universal.demo_support import demo_options, log, point_values, write_summary
from dolfinx_universal.plotting import save

R, tau, lam, mu, p = 3.142, 3.142 / 4, 1.0, 1.0, 1e-3
k_shear, f_load = 12 * mu / tau**2, 12 * p / tau**3
w_exact = f_load * (
    (3 * lam + 5 * mu) * R**4 / (64 * (lam + 2 * mu) * (lam + mu)) + R**2 / (4 * k_shear)
)
assert np.isclose(w_exact, p * (R**4 + R**2 * tau**2) / (4 * tau**3))
w_clamped = f_load * (R**4 / (64 * (lam + 2 * mu)) + R**2 / (4 * k_shear))
# -

# ## The solver
#
# A mixed space $W = P_2^2 \times P_2$; $w = 0$ is an ordinary Dirichlet condition on the
# boundary nodes, $\theta\cdot T = 0$ a {py:class}`SlipConstraint` on `W.sub(0)`.


# +
def eps(v):
    return ufl.sym(ufl.grad(v))


def solve_plate(curved: du.CurvedMesh, tangent: str) -> tuple[fem.Function, SlipConstraint]:
    """Solve the plate on ``curved`` with the given tangent; return ``(theta, w)`` and the
    constraint."""
    msh = curved.mesh
    P2 = basix.ufl.element("Lagrange", "triangle", 2)
    P2v = basix.ufl.element("Lagrange", "triangle", 2, shape=(2,))
    W = fem.functionspace(msh, basix.ufl.mixed_element([P2v, P2]))
    theta, w = ufl.TrialFunctions(W)
    eta, v = ufl.TestFunctions(W)
    a = (
        lam * ufl.div(theta) * ufl.div(eta)
        + 2 * mu * ufl.inner(eps(theta), eps(eta))
        + k_shear * ufl.inner(theta - ufl.grad(w), eta - ufl.grad(v))
    ) * ufl.dx
    L = f_load * v * ufl.dx
    Q, _ = W.sub(1).collapse()
    facets = curved.facet_tags.find(du.IMMERSED)
    dofs = fem.locate_dofs_topological((W.sub(1), Q), 1, facets)
    bc = fem.dirichletbc(fem.Function(Q), dofs, W.sub(1))
    slip = SlipConstraint(W.sub(0), curved, component="tangential", tangent=tangent)
    uh = slip.solve(a, L, bcs=[bc])
    assert slip.residual(uh) < 1e-12
    return uh, slip


def value_at_origin(u: fem.Function) -> float:
    """``u(0, 0)`` of a scalar function, from whichever rank holds the point (collective)."""
    return float(point_values([u], np.zeros((1, 3)))[0][0, 0])


# -

# ## The study
#
# Equilateral backgrounds of size $h_0/2^l$, $h_0 = 0.28 R$, covering the disc with a margin
# of $2 h_0$; each is conformed to the disc once and curved for every variant.

# +
VARIANTS = {
    "I_true_tangent": ("I", 2, "true"),
    "G_true_tangent": ("G", 4, "true"),
    "I_discrete_tangent": ("I", 2, "discrete"),
}
H0 = 0.28 * R
MARGIN = R + 2 * H0


def study(comm: MPI.Comm, levels: int):
    """Centre deflections of every variant and level; the finest ``I_true_tangent`` ``w``
    and the last conforming mesh."""
    disc = du.Circle((0.0, 0.0), R)
    rows = []
    t_start = time.perf_counter()
    for level in range(levels):
        h = H0 / 2**level
        background = du.equilateral_mesh(comm, [[-MARGIN, -MARGIN], [MARGIN, MARGIN]], h)
        cm = du.conform(background, disc)
        for name, (map_, degree, tangent) in VARIANTS.items():
            t0 = time.perf_counter()
            curved = du.curved_mesh(cm, degree, map_)
            uh, slip = solve_plate(curved, tangent)
            dofmap = uh.function_space.dofmap
            ndofs = dofmap.index_map.size_global * dofmap.index_map_bs
            single, double = slip.num_constrained
            w_h = uh.sub(1).collapse()
            wc = value_at_origin(w_h)
            rows.append({"variant": name, "level": level, "h": h, "n_dofs": ndofs, "w_center": wc})
            log(
                comm,
                f"level {level} h={h:.4f} {name:19s} dofs={ndofs:6d} "
                f"nodes={single:3d}+{double:3d} w(0)={wc:.6f} error={wc - w_exact:+.2e} "
                f"({time.perf_counter() - t0:.1f} s)",
            )
            if name == "I_true_tangent":
                finest = w_h
    log(comm, f"study took {time.perf_counter() - t_start:.1f} s")
    return rows, finest, cm


# -

# ## Figures
#
# The deflection on the finest `I_true_tangent` mesh (the P2 nodal values, triangulated),
# and the centre deflection against $h$ for the three variants with the exact and the
# clamped values (left) and its relative error (right). The figures are drawn on rank 0
# with matplotlib's object interface (no pyplot state, no backend to choose).


# +
def deflection_figure(comm: MPI.Comm, w_h: fem.Function, level: int, path: Path) -> None:
    Q = w_h.function_space
    n_owned = Q.dofmap.index_map.size_local
    xs = comm.gather(Q.tabulate_dof_coordinates()[:n_owned, :2], root=0)
    ws = comm.gather(w_h.x.array[:n_owned].copy(), root=0)
    if comm.rank != 0:
        return
    import matplotlib.tri as mtri
    from matplotlib.figure import Figure

    xy, wv = np.concatenate(xs), np.concatenate(ws)
    fig = Figure(figsize=(5.8, 4.8), layout="constrained")
    ax = fig.subplots()
    tc = ax.tricontourf(mtri.Triangulation(xy[:, 0], xy[:, 1]), wv, levels=20, cmap="viridis")
    fig.colorbar(tc, ax=ax, label="deflection w")
    ax.set_aspect("equal")
    ax.set_xlabel("x"), ax.set_ylabel("y")
    ax.set_title(f"deflection, I_true_tangent, level {level}")
    save(fig, path)


def w_center_figure(rows: list[dict], path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11.5, 4.4), layout="constrained")
    ax, ax_err = fig.subplots(1, 2)
    for name, marker in zip(VARIANTS, ("o", "s", "^")):
        sel = [r for r in rows if r["variant"] == name]
        hs = np.array([r["h"] for r in sel])
        wc = np.array([r["w_center"] for r in sel])
        ax.semilogx(hs, wc, marker + "-", label=name)
        ax_err.loglog(hs, np.abs(wc - w_exact) / w_exact, marker + "-", label=name)
    ax.axhline(w_exact, color="k", ls=":", lw=1, label=f"exact {w_exact:.5f}")
    ax.axhline(w_clamped, color="0.5", ls="--", lw=1, label=f"clamped plate {w_clamped:.5f}")
    ax.set_ylabel("centre deflection w(0, 0)")
    ax.set_title("centre deflection")
    ax_err.set_ylabel("|w(0, 0) - exact| / exact")
    ax_err.set_title("relative error of the centre deflection")
    for a in (ax, ax_err):
        a.set_xticks(hs, [f"{h:.3g}" for h in hs])
        a.set_xticks([], minor=True)
        a.set_xlabel("mesh size h")
        a.grid(True, which="both", lw=0.3)
        a.legend(fontsize=8)
    save(fig, path)


# -

# ## The whole study
#
# `main` runs the study, draws the figures and writes `summary.json`: the centre
# deflections (`rows`), the set-up (`parameters`), the exact and clamped centre
# deflections compared with (`reference`), and the versions and number of ranks.


# +
def main(argv: Sequence[str] | None = None) -> dict:
    """Run the study (``argv``: command-line options, ``None`` for ``sys.argv``)."""
    args = demo_options("Reissner-Mindlin plate with slip constraints", "out/plate", argv)
    comm = MPI.COMM_WORLD
    levels = 2 if args.quick else 4
    log(comm, f"exact centre deflection w(0) = {w_exact:.6f} (clamped plate: {w_clamped:.6f})")

    rows, finest, cm = study(comm, levels)
    deflection_figure(comm, finest, levels - 1, args.out / "deflection.png")
    if comm.rank == 0:
        w_center_figure(rows, args.out / "w_center.png")

    parameters = {
        "quick": args.quick,
        "R": R,
        "tau": tau,
        "lambda": lam,
        "mu": mu,
        "p": p,
        "elements": "P2 rotations, P2 deflection",
        "background": "equilateral, square of half-side R + 2 h0",
        "h0": H0,
        "h": [H0 / 2**level for level in range(levels)],
        "variants": {
            name: {"map": m, "geometry_degree": q, "tangent": t}
            for name, (m, q, t) in VARIANTS.items()
        },
        "eta": cm.eta,
        "alpha": cm.alpha,
        "R_r_over_h": comm.allreduce(float(np.max(cm.R_r / cm.h, initial=0.0)), op=MPI.MAX),
    }
    reference = {
        "w_center_exact": w_exact,
        "w_center_exact_formula": "p (R^4 + R^2 tau^2) / (4 tau^3) = 17 p R for tau = R/4",
        "w_center_clamped": w_clamped,
        "w_center_clamped_formula": "f R^4 / (64 (lambda + 2 mu)) + f R^2 / (4 k), "
        "f = 12 p / tau^3, k = 12 mu / tau^2",
    }
    results = {"rows": rows}
    path = write_summary(comm, args.out, results, parameters=parameters, reference=reference)
    log(comm, f"wrote {path}, deflection.png, w_center.png")
    check(comm, rows, levels)
    return results


# -

# ## Checks
#
# With the true tangent the centre deflection converges (successive differences shrink) to
# the exact value; with the discrete tangent it stays away from it. The differences shrink
# by factors of 10 or more (checked: 2), from $4 \cdot 10^{-5}$ to $2 \cdot 10^{-7}$
# ($w \approx 0.053$), far above the rounding of the solves; the exact value is met to
# $10^{-3}$ relative (observed: $2 \cdot 10^{-7}$ at the finest level), while the discrete
# tangent misses it by 60 % or more (checked: 25 %); `spread` (the two true-tangent
# maps) and `miss` differ by orders of magnitude. The slip
# constraint is built into the basis (a rotation of the nodal frame), so it holds to
# rounding, $10^{-17}$ for rotations of size $0.1$; $10^{-12}$ leaves five orders.


# +
def check(comm: MPI.Comm, rows: list[dict], levels: int) -> None:
    w = {n: np.array([r["w_center"] for r in rows if r["variant"] == n]) for n in VARIANTS}
    log(comm, "\nlevel " + " ".join(f"{n:>19s}" for n in VARIANTS))
    for level in range(levels):
        log(comm, f"{level:5d} " + " ".join(f"{w[n][level]:19.6f}" for n in VARIANTS))
    for name in ("I_true_tangent", "G_true_tangent"):
        steps = np.abs(np.diff(w[name]))
        assert np.all(steps[1:] < 0.5 * steps[:-1]), (name, steps)
        assert abs(w[name][-1] - w_exact) < 1e-3 * w_exact, (name, w[name][-1], w_exact)
    spread = np.abs(w["I_true_tangent"] - w["G_true_tangent"])
    miss = np.abs(w["I_discrete_tangent"] - w["I_true_tangent"])
    assert np.all(miss > 100 * spread) and np.all(miss > 0.25 * w_exact), (miss, spread)
    log(
        comm,
        f"true tangents: |w - w_exact| = {abs(w['I_true_tangent'][-1] - w_exact):.1e} "
        f"(I), {abs(w['G_true_tangent'][-1] - w_exact):.1e} (G); discrete tangent off by "
        f"{miss[-1] / w_exact:.0%}",
    )


# -

# +
if __name__ == "__main__":
    main([] if "ipykernel" in sys.modules else None)
# -
