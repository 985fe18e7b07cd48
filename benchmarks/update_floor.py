"""Moving-domain update against a plain numpy/scipy floor doing the same work.

Times :meth:`MovingDomain.update` (degree 2, map ``I``) and the floor of
:class:`_floor.UpdateFloor` (signs near the body, band within each vertex's ``R_r``, closest
points by Newton, degree-2 nodes of the band cells written in place) interleaved, at the
same angles of a rotating body, on

* an equilateral background of 1e5 cells with the three-blade body of ``moving_update.py``;
* the graded background of the propeller demo (``demos/stokes_propeller.py``, its own
  builder; ``local_size=True``) with the demo's propeller.

Prints a table of medians (maximum over ranks) and the ratios package / floor.
Run: ``python benchmarks/update_floor.py [--quick] [--repeats N]``; also under mpirun.
"""

from __future__ import annotations

import argparse

from mpi4py import MPI

import numpy as np
from _floor import UpdateFloor, equilateral, print_table, propeller_demo, three_blades, timed_pairs

import dolfinx_universal as du
from dolfinx_universal.moving import MovingDomain


def compare(comm, background, curve, step_deg, repeats, **options):
    """Median seconds of the package's update and of the floor at the same angles."""
    md = MovingDomain(background, 2, relax=False, **options)
    floor = UpdateFloor(md.universal, curve)

    def package(step):
        md.update(du.Domain(None, [du.RigidMotion(curve, angle=np.radians(step_deg * step))]))

    def plain(step):
        floor.update(np.radians(step_deg * step))

    t = timed_pairs(comm, {"package": package, "floor": plain}, repeats)
    return t["package"], t["floor"], comm.allreduce(background.topology.index_map(2).size_local)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small backgrounds, 3 repeats")
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    repeats = 3 if args.quick else args.repeats
    demo = propeller_demo()
    rows = []
    bg = equilateral(comm, 1e4 if args.quick else 1e5)
    pkg, flo, n = compare(comm, bg, three_blades(), 3.0, repeats)
    rows.append((f"update, equilateral {n} cells, three blades, q=2", pkg, flo))
    h_fine, h_coarse, step = demo.sizes(args.quick)
    bg = demo.background_mesh(comm, h_fine, h_coarse)
    pkg, flo, n = compare(comm, bg, demo.propeller, -step, repeats, local_size=True)
    rows.append((f"update, propeller demo graded {n} cells, q=2", pkg, flo))
    print_table(comm, "MovingDomain.update against the floor", rows)


if __name__ == "__main__":
    main()
