"""DFG 2D-1 accuracy per degree of freedom: universal meshes against body-fitted gmsh meshes.

The steady flow around a cylinder of ``demos/dfg_benchmark.py`` (Schäfer & Turek 1996,
Re = 20) is solved by the demo's own solver (``solve``: Taylor-Hood P2/P1, Newton with
MUMPS, c_D and c_L by the weak residual, Δp by point values of p_h) on

* **gmsh** meshes as the FEniCSx tutorial builds them (its Navier-Stokes demo, DFG 2D-3):
  the OpenCASCADE channel [0, 2.2] x [0, 0.41] minus the disc of radius r = 0.05 at
  (0.2, 0.2), a Distance field from the disc's curve and a Threshold field (``tutorial``:
  LcMin = r/3, LcMax = 0.25 H, DistMin = r, DistMax = 2 H, H = 0.41), ``generate(2)``
  (triangles, the default 2D algorithm: the tutorial recombines into quadrilaterals, which
  Taylor-Hood P2/P1 on triangles does not use), ``setOrder(2)`` (the mid-edge nodes on the
  exact circle) and ``dolfinx.io.gmsh.model_to_mesh``; and variants finer at the cylinder
  (``VARIANTS``). Level l scales every size of every variant by ``FACTORS[l]``.
* **universal** meshes at the same number of degrees of freedom (within 2 %) as each gmsh
  mesh: ``channel_mesh(scale, 2)`` of the demo (its size field), and, to show what limited
  the accuracy before, ``mesh_domain`` with the geometry's own sizing only (``geometry``:
  R / size_factor at the cylinder, growing by 0.2 per unit length to h, the demo's former
  sizing ``h = 0.08 s``, ``size_factor = 2 / s``). Their scale ``s`` is found by a search
  on the number of dofs (which costs one ``mesh_domain`` and the edge count per try): the
  secant step of ``dofs ~ s^-2`` inside a bracket, bisection where it leaves the bracket.
  And ``adaptive``: the demo's adaptive loop (dual-weighted residual indicators of c_D and
  c_L, Dörfler marking, ``refine_size`` mirrored about the cylinder's horizontal axis; run
  once from level 0 past the largest gmsh mesh) up to its last round below the gmsh mesh's
  dofs, then one more refinement whose Dörfler fraction is found by bisection to give
  those dofs (:func:`matched_adaptive`).

For each mesh: the relative errors of c_D, c_L and Δp against the reference values, the
meshing time (gmsh: ``generate(2)`` + ``setOrder(2)``, then ``model_to_mesh``; universal:
the one ``mesh_domain`` call that made the mesh used, not the search) and the solve time
(the demo's ``solve``: spaces, Newton, forces, point values; the same code on both), the
cells on the cylinder. Written as JSON (``--out``) and printed as a table. Timings are wall
times on whatever else runs on the machine (printed load average): the ratios of meshing
times are the point, not the seconds.

Usage::

    python benchmarks/dfg_vs_gmsh.py [--levels 0 1 2 3 4] [--out FILE]
    python benchmarks/dfg_vs_gmsh.py --quick       # level 0 only (about 1e4 dofs)
    python benchmarks/dfg_vs_gmsh.py --spread 2    # six sizes around level 2 (SPREAD)
    python benchmarks/dfg_vs_gmsh.py --layers 2    # where the lift's error sits (wall_layer)
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import dolfinx_universal as du  # initialises the DOLFINx wheel before dolfinx

# isort: split

from mpi4py import MPI

import _results
import gmsh
import numpy as np
from _floor import load_demo
from dolfinx import graph
from dolfinx import mesh as dmesh
from dolfinx.io import gmsh as dgmsh

comm = MPI.COMM_WORLD


demo = load_demo("dfg_benchmark.py", "dfg_benchmark")  # its solver, meshes and constants
R, H = demo.radius, demo.height

VARIANTS: dict[str, dict[str, float]] = {
    "tutorial": {"lc_min": R / 3, "lc_max": 0.25 * H, "dist_min": R, "dist_max": 2 * H},
    "graded": {"lc_min": R / 6, "lc_max": 0.25 * H, "dist_min": R / 2, "dist_max": H},
    "boundary": {"lc_min": R / 12, "lc_max": 0.25 * H, "dist_min": R / 4, "dist_max": H / 2},
}
"""gmsh Threshold fields (at factor 1): the tutorial's; twice finer at the cylinder over a
transition half as long (``graded``); four times finer there over a quarter of it
(``boundary``). At a common factor the three have about the same number of dofs."""

FACTORS = (0.72, 0.425, 0.25, 0.148, 0.087)
"""Size factor of every gmsh variant per level: about 1e4, 3e4, 8e4, 2.4e5, 7e5 dofs with
the tutorial's field (its dofs grow like factor^-2; ratio 1.7 from level to level)."""

MATCH = 0.02
"""Largest relative difference of the universal mesh's dofs to the gmsh mesh's."""


def _relative_errors(q: dict) -> dict[str, float]:
    return {f"err_{k}": (q[k] - v) / v for k, v in demo.reference.items()}


def _count_owned(msh, facets) -> int:
    """Global number of ``facets`` (local indices) counting each once (owned ones)."""
    owned = msh.topology.index_map(1).size_local
    return comm.allreduce(int((facets < owned).sum()), op=MPI.SUM)


def _near_share(msh) -> float:
    """Share of the cells whose midpoint lies within a diameter of the cylinder's surface."""
    owned = msh.topology.index_map(2).size_local
    mid = dmesh.compute_midpoints(msh, 2, np.arange(owned, dtype=np.int32))
    near = np.hypot(mid[:, 0] - demo.centre[0], mid[:, 1] - demo.centre[1]) < 3 * R
    return comm.allreduce(int(near.sum()), op=MPI.SUM) / msh.topology.index_map(2).size_global


# ----------------------------------------------------------------------------- gmsh
def gmsh_mesh(variant: str, factor: float):
    """The body-fitted mesh of ``variant`` with its sizes times ``factor`` (gmsh on rank 0,
    distributed by ``model_to_mesh``): ``(mesh, outer facets, cylinder facets, times)``."""
    field = {k: v * factor if k.startswith("lc") else v for k, v in VARIANTS[variant].items()}
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    times = {"generate_s": 0.0, "model_to_mesh_s": 0.0}
    if comm.rank == 0:
        gmsh.model.add("dfg")
        rect = gmsh.model.occ.addRectangle(0, 0, 0, demo.length, H)
        disc = gmsh.model.occ.addDisk(*demo.centre, 0, R, R)
        fluid, _ = gmsh.model.occ.cut([(2, rect)], [(2, disc)])
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [fluid[0][1]], 1)
        curves = [c[1] for c in gmsh.model.getBoundary(fluid, oriented=False)]
        on_disc = [
            c
            for c in curves
            if abs(math.dist(gmsh.model.occ.getCenterOfMass(1, c)[:2], demo.centre)) < 1e-6
        ]
        gmsh.model.addPhysicalGroup(1, [c for c in curves if c not in on_disc], 1)  # outer
        gmsh.model.addPhysicalGroup(1, on_disc, 2)  # cylinder
        distance = gmsh.model.mesh.field.add("Distance")
        gmsh.model.mesh.field.setNumbers(distance, "EdgesList", on_disc)
        threshold = gmsh.model.mesh.field.add("Threshold")
        gmsh.model.mesh.field.setNumber(threshold, "IField", distance)
        for key, name in (
            ("lc_min", "LcMin"),
            ("lc_max", "LcMax"),
            ("dist_min", "DistMin"),
            ("dist_max", "DistMax"),
        ):
            gmsh.model.mesh.field.setNumber(threshold, name, field[key])
        gmsh.model.mesh.field.setAsBackgroundMesh(threshold)
        t = time.perf_counter()
        gmsh.model.mesh.generate(2)
        gmsh.model.mesh.setOrder(2)
        times["generate_s"] = time.perf_counter() - t
    comm.Barrier()
    t = time.perf_counter()
    # Shared-facet ghosts, as the universal meshes have: the interior-facet integrals of
    # the demo's error indicators (``--layers``) need them on several ranks.
    ghosts = dmesh.create_cell_partitioner(graph.partitioner(), dmesh.GhostMode.shared_facet, 2)
    data = dgmsh.model_to_mesh(gmsh.model, comm, 0, gdim=2, partitioner=ghosts)
    times["model_to_mesh_s"] = comm.allreduce(time.perf_counter() - t, op=MPI.MAX)
    gmsh.finalize()
    times = comm.bcast(times if comm.rank == 0 else None, root=0) | {
        "model_to_mesh_s": times["model_to_mesh_s"]
    }
    tags = data.facet_tags
    return data.mesh, tags.find(1), tags.find(2), times


# ----------------------------------------------------------------------------- universal
DOMAIN = du.Domain(container=None, bodies=[du.Circle(demo.centre, R)])
BOX = [[0.0, 0.0], [demo.length, H]]


def universal_mesh(scale: float, reach: float = 1.0) -> du.MeshedDomain:
    """The demo's mesh (``channel_mesh(scale, 2)``, symmetric about the cylinder's axis),
    its size field's distances times ``reach`` (1: the demo's)."""
    return demo.channel_mesh(scale, 2, reach)


def geometry_mesh(scale: float, reach: float = 1.0) -> du.MeshedDomain:
    """The demo's former sizing: the geometry's own (R / size_factor at the cylinder, growing
    by 0.2 per unit length to h), ``size_factor = 2 / scale``, ``h = 0.08 scale`` (``reach``
    is not used: nothing to widen)."""
    return du.mesh_domain(comm, DOMAIN, 0.08 * scale, degree=2, box=BOX, size_factor=2 / scale)


FAMILIES = {"universal": universal_mesh, "geometry": geometry_mesh, "adaptive": None}
"""Universal meshes matched to each gmsh mesh: the demo's size field, the geometry's own
sizing (the demo before the size field), and the field of the demo's adaptive loop
(:func:`adaptive_family`)."""

ADAPTIVE: dict[str, list] = {"dofs": [], "rounds": []}
"""The rounds of the demo's adaptive loop (run once, past the largest gmsh mesh's dofs)."""


def matched_adaptive(target: int):
    """The adaptive mesh with ``target`` dofs within :data:`MATCH`: the demo's loop up to
    its last round below ``target``, then one more step whose Dörfler fraction (instead of
    the loop's ``THETA``) is found by bisection so that the mesh has ``target`` dofs (the
    dofs grow with the fraction: more cells marked). Returns ``(meshed domain, fraction,
    1.0, seconds of its mesh_domain, tries)``, the closest found if no fraction matches."""
    dofs = ADAPTIVE["dofs"]
    k = max([i for i, d in enumerate(dofs) if d <= target] or [0])
    last = ADAPTIVE["rounds"][k]
    scale = demo.level_scale(0)
    lo, hi = 0.0, 1.0
    best: tuple = (math.inf,)
    for tries in range(1, 31):
        theta = 0.5 * (lo + hi)
        marked = du.mark_cells(last.mesh, last.indicators, theta)
        field = du.refine_size(last.mesh, marked, last.field, mirror=demo.MIRROR)
        t = time.perf_counter()
        md = demo.adaptive_mesh(field, scale)
        seconds = comm.allreduce(time.perf_counter() - t, op=MPI.MAX)
        n = demo.n_dofs(md.mesh)
        found = (md, theta, 1.0, seconds, tries)
        if abs(n / target - 1) < best[0]:
            best = (abs(n / target - 1), *found)
        if abs(n / target - 1) <= MATCH:
            return found
        lo, hi = (theta, hi) if n < target else (lo, theta)
    return best[1:]


def matched_mesh(family: str, target: int, scale: float):
    """The mesh of ``family`` with ``target`` dofs within :data:`MATCH`, searched from the
    guess ``scale``: ``(meshed domain, scale, reach, seconds of its mesh_domain, tries)``.

    First the scale: the secant step of ``dofs ~ scale^-2`` inside a bracket, bisection
    where it leaves it. The quadtree's sizes are powers of two and the field is flat within
    ``dist_min`` of the cylinder (and beyond ``dist_max``), so the count can jump by more
    than the match at one scale (13 % at 9e4 dofs: the whole band of the finest size
    changes level). Where the bracket closes on such a jump, the scale stays at its coarse
    end and ``reach`` >= 1 widens the field's bands (its distances) until the count
    matches: the band's edge moves continuously. The geometry's own sizing has no such knob
    (its band around the circle jumps a quadtree level at once, 17 % of the dofs at 3e4):
    there the closest mesh found is returned (the dofs are in the table, the row's
    ``matched`` is false). So is the demo's field where the jumps of both knobs exceed the
    match: at 1e4 dofs, where the symmetric background's far field is at its root cells'
    size (0.1) and one band of leaves changing level moves the count by 20 %."""
    if family == "adaptive":
        return matched_adaptive(target)
    make = FAMILIES[family]
    assert make is not None
    lo, hi = 0.0, math.inf  # bracket of the knob: dofs(lo) > target > dofs(hi)
    reach = None  # None: searching the scale
    best: tuple = (math.inf,)
    for tries in range(1, 41):
        t = time.perf_counter()
        md = make(scale, 1.0 if reach is None else reach)
        seconds = comm.allreduce(time.perf_counter() - t, op=MPI.MAX)
        dofs = demo.n_dofs(md.mesh)
        found = (md, scale, 1.0 if reach is None else reach, seconds, tries)
        if abs(dofs / target - 1) < best[0]:
            best = (abs(dofs / target - 1), *found)
        if abs(dofs / target - 1) <= MATCH:
            return found
        if reach is None:
            if dofs > target:
                lo = max(lo, scale)
            else:
                hi = min(hi, scale)
            if hi - lo < 1e-3 * hi:  # a jump: the coarse end, then widen the bands
                if family == "geometry":
                    break
                scale, reach, lo, hi = hi, 1.1, 1.0, math.inf  # bracket of reach now
                continue
            guess = scale * math.sqrt(dofs / target)  # dofs ~ scale^-2
            scale = guess if lo < guess < hi else (0.5 * (lo + hi) if hi < math.inf else 2 * lo)
        else:  # dofs grow with reach
            if dofs < target:
                lo = max(lo, reach)
            else:
                hi = min(hi, reach)
            if hi - lo < 1e-4 * hi:
                break
            reach = 0.5 * (lo + hi) if hi < math.inf else 1.0 + 2 * (lo - 1.0)
    return best[1:]


# ----------------------------------------------------------------------------- study
def _adaptive_past(most: float) -> None:
    """The adaptive loop once, past ``most`` dofs (its rounds for :func:`matched_adaptive`)."""
    adaptive_rows, rounds, _ = demo.adaptive_study(most, keep=True)
    ADAPTIVE["dofs"] = [r["n_dofs"] for r in adaptive_rows]
    ADAPTIVE["rounds"] = rounds


def _rows_at(
    level: int, factor: float, variants, families, guesses: dict[str, float], extra=None
) -> list[dict]:
    """Each gmsh variant at ``factor`` and the universal ``families`` at its dofs, solved;
    with ``extra(mesh, outer, cylinder, solution, quantities) -> dict``, its entries in
    each row."""

    def more(*args) -> dict:
        return {} if extra is None else extra(*args)

    rows = []
    for variant in variants:
        msh, outer, cylinder, times = gmsh_mesh(variant, factor)
        q, w = demo.solve(msh, outer, cylinder, f"gmsh_{level}_{variant}")
        row = {
            "level": level,
            "variant": variant,
            "factor": factor,
            "mesh": "gmsh",
            **q,
            **_relative_errors(q),
            "cylinder_edges": _count_owned(msh, cylinder),
            "near_share": _near_share(msh),
            "mesh_s": times["generate_s"] + times["model_to_mesh_s"],
            **times,
            **more(msh, outer, cylinder, w, q),
        }
        rows.append(row)
        report(row)
        for family in families:
            md, scale, reach, seconds, tries = matched_mesh(family, q["n_dofs"], guesses[family])
            knob = {"scale": scale, "reach": reach}
            if family == "adaptive":  # the last step's Doerfler fraction, not a scale
                knob = {"last_fraction": scale}
            else:
                guesses[family] = scale
            tags = md.facet_tags
            out, cyl = tags.find(du.OUTER), tags.find(du.IMMERSED)
            qu, wu = demo.solve(md.mesh, out, cyl, f"{family}_{level}_{variant}")
            row = {
                "level": level,
                "variant": variant,
                "factor": factor,
                "mesh": family,
                **qu,
                **_relative_errors(qu),
                "cylinder_edges": _count_owned(md.mesh, cyl),
                "near_share": _near_share(md.mesh),
                "mesh_s": seconds,
                "matched": abs(qu["n_dofs"] / q["n_dofs"] - 1) <= MATCH,
                **knob,
                "search_tries": tries,
                **more(md.mesh, out, cyl, wu, qu),
            }
            rows.append(row)
            report(row)
    return rows


def run(levels: list[int]) -> list[dict]:
    # The adaptive loop once, past the largest gmsh mesh (its dofs ~ 1e4 (0.72 / factor)^2).
    _adaptive_past(1.3e4 * (FACTORS[0] / FACTORS[max(levels)]) ** 2)
    rows = []
    guesses = {family: 1.0 for family in FAMILIES}
    for level in levels:
        rows += _rows_at(level, FACTORS[level], VARIANTS, FAMILIES, guesses)
    return rows


SPREAD = (0.92, 0.96, 1.0, 1.04, 1.08, 1.12)
"""Factors of ``--spread``: six gmsh meshes of each variant a few per cent apart in size
around a level (dofs about -15 % to +20 %), each with the universal meshes at its dofs."""


def spread(level: int) -> list[dict]:
    """How much the errors move between nearby meshes of each family: the ``graded`` and
    ``tutorial`` gmsh meshes at :data:`SPREAD` times the level's factor, and the demo's
    field and the adaptive loop at the graded meshes' dofs (a single comparison at one
    size cannot tell a systematic difference from the sign changes of the lift)."""
    _adaptive_past(1.3e4 * (FACTORS[0] / (SPREAD[0] * FACTORS[level])) ** 2)
    rows = []
    guesses = {family: 1.0 for family in FAMILIES}
    for f in SPREAD:
        factor = f * FACTORS[level]
        rows += _rows_at(level, factor, ("graded",), ("universal", "adaptive"), guesses)
        rows += _rows_at(level, factor, ("tutorial",), (), guesses)
    return rows


def spread_summary(rows: list[dict]) -> str:
    """Per mesh family: the median and range of |relative error| of c_D and c_L, and in how
    many of the sizes the family's c_L error is below the graded gmsh mesh's."""
    graded = [r for r in rows if r["mesh"] == "gmsh" and r["variant"] == "graded"]
    lines = [
        "| meshes | dofs | median |err c_D| | range | median |err c_L| | range "
        "| c_L below graded gmsh |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, pick in (
        ("gmsh graded", lambda r: r["mesh"] == "gmsh" and r["variant"] == "graded"),
        ("gmsh tutorial", lambda r: r["mesh"] == "gmsh" and r["variant"] == "tutorial"),
        ("universal (field)", lambda r: r["mesh"] == "universal"),
        ("universal (adaptive)", lambda r: r["mesh"] == "adaptive"),
    ):
        mine = [r for r in rows if pick(r)]
        d = np.abs([r["err_c_D"] for r in mine])
        c = np.abs([r["err_c_L"] for r in mine])
        wins = (
            ""
            if name.startswith("gmsh")
            else str(
                sum(
                    abs(r["err_c_L"]) < abs(g["err_c_L"])
                    for r in mine
                    for g in graded
                    if g["factor"] == r["factor"]
                )
            )
            + f" of {len(mine)}"
        )
        n = [r["n_dofs"] for r in mine]
        lines.append(
            f"| {name} | {min(n)}-{max(n)} | {np.median(d):.1e} | {d.min():.1e}-{d.max():.1e} "
            f"| {np.median(c):.1e} | {c.min():.1e}-{c.max():.1e} | {wins} |"
        )
    return "\n".join(lines)


ON_CYLINDER = 1e-9
"""A vertex lies on the cylinder if its distance to the centre is ``R`` within this fraction
of ``R``: both kinds of mesh put their boundary vertices on the circle to rounding (1e-16),
and any other vertex is a fraction of a cell (more than 1e-3 R) away from it."""


def wall_layer(msh, outer, cylinder, w, q: dict) -> dict:
    """Where the forces' errors sit on one mesh (collective).

    The demo's dual-weighted residual indicators (``force_indicators``, whose sums estimate
    the errors of c_D and c_L) split into the first layer (the cells with a vertex on the
    cylinder) and the rest; the first layer's cell diameters (straight, in units of R) and
    the exponent ``a`` of ``|eta_L| ~ diam^a`` over it (least squares of the logarithms); the
    lift's indicators summed separately over the upper and the lower half (cells above and
    below the centre), over the whole mesh and over the first layer: the lift is a
    difference of the two halves' forces, and its error the small difference of the two
    halves' errors."""
    eta_d, eta_l = demo.force_indicators(msh, w, outer, cylinder)
    owned = msh.topology.index_map(2).size_local
    nodes = msh.geometry.dofmaps[0][:owned, :3]  # a triangle's vertices come first
    x = msh.geometry.x[:, :2]
    dist = np.hypot(x[:, 0] - demo.centre[0], x[:, 1] - demo.centre[1])
    first = np.any(np.abs(dist[nodes] - R) <= ON_CYLINDER * R, axis=1)
    p = x[nodes[first]]
    diam = np.max(np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2), axis=1) / R
    upper = x[nodes, 1].mean(axis=1) > demo.centre[1]
    top = upper[first]
    lift = eta_l[first]
    sums = comm.allreduce(
        np.array([eta_d.sum(), eta_l.sum(), np.abs(eta_l).sum(), np.abs(lift).sum(),
                  lift[top].sum(), lift[~top].sum(), np.abs(lift[top]).sum(),
                  np.abs(lift[~top]).sum(), eta_l[upper].sum(), eta_l[~upper].sum()]),
        op=MPI.SUM,
    )  # fmt: skip
    gathered = comm.gather((diam, np.abs(lift)), root=0)
    fit = {}
    if comm.rank == 0:
        d = np.concatenate([g[0] for g in gathered])
        e = np.concatenate([g[1] for g in gathered])
        a = np.polyfit(np.log(d), np.log(np.maximum(e, 1e-300)), 1)[0] if len(d) > 1 else np.nan
        fit = {"cells": len(d), "diam_min": d.min(), "diam_median": np.median(d),
               "diam_max": d.max(), "exponent": a}  # fmt: skip
    fit = comm.bcast(fit, root=0)
    c_d, c_l = q["c_D"], q["c_L"]
    return {
        "first_layer_cells": int(fit["cells"]),
        **{k: float(fit[k]) for k in ("diam_min", "diam_median", "diam_max", "exponent")},
        "estimate_c_D": float(sums[0] / c_d),
        "estimate_c_L": float(sums[1] / c_l),
        "first_layer_share_L": float(sums[3] / sums[2]),
        "first_top_L": float(sums[4] / c_l),
        "first_bottom_L": float(sums[5] / c_l),
        "first_abs_top_L": float(sums[6] / c_l),
        "first_abs_bottom_L": float(sums[7] / c_l),
        "top_L": float(sums[8] / c_l),
        "bottom_L": float(sums[9] / c_l),
    }


def layers(level: int) -> list[dict]:
    """The graded gmsh mesh at ``level``'s factor and the demo's field and adaptive loop at
    its dofs, each with :func:`wall_layer`: what the lift's error is made of."""
    _adaptive_past(1.3e4 * (FACTORS[0] / FACTORS[level]) ** 2)  # past the graded mesh
    guesses = {family: demo.level_scale(level) for family in FAMILIES}
    families = ("universal", "adaptive")
    rows = _rows_at(level, FACTORS[level], ("graded",), families, guesses, extra=wall_layer)
    for r in rows:
        r["mesh"] = "gmsh graded" if r["mesh"] == "gmsh" else r["mesh"]
    return rows


def layers_table(rows: list[dict]) -> str:
    """:func:`layers` as a markdown table (lift terms relative to c_L; the halves: the
    lift's indicators summed over each, whose sum is the estimate)."""
    lines = [
        "| mesh | dofs | err c_L | est. | first layer: cells | diam/R min-median-max "
        "| exponent | its share of sum abs eta_L | upper half | lower half |",
        "|" + "---|" * 10,
    ]
    for r in rows:
        lines.append(
            f"| {r['mesh']} | {r['n_dofs']} | {r['err_c_L']:+.1e} | {r['estimate_c_L']:+.1e} "
            f"| {r['first_layer_cells']} | {r['diam_min']:.3f}-{r['diam_median']:.3f}-"
            f"{r['diam_max']:.3f} | {r['exponent']:.1f} | {r['first_layer_share_L']:.0%} "
            f"| {r['top_L']:+.1e} | {r['bottom_L']:+.1e} |"
        )
    return "\n".join(lines)


COLUMNS = (
    ("level", 5, "d"),
    ("variant", 8, "s"),
    ("mesh", 9, "s"),
    ("n_dofs", 8, "d"),
    ("cylinder_edges", 5, "d"),
    ("near_share", 5, ".2f"),
    ("err_c_D", 9, "+.1e"),
    ("err_c_L", 9, "+.1e"),
    ("err_delta_p", 9, "+.1e"),
    ("mesh_s", 7, ".3f"),
    ("solve_s", 7, ".1f"),
)
HEADS = ("level", "variant", "mesh", "dofs", "cyl", "near", "c_D", "c_L", "Δp", "mesh s", "solve s")


def report(row: dict) -> None:
    if comm.rank == 0:
        print(" ".join(f"{format(row[k], f):>{w}}" for k, w, f in COLUMNS), flush=True)


def markdown(rows: list[dict]) -> str:
    """Side by side at equal dofs: one line per gmsh mesh and its universal meshes (the
    demo's field, the geometry's own sizing, the adaptive loop's field)."""
    lines = [
        "| level | gmsh field | dofs gmsh / univ. / geometry / adaptive | err c_D gmsh | univ. "
        "| geometry | adaptive | err c_L gmsh | univ. | geometry | adaptive | err Δp gmsh "
        "| univ. | geometry | adaptive | mesh s gmsh | univ. | ratio | solve s gmsh | univ. |",
        "|" + "---|" * 20,
    ]
    for g in (r for r in rows if r["mesh"] == "gmsh"):
        u, o, a = (
            next(
                r
                for r in rows
                if r["mesh"] == m and r["level"] == g["level"] and r["variant"] == g["variant"]
            )
            for m in ("universal", "geometry", "adaptive")
        )
        dofs = f"{g['n_dofs']} / {u['n_dofs']} / {o['n_dofs']} / {a['n_dofs']}"
        cells = [str(g["level"]), g["variant"], dofs]
        for k in ("err_c_D", "err_c_L", "err_delta_p"):
            cells += [f"{g[k]:+.1e}", f"{u[k]:+.1e}", f"{o[k]:+.1e}", f"{a[k]:+.1e}"]
        cells += [f"{g['mesh_s']:.2f}", f"{u['mesh_s']:.2f}", f"{g['mesh_s'] / u['mesh_s']:.1f}x"]
        cells += [f"{g['solve_s']:.1f}", f"{u['solve_s']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--levels", type=int, nargs="+", default=list(range(len(FACTORS))))
    p.add_argument("--quick", action="store_true", help="level 0 only")
    p.add_argument("--out", type=Path, default=Path("out/dfg_vs_gmsh.json"))
    p.add_argument(
        "--spread",
        type=int,
        default=None,
        metavar="LEVEL",
        help="the errors' spread over six nearby sizes around LEVEL (SPREAD) instead",
    )
    p.add_argument(
        "--layers",
        type=int,
        default=None,
        metavar="LEVEL",
        help="where the lift's error sits at LEVEL (wall_layer) instead",
    )
    args = p.parse_args()
    if args.layers is not None:
        rows = layers(args.layers)
        if comm.rank == 0:
            print(f"\nthe cylinder's first layer of cells at level {args.layers}:")
            print(layers_table(rows))
            args.out.parent.mkdir(parents=True, exist_ok=True)
            _results.write(args.out, {"layers": args.layers, "rows": rows})
        return
    if args.spread is not None:
        t0 = time.perf_counter()
        rows = spread(args.spread)
        if comm.rank == 0:
            print(
                f"\nspread around level {args.spread} (factors {SPREAD} x {FACTORS[args.spread]}):"
            )
            print(spread_summary(rows))
            print(f"total {time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.2f}")
            args.out.parent.mkdir(parents=True, exist_ok=True)
            _results.write(args.out, {"spread": SPREAD, "rows": rows})
        return
    levels = [0] if args.quick else args.levels
    if comm.rank == 0:
        print(
            f"DFG 2D-1 on gmsh {gmsh.__version__} and universal meshes, levels {levels}, "
            f"{comm.size} rank(s), load average {os.getloadavg()[0]:.2f}"
        )
        print(" ".join(f"{h:>{w}}" for h, (_, w, _) in zip(HEADS, COLUMNS)))
    t0 = time.perf_counter()
    rows = run(levels)
    if comm.rank == 0:
        print("\nrelative errors at equal dofs (geometry: the geometry's own sizing, before):")
        print(markdown(rows))
        print(f"total {time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.2f}")
        args.out.parent.mkdir(parents=True, exist_ok=True)
        summary = {
            "reference": demo.reference,
            "variants": VARIANTS,
            "families": list(FAMILIES),
            "factors": FACTORS,
            "match": MATCH,
            "rows": rows,
        }
        _results.write(args.out, summary)


if __name__ == "__main__":
    main()
