"""Tetrahedral background meshes: the BCC and A15 lattices, serial and built in parallel.

The 3D counterpart of :func:`~dolfinx_universal.backgrounds.lattice_tri.equilateral_triangulation`
and
:func:`~dolfinx_universal.backgrounds.lattice_tri.equilateral_mesh`: uniform tetrahedralisations
covering a
box, every tetrahedron positively oriented (``det[x1 - x0, x2 - x0, x3 - x0] > 0``).

* **BCC** (body-centred cubic; Sommerville's tetrahedron No. 1): vertices at the corners and
  centres of cubes of side ``h``; for each pair of face-adjacent cube centres, the 4
  tetrahedra spanned by the two centres and one edge of the shared face (12 per cube).
  Dihedral angles 60 and 90 degrees, edges ``h`` (corner-corner, centre-centre) and
  ``h sqrt(3)/2`` (corner-centre).
* **A15** (Cr3Si): the Delaunay tetrahedralisation of the 8 sites per cubic cell of side
  ``a = 4^(1/3) h`` (the vertex density of BCC of spacing ``h``); 46 tetrahedra per cell,
  every dihedral angle in ``[53.13, 78.46]`` degrees (strictly acute), edges ``0.79 h``,
  ``0.89 h`` and ``0.97 h``. The periodic template :data:`A15_TETS` was derived once with
  Qhull (``tests/test_background_tet.py`` re-derives it).

The distributed meshes are built like the 2D one: each rank generates a slab of cell layers
along ``z`` and the vertices it owns, with a contiguous global numbering that does not depend
on the number of ranks, and keeps its cells
(:func:`~dolfinx_universal.backgrounds.lattice_tri.layout_partitioner`, shared-facet ghosts, no
graph
partitioning). The global mesh (vertex coordinates by input index and cells) is bitwise that
of the serial tetrahedralisation on any number of ranks.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh

from dolfinx_universal.backgrounds.lattice_tri import create_mesh, layout_partitioner
from dolfinx_universal.core.arrays import Float, Int

__all__ = [
    "A15_SITES",
    "A15_TETS",
    "a15_mesh",
    "a15_num_cells",
    "a15_tetrahedralisation",
    "bcc_mesh",
    "bcc_tetrahedralisation",
]


A15_SITES = np.array(
    [(0, 0, 0), (2, 2, 2), (1, 0, 2), (3, 0, 2), (2, 1, 0), (2, 3, 0), (0, 2, 1), (0, 2, 3)],
    dtype=np.int64,
)
"""The 8 Cr3Si sites of the A15 cell, in quarters of the cell side, shape ``(8, 3)``."""

A15_TETS = np.array(
    [
        ((0, 0, 0, 0), (2, 0, 0, 0), (4, 0, 0, 0), (6, 0, 0, 0)),
        ((0, 0, 0, 0), (2, 0, 0, 0), (5, 0, -1, 0), (4, 0, 0, 0)),
        ((0, 0, 0, 0), (2, 0, 0, 0), (6, 0, 0, 0), (3, -1, 0, 0)),
        ((0, 0, 0, 0), (4, 0, 0, 0), (7, 0, 0, -1), (6, 0, 0, 0)),
        ((0, 0, 0, 1), (2, 0, 0, 0), (3, -1, 0, 0), (7, 0, 0, 0)),
        ((0, 0, 0, 1), (2, 0, 0, 0), (4, 0, 0, 1), (5, 0, -1, 1)),
        ((0, 0, 0, 1), (2, 0, 0, 0), (7, 0, 0, 0), (4, 0, 0, 1)),
        ((0, 0, 1, 0), (2, 0, 1, 0), (3, -1, 1, 0), (6, 0, 0, 0)),
        ((0, 0, 1, 0), (2, 0, 1, 0), (6, 0, 0, 0), (5, 0, 0, 0)),
        ((0, 0, 1, 0), (5, 0, 0, 0), (6, 0, 0, 0), (7, 0, 0, -1)),
        ((0, 0, 1, 1), (2, 0, 1, 0), (5, 0, 0, 1), (7, 0, 0, 0)),
        ((0, 0, 1, 1), (2, 0, 1, 0), (7, 0, 0, 0), (3, -1, 1, 0)),
        ((0, 1, 0, 0), (3, 0, 0, 0), (4, 0, 0, 0), (5, 0, -1, 0)),
        ((0, 1, 0, 0), (3, 0, 0, 0), (6, 1, 0, 0), (4, 0, 0, 0)),
        ((0, 1, 0, 0), (4, 0, 0, 0), (6, 1, 0, 0), (7, 1, 0, -1)),
        ((0, 1, 0, 1), (3, 0, 0, 0), (4, 0, 0, 1), (7, 1, 0, 0)),
        ((0, 1, 0, 1), (3, 0, 0, 0), (5, 0, -1, 1), (4, 0, 0, 1)),
        ((0, 1, 1, 0), (3, 0, 1, 0), (5, 0, 0, 0), (6, 1, 0, 0)),
        ((0, 1, 1, 0), (5, 0, 0, 0), (7, 1, 0, -1), (6, 1, 0, 0)),
        ((0, 1, 1, 1), (3, 0, 1, 0), (7, 1, 0, 0), (5, 0, 0, 1)),
        ((1, 0, 0, 0), (2, 0, 0, 0), (3, 0, 0, 0), (4, 0, 0, 1)),
        ((1, 0, 0, 0), (2, 0, 0, 0), (4, 0, 0, 0), (3, 0, 0, 0)),
        ((1, 0, 0, 0), (2, 0, 0, 0), (4, 0, 0, 1), (7, 0, 0, 0)),
        ((1, 0, 0, 0), (2, 0, 0, 0), (6, 0, 0, 0), (4, 0, 0, 0)),
        ((1, 0, 0, 0), (2, 0, 0, 0), (7, 0, 0, 0), (6, 0, 0, 0)),
        ((1, 0, 0, 0), (2, 0, 1, 0), (3, 0, 1, 0), (5, 0, 0, 0)),
        ((1, 0, 0, 0), (2, 0, 1, 0), (5, 0, 0, 0), (6, 0, 0, 0)),
        ((1, 0, 0, 0), (2, 0, 1, 0), (5, 0, 0, 1), (3, 0, 1, 0)),
        ((1, 0, 0, 0), (2, 0, 1, 0), (6, 0, 0, 0), (7, 0, 0, 0)),
        ((1, 0, 0, 0), (2, 0, 1, 0), (7, 0, 0, 0), (5, 0, 0, 1)),
        ((1, 0, 0, 0), (3, 0, 0, 0), (4, 0, 0, 0), (6, 1, 0, 0)),
        ((1, 0, 0, 0), (3, 0, 0, 0), (6, 1, 0, 0), (7, 1, 0, 0)),
        ((1, 0, 0, 0), (3, 0, 0, 0), (7, 1, 0, 0), (4, 0, 0, 1)),
        ((1, 0, 0, 0), (3, 0, 1, 0), (5, 0, 0, 1), (7, 1, 0, 0)),
        ((1, 0, 0, 0), (3, 0, 1, 0), (6, 1, 0, 0), (5, 0, 0, 0)),
        ((1, 0, 0, 0), (3, 0, 1, 0), (7, 1, 0, 0), (6, 1, 0, 0)),
        ((1, 0, 0, 0), (4, 0, 0, 0), (5, 0, 0, 0), (6, 1, 0, 0)),
        ((1, 0, 0, 0), (4, 0, 0, 0), (6, 0, 0, 0), (5, 0, 0, 0)),
        ((1, 0, 0, 0), (4, 0, 0, 1), (5, 0, 0, 1), (7, 0, 0, 0)),
        ((1, 0, 0, 0), (4, 0, 0, 1), (7, 1, 0, 0), (5, 0, 0, 1)),
        ((2, 0, 0, 0), (3, -1, 0, 0), (7, 0, 0, 0), (6, 0, 0, 0)),
        ((2, 0, 0, 0), (3, 0, 0, 0), (4, 0, 0, 1), (5, 0, -1, 1)),
        ((2, 0, 0, 0), (3, 0, 0, 0), (5, 0, -1, 0), (4, 0, 0, 0)),
        ((2, 0, 1, 0), (3, -1, 1, 0), (6, 0, 0, 0), (7, 0, 0, 0)),
        ((4, 0, 0, 0), (5, 0, 0, 0), (6, 1, 0, 0), (7, 1, 0, -1)),
        ((4, 0, 0, 0), (5, 0, 0, 0), (7, 0, 0, -1), (6, 0, 0, 0)),
    ],
    dtype=np.int64,
)
"""The periodic A15 tetrahedralisation, shape ``(46, 4, 4)``: the tetrahedra whose centroid
lies in the cell ``[0, 1)^3``, each vertex as ``(site, ox, oy, oz)``, the site
(:data:`A15_SITES`) of the cell offset by ``(ox, oy, oz)``; positively oriented. Derived
once from a Qhull Delaunay tetrahedralisation of a 5x5x5 block of cells (the sites are in
general position: no 5 cospherical, so the Delaunay tetrahedralisation is unique)."""

_A15_REACH = 1.5
"""Largest ``|vertex - centroid|`` coordinate over the tetrahedra of :data:`A15_TETS`, in
quarters of the cell side: a point lies in a tetrahedron whose centroid is within this
distance in each coordinate."""


def _layered_mesh(comm: MPI.Comm, x: Float, cells: Int) -> dmesh.Mesh:
    """The DOLFINx mesh of this rank's slab of layers (vertices ``x`` it owns, cells by
    global vertex index), each rank keeping its own cells
    (:func:`~dolfinx_universal.backgrounds.lattice_tri.layout_partitioner`)."""
    partitioner = layout_partitioner() if comm.size > 1 else None
    return create_mesh(comm, cells, x, partitioner, "tetrahedron")


def _check_box(box: npt.ArrayLike, h: float, name: str) -> Float:
    """The box as a checked ``(2, 3)`` array ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``."""
    b = np.asarray(box, dtype=np.float64)
    if b.shape != (2, 3):
        raise ValueError(
            f"{name} mesh needs a box [[xmin, ymin, zmin], [xmax, ymax, zmax]], got shape {b.shape}"
        )
    if not np.all(np.isfinite(b)) or not h > 0 or not np.isfinite(h):
        raise ValueError(f"{name} mesh needs a finite box and h > 0, got box={b.tolist()}, h={h}")
    if np.any(b[1] <= b[0]):
        raise ValueError(f"empty box {b.tolist()}: need xmin < xmax, ymin < ymax and zmin < zmax")
    return b


def _layers(nz: int, rank: int, size: int) -> tuple[int, int, bool, bool]:
    """Cell layers ``first .. last - 1`` of part ``rank`` of ``size``, and whether the part
    also holds the vertices below the first layer (part 0) and above the last (last part)."""
    return rank * nz // size, (rank + 1) * nz // size, rank == 0, rank == size - 1


# ---------------------------------------------------------------------------------------------
# BCC


class _BCCLayout(NamedTuple):
    lo: Float  # (3,) corner (0, 0, 0) of the cube grid
    h: float
    n: tuple[int, int, int]  # cubes per direction


def _bcc_layout(box: npt.ArrayLike, h: float) -> _BCCLayout:
    b = _check_box(box, h, "BCC")
    n = np.maximum(np.ceil((b[1] - b[0]) / h - 1e-12).astype(np.int64), 1)
    return _BCCLayout(b[0].copy(), float(h), (int(n[0]), int(n[1]), int(n[2])))


def _bcc_templates() -> dict[int, npt.NDArray[np.int64]]:
    """The 12 BCC tetrahedron templates, ``{d: (4, 4, 3)}``.

    For the pair (cube, cube + e_d), its 4 tetrahedra: the two centres and one edge of the
    shared face, positively oriented, as vertex positions in half cube sides from the lower
    cube's corner (0, 0, 0) (odd coordinates: a centre, even: a corner).
    """
    out = {}
    e = np.eye(3, dtype=np.int64)
    square = [(0, 0), (1, 0), (1, 1), (0, 1)]
    for d in range(3):
        d1, d2 = (d + 1) % 3, (d + 2) % 3
        c1, c2 = np.ones(3, dtype=np.int64), np.ones(3, dtype=np.int64) + 2 * e[d]
        q = [2 * (e[d] + a * e[d1] + b * e[d2]) for a, b in square]
        arr = np.array([[c1, c2, q[m], q[(m + 1) % 4]] for m in range(4)])
        neg = np.linalg.det((arr[:, 1:] - arr[:, :1]).astype(np.float64)) < 0
        arr[neg, 2], arr[neg, 3] = arr[neg, 3].copy(), arr[neg, 2].copy()
        out[d] = arr
    return out


_BCC_TEMPLATES = _bcc_templates()


def _bcc_part(lay: _BCCLayout, rank: int, size: int) -> tuple[Float, Int]:
    """Vertices and cells of part ``rank`` of ``size`` of the BCC tetrahedralisation.

    Vertex groups, in global order: the centres below the grid (``C(-1)``), then for each
    corner plane ``k = 0 .. nz`` its corners ``P(k)`` and the centres ``C(k)`` of the cube
    layer above it (with one halo centre beyond each side face of the grid; ``C(nz)``: the
    centres above the grid). Part ``r`` holds the groups of its cube layers (and ``C(-1)`` /
    ``P(nz), C(nz)`` if first / last) and the tetrahedra of its layers: per layer ``k`` those
    of the z-pairs through plane ``k``, the x-pairs, the y-pairs (and, in the last part, the
    z-pairs through plane ``nz``). The parts in order give the serial arrays.
    """
    nx, ny, nz = lay.n
    first, last, bottom, top = _layers(nz, rank, size)
    na, nb = nx * ny, (nx + 1) * (ny + 1)
    halo = np.ones((ny + 2, nx + 2), dtype=bool)  # centre (i, j) at [j + 1, i + 1]
    halo[[0, 0, -1, -1], [0, -1, 0, -1]] = False
    lut = (np.cumsum(halo) - 1).reshape(ny + 2, nx + 2)
    nc = int(halo.sum())
    stride = nb + nc  # vertices per layer

    # Vertices, in half cube sides.
    jj, ii = np.divmod(np.arange(nb, dtype=np.int64), nx + 1)
    corner_xy = np.column_stack([2 * ii, 2 * jj])
    jj, ii = np.nonzero(halo)
    centre_xy = np.column_stack([2 * ii - 1, 2 * jj - 1]).astype(np.int64)
    jj, ii = np.divmod(np.arange(na, dtype=np.int64), nx)
    inner_xy = np.column_stack([2 * ii + 1, 2 * jj + 1])

    def plane(xy: Int, z: Int) -> Int:
        """Rows ``(x, y, z)`` for each ``z``, then each ``xy``, shape ``(len(z) len(xy), 3)``."""
        return np.column_stack([np.tile(xy, (len(z), 1)), np.repeat(z, len(xy))])

    ks = np.arange(first, last, dtype=np.int64)
    layer = np.concatenate([plane(corner_xy, 2 * ks), plane(centre_xy, 2 * ks + 1)])
    # Layer by layer: corners then centres.
    order = np.concatenate(
        [
            (np.arange(nb)[None, :] + nb * np.arange(len(ks))[:, None]),
            (len(ks) * nb + np.arange(nc)[None, :] + nc * np.arange(len(ks))[:, None]),
        ],
        axis=1,
    ).reshape(-1)
    groups = [layer[order]]
    if bottom:
        groups.insert(0, plane(inner_xy, np.array([-1], dtype=np.int64)))
    if top:
        groups += [
            plane(corner_xy, np.array([2 * nz], dtype=np.int64)),
            plane(inner_xy, np.array([2 * nz + 1], dtype=np.int64)),
        ]
    half = np.concatenate(groups)
    x = lay.lo + (0.5 * lay.h) * half.astype(np.float64)

    def corner(i: Int, j: Int, k: Int) -> Int:
        return na + k * stride + j * (nx + 1) + i

    def centre(i: Int, j: Int, k: Int) -> Int:
        inner = j * nx + i
        mid = na + np.clip(k, 0, nz - 1) * stride + nb + lut[j + 1, i + 1]
        return np.where(k < 0, inner, np.where(k >= nz, na + nz * stride + nb + inner, mid))

    def pair_tets(i: Int, j: Int, k: Int, d: int) -> Int:
        """Tetrahedra of the pairs (cube (i, j, k), cube + e_d), shape (..., 4 pairs, 4)."""
        tpl = _BCC_TEMPLATES[d]  # (4, 4, 3) half units, from the lower cube's corner (0,0,0)
        out = np.empty((*np.broadcast_shapes(i.shape, j.shape, k.shape), 4, 4), dtype=np.int64)
        for t in range(4):
            for v in range(4):
                ox, oy, oz = tpl[t, v]
                if ox % 2:  # a centre: (2c + 1) half units
                    out[..., t, v] = centre(i + ox // 2, j + oy // 2, k + oz // 2)
                else:
                    out[..., t, v] = corner(i + ox // 2, j + oy // 2, k + oz // 2)
        return out.reshape(out.shape[0], out.shape[1] * 4, 4)

    def grid(ilo: int, ihi: int, jlo: int, jhi: int, k: Int) -> tuple[Int, Int, Int]:
        j, i = np.meshgrid(
            np.arange(jlo, jhi, dtype=np.int64), np.arange(ilo, ihi, dtype=np.int64), indexing="ij"
        )
        return i.reshape(1, -1), j.reshape(1, -1), k[:, None]

    cells = [
        np.concatenate(
            [
                pair_tets(*grid(0, nx, 0, ny, ks - 1), 2),  # z-pairs through plane k
                pair_tets(*grid(-1, nx, 0, ny, ks), 0),  # x-pairs
                pair_tets(*grid(0, nx, -1, ny, ks), 1),  # y-pairs
            ],
            axis=1,
        ).reshape(-1, 4)
    ]
    if top:
        cells.append(pair_tets(*grid(0, nx, 0, ny, np.array([nz - 1])), 2).reshape(-1, 4))
    return x, np.concatenate(cells)


def bcc_tetrahedralisation(box: npt.ArrayLike, h: float) -> tuple[Float, Int]:
    """Vertices and positively oriented cells of the BCC tetrahedralisation covering a box.

    Cubes of side ``h`` from the box's lower corner cover the box; their corners and centres
    are the vertices, with one more centre beyond each boundary face of the cube grid, so
    that the tetrahedra of every face of the grid are complete: the covered region is the
    cube grid with a square pyramid of height ``h/2`` on each boundary face.

    Parameters
    ----------
    box
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``, the box to cover.
    h
        Cube side (the mesh size: the longest edge).

    Returns
    -------
    x
        Vertex coordinates, shape ``(num_vertices, 3)``.
    cells
        Vertex indices of each tetrahedron (positive signed volume), shape ``(num_cells, 4)``.
    """
    return _bcc_part(_bcc_layout(box, h), 0, 1)


def bcc_mesh(comm: MPI.Comm, box: Sequence[Sequence[float]], h: float) -> dmesh.Mesh:
    """Distributed BCC tetrahedral mesh of cube side ``h`` covering ``box``.

    The mesh of :func:`bcc_tetrahedralisation`, built in parallel: rank ``r`` of ``P``
    generates the cube layers ``r nz // P .. (r + 1) nz // P`` along ``z``, the vertices of
    their layers (a contiguous block of the global numbering) and their tetrahedra, and owns
    them (:func:`~dolfinx_universal.backgrounds.lattice_tri.layout_partitioner`, shared-facet
    ghosts). The
    global mesh is bitwise the same on any number of ranks.

    Parameters
    ----------
    comm
        Communicator.
    box
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``.
    h
        Cube side.

    Returns
    -------
    A DOLFINx tetrahedral mesh with degree-1 geometry and shared-facet ghosts.
    """
    return _layered_mesh(comm, *_bcc_part(_bcc_layout(box, h), comm.rank, comm.size))


# ---------------------------------------------------------------------------------------------
# A15


class _A15Layout(NamedTuple):
    lo: Float  # (3,) corner of cell (0, 0, 0)
    q: float  # a quarter of the cell side
    n: tuple[int, int, int]  # cells per direction


def _a15_layout(box: npt.ArrayLike, h: float) -> _A15Layout:
    b = _check_box(box, h, "A15")
    a = float(np.cbrt(4.0)) * float(h)
    reach = _A15_REACH / 4.0  # in cell sides
    n = np.maximum(np.ceil((b[1] - b[0]) / a + 2.0 * reach).astype(np.int64), 1)
    lo = 0.5 * (b[0] + b[1]) - 0.5 * a * n  # the block of cells centred on the box
    return _A15Layout(lo, 0.25 * a, (int(n[0]), int(n[1]), int(n[2])))


def _a15_vertex_layers(
    n: tuple[int, int, int],
) -> tuple[npt.NDArray[np.bool_], Int, Int, Int]:
    """Which vertices of the vertex layers ``-1 .. nz`` the cells of the block use.

    Vertex ``(site s, cell (i, j, k))`` is used iff some tetrahedron of a cell of the block
    has it: ``(s, o)`` in :data:`A15_TETS` with ``(i, j, k) - o`` in the block. Returns
    ``masks`` ``(npat, ny + 2, nx + 2, 8)`` (``[p, j + 1, i + 1, s]``), the pattern of each
    layer ``pid`` ``(nz + 2,)`` (layer ``k`` at ``k + 1``), ``lut`` (like ``masks``: the
    index of a used vertex within its layer) and ``start`` ``(nz + 3,)``, the global index of
    the first vertex of each layer.
    """
    nx, ny, nz = n
    ks = np.arange(-1, nz + 1)
    oz = np.array([-1, 0, 1])
    valid = (ks[:, None] - oz >= 0) & (ks[:, None] - oz < nz)  # (nz + 2, 3)
    pattern = valid @ np.array([1, 2, 4])
    upat, pid = np.unique(pattern, return_inverse=True)
    recs = np.unique(A15_TETS.reshape(-1, 4), axis=0)
    masks = np.zeros((len(upat), ny + 2, nx + 2, 8), dtype=bool)
    for p, bits in enumerate(upat):
        for s, ox, oy, oz_ in recs:  # at most 8 x 27 distinct template vertices
            if bits & (1 << (oz_ + 1)):
                masks[p, oy + 1 : oy + 1 + ny, ox + 1 : ox + 1 + nx, s] = True
    flat = masks.reshape(len(upat), -1)
    lut = (np.cumsum(flat, axis=1) - 1).reshape(masks.shape)
    counts = flat.sum(axis=1)[pid]
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return masks, pid.astype(np.int64), lut.astype(np.int64), start


def _a15_part(lay: _A15Layout, rank: int, size: int) -> tuple[Float, Int]:
    """Vertices and cells of part ``rank`` of ``size`` of the A15 tetrahedralisation.

    Vertices are numbered layer by layer (cell layers ``-1 .. nz`` along ``z``; within a
    layer by ``j``, ``i``, then site), cells by cell layer, ``j``, ``i`` and template
    tetrahedron. Part ``r`` holds the vertex layers of its cell layers (and layer ``-1`` /
    ``nz`` if first / last) and the tetrahedra of its cell layers. The parts in order give the
    serial arrays.
    """
    nx, ny, nz = lay.n
    first, last, bottom, top = _layers(nz, rank, size)
    masks, pid, lut, start = _a15_vertex_layers(lay.n)

    # Vertex positions of each layer pattern, in quarter cell sides, layer k = 0.
    pos = []
    for m in masks:
        j, i, s = np.nonzero(m)
        pos.append(np.column_stack([4 * (i - 1), 4 * (j - 1), np.zeros_like(i)]) + A15_SITES[s])
    vk = np.arange(-1 if bottom else first, nz + 1 if top else last, dtype=np.int64)
    quarter = np.concatenate(
        [np.empty((0, 3), dtype=np.int64)] + [pos[pid[k + 1]] + np.array([0, 0, 4 * k]) for k in vk]
    ).astype(np.float64)
    x = lay.lo + lay.q * quarter

    s, ox, oy, oz = (A15_TETS[..., c] for c in range(4))  # (46, 4) each
    k = np.arange(first, last, dtype=np.int64)[:, None, None, None, None] + oz
    j = np.arange(ny, dtype=np.int64)[None, :, None, None, None] + oy
    i = np.arange(nx, dtype=np.int64)[None, None, :, None, None] + ox
    cells = start[k + 1] + lut[pid[k + 1], j + 1, i + 1, s]
    return x, cells.reshape(-1, 4)


def a15_tetrahedralisation(box: npt.ArrayLike, h: float) -> tuple[Float, Int]:
    """Vertices and positively oriented cells of the A15 tetrahedralisation covering a box.

    Cubic cells of side ``a = 4^(1/3) h`` (the vertex density of BCC of spacing ``h``), a
    block of them centred on the box, each with the 46 tetrahedra of :data:`A15_TETS`
    (those whose centroid lies in the cell). The block reaches ``3a/8`` beyond the box on
    every side, so the tetrahedra cover the box; the mesh is a conforming subset of the
    periodic tiling, its boundary a closed surface near that of the block.

    Parameters
    ----------
    box
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``, the box to cover.
    h
        Mesh size: the edges have lengths ``0.79 h``, ``0.89 h`` and ``0.97 h``.

    Returns
    -------
    x
        Vertex coordinates, shape ``(num_vertices, 3)``.
    cells
        Vertex indices of each tetrahedron (positive signed volume), shape ``(num_cells, 4)``.
    """
    return _a15_part(_a15_layout(box, h), 0, 1)


def a15_num_cells(box: npt.ArrayLike, h: float) -> int:
    """Number of tetrahedra of :func:`a15_mesh` ``(comm, box, h)``, without building it."""
    return len(A15_TETS) * int(np.prod(_a15_layout(box, h).n))


def a15_mesh(comm: MPI.Comm, box: Sequence[Sequence[float]], h: float) -> dmesh.Mesh:
    """Distributed A15 tetrahedral mesh of size ``h`` covering ``box``.

    The mesh of :func:`a15_tetrahedralisation`, built in parallel: rank ``r`` of ``P``
    generates the cell layers ``r nz // P .. (r + 1) nz // P`` along ``z``, the vertices of
    their layers (a contiguous block of the global numbering) and their tetrahedra, and owns
    them (:func:`~dolfinx_universal.backgrounds.lattice_tri.layout_partitioner`, shared-facet
    ghosts). The
    global mesh is bitwise the same on any number of ranks. Every dihedral angle lies in
    ``[53.13, 78.46]`` degrees.

    Parameters
    ----------
    comm
        Communicator.
    box
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``.
    h
        Mesh size (cell side ``4^(1/3) h``).

    Returns
    -------
    A DOLFINx tetrahedral mesh with degree-1 geometry and shared-facet ghosts.
    """
    return _layered_mesh(comm, *_a15_part(_a15_layout(box, h), comm.rank, comm.size))
