"""Background meshes: equilateral triangulations, distribution with ghosts, per-vertex sizes.

The distribution helpers (:func:`create_mesh`, :func:`layout_partitioner`,
:func:`ghosted_partitioner`, :func:`create_background_mesh`) and :func:`vertex_sizes` take
triangles and tetrahedra alike; the tetrahedral lattices are in
:mod:`~dolfinx_universal.backgrounds.lattice_tet`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from mpi4py import MPI

import basix.ufl
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import cpp as _cpp
from dolfinx import graph
from dolfinx import mesh as dmesh
from dolfinx.fem import coordinate_element

from dolfinx_universal.cells.tri import cell_diameters
from dolfinx_universal.core.collective import vertex_reduce

if TYPE_CHECKING:
    from dolfinx.common import IndexMap

__all__ = [
    "GRADATION",
    "cell_type_of",
    "create_background_mesh",
    "create_mesh",
    "equilateral_mesh",
    "equilateral_triangulation",
    "ghosted_partitioner",
    "largest_of_cells",
    "layout_partitioner",
    "refine_uniform",
    "vertex_sizes",
]

GRADATION = 0.2
"""Lipschitz bound of the local size field used on graded backgrounds (``local_size``)."""


def ghosted_partitioner():
    """Cell partitioner that distributes a mesh with shared-facet ghost cells.

    The cells (triangles or tetrahedra) are partitioned by the graph partitioner of DOLFINx
    (SCOTCH in the wheel).

    Returns
    -------
    A partitioner for :func:`dolfinx.mesh.create_mesh` (``None`` on one rank).
    """
    return dmesh.create_cell_partitioner(graph.partitioner(), dmesh.GhostMode.shared_facet, 2)


def _keep_layout(comm: MPI.Comm, nparts: int, dual: graph.AdjacencyList, ghosting: bool):
    """Graph "partitioner" that keeps every cell on the rank that supplies it.

    Independent of the cell type (a facet has at most two cells for triangles and
    tetrahedra alike). ``dual`` is the distributed dual graph of the cells (facet
    neighbours, global cell indices; the cells of rank ``r`` are numbered from the exclusive
    prefix sum of the cell counts, as in DOLFINx's ``build_dual_graph``). A cell's
    destinations are its own rank followed by the other ranks owning a facet neighbour: its
    shared-facet ghost copies.
    """
    n = int(dual.num_nodes)
    counts = np.asarray(comm.allgather(n), dtype=np.int64)
    if nparts != comm.size:  # pragma: no cover  (create_mesh always asks for comm.size)
        raise RuntimeError("the layout partitioner needs one part per rank")
    rank = np.full(n, comm.rank, dtype=np.int32)
    if not ghosting or n == 0:
        return _cpp.graph.AdjacencyList_int32(rank, np.arange(n + 1, dtype=np.int32))
    offsets = np.asarray(dual.offsets, dtype=np.int64)
    owner = np.searchsorted(np.cumsum(counts), np.asarray(dual.array), side="right")
    cell = np.repeat(np.arange(n, dtype=np.int64), np.diff(offsets))
    foreign = owner != comm.rank
    pairs = np.unique(cell[foreign] * comm.size + owner[foreign])  # (cell, ghost rank), sorted
    gcell, grank = pairs // comm.size, (pairs % comm.size).astype(np.int32)
    num = 1 + np.bincount(gcell, minlength=n)
    out_off = np.concatenate([[0], np.cumsum(num)]).astype(np.int32)
    data = np.empty(out_off[-1], dtype=np.int32)
    data[out_off[:-1]] = comm.rank
    # Ghost ranks of each cell follow its owner, in increasing order.
    pos = out_off[gcell] + 1 + (np.arange(len(gcell)) - np.searchsorted(gcell, gcell))
    data[pos] = grank
    return _cpp.graph.AdjacencyList_int32(data, out_off)


def layout_partitioner():
    """Cell partitioner that keeps each cell on its rank and adds shared-facet ghost cells.

    For meshes generated in parallel (:func:`equilateral_mesh`,
    :func:`~dolfinx_universal.backgrounds.graded_tri.graded_mesh`,
    :func:`~dolfinx_universal.backgrounds.lattice_tet.bcc_mesh`,
    :func:`~dolfinx_universal.backgrounds.lattice_tet.a15_mesh`): every rank passes the cells
    (triangles or tetrahedra) it generated to :func:`dolfinx.mesh.create_mesh` and owns them;
    no graph partitioning is done.
    """
    return dmesh.create_cell_partitioner(_keep_layout, dmesh.GhostMode.shared_facet, 2)


_CELL_TYPES = {3: "triangle", 4: "tetrahedron"}
"""Simplex cell type by number of vertices per cell (its topological dimension is one less)."""


def cell_type_of(cells: npt.ArrayLike) -> str:
    """``"triangle"`` for cells of shape ``(n, 3)``, ``"tetrahedron"`` for ``(n, 4)``."""
    shape = np.shape(cells)
    if len(shape) != 2 or shape[1] not in _CELL_TYPES:
        raise ValueError(
            f"cells must have shape (n, 3) (triangles) or (n, 4) (tetrahedra), got {shape}"
        )
    return _CELL_TYPES[shape[1]]


def create_mesh(
    comm: MPI.Comm,
    cells: npt.ArrayLike,
    x: npt.ArrayLike,
    partitioner: Callable | None = None,
    cell_type: str | None = None,
) -> dmesh.Mesh:
    """A degree-1 triangle or tetrahedron mesh from distributed cells and nodes (collective).

    Like :func:`dolfinx.mesh.create_mesh` with a degree-1 vector Lagrange element, but
    passes the cells as one flat array (DOLFINx's mixed-topology entry point with one cell
    type): the same mesh, without the per-row conversion that makes the ``(n, 3)`` entry
    point about three times slower for 1e6 cells. The geometric dimension is the
    topological one (2 for triangles, 3 for tetrahedra).

    Parameters
    ----------
    comm
        Communicator.
    cells
        This rank's cells, global node indices: triangles ``(n, 3)`` or tetrahedra
        ``(n, 4)``.
    x
        Coordinates ``(m, gdim)`` (or more columns, of which the first ``gdim`` are used) of
        this rank's block of nodes: rank ``r`` holds the nodes numbered from the sum of the
        block sizes of the ranks before it.
    partitioner
        Cell partitioner (``None``: DOLFINx's default, no ghosts, on several ranks).
    cell_type
        ``"triangle"`` or ``"tetrahedron"``; by default from the width of ``cells`` (give
        it when ``cells`` is flat). Every rank must build the same cell type.
    """
    if cell_type is None:
        cell_type = cell_type_of(cells)
    if cell_type not in _CELL_TYPES.values():
        raise ValueError(f"cell_type must be 'triangle' or 'tetrahedron', got {cell_type!r}")
    tdim = 2 if cell_type == "triangle" else 3
    element = basix.ufl.element("Lagrange", cell_type, 1, shape=(tdim,))
    cmap = coordinate_element(element.basix_element)
    x = np.ascontiguousarray(np.asarray(x, dtype=np.float64)[:, :tdim])
    flat = np.ascontiguousarray(np.asarray(cells, dtype=np.int64).reshape(-1))
    if partitioner is None and comm.size > 1:
        partitioner = dmesh.create_cell_partitioner(dmesh.GhostMode.none, 2)
    msh = _cpp.mesh.create_mesh(comm, [flat], [cmap._cpp_object], x, partitioner, 2)
    return dmesh.Mesh(msh, ufl.Mesh(element))


def _equilateral_layout(box: npt.ArrayLike, h: float) -> tuple[float, float, float, int, int]:
    """``x0, y0, dy, n, nrows`` of the equilateral triangulation of a box (checked input)."""
    box = np.asarray(box, dtype=np.float64).reshape(2, 2)
    if not np.all(np.isfinite(box)) or h <= 0 or not np.isfinite(h):
        raise ValueError(f"equilateral mesh needs a finite box and h > 0, got box={box}, h={h}")
    (x0, y0), (x1, y1) = box
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"empty box {box.tolist()}: need xmin < xmax and ymin < ymax")
    dy = h * np.sqrt(3.0) / 2.0
    n = max(int(np.ceil((x1 - x0) / h - 1e-12)), 1)
    nrows = max(int(np.ceil((y1 - y0) / dy - 1e-12)), 1) + 1
    return float(x0), float(y0), float(dy), n, nrows


def _equilateral_part(
    x0: float, y0: float, h: float, dy: float, n: int, nrows: int, first: int, last: int
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Vertex rows ``first .. last - 1`` (and the top row if ``last`` is the last strip) and
    the cells of the strips between rows ``first .. last``, numbered globally.

    The strips ``0 .. nrows - 2`` of all parts, in order, are the cells of
    :func:`equilateral_triangulation` in its order; so are the vertex rows.
    """
    # Even rows hold n + 1 vertices starting at x0, odd rows n + 2 starting at x0 - h/2;
    # row j starts at vertex (j // 2) (2n + 3) + (j % 2) (n + 1).
    vlast = nrows if last == nrows - 1 else last
    jr = np.arange(first, vlast, dtype=np.int64)
    counts = np.where(jr % 2 == 0, n + 1, n + 2)
    rows = np.repeat(jr, counts)
    i = np.arange(counts.sum(), dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    x = np.column_stack([x0 + i * h - (rows % 2) * 0.5 * h, y0 + rows * dy])

    strips = np.arange(first, last, dtype=np.int64)
    cells = np.empty((len(strips), 2 * n + 1, 3), dtype=np.int64)
    ie, io = np.arange(n + 1), np.arange(n + 2)
    lo = (strips // 2) * (2 * n + 3) + (strips % 2) * (n + 1)  # first vertex of the lower row
    even = strips % 2 == 0
    # Even strip: even row below (n + 1 vertices), odd row above (n + 2).
    e, o = lo[even, None] + ie, lo[even, None] + (n + 1) + io
    cells[even, :n] = np.stack([e[:, :-1], e[:, 1:], o[:, 1:-1]], axis=2)
    cells[even, n:] = np.stack([e, o[:, 1:], o[:, :-1]], axis=2)
    # Odd strip: odd row below (n + 2 vertices), even row above (n + 1).
    o, e = lo[~even, None] + io, lo[~even, None] + (n + 2) + ie
    cells[~even, : n + 1] = np.stack([o[:, :-1], o[:, 1:], e], axis=2)
    cells[~even, n + 1 :] = np.stack([o[:, 1:-1], e[:, 1:], e[:, :-1]], axis=2)
    return x, cells.reshape(-1, 3)


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
    x0, y0, dy, n, nrows = _equilateral_layout(box, h)
    return _equilateral_part(x0, y0, float(h), dy, n, nrows, 0, nrows - 1)


def create_background_mesh(
    comm: MPI.Comm,
    x: npt.ArrayLike | None,
    cells: npt.ArrayLike | None,
    root: int = 0,
    cell_type: str | None = None,
) -> dmesh.Mesh:
    """Distribute a mesh given on one rank as a DOLFINx mesh with shared-facet ghosts.

    Parameters
    ----------
    comm
        Communicator of the mesh.
    x
        Vertex coordinates ``(num_vertices, gdim)`` (gdim 2 for triangles, 3 for
        tetrahedra), read on ``root`` only (may be None elsewhere).
    cells
        Triangles ``(num_cells, 3)`` or tetrahedra ``(num_cells, 4)`` (global vertex
        indices), read on ``root`` only (may be None elsewhere).
    root
        Rank holding the data.
    cell_type
        ``"triangle"`` or ``"tetrahedron"``; by default the width of ``cells`` on ``root``
        decides (broadcast to the other ranks). Give it on every rank or on none.
    """
    if comm.rank == root:
        assert x is not None and cells is not None, "x and cells are required on root"
    if cell_type is None:  # the same on every rank: all or none take part in the broadcast
        found: str | ValueError | None = None
        if comm.rank == root:
            assert cells is not None
            try:
                found = cell_type_of(cells)
            except ValueError as err:  # raised on every rank, not only on root
                found = err
        if comm.size > 1:
            found = comm.bcast(found, root=root)
        if isinstance(found, ValueError):
            raise ValueError(str(found))
        cell_type = found
    if comm.rank != root:
        width = 3 if cell_type == "triangle" else 4
        x = np.empty((0, width - 1), dtype=np.float64)
        cells = np.empty((0, width), dtype=np.int64)
    assert x is not None and cells is not None
    partitioner = ghosted_partitioner() if comm.size > 1 else None
    return create_mesh(comm, cells, x, partitioner, cell_type)


def equilateral_mesh(comm: MPI.Comm, box: Sequence[Sequence[float]], h: float) -> dmesh.Mesh:
    """Distributed mesh of equilateral triangles of edge ``h`` covering ``box``.

    Equilateral triangles satisfy the angle conditions of the universal-mesh method
    everywhere (all angles 60 degrees).

    Built in parallel: rank ``r`` of ``P`` generates the strips of rows
    ``r (nrows - 1) // P .. (r + 1) (nrows - 1) // P`` and the vertices of their lower rows
    (numbered row by row, as in :func:`equilateral_triangulation`, so each rank supplies a
    contiguous block) and owns those cells (:func:`layout_partitioner`, no graph
    partitioning); no rank holds the whole triangulation. The global mesh is that of
    :func:`equilateral_triangulation` on any number of ranks, with bitwise the same vertex
    coordinates.

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
    x0, y0, dy, n, nrows = _equilateral_layout(box, h)
    first, last = (comm.rank * (nrows - 1) // comm.size, (comm.rank + 1) * (nrows - 1) // comm.size)
    x, cells = _equilateral_part(x0, y0, float(h), dy, n, nrows, first, last)
    return create_mesh(comm, cells, x, layout_partitioner() if comm.size > 1 else None)


def refine_uniform(msh: dmesh.Mesh, times: int = 1) -> dmesh.Mesh:
    """Split every triangle into four similar ones (edge midpoints), ``times`` times.

    Equilateral meshes stay equilateral. On several ranks the children of a cell stay on its
    rank (no repartitioning) and the shared-facet ghost cells are rebuilt.
    """
    for _ in range(times):
        msh.topology.create_entities(1)
        if msh.comm.size > 1:
            msh, _, _ = dmesh.refine(msh)  # DOLFINx's default: keep the partition, new ghosts
        else:
            msh, _, _ = dmesh.refine(msh, partitioner=None)
    return msh


_EDGES: dict[int, tuple[tuple[int, int], ...]] = {
    3: ((0, 1), (1, 2), (2, 0)),
    4: ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)),
}
"""Local vertex pairs of the edges of a triangle and of a tetrahedron."""


def _longest_edges(
    x: npt.NDArray[np.float64], cells: npt.NDArray[np.int32], pairs: Sequence[tuple[int, int]]
) -> npt.NDArray[np.float64]:
    """Longest edge of each cell ``(m,)`` among the local vertex ``pairs``.

    Coordinate by coordinate on contiguous columns and squared lengths, one square root at
    the end: 20 times faster than norms of gathered ``(m, 3)`` differences at 1e6 cells.
    """
    cols = [np.ascontiguousarray(x[:, k]) for k in range(x.shape[1])]
    corner = [np.ascontiguousarray(cells[:, j]) for j in range(cells.shape[1])]
    longest = np.zeros(len(cells))
    for a, b in pairs:
        sq = np.zeros(len(cells))
        for xk in cols:
            d = xk[corner[a]] - xk[corner[b]]
            sq += d * d
        np.maximum(longest, sq, out=longest)
    return np.sqrt(longest)


def largest_of_cells(
    imv: IndexMap, c2v: npt.NDArray[np.int32], values: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """At each vertex, the largest of ``values`` over its cells (collective).

    ``values`` ``(m,)`` belong to the cells ``c2v`` ``(m, nv)`` of this rank (owned ones, or
    owned and ghost); the maximum is taken over the ranks sharing a vertex, so every rank
    gets the same value there. Vertices of no cell get 0. Returns ``(num_vertices,)``
    (owned and ghost vertices of ``imv``).
    """
    out = np.zeros(imv.size_local + imv.num_ghosts)
    np.maximum.at(out, c2v.ravel(), np.repeat(values, c2v.shape[1]))
    return vertex_reduce(imv, out, "max")


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

    The diameter of a cell is its longest edge (3 edges of a triangle, 6 of a tetrahedron).

    Parameters
    ----------
    imv
        Vertex index map of the mesh.
    x
        Process-local vertex coordinates (owned and ghost) ``(num_vertices, gdim)``.
    c2v
        Cell -> vertex connectivity (owned cells first, then ghosts): triangles
        ``(num_cells, 3)`` or tetrahedra ``(num_cells, 4)``.
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
    nv = c2v.shape[1]
    pairs = _EDGES[nv]
    if nv == 3:
        diam = cell_diameters(x, c2v[:num_owned])
    else:
        diam = _longest_edges(x, c2v[:num_owned], pairs)
    if not local:
        hmax = comm.allreduce(float(diam.max()) if len(diam) else 0.0, op=MPI.MAX)
        return np.full(len(x), hmax)
    hv = largest_of_cells(imv, c2v[:num_owned], diam)
    pair = np.sort(np.concatenate([c2v[:, list(p)] for p in pairs]), axis=1).astype(np.int64)
    # The distinct edges, one int each, by a sort (np.unique hashes: 100 times slower).
    key = np.sort(pair[:, 0] * len(x) + pair[:, 1])
    key = key[np.diff(key, prepend=-1) != 0]
    a, b = key // len(x), key % len(x)
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
