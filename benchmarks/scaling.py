"""Strong scaling: per-phase times of the pipeline on a fixed background, on any number of ranks.

For equilateral backgrounds of the square [-1, 1]^2 (about 1e6 and 4e6 cells by default) and
the rotating three-blade body of ``benchmarks/moving_update.py``, the script times

* ``background``: :func:`~dolfinx_universal.background.equilateral_mesh` (each rank builds
  its strip of rows, DOLFINx creates the distributed mesh with shared-facet ghosts);
* ``prepare``: the :class:`~dolfinx_universal.conform.UniversalMesh` constructor;
* ``conform``: :meth:`UniversalMesh.conform` (classification, projections, ``M_h``, the
  DOLFINx submesh with its facets and tags), split into ``straight`` (up to ``M_h``) and
  ``mesh`` (the submesh part);
* ``curved``: :func:`~dolfinx_universal.curved.curved_mesh` with ``q = 2``;
* ``update``: :meth:`~dolfinx_universal.moving.MovingDomain.update` (``q = 2``), the body
  turned by 3 degrees per step.

Each time is the maximum over the ranks (barriers around every call), then the median over
``--repeats`` calls (for ``conform`` and ``update``: after a warm-up call, which samples the
boundary; ``straight`` adds the maxima of its sub-phases). The table also
gives each rank count's share of the cells.

Run (``--quick``: one small background, for CI)::

    python benchmarks/scaling.py [--sizes 1e6 4e6] [--repeats 3] [--quick]
    for n in 1 2 4 8 16; do mpirun -n $n python benchmarks/scaling.py; done

Strong scaling needs as many cores as ranks: run 1 .. 16 ranks on a machine with at least 16
cores (the speed-up of a phase is its 1-rank time over its n-rank time, same ``--sizes``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mpi4py import MPI

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from moving_update import propeller, timed  # noqa: E402

import dolfinx_universal as du  # noqa: E402
from dolfinx_universal.moving import MovingDomain  # noqa: E402

comm = MPI.COMM_WORLD
PHASES = ("background", "prepare", "conform", "straight", "mesh", "curved", "update")


def run(target: float, repeats: int) -> dict:
    """Median phase times (max over ranks) on an equilateral background of ~``target`` cells."""
    h = float(np.sqrt(4.0 / (target * np.sqrt(3) / 4)))
    box = [[-1.0, -1.0], [1.0, 1.0]]
    body = propeller()
    times: dict[str, list[float]] = {k: [] for k in PHASES}
    background = None
    for _ in range(repeats):
        background = None  # free the previous one first
        background, t = timed(du.equilateral_mesh, comm, box, h)
        times["background"].append(t)
    assert background is not None
    ncells = comm.allreduce(background.topology.index_map(2).size_local)
    for _ in range(repeats):
        um, t = timed(du.UniversalMesh, background)
        times["prepare"].append(t)
    shape = du.Domain(None, [du.RigidMotion(body)])
    for rep in range(repeats + 1):
        cm, t = timed(um.conform, shape)
        if not rep:  # warm-up: samples the boundary once (cached by UniversalMesh)
            continue
        times["conform"].append(t)
        split = {k: comm.allreduce(float(v), op=MPI.MAX) for k, v in cm.timings.items()}
        times["mesh"].append(split["mesh"])
        times["straight"].append(sum(v for k, v in split.items() if k != "mesh"))
    for _ in range(repeats):
        _, t = timed(du.curved_mesh, cm, 2)
        times["curved"].append(t)
    del um, cm
    md = MovingDomain(background, 2)
    for step in range(repeats + 1):
        boundary = du.Domain(None, [du.RigidMotion(body, angle=np.radians(3.0 * step))])
        _, t = timed(md.update, boundary)
        if step:  # the first step is the warm-up
            times["update"].append(t)
    row = {k: float(np.median(v)) for k, v in times.items()}
    row["cells"] = ncells
    row["max_local"] = comm.allreduce(background.topology.index_map(2).size_local, op=MPI.MAX)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e6, 4e6])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--quick", action="store_true", help="one small background (2e4 cells), 2 repeats"
    )
    args = parser.parse_args()
    if args.quick:
        args.sizes, args.repeats = [2e4], 2
    rows = [run(target, args.repeats) for target in args.sizes]
    if comm.rank == 0:
        print(
            f"\nranks: {comm.size}; seconds, max over ranks, median of {args.repeats} "
            "(conform, update: after a warm-up call)"
        )
        head = f"{'cells':>9} {'max/rank':>9} " + " ".join(f"{k:>10}" for k in PHASES)
        print(head)
        for r in rows:
            print(
                f"{r['cells']:9d} {r['max_local']:9d} " + " ".join(f"{r[k]:10.4f}" for k in PHASES)
            )


if __name__ == "__main__":
    main()
