"""Meshing the unit ball: a universal mesh against gmsh's 3D mesher, times and dihedral angles.

The domain is the unit ball (centre 0, radius 1). For each target size (default about 1e6
tetrahedra in the ball; ``--quick``: 2e4) the benchmark measures

1. **universal** -- an A15 background (:func:`~dolfinx_universal.a15_mesh`) of size ``h``
   on ``[-L, L]^3``, ``L = 1 + 4 h`` (the relaxation radius ``3 h`` and a cell more), ``h``
   chosen from the target (the A15 lattice has ``11.5 / h^3`` tetrahedra per unit volume);
   then ``UniversalMesh(background)`` (defaults: ``relax=True``, ``eta=0.2``) and
   ``.conform(Sphere(0, 1))``. Timed separately: the background's construction (``bg``),
   the preparation (``prepare``), the first conform on the new background (``first``, cold:
   it also pays DOLFINx's first-use costs on that background) and, since a background is
   built once for many domains, the median of ``--repeat`` further conforms of the ball
   moved by a fraction of ``h`` (``OFFSETS``, fixed, never tuned) with their stage split
   (``ConformingMesh.timings``; ``map`` includes ``relax``). ``universal`` = bg + prepare +
   first: meshing one ball from nothing.
2. **gmsh** -- ``occ.addSphere(0, 0, 0, 1)``, ``Mesh.MeshSizeMin = Mesh.MeshSizeMax = size``,
   ``gmsh.model.mesh.generate(3)`` with the default 3D algorithm and optimiser (``Mesh.Optimize
   = 1``; the options are printed), order 1, then ``dolfinx.io.gmsh.model_to_mesh``. ``size``
   is set so that gmsh's tetrahedron count matches the universal mesh's (a volume and a
   boundary term, ``cells = a / size^3 + b / size^2``, fitted to two untimed meshes of about
   1e4 and 9e4 tetrahedra); the counts are reported. ``--repeat`` repetitions
   (median), one from ``--gmsh-single-from`` target cells on (default 5e5: at 1e6 gmsh takes
   minutes).

Quality of both meshes (the centred ball's universal mesh and gmsh's): the smallest and
largest dihedral angle, the histogram of all dihedral angles in 10-degree bins, the
smallest radius ratio ``3 r_in / R_circ`` and mean ratio (both 1 for the regular
tetrahedron), by :func:`dolfinx_universal.conforming.quality.cell_quality` (what
:func:`~dolfinx_universal.quality_report` computes) on the owned cells of each DOLFINx mesh.

Neither side includes function spaces, assembly or I/O. One untimed warm-up of each
pipeline on a small ball comes first (imports, first-call costs). In parallel every timing
is the maximum over ranks (barrier, then ``perf_counter`` around the collective call);
gmsh generates on rank 0 while the other ranks sleep. The machine's load average is printed
before and after, and process CPU times beside the wall times.

Usage::

    python benchmarks/conform_vs_gmsh_3d.py [--sizes 1e6] [--repeat 3] [--out FILE]
    python benchmarks/conform_vs_gmsh_3d.py --quick        # 2e4 tetrahedra, one repetition
"""

from __future__ import annotations

import argparse
import math
import statistics
import warnings

import dolfinx_universal as du  # initialises the DOLFINx wheel before dolfinx

# isort: split

from mpi4py import MPI

import _results
import gmsh
import numpy as np
from _tables import columns, header
from conform_vs_gmsh import Clock, load, timed
from dolfinx.io import gmsh as dgmsh

from dolfinx_universal.cells.tet import DIHEDRAL_BIN_EDGES
from dolfinx_universal.conforming.quality import cell_quality

BALL_VOLUME = 4.0 * math.pi / 3.0
A15_DENSITY = 11.5
"""Tetrahedra of the A15 lattice of size ``h`` per unit volume, times ``h^3`` (46 per cell
of side ``4^(1/3) h``)."""
STAGES = ("classify", "project", "relax", "map", "mesh")
OFFSETS = [(0.37, 0.11, -0.23), (-0.23, 0.41, 0.17), (0.13, -0.29, 0.31), (-0.41, -0.17, -0.07)]
"""Ball centre offsets in units of ``h`` of the warm conforms (fixed, not tuned)."""


def size_for_cells(num_cells: float) -> float:
    """A15 size ``h`` with about ``num_cells`` tetrahedra in the unit ball."""
    return float(np.cbrt(A15_DENSITY * BALL_VOLUME / num_cells))


def num_cells(msh) -> int:
    """Global number of cells of a DOLFINx mesh."""
    return msh.topology.index_map(msh.topology.dim).size_global


def quality(comm: MPI.Comm, x: np.ndarray, cells: np.ndarray) -> dict:
    """Dihedral angles, radius and mean ratios of owned tetrahedra ``cells`` (collective)."""
    n = len(x)
    q = cell_quality(comm, x, x, cells, -np.ones(n), np.zeros(n, dtype=bool))
    keys = ("n_cells", "theta_min_deg", "theta_max_deg", "radius_ratio_min", "mean_ratio_min")
    return {k: q[k] for k in keys + ("n_inverted", "dihedral_histogram")}


def mesh_quality(comm: MPI.Comm, msh) -> dict:
    """:func:`quality` of a degree-1 DOLFINx tetrahedral mesh."""
    nco = msh.topology.index_map(3).size_local
    return quality(comm, msh.geometry.x, msh.geometry.dofmaps[0][:nco])


def bench_universal(comm: MPI.Comm, h: float, repeat: int) -> dict:
    """Background, preparation, first conform of the ball, then ``repeat`` moved conforms."""
    L = 1.0 + 4.0 * h
    background, t_bg = timed(comm, du.a15_mesh, comm, [[-L] * 3, [L] * 3], h)
    c_bg = Clock.cpu
    um, t_prep = timed(comm, du.UniversalMesh, background)
    c_prep = Clock.cpu
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UserWarning)
        cm, t_first = timed(comm, um.conform, du.Sphere((0.0, 0.0, 0.0), 1.0))
        c_first = Clock.cpu
        report = du.quality_report(cm)
        first_cells = num_cells(cm.mesh)
        del cm
        runs = []
        for i in range(repeat):
            centre = h * np.asarray(OFFSETS[i % len(OFFSETS)])
            cm, t = timed(comm, um.conform, du.Sphere(centre, 1.0))
            stages = {k: comm.allreduce(cm.timings.get(k, 0.0), op=MPI.MAX) for k in STAGES}
            runs.append({"total": t, "cpu": Clock.cpu, "stages": stages})
            del cm
    totals = [r["total"] for r in runs]
    med = statistics.median(totals)
    pick = min(runs, key=lambda r: abs(r["total"] - med))
    keys = ("n_cells", "theta_min_deg", "theta_max_deg", "radius_ratio_min", "mean_ratio_min")
    return {
        "h": h,
        "box_half_width": L,
        "background_cells": num_cells(background),
        "background_build_s": t_bg,
        "prepare_s": t_prep,
        "first_conform_s": t_first,
        "universal_total_s": t_bg + t_prep + t_first,
        "universal_total_cpu_s": c_bg + c_prep + c_first,
        "conform_cells": first_cells,
        "conform_s": med,
        "conform_cpu_s": pick["cpu"],
        "conform_stages_s": pick["stages"],
        "conform_totals_s": totals,
        "universal_quality": {k: report[k] for k in keys + ("n_inverted", "dihedral_histogram")},
        "universal_warnings": len(caught),
    }


def gmsh_ball(comm: MPI.Comm, size: float):
    """Mesh the unit ball with gmsh on rank 0 and load it into DOLFINx.

    Returns the DOLFINx mesh and the wall and CPU seconds of generate(3) and model_to_mesh.
    """
    if comm.rank == 0:
        gmsh.clear()
        gmsh.model.add("ball")
        ball = gmsh.model.occ.addSphere(0.0, 0.0, 0.0, 1.0)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [ball], 1)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
    _, t_gen = timed(comm, lambda: gmsh.model.mesh.generate(3) if comm.rank == 0 else None)
    c_gen = Clock.cpu
    data, t_m2m = timed(comm, dgmsh.model_to_mesh, gmsh.model, comm, 0, gdim=3)
    c_m2m = Clock.cpu
    if comm.rank == 0:
        gmsh.clear()
    return data.mesh, {"generate": t_gen, "m2m": t_m2m, "generate_cpu": c_gen, "m2m_cpu": c_m2m}


def bench_gmsh(comm: MPI.Comm, size: float, repeat: int) -> dict:
    """Time gmsh generate(3) + model_to_mesh ``repeat`` times; the median run's figures."""
    runs = []
    for _ in range(repeat):
        msh, t = gmsh_ball(comm, size)
        runs.append(dict(t, cells=num_cells(msh), quality=mesh_quality(comm, msh)))
        del msh
    totals = [r["generate"] + r["m2m"] for r in runs]
    med = statistics.median(totals)
    pick = min(runs, key=lambda r: abs(r["generate"] + r["m2m"] - med))
    return {
        "gmsh_size": size,
        "gmsh_cells": pick["cells"],
        "gmsh_generate_s": pick["generate"],
        "gmsh_model_to_mesh_s": pick["m2m"],
        "gmsh_total_s": pick["generate"] + pick["m2m"],
        "gmsh_total_cpu_s": pick["generate_cpu"] + pick["m2m_cpu"],
        "gmsh_repetitions": len(runs),
        "gmsh_quality": pick["quality"],
    }


CALIBRATION_SIZES = (0.12, 0.06)
"""gmsh sizes of the untimed calibration meshes (about 1e4 and 9e4 tetrahedra)."""


def calibrate_gmsh(comm: MPI.Comm) -> tuple[float, float]:
    """Untimed gmsh + model_to_mesh runs (also the warm-up): ``(a, b)`` of the fit
    ``cells = a / size^3 + b / size^2`` (a volume and a boundary term) through the
    :data:`CALIBRATION_SIZES`. A volume term alone (``cells * size^3`` of one small mesh)
    undershoots: its ratio grows with the mesh (the boundary's share falls), and it gave
    915082 tetrahedra for a target of 1024292."""
    s = np.asarray(CALIBRATION_SIZES)
    cells = [num_cells(gmsh_ball(comm, float(si))[0]) for si in s]
    a, b = np.linalg.solve(np.column_stack([s**-3.0, s**-2.0]), np.asarray(cells, float))
    return float(a), float(b)


def gmsh_size(fit: tuple[float, float], cells: int) -> float:
    """The gmsh size whose fitted count (:func:`calibrate_gmsh`) is ``cells``."""
    a, b = fit
    roots = np.roots([a, b, 0.0, -float(cells)])  # a u^3 + b u^2 = cells, u = 1 / size
    u = max(r.real for r in roots if abs(r.imag) < 1e-9 * abs(r) and r.real > 0)
    return float(1.0 / u)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sizes", type=float, nargs="+", default=[1e6],
        help="target tetrahedron counts in the ball (default 1e6)",
    )  # fmt: skip
    parser.add_argument("--repeat", type=int, default=3, help="timed repetitions (default 3)")
    parser.add_argument("--quick", action="store_true", help="2e4 tetrahedra, one repetition")
    parser.add_argument(
        "--gmsh-single-from", type=float, default=5e5,
        help="one gmsh repetition only from this target count on",
    )  # fmt: skip
    parser.add_argument("--out", help="write the results as JSON to this file")
    args = parser.parse_args(argv)
    if args.quick:
        args.sizes, args.repeat = [2e4], 1
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    comm = MPI.COMM_WORLD
    root = comm.rank == 0

    def say(*a):
        if root:
            print(*a, flush=True)

    options = ""
    if root:
        gmsh.initialize()
        gmsh.option.setNumber("General.Terminal", 0)
        names = (
            "Mesh.Algorithm3D", "Mesh.Optimize", "Mesh.OptimizeNetgen", "Mesh.ElementOrder",
            "General.NumThreads", "Mesh.MaxNumThreads3D",
        )  # fmt: skip
        options = ", ".join(f"{n}={gmsh.option.getNumber(n):g}" for n in names)
    say(f"unit ball; MPI ranks: {comm.size}; load average {load()}")
    say(f"gmsh {gmsh.__version__}: OCC sphere, generate(3), defaults ({options})")
    say(f"universal: A15 background, UniversalMesh defaults (relax=True); repeat={args.repeat}")

    # Untimed warm-ups of both pipelines (first-call costs).
    fit = calibrate_gmsh(comm)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        h0 = size_for_cells(5e3)
        bg0 = du.a15_mesh(comm, [[-1 - 4 * h0] * 3, [1 + 4 * h0] * 3], h0)
        du.UniversalMesh(bg0).conform(du.Sphere((0.0, 0.0, 0.0), 1.0))

    rows = []
    for target in args.sizes:
        h = size_for_cells(target)
        say(f"\n-- target {target:.0e} tetrahedra in the ball: h = {h:.4g}")
        row = {"target_cells": int(target), "ranks": comm.size}
        row.update(bench_universal(comm, h, args.repeat))
        say(
            f"   universal: background {row['background_cells']} tets on [-L, L]^3, "
            f"L = {row['box_half_width']:.4g}, built in {row['background_build_s']:.3f} s, "
            f"prepared in {row['prepare_s']:.3f} s, first conform {row['first_conform_s']:.3f}"
            " s; conforms of the moved ball "
            + ", ".join(f"{t:.3f}" for t in row["conform_totals_s"])
            + f" s; {row['universal_warnings']} low-quality warning(s)"
        )
        size = gmsh_size(fit, row["conform_cells"])
        gmsh_repeat = 1 if target >= args.gmsh_single_from else args.repeat
        row.update(bench_gmsh(comm, size, gmsh_repeat))
        say(
            f"   gmsh size {size:.4g}: {row['gmsh_cells']} tets, generate "
            f"{row['gmsh_generate_s']:.3f} s + model_to_mesh {row['gmsh_model_to_mesh_s']:.3f} s"
            f" ({row['gmsh_repetitions']} repetition(s))"
        )
        row["ratio_total"] = row["gmsh_total_s"] / row["universal_total_s"]
        row["ratio_conform"] = row["gmsh_total_s"] / row["conform_s"]
        row["ratio_total_cpu"] = row["gmsh_total_cpu_s"] / row["universal_total_cpu_s"]
        row["ratio_conform_cpu"] = row["gmsh_total_cpu_s"] / row["conform_cpu_s"]
        rows.append(row)

    if root:
        gmsh.finalize()
    say("\n" + table(rows, comm.size))
    say(f"load average {load()}")
    if args.out and root:
        results = {"ranks": comm.size, "gmsh_options": options, "rows": rows}
        _results.write(args.out, results, None if argv is None else [__file__, *argv])
        say(f"wrote {args.out}")
    return rows


def table(rows: list[dict], ranks: int) -> str:
    """Fixed-width text tables of the results."""
    lines = [f"Mesh the unit ball ({ranks} MPI rank(s), wall seconds, max over ranks)"]
    head = ["target", "h", "bg tets", "bg", "prepare", "first", "universal", "tets"]
    head += ["conform", "classify", "project", "relax", "map", "mesh"]
    lines += header(head)
    for r in rows:
        st = r["conform_stages_s"]
        lines.append(
            columns(
                [
                    f"{r['target_cells']:.0e}",
                    f"{r['h']:.4f}",
                    r["background_cells"],
                    f"{r['background_build_s']:.3f}",
                    f"{r['prepare_s']:.3f}",
                    f"{r['first_conform_s']:.3f}",
                    f"{r['universal_total_s']:.3f}",
                    r["conform_cells"],
                    f"{r['conform_s']:.3f}",
                ]
                + [f"{st[k]:.3f}" for k in STAGES]
            )
        )
    lines.append(
        "universal = bg (a15_mesh) + prepare (UniversalMesh, relax=True) + first (conform on "
        "the new\nbackground); conform = median of the conforms of the moved ball on the "
        "prepared background,\nsplit by stage (map includes relax)."
    )
    head = ["target", "gmsh tets", "generate", "to_mesh", "gmsh", "gmsh/univ", "gmsh/conf"]
    head += ["cpu g/u", "cpu g/c"]
    lines += ["", *header(head)]
    for r in rows:
        lines.append(
            columns(
                [
                    f"{r['target_cells']:.0e}",
                    r["gmsh_cells"],
                    f"{r['gmsh_generate_s']:.3f}",
                    f"{r['gmsh_model_to_mesh_s']:.3f}",
                    f"{r['gmsh_total_s']:.3f}",
                    f"{r['ratio_total']:.1f}",
                    f"{r['ratio_conform']:.1f}",
                    f"{r['ratio_total_cpu']:.1f}",
                    f"{r['ratio_conform_cpu']:.1f}",
                ]
            )
        )
    lines.append(
        "gmsh = generate(3) + model_to_mesh; gmsh/univ, gmsh/conf = its wall time over "
        "universal and\nover conform; cpu g/u, cpu g/c = the same with process CPU times."
    )
    edges = DIHEDRAL_BIN_EDGES.astype(int)
    bins = [f"{a}-{b}" for a, b in zip(edges[:-1], edges[1:], strict=True)]
    for r in rows:
        lines += ["", f"Quality, target {r['target_cells']:.0e}"]
        head = ["mesh", "tets", "min dih", "max dih", "rad ratio", "mean rat", "inverted"]
        lines += header(head, width=10)
        for name, q in (("universal", r["universal_quality"]), ("gmsh", r["gmsh_quality"])):
            lines.append(
                columns(
                    [
                        name,
                        q["n_cells"],
                        f"{q['theta_min_deg']:.2f}",
                        f"{q['theta_max_deg']:.2f}",
                        f"{q['radius_ratio_min']:.3f}",
                        f"{q['mean_ratio_min']:.3f}",
                        q["n_inverted"],
                    ],
                    10,
                )
            )
        lines.append("dihedral angle histogram (degrees: counts of all 6 angles per tetrahedron)")
        keep = [
            i
            for i in range(len(bins))
            if r["universal_quality"]["dihedral_histogram"][i]
            or r["gmsh_quality"]["dihedral_histogram"][i]
        ]
        lo, hi = min(keep), max(keep) + 1
        lines.append(columns(["bin"] + bins[lo:hi], 8))
        for name, q in (("univ", r["universal_quality"]), ("gmsh", r["gmsh_quality"])):
            lines.append(columns([name] + q["dihedral_histogram"][lo:hi], 8))
    return "\n".join(lines)


if __name__ == "__main__":
    main()
