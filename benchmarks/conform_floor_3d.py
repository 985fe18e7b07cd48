"""Conforming a tetrahedral background against a plain numpy floor that includes ``create_submesh``.

The 3D counterpart of ``conform_floor.py``. The background is an A15 mesh
(:func:`~dolfinx_universal.a15_mesh`) of about 1e6 tetrahedra (8e4 with ``--quick``: the
torus needs ``h`` below about 0.15) on ``[-L, L]^3``, ``L = 0.85 + 3.5 h`` (1.01 at 1e6); the
domains are a ball (a :class:`~dolfinx_universal.boundaries.surfaces.Sphere` of radius 0.8) and a
solid torus (major radius 0.55, minor radius 0.3, tilted axis), moved by a fraction of ``h``
at every step (the offsets ``OFFSETS``, fixed, never tuned), so that no step finds
another's cached samples.

The floor (:class:`ConformFloor3D`) does the minimal work of ``M_h`` on tetrahedra in closed
form, reusing the package's prepared arrays (vertex coordinates, cells, sizes ``h``, which
are not timed, as in 2D):

* classify every vertex (inside the domain when deeper than ``eta h``: the package's
  perturbation counts the shallower inside vertices as on Gamma);
* the cells with at least one inside vertex (kept) and those with exactly one (positively
  cut): the other three vertices of the latter span the positive faces;
* project the vertices of the positive faces onto the surface (closed form for the sphere
  and the torus), leave every other vertex where it is (in 3D ``M_h`` only snaps);
* ``dolfinx.mesh.create_submesh`` of the kept owned cells and one write of the mapped
  coordinates into it (the package's ``conform`` returns a DOLFINx submesh, so the floor
  creates one too).

It does none of the package's checks (containment, Gamma_h's topology, conditioning,
inverted or low-quality cells), no repair of interior faces with three outside vertices (none
arise on these domains: the floor's mesh is compared with the package's below) and no vertex
relaxation.

Rows per domain: the package's ``UniversalMesh(bg, relax=False).conform`` against the floor;
the same without ``create_submesh`` on both sides (``UniversalMesh.straight_map`` against
the floor stopping at the mapped coordinates and the kept cells); ``relax=True`` (the
default, work the floor does not do) against the same floor, and the relaxation's share of
the relaxed conform (``timings["relax"]`` over the sum of the stages, median over steps).
Each ``UniversalMesh`` is built once, outside the timing. All five calls are interleaved at
every step (one untimed warm-up step), medians of ``--repeats`` steps, maximum over ranks.

Run: ``python benchmarks/conform_floor_3d.py [--quick] [--repeats N] [--cells N]``; also
under mpirun.
"""

from __future__ import annotations

import argparse
import warnings

from mpi4py import MPI

import _results
import numpy as np
from _floor import TABLES, print_table, timed_pairs
from dolfinx import mesh as dmesh

import dolfinx_universal as du
from dolfinx_universal.backgrounds.lattice_tet import _a15_layout

EXTENT = 0.85
"""The domains lie in ``[-EXTENT, EXTENT]^3`` (up to the offsets)."""
OFFSETS = [(0.37, 0.11, -0.23), (-0.23, 0.41, 0.17), (0.13, -0.29, 0.31), (-0.41, -0.17, -0.07)]
"""Centre offsets in units of ``h`` of the steps (step ``i`` uses ``OFFSETS[i % 4]``)."""
TORUS_AXIS = (0.3, 0.2, 1.0)
QUICK_CELLS = 8e4
"""``--quick``: the torus's tube (0.3) needs ``h`` below about 0.15 (two cells across)."""


def a15_h(box, cells: float) -> float:
    """Size ``h`` of the A15 mesh of ``box`` (:func:`du.a15_mesh`) with about ``cells`` tets.

    The layout pads the box by part of a cell: the count ``46 nx ny nz`` is matched by a
    few fixed-point steps from the unpadded estimate (46 tetrahedra per cell of side
    ``4^(1/3) h``)."""
    vol = float(np.prod(np.subtract(box[1], box[0])))
    h = float(np.cbrt(11.5 * vol / cells))
    for _ in range(8):
        n = 46 * np.prod(_a15_layout(box, h).n)
        h *= float(np.cbrt(n / cells))
    return h


def background_box(cells: float) -> tuple[list[list[float]], float]:
    """The box ``[-L, L]^3`` and size ``h`` of an A15 background of about ``cells`` tets,
    ``L = EXTENT + 3.5 h`` (the domains' extent, then the relaxation radius ``3 h`` and
    half a cell more: the background's boundary must stay out of the band)."""
    lo, hi = EXTENT, 10.0 * EXTENT  # L - EXTENT - 3.5 h(L) changes sign once in between
    for _ in range(60):
        L = 0.5 * (lo + hi)
        h = a15_h([[-L] * 3, [L] * 3], cells)
        lo, hi = (L, hi) if L < EXTENT + 3.5 * h else (lo, L)
    return [[-hi] * 3, [hi] * 3], a15_h([[-hi] * 3, [hi] * 3], cells)


class SphereFloor:
    """Closed-form inside test and closest point of a sphere."""

    def __init__(self, sphere: du.Sphere) -> None:
        self.c, self.r = np.asarray(sphere.center, dtype=float), float(sphere.radius)

    def inside(self, x: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Points deeper than ``depth`` inside."""
        d = x - self.c
        return (d * d).sum(axis=1) < (self.r - depth) ** 2

    def project(self, x: np.ndarray) -> np.ndarray:
        d = x - self.c
        return self.c + (self.r / np.sqrt((d * d).sum(axis=1)))[:, None] * d


class TorusFloor:
    """Closed-form inside test and closest point of a ring torus (any axis)."""

    def __init__(self, torus: du.Torus) -> None:
        self.c, self.k = np.asarray(torus.center, dtype=float), np.asarray(torus.axis, float)
        self.R, self.r = float(torus.major), float(torus.minor)

    def _core(self, x: np.ndarray):
        d = x - self.c
        z = d @ self.k
        w = d - z[:, None] * self.k
        rho = np.sqrt((w * w).sum(axis=1))
        return z, w, rho

    def inside(self, x: np.ndarray, depth: np.ndarray) -> np.ndarray:
        z, _, rho = self._core(x)
        return (rho - self.R) ** 2 + z * z < (self.r - depth) ** 2

    def project(self, x: np.ndarray) -> np.ndarray:
        _, w, rho = self._core(x)
        core = self.c + (self.R / rho)[:, None] * w
        e = x - core
        return core + (self.r / np.sqrt((e * e).sum(axis=1)))[:, None] * e


def floor_of(surface):
    return SphereFloor(surface) if isinstance(surface, du.Sphere) else TorusFloor(surface)


class ConformFloor3D:
    """The floor of conforming a tetrahedral background (see the module docstring)."""

    def __init__(self, um: du.UniversalMesh) -> None:
        self.background = um.background
        self.x, self.c2v, self.n2v, self.nco = um._x, um._c2v, um._n2v, um._nco
        self.depth = um.eta * um.h  # inside vertices shallower than eta h count as on Gamma

    def snapped(self, surface) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mapped vertex coordinates, the vertices snapped onto the surface and the
        inside vertices of each cell."""
        x, c2v = self.x, self.c2v
        f = floor_of(surface)
        inside = f.inside(x, self.depth)
        n_in = inside[c2v].sum(axis=1, dtype=np.int8)
        on = np.zeros(len(x), dtype=bool)
        on[c2v[n_in == 1]] = True
        on &= ~inside
        y = x.copy()
        y[on] = f.project(x[on])
        return y, on, n_in

    def straight(self, surface) -> tuple[np.ndarray, np.ndarray]:
        """Mapped vertex coordinates and the kept owned cells."""
        y, _, n_in = self.snapped(surface)
        return y, np.flatnonzero(n_in[: self.nco] > 0).astype(np.int32)

    def conform(self, surface) -> dmesh.Mesh:
        y, kept = self.straight(surface)
        sub, _, _, node_map = dmesh.create_submesh(self.background, 3, kept)
        sub.geometry.x[:] = y[self.n2v[node_map]]
        return sub


def surfaces(kind: str, h: float, step: int):
    """The domain of a step: centre moved by ``h * OFFSETS[step % 4]``."""
    off = h * np.asarray(OFFSETS[step % len(OFFSETS)])
    if kind == "sphere":
        return du.Sphere(off, 0.8)
    return du.Torus(off, 0.55, 0.3, axis=TORUS_AXIS)


def check_floor(comm, um: du.UniversalMesh, floor: ConformFloor3D, surface) -> str:
    """Compare the floor's mesh with the package's ``relax=False`` mesh (untimed)."""
    cm = um.conform(surface)
    sub = floor.conform(surface)
    nco = cm.mesh.topology.index_map(3).size_local
    same_cells = np.array_equal(
        np.sort(cm.cell_map[:nco]), np.sort(np.asarray(floor.straight(surface)[1]))
    )
    same_cells = comm.allreduce(bool(same_cells), op=MPI.LAND)
    dx = np.inf
    if same_cells and len(sub.geometry.x) == len(cm.mesh.geometry.x):
        dx = float(np.abs(sub.geometry.x - cm.mesh.geometry.x).max(initial=0.0))
    dx = comm.allreduce(dx, op=MPI.MAX)
    relocated = cm.num_relocated
    n = cm.mesh.topology.index_map(3).size_global
    return (
        f"{n} kept cells, the same as the floor's: {same_cells}; largest vertex difference "
        f"{dx:.1e}; {relocated} vertices relocated by the package (eta and repairs)"
    )


def compare(comm, background, kind: str, repeats: int):
    """Medians (s) of the package and floor calls, interleaved; the relaxation's share."""
    um = du.UniversalMesh(background, relax=False)
    relaxed = du.UniversalMesh(background, relax=True)
    floor = ConformFloor3D(um)
    h = float(comm.allreduce(float(um.h.max()) if len(um.h) else 0.0, op=MPI.MAX))
    shares: list[float] = []

    def relaxed_conform(step):
        cm = relaxed.conform(surfaces(kind, h, step))
        t = cm.timings
        total = comm.allreduce(sum(t[k] for k in ("classify", "project", "map", "mesh")), MPI.MAX)
        if step:
            shares.append(comm.allreduce(t["relax"], op=MPI.MAX) / total)

    fns = {
        "package": lambda step: um.conform(surfaces(kind, h, step)),
        "floor": lambda step: floor.conform(surfaces(kind, h, step)),
        "package_nosub": lambda step: um.straight_map(surfaces(kind, h, step)),
        "floor_nosub": lambda step: floor.straight(surfaces(kind, h, step)),
        "relaxed": relaxed_conform,
    }
    with warnings.catch_warnings():  # low-quality warnings of relax=False: not timed here
        warnings.simplefilter("ignore", UserWarning)
        note = check_floor(comm, um, floor, surfaces(kind, h, 0))
        t = timed_pairs(comm, fns, repeats)
    return t, float(np.median(shares)), note


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="8e4 tetrahedra, 3 repeats")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--cells", type=float, default=1e6)
    parser.add_argument("--json", help="write the results as JSON to this file")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    repeats = 3 if args.quick else args.repeats
    cells = QUICK_CELLS if args.quick else args.cells
    box, h = background_box(cells)
    bg = du.a15_mesh(comm, box, h)
    n = bg.topology.index_map(3).size_global
    rows, shares, notes = [], [], []
    for kind, label in (("sphere", "ball r=0.8"), ("torus", "torus R=0.55 r=0.3")):
        t, share, note = compare(comm, bg, kind, repeats)
        rows += [
            (f"conform, A15 {n} tets, {label}", t["package"], t["floor"]),
            ("  the same without create_submesh (straight_map)", t["package_nosub"],
             t["floor_nosub"]),
            ("  with the vertex relaxation (default)", t["relaxed"], t["floor"]),
        ]  # fmt: skip
        shares.append((label, share))
        notes.append(f"{label}: {note}")
    print_table(comm, "UniversalMesh.conform (tetrahedra) against the floor", rows)
    if comm.rank == 0:
        print(
            "relaxation share of the relaxed conform (median): "
            + ", ".join(f"{name}: {100 * s:.0f} %" for name, s in shares)
        )
        print("floor check (relax=False, step 0): " + "; ".join(notes))
        if args.json:
            results = {"repeats": repeats, "tables": TABLES, "floor_check": notes}
            _results.write(args.json, {**results, "relax_share": dict(shares)})


if __name__ == "__main__":
    main()
