"""Conforming a background against a plain numpy/scipy floor that includes ``create_submesh``.

Times :meth:`UniversalMesh.conform` and the floor of :class:`_floor.ConformFloor` (the
straight map of :class:`_floor.MotionFloor`, the kept cells and
``dolfinx.mesh.create_submesh`` with the mapped vertices written) interleaved, at the same
angles of the three-blade body of ``moving_update.py`` on an equilateral background of 1e6
cells (1e4 with ``--quick``), and on the propeller demo's graded background.

Prints a table of medians (maximum over ranks) and the ratios package / floor.
Run: ``python benchmarks/conform_floor.py [--quick] [--repeats N] [--cells N]``; also under
mpirun.
"""

from __future__ import annotations

import argparse

from mpi4py import MPI

import _results
import numpy as np
from _floor import (
    TABLES,
    ConformFloor,
    equilateral,
    print_table,
    propeller_demo,
    three_blades,
    timed_pairs,
)

import dolfinx_universal as du


def compare(comm, background, curve, step_deg, repeats, **options):
    """Median seconds of the package's conform and of the floor at the same angles."""
    um = du.UniversalMesh(background, relax=False, **options)
    floor = ConformFloor(um, curve)

    def package(step):
        um.conform(du.Domain(None, [du.RigidMotion(curve, angle=np.radians(step_deg * step))]))

    def plain(step):
        floor.conform(np.radians(step_deg * step))

    t = timed_pairs(comm, {"package": package, "floor": plain}, repeats)
    return t["package"], t["floor"], comm.allreduce(background.topology.index_map(2).size_local)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small backgrounds, 3 repeats")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--cells", type=float, default=1e6)
    parser.add_argument("--json", help="write the results as JSON to this file")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    repeats = 3 if args.quick else args.repeats
    rows = []
    bg = equilateral(comm, 1e4 if args.quick else args.cells)
    pkg, flo, n = compare(comm, bg, three_blades(), 3.0, repeats)
    rows.append((f"conform, equilateral {n} cells, three blades", pkg, flo))
    demo = propeller_demo()
    h_fine, h_coarse, step = demo.sizes(args.quick)
    bg = demo.background_mesh(comm, h_fine, h_coarse)
    pkg, flo, n = compare(comm, bg, demo.propeller, -step, repeats, local_size=True)
    rows.append((f"conform, propeller demo graded {n} cells", pkg, flo))
    print_table(comm, "UniversalMesh.conform against the floor (incl. create_submesh)", rows)
    if args.json and comm.rank == 0:
        _results.write(args.json, {"repeats": repeats, "tables": TABLES})


if __name__ == "__main__":
    main()
