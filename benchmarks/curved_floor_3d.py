"""Curved tetrahedra against their floors: ``curved_mesh`` and ``MovingDomain.update``.

The 3D counterpart of ``curved_floor.py`` and ``update_floor.py``, on the A15 background and
the two domains of ``conform_floor_3d.py`` (a ball of radius 0.8 and a tilted solid torus,
moved by fractions of ``h`` from step to step; about 1e6 tetrahedra, 8e4 with ``--quick``).

* ``curved_mesh`` (q = 2 and 3, the default map ``I~`` for surfaces) of the relaxed
  conforming mesh against its floor: DOLFINx's ``interpolate_geometry`` of the same mesh
  plus the closest points of the nodes it needs, the distinct geometry nodes of the faces
  tagged ``IMMERSED`` (closed form for the sphere and the torus; the package's
  ``closest_point`` is general). The package also finds the entities of Gamma_h, blends the
  nodes into the cells and proves every curved cell valid (Bernstein bounds of ``det J``):
  work the floor does not do. The meshes' edges and faces are created before the timing
  (both sides need them: the degree-q geometry has nodes on them), and so are the
  entities' permutations: ``interpolate_geometry`` computes them at q >= 3 (two nodes on an
  edge), ``curved_mesh`` does not need them (it numbers its nodes itself), but a degree-q
  function space on the mesh does, so the cost (25 / 12 ms on a fresh ball / torus mesh) is
  the user's either way; left in, it would land on whichever side runs first on each
  fresh mesh.
* ``MovingDomain.update`` (q = 2, ``I~``) against its floor: the straight map of
  ``conform_floor_3d.ConformFloor3D`` (classification of every vertex, closest points of
  the positive faces' vertices) and the degree-2 nodes of the cells with a vertex on Gamma
  (now or at the previous step) written in place: affine, with the midpoints of the edges
  on Gamma projected. The package's update without the relaxation (``relax=False``, as the
  floor), then with it (the default), and the relaxation's share of the relaxed update.

All calls of a row group are interleaved at every step (one untimed warm-up step), medians
of ``--repeats`` steps, maximum over ranks; ``--apart`` times the ``curved_mesh`` rows one
side after the other instead (all steps of the package, then all of the floor): the
allocator can move the two orders apart by more than the machine's drift
(``_floor.timed_pairs``).

Run: ``python benchmarks/curved_floor_3d.py [--quick] [--repeats N] [--cells N] [--apart]``; also
under mpirun.
"""

from __future__ import annotations

import argparse

from mpi4py import MPI

import _results
import basix
import numpy as np
from _floor import TABLES, print_table, timed_pairs
from conform_floor_3d import QUICK_CELLS, ConformFloor3D, background_box, floor_of, surfaces
from dolfinx import fem
from dolfinx import mesh as dmesh

import dolfinx_universal as du

LABELS = {"sphere": "ball r=0.8", "torus": "torus R=0.55 r=0.3"}


def curved_rows(
    comm, background, kind: str, repeats: int, apart: bool = False
) -> list[tuple[str, float, float]]:
    """``curved_mesh`` against ``interpolate_geometry`` plus the projections, q = 2, 3."""
    um = du.UniversalMesh(background)
    h = float(comm.allreduce(float(um.h.max()) if len(um.h) else 0.0, op=MPI.MAX))
    meshes = [um.conform(surfaces(kind, h, step)) for step in range(repeats + 1)]
    for cm in meshes:  # edges, faces and their permutations (untimed: see the docstring)
        cm.mesh.topology.create_entities(1)
        cm.mesh.topology.create_connectivity(3, 1)
        cm.mesh.topology.create_connectivity(3, 2)
        cm.mesh.topology.create_connectivity(2, 3)
        cm.mesh.topology.create_entity_permutations()
    rows = []
    for q in (2, 3):
        ce = fem.coordinate_element(dmesh.CellType.tetrahedron, q, basix.LagrangeVariant.gll_warped)

        def floor(step: int, ce=ce) -> None:
            cm = meshes[step]
            msh = fem.interpolate_geometry(cm.mesh, ce)
            nodes = np.unique(dmesh.entities_to_geometry(msh, 2, cm.facet_tags.find(du.IMMERSED)))
            x = msh.geometry.x
            x[nodes] = floor_of(surfaces(kind, h, step)).project(x[nodes])

        fns = {"package": lambda step, q=q: du.curved_mesh(meshes[step], q, "I~"), "floor": floor}
        t = timed_pairs(comm, fns, repeats, apart)
        n = meshes[0].mesh.topology.index_map(3).size_global
        rows.append((f"curved_mesh q={q}, {n} tets, {LABELS[kind]}", t["package"], t["floor"]))
    return rows


class UpdateFloor3D(ConformFloor3D):
    """The floor of a degree-2 moving-domain update on tetrahedra (module docstring)."""

    def __init__(self, um: du.UniversalMesh) -> None:
        super().__init__(um)
        ce = fem.coordinate_element(dmesh.CellType.tetrahedron, 2, basix.LagrangeVariant.gll_warped)
        self.mesh = fem.interpolate_geometry(um.background, ce)
        self.dofmap = self.mesh.geometry.dofmaps[0]
        self.dirty = np.zeros(len(self.c2v), dtype=bool)
        p = basix.create_element(
            basix.ElementFamily.P, basix.CellType.tetrahedron, 2, basix.LagrangeVariant.gll_warped
        ).points
        self.lam = np.column_stack([1.0 - p.sum(axis=1), p])  # vertices, edges 0-5
        self.edges = np.array(basix.topology(basix.CellType.tetrahedron)[1])  # (6, 2)

    def update(self, surface) -> None:
        c2v, f = self.c2v, floor_of(surface)
        y, on, _ = self.snapped(surface)
        near = on[c2v].any(axis=1)
        redo = np.flatnonzero(near | self.dirty)
        cv = c2v[redo]
        yc = y[cv]  # (m, 4, 3)
        nodes = np.einsum("pi,cid->cpd", self.lam, yc)
        both = on[cv[:, self.edges[:, 0]]] & on[cv[:, self.edges[:, 1]]]  # (m, 6)
        c, e = np.nonzero(both)
        nodes[c, 4 + e] = f.project(nodes[c, 4 + e])  # the edges on Gamma, midpoints onto it
        self.mesh.geometry.x[self.dofmap[redo].ravel()] = nodes.reshape(-1, 3)
        self.dirty = near


def update_rows(comm, background, kind: str, repeats: int):
    """``MovingDomain.update`` against the floor; the relaxation's share of it."""
    md = du.MovingDomain(background, degree=2, map="I~")
    floor = UpdateFloor3D(md.universal)
    h = float(comm.allreduce(float(md.universal.h.max()), op=MPI.MAX))
    fns = {
        "package": lambda step: md.update(surfaces(kind, h, step)),
        "floor": lambda step: floor.update(surfaces(kind, h, step)),
    }
    t = timed_pairs(comm, fns, repeats)
    relax = [comm.allreduce(r.timings["relax"], op=MPI.MAX) for r in md.steps[1:]]
    total = [comm.allreduce(r.timings["total"], op=MPI.MAX) for r in md.steps[1:]]
    n = background.topology.index_map(3).size_global
    rows = [
        (f"update q=2, A15 {n} tets, {LABELS[kind]}", t["package"], t["floor"]),
        (
            "  the same less its relaxation stage",
            t["package"] - float(np.median(relax)),
            t["floor"],
        ),
    ]
    return rows, float(np.median(np.divide(relax, total)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="8e4 tetrahedra, 3 repeats")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--cells", type=float, default=1e6)
    parser.add_argument("--json", help="write the results as JSON to this file")
    parser.add_argument(
        "--apart",
        action="store_true",
        help="curved_mesh rows: time all steps of each side in turn, not interleaved",
    )
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    repeats = 3 if args.quick else args.repeats
    box, h = background_box(QUICK_CELLS if args.quick else args.cells)
    bg = du.a15_mesh(comm, box, h)
    curved, update, shares = [], [], []
    for kind in ("sphere", "torus"):
        curved += curved_rows(comm, bg, kind, repeats, args.apart)
        rows, share = update_rows(comm, bg, kind, repeats)
        update += rows
        shares.append((LABELS[kind], share))
    print_table(comm, "curved_mesh (tetrahedra) against interpolate_geometry", curved)
    print_table(comm, "MovingDomain.update (tetrahedra) against the floor", update)
    if comm.rank == 0:
        print(
            "relaxation share of the relaxed update (median): "
            + ", ".join(f"{name}: {100 * s:.0f} %" for name, s in shares)
        )
        if args.json:
            results = {"repeats": repeats, "tables": TABLES, "relax_share": dict(shares)}
            _results.write(args.json, results)


if __name__ == "__main__":
    main()
