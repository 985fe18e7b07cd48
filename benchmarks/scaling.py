"""Strong scaling: per-phase times of the pipeline on a fixed background, on any number of ranks.

For equilateral backgrounds of the square [-1, 1]^2 (about 1e6 and 4e6 cells by default) and
the rotating three-blade body of ``benchmarks/moving_update.py``, the script times

* ``background``: :func:`~dolfinx_universal.backgrounds.lattice_tri.equilateral_mesh` (each rank
builds
  its strip of rows, DOLFINx creates the distributed mesh with shared-facet ghosts);
* ``prepare``: the :class:`~dolfinx_universal.conforming.universal.UniversalMesh` constructor;
* ``conform``: :meth:`UniversalMesh.conform` (classification, projections, ``M_h``, the
  DOLFINx submesh with its facets and tags), split into ``straight`` (up to ``M_h``) and
  ``mesh`` (the submesh part);
* ``curved``: :func:`~dolfinx_universal.curved.maps.curved_mesh` with ``q = 2``;
* ``update``: :meth:`~dolfinx_universal.moving.domain.MovingDomain.update` (``q = 2``), the body
  turned by 3 degrees per step.

Each time is the maximum over the ranks (barriers around every call), then the median over
``--repeats`` calls (for ``conform`` and ``update``: after a warm-up call, which samples the
boundary; ``straight`` adds the maxima of its sub-phases: classification, projections, the
map with its relaxation). The table also gives each rank count's share of the cells.

With ``--dim 3`` the same phases run on tetrahedra: an A15 background
(:func:`~dolfinx_universal.a15_mesh`, about 1e6 and 4e6 tetrahedra by default) of the box of
``benchmarks/conform_floor_3d.py`` and its tilted solid torus, moved by a fraction of ``h`` at
every step (``background``: ``a15_mesh``; ``update``: ``MovingDomain(degree=2, map="I~")``).

Every row also gives figures that define the mesh and do not depend on the partition, so that
runs on different numbers of ranks can be compared (the same mesh on any number of ranks):
the kept cells and positively cut cells (integers), the extreme angles (interior angles of
triangles, dihedral angles of tetrahedra; minima and maxima over the cells, which no
summation order changes), the proven Jacobian ratio of ``curved_mesh`` and the sum of the
squared vertex coordinates of the conforming mesh (a sum over the ranks: equal up to its
summation order, about 1e-13 relative). ``--json FILE`` writes the rows (under ``"rows"``).

``--mesh-domain H`` times :func:`~dolfinx_universal.mesh_domain` of that torus instead (graded
octree background, largest size ``H``, q = 2) and gives how evenly the ranks hold the kept
cells and the moved vertices (busiest rank over the mean), and the time and balance of
:func:`~dolfinx_universal.io.redistribute` of the mesh; with ``--solve`` also a P2 Poisson
solve (CG + GAMG) on the mesh before and after.

``--partition graph`` redistributes the background by DOLFINx's graph partitioner
(:func:`~dolfinx_universal.io.redistribute`, untimed) before the phases after ``background``:
the package builds backgrounds in slabs of layers, so the band near Gamma lies on the ranks
whose slabs the boundary crosses; compact parts share it (and the domain's cells) among all
ranks. Each run also prints the busiest rank's share of the active cells of the last
update over the mean.

Run (``--quick``: one small background, for CI)::

    python benchmarks/scaling.py [--dim 2|3] [--sizes 1e6 4e6] [--repeats 3] [--quick]
                                 [--partition layers|graph]
    python benchmarks/scaling.py --mesh-domain 0.04 [--solve]
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

import _results  # noqa: E402
from moving_update import propeller, timed  # noqa: E402

import dolfinx_universal as du  # noqa: E402
from dolfinx_universal import io as duio  # noqa: E402
from dolfinx_universal.conforming.quality import quality_report  # noqa: E402
from dolfinx_universal.moving.domain import MovingDomain  # noqa: E402

comm = MPI.COMM_WORLD
PHASES = ("background", "prepare", "conform", "straight", "mesh", "curved", "update")
FINGERPRINT = ("kept", "positively_cut", "angle_min", "angle_max", "jacobian_ratio", "moment")


def case(dim: int, target: float):
    """The background builder, its arguments, the domain of each step and the curved map
    (``dim`` 2 or 3)."""
    if dim == 2:
        h = float(np.sqrt(4.0 / (target * np.sqrt(3) / 4)))
        body = propeller()

        def domain2(step: int):
            return du.Domain(None, [du.RigidMotion(body, angle=np.radians(3.0 * step))])

        return du.equilateral_mesh, ([[-1.0, -1.0], [1.0, 1.0]], h), domain2, "I"
    from conform_floor_3d import background_box, surfaces

    box, h = background_box(target)

    def domain3(step: int):
        return surfaces("torus", h, step)

    return du.a15_mesh, (box, h), domain3, "I~"


def fingerprint(cm, curved) -> dict:
    """Partition-independent figures of a conforming mesh and its curved mesh (module
    docstring)."""
    report = quality_report(cm)
    x = cm.mesh.geometry.x[: cm.mesh.geometry.index_map().size_local]  # each node once
    return {
        "kept": int(report["n_cells"]),
        "positively_cut": int(report["n_positively_cut"]),
        "angle_min": float(report["theta_min_deg"]),
        "angle_max": float(report["theta_max_deg"]),
        "jacobian_ratio": float(curved.min_jacobian_ratio),
        "moment": comm.allreduce(float((x * x).sum()), op=MPI.SUM),
    }


def run(dim: int, target: float, repeats: int, partition: str = "layers") -> dict:
    """Median phase times (max over ranks) on a background of about ``target`` cells; with
    ``partition="graph"`` the background is redistributed first (untimed)."""
    build, args, domain, kind = case(dim, target)
    times: dict[str, list[float]] = {k: [] for k in PHASES}
    background = None
    for _ in range(repeats):
        background = None  # free the previous one first
        background, t = timed(build, comm, *args)
        times["background"].append(t)
    assert background is not None
    if partition == "graph" and comm.size > 1:
        background = duio.redistribute(background)[0]
    nlocal = background.topology.index_map(dim).size_local
    ncells = comm.allreduce(nlocal)
    for _ in range(repeats):
        um, t = timed(du.UniversalMesh, background)
        times["prepare"].append(t)
    shape = domain(0)
    for rep in range(repeats + 1):
        cm, t = timed(um.conform, shape)
        if not rep:  # warm-up: samples the boundary once (cached by UniversalMesh)
            continue
        times["conform"].append(t)
        split = {k: comm.allreduce(float(v), op=MPI.MAX) for k, v in cm.timings.items()}
        times["mesh"].append(split["mesh"])
        times["straight"].append(sum(v for k, v in split.items() if k not in ("mesh", "relax")))
    for _ in range(repeats):
        curved, t = timed(du.curved_mesh, cm, 2, kind)
        times["curved"].append(t)
    row: dict = fingerprint(cm, curved)
    del um, cm, curved
    md = MovingDomain(background, 2, map=kind)
    for step in range(repeats + 1):
        _, t = timed(md.update, domain(step))
        if step:  # the first step is the warm-up
            times["update"].append(t)
    row |= {k: float(np.median(v)) for k, v in times.items()}
    active = comm.gather(int(np.count_nonzero(md.active_cells < nlocal)), root=0)
    row["active_balance"] = float(np.max(active) / np.mean(active)) if comm.rank == 0 else 0.0
    row["cells"] = ncells
    row["max_local"] = comm.allreduce(background.topology.index_map(dim).size_local, op=MPI.MAX)
    row["ranks"] = comm.size
    return row


def poisson_seconds(msh, facet_tags, repeats: int) -> float:
    """Fastest of ``repeats`` P2 Poisson solves on ``msh`` (zero Dirichlet data on Gamma,
    CG + GAMG to 1e-10): assembly, preconditioner set-up and iterations."""
    import ufl
    from dolfinx import fem
    from dolfinx.fem.petsc import LinearProblem

    V = fem.functionspace(msh, ("Lagrange", 2))
    u, v, x = ufl.TrialFunction(V), ufl.TestFunction(V), ufl.SpatialCoordinate(msh)
    msh.topology.create_connectivity(2, 3)
    dofs = fem.locate_dofs_topological(V, 2, facet_tags.find(du.IMMERSED))
    options = {"ksp_type": "cg", "pc_type": "gamg", "ksp_rtol": 1e-10}
    times = []
    for _ in range(repeats):
        problem = LinearProblem(
            ufl.inner(ufl.grad(u), ufl.grad(v)) * ufl.dx,
            ufl.sin(x[0]) * ufl.cos(x[1]) * v * ufl.dx,
            bcs=[fem.dirichletbc(0.0, dofs, V)],
            petsc_options=options,
            petsc_options_prefix="scaling_",
        )
        _, t = timed(problem.solve)
        times.append(t)
    return min(times)


def mesh_domain_row(h: float, repeats: int, solve: bool) -> None:
    """Time ``mesh_domain`` of the torus of ``--dim 3`` (q = 2), print how evenly the
    ranks hold the work near Gamma, before and after ``io.redistribute`` (with ``solve``:
    and a Poisson solve on both meshes)."""
    from conform_floor_3d import surfaces

    times = []
    for _ in range(repeats):
        md, t = timed(lambda: du.mesh_domain(comm, surfaces("torus", h, 0), h, degree=2))
        times.append(t)
    cm = md.conforming
    nv = cm.mesh.topology.index_map(0).size_local
    local = np.array(
        [cm.mesh.topology.index_map(3).size_local, np.count_nonzero(cm.moved[:nv])], dtype=float
    )
    most, total = np.empty(2), np.empty(2)
    comm.Allreduce(local, most, op=MPI.MAX)
    comm.Allreduce(local, total, op=MPI.SUM)
    background = cm.background.topology.index_map(3).size_global
    (even, even_tags), t_even = timed(duio.redistribute, md.mesh, md.facet_tags)
    spread = comm.allreduce(even.topology.index_map(3).size_local, op=MPI.MAX)
    if solve:
        before = poisson_seconds(md.mesh, md.facet_tags, repeats)
        after = poisson_seconds(even, even_tags, repeats)
    if comm.rank == 0:
        balance = most * comm.size / np.maximum(total, 1.0)
        print(
            f"\nranks: {comm.size}; mesh_domain(torus, h={h}, degree=2): "
            f"{np.median(times):.3f} s (median of {repeats}); {background} background and "
            f"{int(total[0])} kept tetrahedra; busiest rank over the mean: kept cells "
            f"{balance[0]:.2f}, moved vertices {balance[1]:.2f}; proven Jacobian ratio "
            f"{md.certificate.min_jacobian_ratio!r}; io.redistribute: {t_even:.3f} s, "
            f"busiest rank over the mean {spread * comm.size / max(total[0], 1.0):.2f}"
        )
        if solve:
            print(f"P2 Poisson solve (CG + GAMG): {before:.3f} s before, {after:.3f} s after")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dim", type=int, choices=(2, 3), default=2)
    parser.add_argument("--sizes", type=float, nargs="+", help="cells (default: module docstring)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--quick", action="store_true", help="one small background (2e4 / 8e4 cells), 2 repeats"
    )
    parser.add_argument("--json", help="write the rows as JSON to this file")
    parser.add_argument(
        "--partition",
        choices=("layers", "graph"),
        default="layers",
        help="the background's partition: as built (slabs of layers) or redistributed by "
        "DOLFINx's graph partitioner (io.redistribute, untimed)",
    )
    parser.add_argument("--mesh-domain", type=float, help="time mesh_domain of the torus, h = H")
    parser.add_argument("--solve", action="store_true", help="--mesh-domain: and Poisson solves")
    args = parser.parse_args()
    if args.quick:
        args.sizes, args.repeats = [2e4 if args.dim == 2 else 8e4], 2
    elif args.sizes is None:
        args.sizes = [1e6, 4e6]
    if args.mesh_domain:
        return mesh_domain_row(args.mesh_domain, args.repeats, args.solve)
    rows = [run(args.dim, target, args.repeats, args.partition) for target in args.sizes]
    if args.json and comm.rank == 0:
        _results.write(args.json, {"partition": args.partition, "rows": rows})
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
        print(
            f"partition: {args.partition}; active cells of the last update, busiest rank over "
            "the mean: " + ", ".join(f"{r['active_balance']:.2f}" for r in rows)
        )
        print("the meshes (the same on any number of ranks):")
        for r in rows:
            print(f"{r['cells']:9d} " + ", ".join(f"{k} {r[k]!r}" for k in FINGERPRINT))


if __name__ == "__main__":
    main()
