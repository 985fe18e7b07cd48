"""Re-conforming a universal mesh to a moved disc, against remeshing the disc with gmsh.

The domain is a disc of radius 0.3 in the unit square. For each target size (about 1e4, 1e5
and 1e6 cells in the conforming mesh) the benchmark measures

1. **conform** -- re-conforming a *moved* disc on a background that is built and prepared
   once: ``UniversalMesh(background, eta=0.2)`` (everything that depends only on the
   background: vertex arrays, connectivities, mesh sizes) then ``.conform(circle)`` for each
   position. The background is an equilateral mesh of the unit square whose edge ``h`` is
   chosen from the target count (an equilateral triangle of edge ``h`` has area
   ``sqrt(3)/4 h^2``; the disc has area ``0.09 pi``). One warm-up call conforms the disc
   centred at (0.5, 0.5); each timed repetition then conforms the disc centred at
   ``(0.5, 0.5) + h * offset``, cycling through fixed offsets (``OFFSETS`` below, chosen once
   before any measurement and never tuned). The median total is reported, with the stage
   split (``ConformingMesh.timings``) of the repetition that gave the median. The one-shot
   shorthand ``conform(background, circle)``, which redoes the preparation at every call, is
   timed once too (``oneshot``; it runs after ``prepare`` and so finds the background's
   facet connectivities already computed, which can make it cheaper than ``prepare``).
   Without ``UniversalMesh`` (older package versions) the one-shot ``conform`` is the timed
   call.
2. **gmsh** -- what a user would otherwise do every time the domain moves: build the OCC
   disc, ``gmsh.model.mesh.generate(2)`` (default 2D algorithm, Frontal-Delaunay, threads as
   printed), and load it with ``dolfinx.io.gmsh.model_to_mesh`` (default partitioner, no
   ghosts). The gmsh mesh size is set so that its cell count matches the conforming mesh's
   (calibrated on an untimed small mesh); the actual count is reported. ``--repeat``
   repetitions (median), but a single one from ``--gmsh-single-from`` target cells on
   (default 5e5: the 1e6 case, where gmsh takes more than a minute).

What is timed and what is not:

- conform total = wall time of the ``conform`` call (all stages, validity checks included,
  and building the DOLFINx submesh with its facet tags).
- The background construction and its preparation are NOT part of the re-conform time: they
  are done once and reused for every position of the disc. Their one-off times are printed
  too ("bg build", "prepare"), as is the one-shot ``conform()`` (preparation + conform).
- gmsh generate = ``generate(2)`` only (creating the OCC disc and the physical group takes
  milliseconds and is not counted); model_to_mesh = the DOLFINx import and distribution.
- Neither side includes function spaces, assembly or I/O.
- One untimed warm-up of each pipeline is done first (imports, first-call costs).

In parallel (``mpirun -n N``) every timing is taken as a barrier then ``perf_counter()``
around the (collective) call, and the maximum over ranks is reported; gmsh generates on rank 0
only (the other ranks wait in a sleeping barrier, so that they leave the cores to gmsh) and
``model_to_mesh`` distributes the mesh. Output comes from rank 0. The load average of the
machine is printed before and after: other processes running meanwhile inflate wall times,
the longer gmsh runs more than the short conform calls; process CPU times (max over ranks) are
reported beside them as a check that is less sensitive to that load.

Usage::

    python benchmarks/conform_vs_gmsh.py [--sizes 1e4 1e5 1e6] [--repeat 3] [--out FILE]
    python benchmarks/conform_vs_gmsh.py --quick        # 1e4 cells, one repetition
    mpirun -n 2 python benchmarks/conform_vs_gmsh.py --quick
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import dolfinx_universal  # noqa: F401  (initialises the DOLFINx wheel before dolfinx)

# isort: split

from mpi4py import MPI

import _results
import gmsh
from _tables import columns, header
from dolfinx.io import gmsh as dgmsh

from dolfinx_universal.backgrounds.lattice_tri import equilateral_mesh
from dolfinx_universal.boundaries.curves import Circle
from dolfinx_universal.conforming.universal import conform

try:
    from dolfinx_universal.conforming.universal import UniversalMesh
except ImportError:  # package versions without the reusable preparation
    UniversalMesh = None

CENTER = (0.5, 0.5)
RADIUS = 0.3
BOX = [[0.0, 0.0], [1.0, 1.0]]
DISC_AREA = math.pi * RADIUS**2
STAGES = ("classify", "project", "map", "mesh")
ETA = 0.2
OFFSETS = [(0.37, 0.11), (-0.23, 0.41), (0.13, -0.29), (-0.41, -0.17)]
"""Disc centre offsets in units of h for the timed repetitions (fixed, not tuned)."""


def edge_for_cells(num_cells: float) -> float:
    """Edge ``h`` of equilateral triangles such that ``num_cells`` of them cover the disc."""
    return math.sqrt(DISC_AREA / (num_cells * math.sqrt(3.0) / 4.0))


def barrier(comm: MPI.Comm) -> None:
    """``comm.Barrier()`` that sleeps while waiting instead of spinning.

    Ranks idling while rank 0 runs gmsh would otherwise busy-poll and compete for the cores.
    """
    req = comm.Ibarrier()
    while not req.Test():
        time.sleep(1e-4)


class Clock:
    """Wall and CPU seconds of the last :func:`timed` call (max over ranks)."""

    cpu = 0.0


def timed(comm: MPI.Comm, fn, *args, **kwargs):
    """Run ``fn`` on every rank between a barrier and a timer; (result, max wall seconds).

    The process CPU time of the call (max over ranks) is left in ``Clock.cpu``.
    """
    barrier(comm)
    t, c = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    t, c = time.perf_counter() - t, time.process_time() - c
    Clock.cpu = comm.allreduce(c, op=MPI.MAX)
    return out, comm.allreduce(t, op=MPI.MAX)


def load() -> str:
    """Load averages (1, 5, 15 min) of the machine, for the record."""
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def num_cells(msh) -> int:
    """Global number of cells of a DOLFINx mesh."""
    return msh.topology.index_map(2).size_global


def bench_conform(comm: MPI.Comm, h: float, repeat: int) -> dict:
    """Build and prepare the background once, warm up, then time conforms of moved discs."""
    background, t_bg = timed(comm, equilateral_mesh, comm, BOX, h)
    if UniversalMesh is not None:
        um, t_prep = timed(comm, UniversalMesh, background, eta=ETA)
        reconform = um.conform
    else:
        t_prep = float("nan")

        def reconform(boundary):
            return conform(background, boundary, eta=ETA)

    timed(comm, reconform, Circle(CENTER, RADIUS))  # warm-up, unmoved disc
    runs = []
    for i in range(repeat):
        dx, dy = OFFSETS[i % len(OFFSETS)]
        circle = Circle((CENTER[0] + dx * h, CENTER[1] + dy * h), RADIUS)
        cm, t = timed(comm, reconform, circle)
        cpu = Clock.cpu
        stages = {k: comm.allreduce(cm.timings.get(k, 0.0), op=MPI.MAX) for k in STAGES}
        runs.append({"total": t, "cpu": cpu, "stages": stages, "cells": num_cells(cm.mesh)})
        del cm
    dx, dy = OFFSETS[repeat % len(OFFSETS)]
    circle = Circle((CENTER[0] + dx * h, CENTER[1] + dy * h), RADIUS)
    _, t_oneshot = timed(comm, conform, background, circle, eta=ETA)
    totals = [r["total"] for r in runs]
    med = statistics.median(totals)
    pick = min(runs, key=lambda r: abs(r["total"] - med))
    return {
        "background_cells": num_cells(background),
        "background_build_s": t_bg,
        "prepare_s": t_prep,
        "oneshot_conform_s": t_oneshot,
        "conform_cells": pick["cells"],
        "conform_total_s": med,
        "conform_cpu_s": pick["cpu"],
        "conform_stages_s": pick["stages"],
        "conform_totals_s": totals,
    }


def gmsh_disc(comm: MPI.Comm, size: float):
    """Mesh the disc with gmsh on rank 0 and load it into DOLFINx.

    Returns MeshData and the wall and CPU seconds of generate(2) and of model_to_mesh.
    """
    if comm.rank == 0:
        gmsh.clear()
        gmsh.model.add("disc")
        disc = gmsh.model.occ.addDisk(CENTER[0], CENTER[1], 0.0, RADIUS, RADIUS)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [disc], 1)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
    _, t_gen = timed(comm, lambda: gmsh.model.mesh.generate(2) if comm.rank == 0 else None)
    c_gen = Clock.cpu
    data, t_m2m = timed(comm, dgmsh.model_to_mesh, gmsh.model, comm, 0, gdim=2)
    c_m2m = Clock.cpu
    if comm.rank == 0:
        gmsh.clear()
    return data, {"generate": t_gen, "m2m": t_m2m, "generate_cpu": c_gen, "m2m_cpu": c_m2m}


def bench_gmsh(comm: MPI.Comm, size: float, repeat: int) -> dict:
    """Time gmsh generate + model_to_mesh ``repeat`` times; the median run."""
    runs = []
    for _ in range(repeat):
        data, t = gmsh_disc(comm, size)
        runs.append(dict(t, cells=num_cells(data.mesh)))
        del data
    totals = [r["generate"] + r["m2m"] for r in runs]
    med = statistics.median(totals)
    pick = min(runs, key=lambda r: abs(r["generate"] + r["m2m"] - med))
    return {
        "gmsh_size": size,
        "gmsh_cells": pick["cells"],
        "gmsh_generate_s": pick["generate"],
        "gmsh_model_to_mesh_s": pick["m2m"],
        "gmsh_total_s": pick["generate"] + pick["m2m"],
        "gmsh_generate_cpu_s": pick["generate_cpu"],
        "gmsh_model_to_mesh_cpu_s": pick["m2m_cpu"],
        "gmsh_total_cpu_s": pick["generate_cpu"] + pick["m2m_cpu"],
        "gmsh_repetitions": len(runs),
    }


def calibrate_gmsh(comm: MPI.Comm, size: float = 0.006) -> float:
    """Untimed warm-up of gmsh + model_to_mesh; returns cells * size^2 (about constant)."""
    data, _ = gmsh_disc(comm, size)
    return num_cells(data.mesh) * size**2


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sizes",
        type=float,
        nargs="+",
        default=[1e4, 1e5, 1e6],
        help="target cell counts of the conforming mesh (default 1e4 1e5 1e6)",
    )
    parser.add_argument("--repeat", type=int, default=3, help="timed repetitions (default 3)")
    parser.add_argument(
        "--quick", action="store_true", help="smoke test: sizes 1e4 only, one repetition"
    )
    parser.add_argument(
        "--gmsh-single-from",
        type=float,
        default=5e5,
        help="one gmsh repetition only from this target cell count on",
    )
    parser.add_argument("--out", help="write the table as JSON to this file")
    args = parser.parse_args(argv)
    if args.quick:
        args.sizes, args.repeat = [1e4], 1
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")

    comm = MPI.COMM_WORLD
    root = comm.rank == 0

    def say(*a):
        if root:
            print(*a, flush=True)

    threads = ""
    if root:
        gmsh.initialize()
        gmsh.option.setNumber("General.Terminal", 0)
        threads = (
            f"General.NumThreads={gmsh.option.getNumber('General.NumThreads'):g}, "
            f"Mesh.MaxNumThreads2D={gmsh.option.getNumber('Mesh.MaxNumThreads2D'):g}, "
            f"Mesh.Algorithm={gmsh.option.getNumber('Mesh.Algorithm'):g}"
        )
    say(
        f"disc r={RADIUS} centred at {CENTER} in {BOX}; MPI ranks: {comm.size}; "
        f"load average {load()}"
    )
    say(
        f"gmsh {gmsh.__version__}: OCC disk, generate(2), defaults ({threads}); "
        "one surface, so 2D meshing runs on one thread"
    )
    say(
        f"repeat={args.repeat} (median); conform offsets/h: {OFFSETS[: args.repeat]}; eta={ETA}; "
        + ("UniversalMesh reused" if UniversalMesh is not None else "conform() per call")
    )

    # Untimed warm-ups of both pipelines (first-call costs).
    k_gmsh = calibrate_gmsh(comm)
    timed(comm, conform, equilateral_mesh(comm, BOX, 0.03), Circle(CENTER, RADIUS), eta=ETA)

    rows = []
    for target in args.sizes:
        h = edge_for_cells(target)
        say(f"\n-- target {target:.0e} cells: h = {h:.4g}")
        row = {"target_cells": int(target), "h": h, "ranks": comm.size}
        row.update(bench_conform(comm, h, args.repeat))
        say(
            f"   background {row['background_cells']} cells built in "
            f"{row['background_build_s']:.3f} s, prepared in {row['prepare_s']:.3f} s; "
            "re-conform totals "
            + ", ".join(f"{t:.3f}" for t in row["conform_totals_s"])
            + f" s; one-shot conform() {row['oneshot_conform_s']:.3f} s"
        )
        size = math.sqrt(k_gmsh / row["conform_cells"])
        gmsh_repeat = 1 if target >= args.gmsh_single_from else args.repeat
        row.update(bench_gmsh(comm, size, gmsh_repeat))
        say(
            f"   gmsh size {size:.4g}: {row['gmsh_cells']} cells, generate "
            f"{row['gmsh_generate_s']:.3f} s + model_to_mesh {row['gmsh_model_to_mesh_s']:.3f} s"
            f" ({row['gmsh_repetitions']} repetition(s))"
        )
        row["ratio_total"] = row["gmsh_total_s"] / row["conform_total_s"]
        row["ratio_generate"] = row["gmsh_generate_s"] / row["conform_total_s"]
        row["ratio_total_cpu"] = row["gmsh_total_cpu_s"] / row["conform_cpu_s"]
        row["ratio_generate_cpu"] = row["gmsh_generate_cpu_s"] / row["conform_cpu_s"]
        rows.append(row)

    if root:
        gmsh.finalize()
    say("\n" + table(rows, comm.size))
    say(f"load average {load()}")
    if args.out and root:
        results = {"ranks": comm.size, "gmsh_options": threads, "rows": rows}
        _results.write(args.out, results, None if argv is None else [__file__, *argv])
        say(f"wrote {args.out}")
    return rows


def table(rows: list[dict], ranks: int) -> str:
    """Fixed-width text tables of the results."""
    lines = [f"Re-conform a moved disc: universal mesh ({ranks} MPI rank(s), max over ranks)"]
    head = [
        "target",
        "h",
        "bg build",
        "prepare",
        "oneshot",
        "cells",
        "conform",
        "classify",
        "project",
        "map",
        "mesh",
        "conf cpu",
    ]
    units = ["cells", "", "[s]", "[s]", "[s]", "", "[s]", "[s]", "[s]", "[s]", "[s]", "[s]"]
    lines += header(head, units)
    for r in rows:
        st = r["conform_stages_s"]
        lines.append(
            columns(
                [
                    f"{r['target_cells']:.0e}",
                    f"{r['h']:.2e}",
                    f"{r['background_build_s']:.3f}",
                    f"{r['prepare_s']:.3f}",
                    f"{r['oneshot_conform_s']:.3f}",
                    r["conform_cells"],
                    f"{r['conform_total_s']:.4f}",
                ]
                + [f"{st[k]:.4f}" for k in STAGES]
                + [f"{r['conform_cpu_s']:.4f}"]
            )
        )
    lines.append(
        "conform = median wall time of re-conforming a moved disc on the reused, prepared "
        "background, split\nby stage (that run's ConformingMesh.timings); conf cpu = its "
        "process CPU time; bg build, prepare =\none-off costs, NOT in conform; oneshot = "
        "conform(background, circle) timed once: it prepares again\nbut finds the facets that "
        "prepare created on the background (a first call costs ~ prepare + conform)."
    )
    lines += [
        "",
        f"Remesh the disc with gmsh + model_to_mesh ({ranks} MPI rank(s)); "
        "ratios to the re-conform time",
    ]
    head = [
        "target",
        "gmsh cells",
        "generate",
        "to_mesh",
        "gmsh",
        "gmsh cpu",
        "gmsh/conf",
        "gen/conf",
        "cpu ratio",
        "cpu gen",
    ]
    units = ["cells", "", "[s]", "[s]", "[s]", "[s]", "wall", "wall", "gmsh/conf", "/conf"]
    lines += header(head, units)
    for r in rows:
        lines.append(
            columns(
                [
                    f"{r['target_cells']:.0e}",
                    r["gmsh_cells"],
                    f"{r['gmsh_generate_s']:.3f}",
                    f"{r['gmsh_model_to_mesh_s']:.3f}",
                    f"{r['gmsh_total_s']:.3f}",
                    f"{r['gmsh_total_cpu_s']:.3f}",
                    f"{r['ratio_total']:.1f}",
                    f"{r['ratio_generate']:.1f}",
                    f"{r['ratio_total_cpu']:.1f}",
                    f"{r['ratio_generate_cpu']:.1f}",
                ]
            )
        )
    lines.append(
        "gmsh = generate(2) + model_to_mesh (wall; the median run; repetitions as logged "
        "above);\ngmsh/conf, gen/conf = wall-time ratios (all of gmsh, generate alone); cpu "
        "ratio, cpu gen = the\nsame with process CPU times, less sensitive to other load on "
        "the machine."
    )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
