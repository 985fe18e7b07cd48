"""Background meshes: equilateral triangulations, distribution with ghosts, per-vertex sizes."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from mpi4py import MPI

import basix.ufl
import numpy as np
import numpy.typing as npt
from dolfinx import graph
from dolfinx import mesh as dmesh

from ._geometry import cell_diameters
from .validation import vertex_reduce

if TYPE_CHECKING:
    from dolfinx.common import IndexMap

__all__ = [
    "GRADATION",
    "create_background_mesh",
    "equilateral_mesh",
    "equilateral_triangulation",
    "ghosted_partitioner",
    "refine_uniform",
    "vertex_sizes",
]

GRADATION = 0.2
"""Lipschitz bound of the local size field used on graded backgrounds (``local_size``)."""


def ghosted_partitioner():
    """Cell partitioner that distributes a mesh with shared-facet ghost cells.

    Returns
    -------
    A partitioner for :func:`dolfinx.mesh.create_mesh` (``None`` on one rank).
    """
    return dmesh.create_cell_partitioner(graph.partitioner(), dmesh.GhostMode.shared_facet, 2)


def equilateral_triangulation(
    box: npt.ArrayLike, h: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Vertices and counter-clockwise cells of an equilateral triangulation covering a box.

    Rows of vertices lie ``h sqrt(3)/2`` apart; odd rows are shifted by ``h/2``, so the
    covered polygon has zig-zag vertical sides lying outside the box.

    Parameters
    ----------
    box
        ``[[xmin, ymin], [xmax, ymax]]``, the rectangle to cover.
    h
        Edge length of the triangles (the mesh size).

    Returns
    -------
    x
        Vertex coordinates, shape ``(num_vertices, 2)``.
    cells
        Vertex indices of each triangle (counter-clockwise), shape ``(num_cells, 3)``.
    """
    box = np.asarray(box, dtype=np.float64).reshape(2, 2)
    if not np.all(np.isfinite(box)) or h <= 0 or not np.isfinite(h):
        raise ValueError(f"equilateral mesh needs a finite box and h > 0, got box={box}, h={h}")
    (x0, y0), (x1, y1) = box
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"empty box {box.tolist()}: need xmin < xmax and ymin < ymax")
    dy = h * np.sqrt(3.0) / 2.0
    n = max(int(np.ceil((x1 - x0) / h - 1e-12)), 1)
    nrows = max(int(np.ceil((y1 - y0) / dy - 1e-12)), 1) + 1
    # Even rows hold n + 1 vertices starting at x0, odd rows n + 2 starting at x0 - h/2.
    counts = np.where(np.arange(nrows) % 2 == 0, n + 1, n + 2)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rows = np.repeat(np.arange(nrows), counts)
    i = np.arange(counts.sum()) - start[rows]
    x = np.column_stack([x0 + i * h - (rows % 2) * 0.5 * h, y0 + rows * dy])

    cells = []
    ie, io = np.arange(n + 1), np.arange(n + 2)
    for j in range(nrows - 1):  # one vectorised strip per row pair
        if j % 2 == 0:  # even row below, odd row above
            e, o = start[j] + ie, start[j + 1] + io
            cells.append(np.column_stack([e[:-1], e[1:], o[1:-1]]))
            cells.append(np.column_stack([e, o[1:], o[:-1]]))
        else:  # odd row below, even row above
            o, e = start[j] + io, start[j + 1] + ie
            cells.append(np.column_stack([o[:-1], o[1:], e]))
            cells.append(np.column_stack([o[1:-1], e[1:], e[:-1]]))
    return x, np.concatenate(cells).astype(np.int64)


def create_background_mesh(
    comm: MPI.Comm, x: npt.ArrayLike | None, cells: npt.ArrayLike | None, root: int = 0
) -> dmesh.Mesh:
    """Distribute a triangulation given on one rank as a DOLFINx mesh with shared-facet ghosts.

    Parameters
    ----------
    comm
        Communicator of the mesh.
    x
        Vertex coordinates ``(num_vertices, 2)``, read on ``root`` only (may be None elsewhere).
    cells
        Triangles ``(num_cells, 3)`` (global vertex indices), read on ``root`` only (may be
        None elsewhere).
    root
        Rank holding the data.
    """
    element = basix.ufl.element("Lagrange", "triangle", 1, shape=(2,))
    if comm.rank == root:
        assert x is not None and cells is not None, "x and cells are required on root"
        x = np.ascontiguousarray(np.asarray(x, dtype=np.float64)[:, :2])
        cells = np.ascontiguousarray(np.asarray(cells, dtype=np.int64))
    else:
        x = np.empty((0, 2), dtype=np.float64)
        cells = np.empty((0, 3), dtype=np.int64)
    partitioner = ghosted_partitioner() if comm.size > 1 else None
    return dmesh.create_mesh(comm, cells, element, x, partitioner=partitioner)


def equilateral_mesh(comm: MPI.Comm, box: Sequence[Sequence[float]], h: float) -> dmesh.Mesh:
    """Distributed mesh of equilateral triangles of edge ``h`` covering ``box``.

    Equilateral triangles satisfy the angle conditions of the universal-mesh method
    everywhere (all angles 60 degrees).

    Parameters
    ----------
    comm
        Communicator.
    box
        ``[[xmin, ymin], [xmax, ymax]]``.
    h
        Edge length.

    Returns
    -------
    A DOLFINx mesh with degree-1 geometry and shared-facet ghosts.
    """
    x, cells = equilateral_triangulation(box, h) if comm.rank == 0 else (None, None)
    return create_background_mesh(comm, x, cells)


def refine_uniform(msh: dmesh.Mesh, times: int = 1) -> dmesh.Mesh:
    """Split every triangle into four similar ones (edge midpoints), ``times`` times.

    Equilateral meshes stay equilateral. The refined mesh is redistributed with shared-facet
    ghosts when run on several ranks.
    """
    for _ in range(times):
        msh.topology.create_entities(1)
        partitioner = ghosted_partitioner() if msh.comm.size > 1 else None
        msh, _, _ = dmesh.refine(msh, partitioner=partitioner)
    return msh


def vertex_sizes(
    imv: IndexMap,
    x: npt.NDArray[np.float64],
    c2v: npt.NDArray[np.int32],
    num_owned: int,
    local: bool,
    comm: MPI.Comm,
) -> npt.NDArray[np.float64]:
    """Mesh size at each vertex: the global max diameter, or a smoothed local size (collective).

    The local size starts as the largest diameter of the vertex's cells and is then raised
    to the smallest field ``h_s >= h`` with ``|h_s(a) - h_s(b)| <= GRADATION |a - b|`` along
    edges (a max-plus relaxation over the mesh graph). The relaxation ``alpha h (1 + phi/R_r)``
    then has a small tangential gradient across the level changes of a graded background,
    where the raw cell size jumps by a factor 2 (which folds triangles there).

    Parameters
    ----------
    imv
        Vertex index map of the mesh.
    x
        Process-local vertex coordinates (owned and ghost) ``(num_vertices, 2)``.
    c2v
        Cell -> vertex connectivity (owned cells first, then ghosts) ``(num_cells, 3)``.
    num_owned
        Number of owned cells.
    local
        Smoothed local sizes (graded backgrounds) instead of the global largest diameter.
    comm
        Communicator of the mesh.

    Returns
    -------
    Sizes ``(num_vertices,)``, the same on every rank sharing a vertex.
    """
    diam = cell_diameters(x, c2v[:num_owned])
    if not local:
        hmax = comm.allreduce(float(diam.max()) if len(diam) else 0.0, op=MPI.MAX)
        return np.full(len(x), hmax)
    hv = np.zeros(len(x))
    np.maximum.at(hv, c2v[:num_owned].ravel(), np.repeat(diam, 3))
    hv = vertex_reduce(imv, hv, "max")
    edges = np.unique(
        np.sort(np.concatenate([c2v[:, [0, 1]], c2v[:, [1, 2]], c2v[:, [2, 0]]]), axis=1), axis=0
    )
    a, b = edges[:, 0], edges[:, 1]
    drop = GRADATION * np.linalg.norm(x[a] - x[b], axis=1)
    while True:
        new = hv.copy()
        np.maximum.at(new, a, hv[b] - drop)
        np.maximum.at(new, b, hv[a] - drop)
        new = vertex_reduce(imv, new, "max")
        change = float(np.max(new - hv)) if len(hv) else 0.0
        hv = new
        if comm.allreduce(change, op=MPI.MAX) <= 1e-12 * (float(hv.max()) if len(hv) else 1.0):
            return hv
