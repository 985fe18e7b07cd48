"""``curved_mesh`` against its floor, ``dolfinx.fem.interpolate_geometry``.

The curved mesh of a conforming mesh is its degree-q interpolated geometry with the nodes
of the positively cut cells moved onto the blend ``G_h``: the floor is the interpolation
alone. Times :func:`curved_mesh` (q = 2 and 3, map ``I``) and ``interpolate_geometry``
interleaved on the conforming mesh of the three-blade body of ``moving_update.py`` on an
equilateral background of 1e5 cells (1e4 with ``--quick``) and of the propeller demo's
graded background.

Prints a table of medians (maximum over ranks) and the ratios package / floor.
Run: ``python benchmarks/curved_floor.py [--quick] [--repeats N]``; also under mpirun.
"""

from __future__ import annotations

import argparse

from mpi4py import MPI

import _results
import basix
from _floor import TABLES, equilateral, print_table, propeller_demo, three_blades, timed_pairs
from dolfinx import fem
from dolfinx import mesh as dmesh

import dolfinx_universal as du


def compare(comm, background, curve, degree, repeats, **options):
    """Median seconds of ``curved_mesh`` and ``interpolate_geometry`` on one conforming mesh."""
    boundary = du.Domain(None, [du.RigidMotion(curve, angle=0.1)])
    cm = du.UniversalMesh(background, relax=False, **options).conform(boundary)
    ce = fem.coordinate_element(dmesh.CellType.triangle, degree, basix.LagrangeVariant.gll_warped)
    fns = {
        "package": lambda step: du.curved_mesh(cm, degree),
        "floor": lambda step: fem.interpolate_geometry(cm.mesh, ce),
    }
    t = timed_pairs(comm, fns, repeats)
    return t["package"], t["floor"], comm.allreduce(background.topology.index_map(2).size_local)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small backgrounds, 3 repeats")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--json", help="write the results as JSON to this file")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    repeats = 3 if args.quick else args.repeats
    demo = propeller_demo()
    h_fine, h_coarse, _ = demo.sizes(args.quick)
    backgrounds = [
        ("equilateral", equilateral(comm, 1e4 if args.quick else 1e5), three_blades(), {}),
        (
            "propeller demo graded",
            demo.background_mesh(comm, h_fine, h_coarse),
            demo.propeller,
            {"local_size": True},
        ),
    ]
    rows = []
    for name, bg, curve, options in backgrounds:
        for q in (2, 3):
            pkg, flo, n = compare(comm, bg, curve, q, repeats, **options)
            rows.append((f"curved_mesh q={q}, {name} {n} cells", pkg, flo))
    print_table(comm, "curved_mesh against interpolate_geometry", rows)
    if args.json and comm.rank == 0:
        _results.write(args.json, {"repeats": repeats, "tables": TABLES})


if __name__ == "__main__":
    main()
