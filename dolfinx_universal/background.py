"""Background meshes: equilateral triangulations of a box, distributed with shared-facet ghosts."""

from __future__ import annotations

from collections.abc import Sequence

from mpi4py import MPI

import basix.ufl
import numpy as np
import numpy.typing as npt
from dolfinx import graph
from dolfinx import mesh as dmesh

__all__ = [
    "create_background_mesh",
    "equilateral_mesh",
    "equilateral_triangulation",
    "ghosted_partitioner",
    "refine_uniform",
]


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
    comm: MPI.Comm, x: npt.ArrayLike, cells: npt.ArrayLike, root: int = 0
) -> dmesh.Mesh:
    """Distribute a triangulation given on one rank as a DOLFINx mesh with shared-facet ghosts.

    Parameters
    ----------
    comm
        Communicator of the mesh.
    x
        Vertex coordinates ``(num_vertices, 2)``, read on ``root`` only.
    cells
        Triangles ``(num_cells, 3)`` (global vertex indices), read on ``root`` only.
    root
        Rank holding the data.
    """
    element = basix.ufl.element("Lagrange", "triangle", 1, shape=(2,))
    if comm.rank == root:
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
