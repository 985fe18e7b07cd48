"""Moving-domain update against a plain numpy/scipy floor doing the same work.

Times :meth:`MovingDomain.update` (degree 2, map ``I``) and the floor of
:class:`_floor.UpdateFloor` (signs near the body, band within each vertex's ``R_r``, closest
points by Newton, degree-2 nodes of the band cells written in place) interleaved, at the
same angles of a rotating body, on

* an equilateral background of 1e5 cells with the three-blade body of ``moving_update.py``;
* the graded background of the propeller demo (``demos/stokes_propeller.py``, its own
  builder; ``local_size=True``) with the demo's propeller.

Prints a table of medians (maximum over ranks) and the ratios package / floor: the update
as the floor does it (``relax=False``) and, in the next row, with the vertex relaxation
that is on by default (work the floor does not do), and the relaxation's share of it.
Run: ``python benchmarks/update_floor.py [--quick] [--repeats N]``; also under mpirun.
"""

from __future__ import annotations

import argparse

from mpi4py import MPI

import _results
import numpy as np
from _floor import (
    TABLES,
    UpdateFloor,
    equilateral,
    print_table,
    propeller_demo,
    three_blades,
    timed_pairs,
)

import dolfinx_universal as du
from dolfinx_universal.moving.domain import MovingDomain


def compare(comm, background, curve, step_deg, repeats, **options):
    """Median seconds of the package's update (without and with the vertex relaxation,
    which the floor does not do) and of the floor at the same angles; the median share of
    the relaxation in the relaxed update."""
    md = MovingDomain(background, 2, relax=False, **options)
    relaxed = MovingDomain(background, 2, relax=True, **options)
    floor = UpdateFloor(md.universal, curve)

    def domain(step):
        return du.Domain(None, [du.RigidMotion(curve, angle=np.radians(step_deg * step))])

    def plain(step):
        floor.update(np.radians(step_deg * step))

    fns = {
        "package": lambda step: md.update(domain(step)),
        "relaxed": lambda step: relaxed.update(domain(step)),
        "floor": plain,
    }
    t = timed_pairs(comm, fns, repeats)
    share = [
        comm.allreduce(r.timings["relax"], op=MPI.MAX)
        / comm.allreduce(r.timings["total"], op=MPI.MAX)
        for r in relaxed.steps[1:]
    ]
    n = comm.allreduce(background.topology.index_map(2).size_local)
    return t["package"], t["relaxed"], t["floor"], float(np.median(share)), n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small backgrounds, 3 repeats")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--json", help="write the results as JSON to this file")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    repeats = 3 if args.quick else args.repeats
    demo = propeller_demo()
    rows, shares = [], []
    bg = equilateral(comm, 1e4 if args.quick else 1e5)
    pkg, rel, flo, share, n = compare(comm, bg, three_blades(), 3.0, repeats)
    rows += [(f"update, equilateral {n} cells, three blades, q=2", pkg, flo)]
    rows += [("  the same with the vertex relaxation (default)", rel, flo)]
    shares.append(("equilateral", share))
    h_fine, h_coarse, step = demo.sizes(args.quick)
    bg = demo.background_mesh(comm, h_fine, h_coarse)
    pkg, rel, flo, share, n = compare(comm, bg, demo.propeller, -step, repeats, local_size=True)
    rows += [(f"update, propeller demo graded {n} cells, q=2", pkg, flo)]
    rows += [("  the same with the vertex relaxation (default)", rel, flo)]
    shares.append(("propeller graded", share))
    print_table(comm, "MovingDomain.update against the floor", rows)
    if comm.rank == 0:
        print(
            "relaxation share of the relaxed update (median): "
            + ", ".join(f"{name}: {100 * s:.0f} %" for name, s in shares)
        )
        if args.json:
            relax_share = {name: s for name, s in shares}
            _results.write(
                args.json, {"repeats": repeats, "tables": TABLES, "relax_share": relax_share}
            )


if __name__ == "__main__":
    main()
