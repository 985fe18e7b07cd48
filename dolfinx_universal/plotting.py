"""Matplotlib figures of background, conforming and curved meshes and of fields on them.

Every figure function is collective (call it on every rank): the cells are gathered to rank
0, which alone draws. Curved (degree > 1) cells are drawn curved: their edges are polylines of
the mapped reference edges and fields are drawn on a lattice of each cell mapped by the
cell's coordinate map, so that the colours reach the curved boundary. Tetrahedron meshes
are drawn in 3D by :func:`plot_tetrahedra` (a clipped view or the surface, coloured by the
cells' smallest dihedral angles). Everything is built from arrays (one collection per layer,
no Python loop over cells). Matplotlib is optional (``pip install dolfinx_universal[plot]``).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, overload

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.cells import tet as _tetrahedron
from dolfinx_universal.conforming.universal import IMMERSED
from dolfinx_universal.core.arrays import Float, lagrange_element

if TYPE_CHECKING:
    from dolfinx import fem
    from dolfinx import mesh as dmesh
    from matplotlib.axes import Axes
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    from dolfinx_universal.conforming.universal import ConformingMesh
    from dolfinx_universal.curved.maps import CurvedMesh

__all__ = [
    "KIND_NAMES",
    "add_inset",
    "auto_inset",
    "boundary_polyline",
    "cell_edges",
    "cell_kinds",
    "cell_outlines",
    "clipped_faces",
    "curved_cells",
    "field_triangulation",
    "gather_cells",
    "gather_tetrahedra",
    "plot_conforming",
    "plot_function",
    "plot_mesh",
    "plot_tetrahedra",
    "reference_lattice",
    "save",
    "subdivide_cells",
    "unique_edges",
]

#: Default colours of :func:`plot_conforming`.
BACKGROUND_EDGE = "0.78"
KEPT_FACE = "#dbe7f3"
MOVED_FACE = "#a9c8e6"
CUT_FACE = "#5f93c9"
CURVED_FACE = "#f4a259"
BOUNDARY_COLOR = "tab:red"
GAMMA_H_COLOR = "#1b1b7a"

#: Names of the cell kinds of :func:`cell_kinds` (codes 0, 1, 2, 3), used in legends.
KIND_NAMES = ("unaltered", "moved", "positively cut", "curved")

#: Above this many drawn cells, interior edges are left out of the main axes (faces, outer
#: edges and Gamma_h are still drawn; an inset shows the edges).
MAX_EDGE_CELLS = 20000

_MPL_MISSING = "matplotlib is needed for plotting: pip install dolfinx_universal[plot]"


def _mpl() -> Any:
    """Import matplotlib or raise a clear :class:`ImportError`."""
    try:
        import matplotlib
        import matplotlib.collections  # noqa: F401
        import matplotlib.figure  # noqa: F401
        import matplotlib.tri  # noqa: F401
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(_MPL_MISSING) from e
    return matplotlib


def _degree_of(ndofs: int) -> int:
    """Lagrange degree ``k`` of a triangle with ``(k + 1)(k + 2)/2`` nodes."""
    k = int(round((np.sqrt(8 * ndofs + 1) - 3) / 2))
    if k < 1 or (k + 1) * (k + 2) // 2 != ndofs:
        raise ValueError(f"{ndofs} nodes per cell is not a Lagrange triangle")
    return k


def _check_nodes(nodes: npt.ArrayLike, degree: int | None) -> tuple[npt.NDArray, int]:
    nodes = np.asarray(nodes, dtype=np.float64)
    if nodes.ndim != 3 or nodes.shape[2] < 2:
        raise ValueError(f"nodes must have shape (num_cells, num_nodes, 2), got {nodes.shape}")
    nodes = nodes[:, :, :2]
    k = _degree_of(nodes.shape[1]) if degree is None else int(degree)
    needed = (k + 1) * (k + 2) // 2
    if nodes.shape[1] != needed:
        raise ValueError(f"degree {k} needs {needed} nodes per cell, got {nodes.shape[1]}")
    return nodes, k


def _coordinate_element(k: int, variant: Any = None) -> Any:
    """The basix Lagrange triangle of degree ``k`` (GLL-warped unless told otherwise)."""
    import basix

    if variant is None:
        variant = basix.LagrangeVariant.gll_warped
    elif not isinstance(variant, basix.LagrangeVariant):
        variant = basix.LagrangeVariant(int(variant))
    if variant == basix.LagrangeVariant.unset:
        variant = basix.LagrangeVariant.gll_warped
    return lagrange_element("triangle", k, variant)


def _map(nodes: npt.NDArray, k: int, variant: Any, ref: npt.NDArray) -> npt.NDArray:
    """Images ``(num_cells, num_points, 2)`` of reference points under the cells' maps."""
    if k == 1:  # affine: barycentric combination of the vertices
        lam = np.column_stack([1.0 - ref[:, 0] - ref[:, 1], ref[:, 0], ref[:, 1]])
        return np.einsum("pn,cnd->cpd", lam, nodes[:, :3])
    phi = _coordinate_element(k, variant).tabulate(0, ref)[0, :, :, 0]
    return np.einsum("pn,cnd->cpd", phi, nodes)


@overload
def gather_cells(
    msh: dmesh.Mesh, values: None = None, root: int = 0, *, cells: npt.ArrayLike | None = None
) -> npt.NDArray[np.float64] | None: ...


@overload
def gather_cells(
    msh: dmesh.Mesh, values: npt.ArrayLike, root: int = 0, *, cells: npt.ArrayLike | None = None
) -> tuple[npt.NDArray[np.float64] | None, npt.NDArray | None]: ...


def gather_cells(msh, values=None, root=0, *, cells=None):
    """Coordinates of the geometry nodes of every owned cell, gathered to one rank (collective).

    Works for any geometry degree: the nodes of a cell are listed in the order of the
    geometry dofmap (the reference order of the coordinate element: vertices, then edge
    nodes, then interior nodes).

    Parameters
    ----------
    msh
        A triangle mesh (any geometry degree), possibly distributed.
    values
        Optional per-cell data, indexed by local cell (owned cells first; ghost entries, if
        any, are ignored), gathered in the same order as the cells.
    root
        Rank that receives the data.
    cells
        Optional local cells to gather (e.g. the active cells of a
        :class:`~dolfinx_universal.moving.domain.MovingDomain`); ghosts among them are ignored.
        Default: every owned cell.

    Returns
    -------
    nodes
        ``(num_cells_global, num_nodes_per_cell, 2)`` on ``root``, ``None`` elsewhere.
    values
        Only when ``values`` is given (the result is then a tuple ``(nodes, values)``):
        the gathered values ``(num_cells_global, ...)`` on ``root``, ``None`` elsewhere.
    """
    comm = msh.comm
    nco = msh.topology.index_map(msh.topology.dim).size_local
    sel = _owned(cells, nco)
    dofmap = msh.geometry.dofmaps[0][sel]
    local = msh.geometry.x[dofmap][:, :, :2]
    parts = comm.gather(np.ascontiguousarray(local), root=root)
    nodes = np.concatenate(parts, axis=0) if comm.rank == root else None
    if values is None:
        return nodes
    vals = np.asarray(values)[sel]
    vparts = comm.gather(np.ascontiguousarray(vals), root=root)
    gathered = np.concatenate(vparts, axis=0) if comm.rank == root else None
    return nodes, gathered


def _owned(cells: npt.ArrayLike | None, nco: int) -> Any:
    """Index of the owned cells among ``cells`` (all owned cells when ``None``)."""
    if cells is None:
        return slice(0, nco)
    cells = np.asarray(cells, dtype=np.int64).ravel()
    return cells[cells < nco]


def _active_cells(msh: dmesh.Mesh, active: Any, cells: Any) -> Any:
    """Local cells selected by ``cells`` or by a DG0 indicator ``active`` (> 0.5)."""
    if cells is not None:
        return np.asarray(cells, dtype=np.int64).ravel()
    if active is None:
        return None
    if hasattr(active, "function_space"):  # DG0 fem.Function
        dofs = active.function_space.dofmap.list[:, 0]
        values = active.x.array[dofs]
    else:
        values = np.asarray(active)
    return np.flatnonzero(np.asarray(values) > 0.5)


def reference_lattice(n: int) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int32]]:
    """Lattice of the reference triangle with ``n`` intervals per edge, and its triangles.

    Returns
    -------
    points
        ``((n + 1)(n + 2)/2, 2)`` points ``(i/n, j/n)``, ``i + j <= n``.
    triangles
        ``(n**2, 3)`` counter-clockwise triangles indexing ``points``.
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"need n >= 1 intervals, got {n}")
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    i, j = i[keep], j[keep]
    index = -np.ones((n + 2, n + 2), dtype=np.int64)
    index[i, j] = np.arange(len(i))
    points = np.column_stack([i, j]).astype(np.float64) / n
    a, b = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    up = a + b <= n - 1  # (a, b), (a+1, b), (a, b+1)
    down = a + b <= n - 2  # (a+1, b), (a+1, b+1), (a, b+1)
    au, bu, ad, bd = a[up], b[up], a[down], b[down]
    tris = np.concatenate(
        [
            np.column_stack([index[au, bu], index[au + 1, bu], index[au, bu + 1]]),
            np.column_stack([index[ad + 1, bd], index[ad + 1, bd + 1], index[ad, bd + 1]]),
        ]
    )
    return points, tris.astype(np.int32)


def subdivide_cells(
    nodes: npt.ArrayLike,
    degree: int | None = None,
    n: int = 8,
    variant: Any = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Straight sub-triangles of each cell: its coordinate map on a reference lattice.

    Parameters
    ----------
    nodes
        Geometry nodes ``(num_cells, num_nodes, 2)`` (see :func:`gather_cells`).
    degree, variant
        Geometry degree (inferred when ``None``) and Lagrange variant (GLL-warped default).
    n
        Lattice intervals per reference edge.

    Returns
    -------
    points
        ``(num_cells * P, 2)`` mapped lattice points, cell by cell (``P = (n+1)(n+2)/2``).
    triangles
        ``(num_cells * n**2, 3)`` triangles indexing ``points``. The boundary points of each
        cell are its edge samples ``t = i/n``, as in :func:`cell_edges` with
        ``points_per_edge = n``, so the sub-triangles fill exactly the drawn curved cells.
    """
    nodes, k = _check_nodes(nodes, degree)
    ref, tris = reference_lattice(n)
    pts = _map(nodes, k, variant, ref)  # (C, P, 2)
    offsets = (np.arange(len(nodes), dtype=np.int64) * len(ref))[:, None, None]
    triangles = (tris[None, :, :] + offsets).reshape(-1, 3)
    return pts.reshape(-1, 2), triangles


#: Reference edges of the DOLFINx triangle: edge i is opposite vertex i.
_EDGES = ((1, 2), (0, 2), (0, 1))
_REF_VERTICES = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


def cell_edges(
    nodes: npt.ArrayLike,
    degree: int | None = None,
    points_per_edge: int = 8,
    variant: Any = None,
) -> npt.NDArray[np.float64]:
    """Polylines of the three edges of each cell, the images of the reference edges.

    Edge ``i`` is the DOLFINx local facet ``i`` (opposite vertex ``i``: vertices 1-2, 0-2,
    0-1), sampled at ``t = j / points_per_edge``, ``j = 0..points_per_edge`` (both ends).

    Returns
    -------
    ``(num_cells, 3, m, 2)`` with ``m = points_per_edge + 1`` (``m = 2`` for degree 1).
    """
    nodes, k = _check_nodes(nodes, degree)
    m = 1 if k == 1 else max(1, int(points_per_edge))
    t = np.linspace(0.0, 1.0, m + 1)[:, None]
    ref = np.concatenate([(1.0 - t) * _REF_VERTICES[a] + t * _REF_VERTICES[b] for a, b in _EDGES])
    pts = _map(nodes, k, variant, ref)
    return pts.reshape(len(nodes), 3, m + 1, 2)


def unique_edges(
    edges: npt.NDArray[np.float64], decimals: int | None = None
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_], npt.NDArray[np.int64]]:
    """Edges shared by two cells listed once; which of them lie on the drawn region's boundary.

    Parameters
    ----------
    edges
        ``(num_cells, 3, m, 2)`` from :func:`cell_edges`.
    decimals
        Rounding of the end points that identifies an edge (default: 10 digits below the
        extent of the points).

    Returns
    -------
    polylines
        ``(num_edges, m, 2)``, one per distinct edge.
    boundary
        ``(num_edges,)``: the edge belongs to one cell only.
    first
        ``(num_edges,)`` flat index ``3 * cell + local_edge`` of each edge's first copy.
    """
    flat = edges.reshape(-1, edges.shape[2], 2)
    if len(flat) == 0:
        return flat, np.zeros(0, dtype=bool), np.zeros(0, dtype=np.int64)
    if decimals is None:
        extent = float(np.ptp(flat.reshape(-1, 2), axis=0).max()) or 1.0
        decimals = int(np.clip(10 - np.floor(np.log10(extent)), 0, 15))
    ends = np.round(np.stack([flat[:, 0], flat[:, -1]], axis=1), decimals)  # (E, 2, 2)
    swap = (ends[:, 0, 0] > ends[:, 1, 0]) | (
        (ends[:, 0, 0] == ends[:, 1, 0]) & (ends[:, 0, 1] > ends[:, 1, 1])
    )
    ends[swap] = ends[swap, ::-1]
    points = flat.shape[1]  # per polyline: a middle point tells curved edges apart
    mid = np.round(flat[:, points // 2], decimals) if points > 2 else None
    key = ends.reshape(-1, 4) if mid is None else np.column_stack([ends.reshape(-1, 4), mid])
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return flat[first], counts == 1, first


def cell_outlines(
    nodes: npt.ArrayLike,
    degree: int | None = None,
    points_per_edge: int = 8,
    variant: Any = None,
) -> npt.NDArray[np.float64]:
    """Closed outlines of triangles, sampling curved (degree > 1) edges.

    Each edge of a degree-``k`` cell is the image of a reference edge under the cell's
    Lagrange coordinate map; it is sampled at ``points_per_edge`` points by evaluating the
    degree-``k`` basis (vectorised over cells).

    Parameters
    ----------
    nodes
        Geometry nodes ``(num_cells, (k + 1)(k + 2)/2, 2)`` as from :func:`gather_cells`.
    degree
        Geometry degree ``k``; inferred from the number of nodes when ``None``.
    points_per_edge
        Samples per edge (the first vertex of the edge included, the last excluded).
    variant
        :class:`basix.LagrangeVariant` of the coordinate element; default ``gll_warped``
        (the DOLFINx default; irrelevant for ``k <= 2``).

    Returns
    -------
    Outline points ``(num_cells, 3, 2)`` for degree 1, else
    ``(num_cells, 3 * points_per_edge, 2)``, going round vertices 0 -> 1 -> 2.
    """
    nodes, k = _check_nodes(nodes, degree)
    if k == 1:
        return nodes[:, :3].copy()
    t = np.arange(points_per_edge) / points_per_edge
    zero = np.zeros_like(t)
    ref = np.concatenate(
        [
            np.column_stack([t, zero]),  # vertex 0 -> vertex 1
            np.column_stack([1.0 - t, t]),  # vertex 1 -> vertex 2
            np.column_stack([zero, 1.0 - t]),  # vertex 2 -> vertex 0
        ]
    )
    return _map(nodes, k, variant, ref)


def curved_cells(
    nodes: npt.ArrayLike, degree: int | None = None, variant: Any = None, rtol: float = 1e-9
) -> npt.NDArray[np.bool_]:
    """Cells whose geometry nodes are not the affine image of their vertices."""
    nodes, k = _check_nodes(nodes, degree)
    if k == 1 or len(nodes) == 0:
        return np.zeros(len(nodes), dtype=bool)
    ref = np.asarray(_coordinate_element(k, variant).points)
    affine = _map(nodes[:, :3], 1, None, ref)
    dev = np.abs(nodes - affine).max(axis=(1, 2))
    size = np.abs(nodes[:, :3] - nodes[:, :1]).max(axis=(1, 2))
    return dev > rtol * np.maximum(size, np.finfo(float).tiny)


def _is_none(color: Any) -> bool:
    return color is None or (isinstance(color, str) and color == "none")


def _figure(ax: Axes) -> Figure:
    """The figure of ``ax`` (axes of a SubFigure, which has no figure size, are unsupported)."""
    from matplotlib.figure import Figure

    fig = ax.figure
    assert isinstance(fig, Figure), "axes of a matplotlib SubFigure are not supported"
    return fig


def _auto_linewidth(ax: Axes, num_cells: int, scale: float = 1.0) -> float:
    """Edge width (points) for ``num_cells`` cells filling the axes: thinner for more cells
    and smaller axes (0.35 pt for 4000 cells in 6 inches), between 0.03 and 0.8."""
    fig = _figure(ax)
    width = ax.get_position().width * fig.get_figwidth()
    lw = 0.35 * np.sqrt(4000.0 / max(num_cells, 1)) * width / 6.0 * scale
    return float(np.clip(lw, 0.03, 0.8))


def _draw_cells(
    ax: Axes,
    nodes: npt.NDArray,
    degree: int,
    variant: Any,
    *,
    facecolors: Any = None,
    values: Any = None,
    cmap: Any = None,
    edgecolor: Any = "k",
    linewidth: float | None = None,
    points_per_edge: int = 8,
    zorder: float = 1.0,
    max_edge_cells: int | None = MAX_EDGE_CELLS,
    autoscale: bool = True,
    **kwargs: Any,
) -> tuple[Any, Any]:
    """Faces (one PolyCollection of curved outlines) and edges (one LineCollection of the
    distinct edges, interior ones left out above ``max_edge_cells`` cells)."""
    from matplotlib.collections import LineCollection, PolyCollection

    filled = values is not None or not _is_none(facecolors)
    edged = not _is_none(edgecolor)
    faces = edges = None
    if filled:
        outlines = cell_outlines(nodes, degree, points_per_edge, variant)
        faces = PolyCollection(
            outlines,  # type: ignore[arg-type]  # stubs want a Sequence; an (n, m, 2) array works
            facecolors="none" if facecolors is None else facecolors,
            edgecolors="none",
            linewidths=0.0,
            zorder=zorder,
            **kwargs,
        )
        if values is not None:
            faces.set_array(np.asarray(values, dtype=np.float64))
            if cmap is not None:
                faces.set_cmap(cmap)
        ax.add_collection(faces, autolim=autoscale)
    if edged or faces is None:
        lines, on_boundary, _ = unique_edges(cell_edges(nodes, degree, points_per_edge, variant))
        if max_edge_cells is not None and len(nodes) > max_edge_cells:
            lines = lines[on_boundary]
        lw = _auto_linewidth(ax, len(nodes)) if linewidth is None else linewidth
        edges = LineCollection(
            lines,  # type: ignore[arg-type]  # stubs want a Sequence; an (n, m, 2) array works
            colors="k" if not edged else edgecolor,
            linewidths=lw,
            zorder=zorder + 0.01,
            capstyle="round",
            joinstyle="round",
            **{k: v for k, v in kwargs.items() if k in ("alpha", "label", "rasterized")},
        )
        ax.add_collection(edges, autolim=autoscale and faces is None)
    if autoscale and len(nodes):
        ax.set_aspect("equal")
        ax.autoscale_view()
    return faces, edges


def plot_mesh(
    ax: Axes | None,
    nodes: npt.ArrayLike | None,
    degree: int | None = None,
    facecolors: Any = None,
    edgecolor: Any = "k",
    linewidth: float | None = None,
    *,
    values: npt.ArrayLike | None = None,
    cmap: Any = None,
    points_per_edge: int = 8,
    variant: Any = None,
    autoscale: bool = True,
    max_edge_cells: int | None = MAX_EDGE_CELLS,
    axis_labels: bool = True,
    **kwargs: Any,
) -> PolyCollection | None:
    """Draw triangles (straight or curved): one PolyCollection of faces, one LineCollection
    of edges.

    Call it on the rank holding ``nodes`` (rank 0 after :func:`gather_cells`); with
    ``nodes=None`` (other ranks) it does nothing.

    Parameters
    ----------
    ax
        Axes to draw into.
    nodes
        Geometry nodes ``(num_cells, num_nodes, 2)`` (see :func:`gather_cells`).
    degree
        Geometry degree; inferred from ``nodes`` when ``None``. Cells of degree > 1 are drawn
        with curved edges (polylines of the mapped reference edges, see :func:`cell_edges`).
    facecolors
        A colour, one colour per cell, or ``None`` (no fill; ``"none"`` also works).
    edgecolor, linewidth
        Edges; ``edgecolor="none"`` hides them. Each edge is drawn once. ``linewidth=None``
        (default) scales the width with the number of cells and the axes size.
    values
        Per-cell numbers coloured through ``cmap`` (overrides ``facecolors``).
    cmap
        Colormap for ``values``.
    points_per_edge
        Samples per curved edge.
    variant
        Lagrange variant of the coordinate element (degree >= 3).
    autoscale
        Update the data limits and view of ``ax``.
    max_edge_cells
        Above this many cells only the edges on the boundary of the drawn cells are drawn
        (``None``: always all edges).
    axis_labels
        Label the axes ``x`` and ``y`` (when they have no label yet).
    **kwargs
        Passed to :class:`~matplotlib.collections.PolyCollection` (``zorder``, ``alpha``...).

    Returns
    -------
    The collection of the cells' faces (it carries ``values`` for a colorbar), or of their
    edges when unfilled; ``None`` when ``nodes`` is ``None``. Faces and edges are two
    collections, faces first, so that no face hides a neighbour's edge.
    """
    if nodes is None or ax is None:
        return None
    _mpl()
    nodes, k = _check_nodes(nodes, degree)
    zorder = kwargs.pop("zorder", 1.0)
    faces, edges = _draw_cells(
        ax,
        nodes,
        k,
        variant,
        facecolors=facecolors,
        values=values,
        cmap=cmap,
        edgecolor=edgecolor,
        linewidth=linewidth,
        points_per_edge=points_per_edge,
        zorder=zorder,
        max_edge_cells=max_edge_cells,
        autoscale=autoscale,
        **kwargs,
    )
    if axis_labels:
        _label_axes(ax)
    return faces if faces is not None else edges


def _label_axes(ax: Axes) -> None:
    if not ax.get_xlabel():
        ax.set_xlabel("x")
    if not ax.get_ylabel():
        ax.set_ylabel("y")
    ax.set_aspect("equal")


def _geometry_degree(msh: dmesh.Mesh) -> tuple[int, Any]:
    """Degree and Lagrange variant of a mesh's coordinate element."""
    cmap = msh.geometry.cmaps[0]
    return int(cmap.degree), cmap.variant


def cell_kinds(cm: ConformingMesh, mesh: dmesh.Mesh | CurvedMesh | None = None) -> npt.NDArray:
    """Kind of every local cell of ``cm.mesh`` (codes into :data:`KIND_NAMES`).

    0 unaltered (no vertex moved), 1 moved (a vertex moved), 2 positively cut (an edge on
    Gamma_h), 3 curved (its nodes in ``mesh``, a curved mesh on the topology of
    ``cm.mesh``, are not the affine image of its vertices). Local, not collective.
    """
    cells = cm.cells
    kind = np.where(np.asarray(cm.moved)[cells].any(axis=1), 1, 0).astype(np.int8)
    kind[np.asarray(cm.positively_cut, dtype=bool)] = 2
    msh: dmesh.Mesh | None = None if mesh is None else getattr(mesh, "mesh", mesh)
    if msh is not None and msh is not cm.mesh:
        degree, variant = _geometry_degree(msh)
        if degree > 1 and len(msh.geometry.dofmaps[0]) == len(kind):
            nodes = msh.geometry.x[msh.geometry.dofmaps[0]][:, :, :2]
            kind[curved_cells(nodes, degree, variant)] = 3
    return kind


def _immersed_mask(msh: dmesh.Mesh, tags: Any, value: int) -> npt.NDArray[np.bool_]:
    """``(num_local_cells, 3)``: local edge ``i`` of the cell carries the tag ``value``."""
    tdim = msh.topology.dim
    ncells = msh.topology.index_map(tdim).size_local + msh.topology.index_map(tdim).num_ghosts
    if tags is None:
        return np.zeros((ncells, 3), dtype=bool)
    msh.topology.create_connectivity(tdim, tdim - 1)
    c2f = msh.topology.connectivity(tdim, tdim - 1).array.reshape(-1, 3)
    imf = msh.topology.index_map(tdim - 1)
    marked = np.zeros(imf.size_local + imf.num_ghosts, dtype=bool)
    marked[tags.indices[tags.values == value]] = True
    return marked[c2f[:ncells]]


def _gamma_lines(edges: npt.NDArray, mask: npt.NDArray) -> npt.NDArray:
    """Polylines of the marked local edges ``(n, m, 2)``."""
    return edges[np.asarray(mask, dtype=bool)]


def auto_inset(
    gamma_lines: npt.NDArray[np.float64], boundary: Any = None, width: float = 2.0
) -> tuple[float, float, float, float] | None:
    """A zoom window where Gamma bends most over one edge of Gamma_h.

    For every edge of Gamma_h (polylines ``(n, m, 2)``) the exact boundary's distance from
    the chord's midpoint, relative to the chord's length, is computed (from the drawn
    polyline when ``boundary`` is ``None``); the window, ``width`` chord lengths wide, is
    centred on the edge where it is largest, so that straight and curved cells differ most.
    """
    if gamma_lines is None or len(gamma_lines) == 0:
        return None
    a, b = gamma_lines[:, 0], gamma_lines[:, -1]
    mid = 0.5 * (a + b)
    length = np.linalg.norm(b - a, axis=1)
    if boundary is not None:
        target = np.asarray(boundary.closest_point(mid), dtype=np.float64)[:, :2]
    else:
        target = gamma_lines[:, gamma_lines.shape[1] // 2]
    sag = np.linalg.norm(target - mid, axis=1) / np.maximum(length, np.finfo(float).tiny)
    i = int(np.argmax(sag))
    c = 0.5 * (mid[i] + target[i])
    half = 0.5 * width * float(length[i])
    return (c[0] - half, c[1] - half, c[0] + half, c[1] + half)


def add_inset(
    ax: Axes,
    inset: tuple[float, float, float, float],
    draw: Any,
    *,
    size: float = 0.4,
    loc: str | None = None,
    avoid: str | None = "upper left",
) -> Axes:
    """Inset axes zooming on ``inset = (x0, y0, x1, y1)``, its rectangle marked on ``ax``.

    ``draw(axes)`` draws the content into the inset. The inset goes into the corner of
    ``ax`` (``loc``: ``"upper right"``...) farthest from the window, not into ``avoid``
    (where the legend goes).
    """
    x0, y0, x1, y1 = (float(v) for v in inset)
    corners = {
        "upper right": (1.0 - size, 1.0 - size),
        "lower right": (1.0 - size, 0.0),
        "lower left": (0.0, 0.0),
        "upper left": (0.0, 1.0 - size),
    }
    if loc is None:
        xl, yl = ax.get_xlim(), ax.get_ylim()
        cx = ((x0 + x1) / 2 - xl[0]) / (xl[1] - xl[0])
        cy = ((y0 + y1) / 2 - yl[0]) / (yl[1] - yl[0])
        choices = {k: v for k, v in corners.items() if k != avoid}
        loc = max(
            choices,
            key=lambda k: np.hypot(choices[k][0] + size / 2 - cx, choices[k][1] + size / 2 - cy),
        )
    px, py = corners[loc]
    pad = 0.01
    sub = ax.inset_axes(
        (px + (pad if px == 0 else -pad), py + (pad if py == 0 else -pad), size, size)
    )
    draw(sub)
    sub.set_xlim(x0, x1)
    sub.set_ylim(y0, y1)
    sub.set_aspect("equal")
    sub.set_xticks([])
    sub.set_yticks([])
    sub.set_facecolor("white")
    for spine in sub.spines.values():
        spine.set_edgecolor("0.15")
        spine.set_linewidth(1.0)
    ax.indicate_inset_zoom(sub, edgecolor="0.15", linewidth=0.9, alpha=0.9)
    return sub


def _new_figure(figsize: tuple[float, float]) -> tuple[Figure, Axes]:
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    return fig, fig.add_subplot()


class _ConformingLayers(NamedTuple):
    """What :func:`plot_conforming` draws, bottom to top: the background's edges, the
    conforming (or curved) cells, Gamma_h and the exact boundary; and their legend."""

    bg_nodes: Float | None
    background_edgecolor: Any
    nodes: Float
    degree: int
    variant: Any
    faces: Any
    edgecolor: Any
    points_per_edge: int
    gamma: Float
    gamma_h_color: Any
    gamma_h_linewidth: float | None
    exact: Float | None
    boundary_color: Any
    boundary_linewidth: float

    def draw(self, target: Axes, lw: float, limit: int | None) -> None:
        """Draw the layers on ``target`` with edges of width ``lw``, the interior edges only
        up to ``limit`` cells."""
        from matplotlib.collections import LineCollection

        if self.bg_nodes is not None:
            plot_mesh(
                target,
                self.bg_nodes,
                1,
                facecolors="none",
                edgecolor=self.background_edgecolor,
                linewidth=lw,
                zorder=1,
                max_edge_cells=limit,
                axis_labels=False,
            )
        plot_mesh(
            target,
            self.nodes,
            self.degree,
            facecolors=self.faces,
            edgecolor=self.edgecolor,
            linewidth=lw,
            points_per_edge=self.points_per_edge,
            variant=self.variant,
            zorder=2,
            max_edge_cells=limit,
            axis_labels=False,
        )
        if len(self.gamma):
            glw = self.gamma_h_linewidth
            target.add_collection(
                LineCollection(
                    self.gamma,  # type: ignore[arg-type]  # stubs want a Sequence; arrays work
                    colors=self.gamma_h_color,
                    linewidths=glw if glw is not None else max(1.0, 3 * lw),
                    zorder=3,
                    capstyle="round",
                ),
                autolim=False,
            )
        if self.exact is not None:
            target.plot(
                self.exact[:, 0],
                self.exact[:, 1],
                color=self.boundary_color,
                linewidth=self.boundary_linewidth,
                zorder=4,
            )

    def handles(self, shade: bool, kinds: npt.NDArray | None, colours: npt.NDArray) -> list:
        """Legend entries of the layers: the cells' kinds (``kinds``: per cell, or ``None``
        for plain cells) if ``shade``, then the lines."""
        from matplotlib.lines import Line2D

        handles: list = []
        if shade:
            handles += _kind_patches(kinds, len(self.nodes), colours, self.edgecolor, self.degree)
        if self.bg_nodes is not None:
            handles.append(
                Line2D([], [], color=self.background_edgecolor, lw=1.0, label="background mesh")
            )
        if len(self.gamma):
            handles.append(
                Line2D(
                    [], [], color=self.gamma_h_color, lw=2.5, label=r"$\Gamma_h$ (immersed facets)"
                )
            )
        if self.exact is not None:
            handles.append(
                Line2D([], [], color=self.boundary_color, lw=1.2, label=r"$\Gamma$ (exact)")
            )
        return handles


def plot_conforming(
    ax: Axes | None,
    cm: ConformingMesh,
    show_background: bool = True,
    *,
    mesh: dmesh.Mesh | CurvedMesh | None = None,
    show_boundary: bool = True,
    shade: bool = True,
    background_edgecolor: Any = BACKGROUND_EDGE,
    kept_color: Any = KEPT_FACE,
    cut_color: Any = CUT_FACE,
    edgecolor: Any = "k",
    linewidth: float | None = None,
    boundary_color: Any = BOUNDARY_COLOR,
    boundary_linewidth: float = 0.8,
    boundary_samples: int = 2000,
    points_per_edge: int = 8,
    title: str | None = None,
    figsize: tuple[float, float] = (7.0, 7.0),
    moved_color: Any = MOVED_FACE,
    curved_color: Any = CURVED_FACE,
    show_gamma_h: bool = True,
    gamma_h_color: Any = GAMMA_H_COLOR,
    gamma_h_linewidth: float | None = None,
    legend: bool | str = True,
    inset: Any = None,
    max_edge_cells: int | None = MAX_EDGE_CELLS,
) -> tuple[Figure | None, Axes | None]:
    """Figure of a conforming mesh over its background, as in the universal-mesh papers.

    The cells of the conforming mesh are coloured by kind (unaltered, moved, positively cut,
    curved: see :func:`cell_kinds`) with a legend naming each colour and the number of its
    cells; Gamma_h (the facets tagged IMMERSED) is drawn as a thick dark line along the cells'
    (curved) edges and the exact boundary Gamma as a thin coloured line on top. With
    ``show_background=True`` the background triangulation is drawn underneath with light grey
    edges. Curved cells are drawn curved (edges are polylines of the mapped reference
    edges). Axes are labelled ``x``, ``y`` with equal aspect. An inset can enlarge a window
    (``inset``), by default where Gamma bends most over one edge, when the figure is new.

    Collective: call on every rank. Drawing happens on rank 0 only.

    Parameters
    ----------
    ax
        Axes to draw into on rank 0, or ``None`` to create a new figure there.
    cm
        The conforming mesh.
    show_background
        Draw the background mesh underneath.
    mesh
        Mesh drawn as the conforming mesh instead of ``cm.mesh``, e.g. the curved mesh of
        :func:`dolfinx_universal.curved.maps.curved_mesh` (a ``CurvedMesh`` or its ``.mesh``;
        drawn with curved edges). Kinds and Gamma_h need the same local cells as ``cm.mesh``
        (true for curved meshes, which share its topology); otherwise cells are shaded
        uniformly and Gamma_h is not drawn.
    show_boundary
        Draw ``cm.boundary`` sampled at ``boundary_samples`` points.
    shade
        Colour the cells by kind (else no fill and no kind legend).
    background_edgecolor, kept_color, cut_color, moved_color, curved_color
        Colours of the background edges and of the unaltered, positively cut, moved and
        curved cells.
    edgecolor, linewidth
        Edges of the conforming mesh; ``linewidth=None`` scales with the number of cells and
        the axes size.
    boundary_color, boundary_linewidth
        Line of the exact boundary.
    boundary_samples
        Points sampled on the boundary.
    points_per_edge
        Samples per curved edge.
    title
        Axes title.
    figsize
        Size in inches of a new figure.
    show_gamma_h, gamma_h_color, gamma_h_linewidth
        Gamma_h line (width default: 3 times the edges, at least 1).
    legend
        Draw the legend: ``True`` (upper left, inside), ``False``, a matplotlib ``loc``
        string, or ``"outside"`` (right of the axes).
    inset
        Zoom inset: ``(x0, y0, x1, y1)``, ``"auto"`` (where Gamma bends most over an edge of
        Gamma_h), ``False`` (none) or ``None`` (``"auto"`` for a new figure, else none).
    max_edge_cells
        Above this many cells the interior edges are drawn in the inset only.

    Returns
    -------
    ``(figure, axes)`` on rank 0, ``(None, None)`` on the other ranks.
    """
    _mpl()
    msh: dmesh.Mesh = cm.mesh if mesh is None else getattr(mesh, "mesh", mesh)  # CurvedMesh.mesh
    degree, variant = _geometry_degree(msh)
    nodes, data = _gather_kinds(cm, msh, getattr(mesh, "facet_tags", None))
    bg_nodes = gather_cells(cm.background) if show_background else None
    if cm.mesh.comm.rank != 0:
        return None, None
    assert nodes is not None  # gathered on rank 0

    new = ax is None
    if ax is None:
        fig, ax = _new_figure(figsize)
    else:
        fig = _figure(ax)
    kind, gmask = _kinds_and_gamma(data, len(nodes))
    colours = np.array([kept_color, moved_color, cut_color, curved_color], dtype=object)
    faces = colours[kind] if (shade and data is not None) else (kept_color if shade else "none")
    edges = cell_edges(nodes, degree, points_per_edge, variant)
    gamma = _gamma_lines(edges, gmask) if show_gamma_h else np.zeros((0, 2, 2))
    boundary = getattr(cm, "boundary", None) if show_boundary else None
    exact = boundary_polyline(boundary, boundary_samples) if boundary is not None else None
    lw_main = _auto_linewidth(ax, len(nodes)) if linewidth is None else linewidth

    layers = _ConformingLayers(
        bg_nodes, background_edgecolor, nodes, degree, variant, faces, edgecolor,
        points_per_edge, gamma, gamma_h_color, gamma_h_linewidth, exact, boundary_color,
        boundary_linewidth,
    )  # fmt: skip
    layers.draw(ax, lw_main, max_edge_cells)
    _label_axes(ax)
    ax.autoscale_view()
    if title is not None:
        ax.set_title(title)

    if legend:
        kinds = kind if data is not None else None
        _legend(ax, layers.handles(shade, kinds, colours), legend)

    if inset is None:
        inset = "auto" if new else False
    if isinstance(inset, str) and inset == "auto":
        inset = auto_inset(gamma, boundary)
    if inset is not None and inset is not False:
        _conforming_inset(ax, inset, nodes, layers, legend)
    return fig, ax


def _conforming_inset(
    ax: Axes,
    window: tuple[float, float, float, float],
    nodes: npt.NDArray,
    layers: _ConformingLayers,
    legend: bool | str,
) -> None:
    """The inset of :func:`plot_conforming` enlarging ``window``, its lines as thick as the
    cells inside it allow, away from the legend's corner."""
    x0, y0, x1, y1 = window
    inside = _cells_in_window(nodes, (x0, y0, x1, y1))
    lw_in = float(np.clip(3.0 * _auto_linewidth(ax, max(inside, 1) * 6), 0.4, 1.2))
    add_inset(
        ax,
        (x0, y0, x1, y1),
        lambda a: layers.draw(a, lw_in, None),
        avoid=_legend_corner(legend),
    )


def _kinds_and_gamma(
    data: npt.NDArray | None, num_cells: int
) -> tuple[npt.NDArray[np.int8], npt.NDArray[np.bool_]]:
    """Each cell's kind and which of its edges lie on Gamma_h, from the gathered ``data``
    of :func:`_gather_kinds` (without it: unaltered, none)."""
    if data is None:
        return np.zeros(num_cells, dtype=np.int8), np.zeros((num_cells, 3), np.bool_)
    return data[:, 0], data[:, 1:].astype(bool)


def _gather_kinds(
    cm: ConformingMesh, msh: dmesh.Mesh, tags: Any
) -> tuple[npt.NDArray | None, npt.NDArray | None]:
    """The cells of ``msh`` gathered on rank 0 with, per cell, its kind (:func:`cell_kinds`)
    and which of its edges lie on Gamma_h (``IMMERSED`` in ``tags``, else in ``cm``'s
    tags), ``(n, 4)`` int8; no data where ``msh`` does not have ``cm.mesh``'s local cells
    on every rank (collective)."""
    sub = cm.mesh
    local_ok = int(msh is sub or msh.topology.index_map(2).size_local == _owned_cells(sub))
    if sub.comm.allreduce(local_ok, op=MPI.MIN) != 1:
        return gather_cells(msh), None
    kind = cell_kinds(cm, msh)
    gmask = _immersed_mask(sub, cm.facet_tags if tags is None else tags, IMMERSED)
    return gather_cells(msh, np.column_stack([kind, gmask]).astype(np.int8))


def _owned_cells(msh: dmesh.Mesh) -> int:
    return msh.topology.index_map(msh.topology.dim).size_local


def _kind_patches(
    kind: npt.NDArray | None, num_cells: int, colours: npt.NDArray, edgecolor: Any, degree: int
) -> list[Any]:
    """Legend patches of the cell kinds present, with their counts (one patch for all
    cells when the kinds are unknown, ``kind=None``)."""
    from matplotlib.patches import Patch

    if kind is None:
        return [Patch(facecolor=colours[0], edgecolor=edgecolor, linewidth=0.5,
                      label=f"cells ({num_cells})")]  # fmt: skip
    counts = np.bincount(kind.astype(np.int64), minlength=4)
    patches = []
    for code, name in enumerate(KIND_NAMES):
        if counts[code]:
            label = f"{name} ({counts[code]})"
            if code == 3:
                label = f"curved, degree {degree} ({counts[code]})"
            patches.append(
                Patch(facecolor=colours[code], edgecolor=edgecolor, linewidth=0.5, label=label)
            )
    return patches


def _cells_in_window(nodes: npt.NDArray, window: tuple[float, float, float, float]) -> int:
    x0, y0, x1, y1 = window
    c = nodes[:, :3].mean(axis=1)
    return int(
        np.count_nonzero((c[:, 0] >= x0) & (c[:, 0] <= x1) & (c[:, 1] >= y0) & (c[:, 1] <= y1))
    )


def _legend_corner(legend: Any) -> str | None:
    if legend is True:
        return "upper left"
    if isinstance(legend, str) and legend in (
        "upper left",
        "upper right",
        "lower left",
        "lower right",
    ):
        return legend
    return None


def _legend(ax: Axes, handles: list, legend: Any) -> None:
    if not handles:
        return
    if isinstance(legend, str) and legend == "outside":
        ax.legend(
            handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False
        )
    else:
        loc = "upper left" if legend is True else legend
        ax.legend(handles=handles, loc=loc, fontsize=7, framealpha=0.92)


def _field_element(V: Any) -> tuple[Any, int]:
    """The scalar basix element of a (blocked) Lagrange-like space and its block size."""
    import basix

    message = (
        "plot_function draws scalar or blocked Lagrange/DG spaces on the function's own "
        "mesh only; interpolate into one first"
    )
    try:
        be = V.ufl_element().basix_element
    except (AttributeError, NotImplementedError, ValueError):
        raise ValueError(message) from None
    if (
        be.value_size != 1
        or V.element.needs_dof_transformations
        or be.map_type != basix.MapType.identity
    ):
        raise ValueError(message)
    return be, int(V.dofmap.bs)


def field_triangulation(
    u: fem.Function,
    *,
    cells: npt.ArrayLike | None = None,
    active: Any = None,
    subdivisions: int | None = None,
    curved_subdivisions: int | None = None,
    component: int | str | None = "magnitude",
    root: int = 0,
) -> tuple[npt.NDArray | None, npt.NDArray | None, npt.NDArray | None]:
    """A function evaluated on the subdivided (curved) cells of its mesh, gathered (collective).

    Each cell is split into the images of a reference lattice under its coordinate map
    (:func:`subdivide_cells`), so the sub-triangles fill the curved cells, and ``u`` is
    evaluated at the lattice points from its cell dofs and the tabulated basis of its
    element (Lagrange or DG spaces, scalar or blocked, on the mesh itself).

    Parameters
    ----------
    u
        The function.
    cells, active
        Draw only these local cells, or the cells where the DG0 indicator (function or
        per-cell array) ``active`` exceeds 1/2 (e.g. ``MovingDomain.active``). Default: all.
    subdivisions
        Lattice intervals of straight cells (default 1 for degree-1 fields, else ``2 k``).
    curved_subdivisions
        Lattice intervals of curved cells (default ``max(subdivisions, 4 q)``, ``q`` the
        geometry degree).
    component
        For blocked (vector) spaces: ``"magnitude"`` or the index of a component.
    root
        Rank that receives the result.

    Returns
    -------
    ``(points (n, 2), triangles (t, 3), values (n,))`` on ``root``, ``(None,) * 3`` elsewhere.
    """
    V = u.function_space
    msh = V.mesh
    comm = msh.comm
    be, bs = _field_element(V)
    degree, variant = _geometry_degree(msh)
    nco = msh.topology.index_map(2).size_local
    sel = _active_cells(msh, active, cells)
    sel = np.arange(nco) if sel is None else np.asarray(sel, dtype=np.int64)
    sel = sel[sel < nco]
    nodes = msh.geometry.x[msh.geometry.dofmaps[0][sel]][:, :, :2]
    n_straight = (1 if be.degree <= 1 else 2 * be.degree) if subdivisions is None else subdivisions
    n_curved = max(n_straight, 4 * degree) if curved_subdivisions is None else curved_subdivisions
    curved = curved_cells(nodes, degree, variant)
    u.x.scatter_forward()
    dofs = V.dofmap.list[sel]
    coeffs = u.x.array[(dofs[:, :, None] * bs + np.arange(bs)).reshape(len(sel), -1)]
    coeffs = coeffs.reshape(len(sel), dofs.shape[1], bs)
    pts, tris, vals = [], [], []
    offset = 0
    for group, n in ((~curved, n_straight), (curved, n_curved)):  # two groups, not cells
        if not group.any():
            continue
        ref, _ = reference_lattice(n)
        p, t = subdivide_cells(nodes[group], degree, n, variant)
        phi = be.tabulate(0, ref)[0, :, :, 0]  # (P, ndofs)
        v = np.einsum("pn,cnj->cpj", phi, coeffs[group]).reshape(-1, bs)
        pts.append(p)
        tris.append(t + offset)
        vals.append(v)
        offset += len(p)
    points = np.concatenate(pts) if pts else np.zeros((0, 2))
    triangles = np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)
    values = np.concatenate(vals) if vals else np.zeros((0, bs))
    if bs == 1:
        values = values[:, 0]
    elif component == "magnitude" or component is None:
        values = np.linalg.norm(values, axis=1)
    else:
        values = values[:, int(component)]
    parts = comm.gather((points, triangles, values), root=root)
    if comm.rank != root:
        return None, None, None
    shift = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    return (
        np.concatenate([p[0] for p in parts]),
        np.concatenate([p[1] + s for p, s in zip(parts, shift)]),
        np.concatenate([p[2] for p in parts]),
    )


def plot_function(
    ax: Axes | None,
    u: fem.Function,
    *,
    cmap: Any = "viridis",
    vmin: float | None = None,
    vmax: float | None = None,
    colorbar: bool = True,
    label: str | None = None,
    shading: str = "gouraud",
    show_mesh: bool = False,
    show_outline: bool = True,
    mesh_color: Any = "0.25",
    linewidth: float | None = None,
    boundary: Any = None,
    boundary_color: Any = BOUNDARY_COLOR,
    boundary_samples: int = 2000,
    inset: tuple[float, float, float, float] | None = None,
    inset_loc: str | None = None,
    title: str | None = None,
    figsize: tuple[float, float] = (7.5, 6.5),
    **field: Any,
) -> tuple[Figure | None, Axes | None]:
    """Colour plot of a function on its (curved) cells, reaching the curved boundary.

    The field is drawn with :meth:`~matplotlib.axes.Axes.tripcolor` on the sub-triangles of
    :func:`field_triangulation` (each curved cell subdivided by its coordinate map), so it
    fills the cells drawn by :func:`plot_mesh` with no gap along a curved boundary. For a
    :class:`~dolfinx_universal.moving.domain.MovingDomain` pass ``active=md.active`` (or
    ``cells=md.active_cells``) to draw the fluid cells only. Collective: call on every rank;
    rank 0 draws.

    Parameters
    ----------
    ax
        Axes on rank 0, or ``None`` for a new figure.
    u
        The function.
    field
        ``cells``, ``active``, ``subdivisions``, ``curved_subdivisions``, ``component``: see
        :func:`field_triangulation`.
    cmap, vmin, vmax, shading
        Passed to ``tripcolor`` (``shading="flat"`` colours sub-triangles uniformly).
    colorbar, label
        Colorbar and its label (default: the function's name).
    show_mesh, mesh_color, linewidth
        Draw the cell edges on top (curved; width scaled with the cell count by default).
    show_outline
        Draw the boundary edges of the drawn cells (thin, dark).
    boundary, boundary_color, boundary_samples
        An exact boundary (:class:`~dolfinx_universal.boundaries.base.Boundary`) drawn on top.
    inset, inset_loc
        Zoom window ``(x0, y0, x1, y1)`` drawn in an inset, in the corner ``inset_loc``
        (``"upper right"``...; default: the corner farthest from the window).
    title, figsize
        Title; size of a new figure.

    Returns
    -------
    ``(figure, axes)`` on rank 0, ``(None, None)`` elsewhere.
    """
    _mpl()
    msh = u.function_space.mesh
    degree, variant = _geometry_degree(msh)
    points, triangles, values = field_triangulation(u, **field)
    sel = _active_cells(msh, field.get("active"), field.get("cells"))
    curved_subdivisions = field.get("curved_subdivisions")
    component = field.get("component", "magnitude")
    nodes = gather_cells(msh, cells=sel) if (show_mesh or show_outline) else None
    if msh.comm.rank != 0:
        return None, None
    assert points is not None and triangles is not None and values is not None  # on rank 0
    from matplotlib.collections import LineCollection
    from matplotlib.tri import Triangulation

    if ax is None:
        fig, ax = _new_figure(figsize)
    else:
        fig = _figure(ax)
    tri = Triangulation(points[:, 0], points[:, 1], triangles)
    lo = float(np.min(values)) if vmin is None and len(values) else vmin
    hi = float(np.max(values)) if vmax is None and len(values) else vmax
    n_edge = max(4 * degree, 8) if curved_subdivisions is None else curved_subdivisions
    lines = boundary_lines = None
    if nodes is not None and len(nodes):
        lines, on_boundary, _ = unique_edges(cell_edges(nodes, degree, n_edge, variant))
        boundary_lines = lines[on_boundary]
    exact = boundary_polyline(boundary, boundary_samples) if boundary is not None else None

    def draw(target: Axes, lw: float) -> Any:
        mappable = target.tripcolor(
            tri, values, shading=shading, cmap=cmap, vmin=lo, vmax=hi, rasterized=True
        )
        if show_mesh and lines is not None:
            target.add_collection(
                LineCollection(lines, colors=mesh_color, linewidths=lw, zorder=2),  # type: ignore[arg-type]
                autolim=False,
            )
        if show_outline and boundary_lines is not None:
            target.add_collection(
                LineCollection(
                    boundary_lines,  # type: ignore[arg-type]  # stubs want a Sequence
                    colors="k",
                    linewidths=max(0.6, 2 * lw),
                    zorder=3,
                ),
                autolim=False,
            )
        if exact is not None:
            target.plot(exact[:, 0], exact[:, 1], color=boundary_color, lw=0.8, zorder=4)
        return mappable

    ncells = 0 if nodes is None else len(nodes)
    lw = _auto_linewidth(ax, ncells) if linewidth is None else linewidth
    mappable = draw(ax, lw)
    _label_axes(ax)
    ax.autoscale_view()
    if colorbar:
        name = label if label is not None else getattr(u, "name", None)
        if u.function_space.dofmap.bs > 1 and label is None:
            name = f"|{name}|" if component in ("magnitude", None) else f"{name}[{component}]"
        fig.colorbar(mappable, ax=ax, label=name, shrink=0.85)
    if title is not None:
        ax.set_title(title)
    if inset is not None:
        add_inset(ax, inset, lambda a: draw(a, max(3 * lw, 0.4)), loc=inset_loc, avoid=None)
    return fig, ax


def boundary_polyline(boundary: Any, n: int = 2000) -> npt.NDArray[np.float64]:
    """Closed polyline(s) through ``n`` samples of a boundary, NaN rows between curves.

    ``boundary.sample(n)`` lists the points of each closed curve in turn; a new curve is
    assumed to start where consecutive samples are more than 8 times the median spacing
    apart (an approximation for boundaries of several curves).

    Returns
    -------
    Points ``(m, 2)`` for :meth:`matplotlib.axes.Axes.plot`: each curve closed, curves
    separated by a row of NaN.
    """
    pts = np.asarray(boundary.sample(n), dtype=np.float64)[:, :2]
    if len(pts) < 3:
        return pts
    gaps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    cut = np.flatnonzero(gaps > 8.0 * np.median(gaps)) + 1
    pieces = np.split(pts, cut)
    nan = np.full((1, 2), np.nan)
    out = []
    for piece in pieces:  # one per curve (a handful), not per cell
        out.extend([piece, piece[:1], nan])
    return np.concatenate(out[:-1])


def save(fig: Figure | None, path: str | Path, dpi: int = 150, **kwargs: Any) -> None:
    """Write a figure (tight bounding box) and close it; does nothing when ``fig`` is ``None``.

    Parameters
    ----------
    fig
        The figure (``None`` on ranks other than 0, as returned by :func:`plot_conforming`).
    path
        Output file; the format follows its suffix (``.png``, ``.pdf``, ``.svg``...).
    dpi
        Resolution of raster formats.
    **kwargs
        Passed to :meth:`matplotlib.figure.Figure.savefig`.
    """
    if fig is None:
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    kwargs.setdefault("bbox_inches", "tight")
    fig.savefig(path, dpi=dpi, **kwargs)
    if "matplotlib.pyplot" in sys.modules:  # release figures created through pyplot
        sys.modules["matplotlib.pyplot"].close(fig)


# --------------------------------------------------------------------------------------------
# Tetrahedra
# --------------------------------------------------------------------------------------------

# Outward faces of a positively oriented tetrahedron: face k is opposite vertex k (basix's
# numbering, which DOLFINx's cell-to-facet connectivity follows).
_TET_FACES = _tetrahedron.FACETS


def gather_tetrahedra(
    msh: dmesh.Mesh,
    facet_tags: dmesh.MeshTags | None = None,
    tag: int | None = 1,
    root: int = 0,
) -> dict[str, npt.NDArray] | None:
    """The owned tetrahedra of a mesh with their quality and tagged faces, on one rank.

    Collective. Straight cells through the vertices (the first four geometry nodes).

    Parameters
    ----------
    msh
        A tetrahedron mesh, possibly distributed.
    facet_tags
        Face tags; ``None``: the exterior faces count as tagged.
    tag
        The tag value of the faces to mark (``None``: every tagged face).
    root
        Rank that receives the data.

    Returns
    -------
    On ``root`` a dict of arrays over the ``n`` global cells, ``None`` elsewhere:
    ``corners`` ``(n, 4, 3)``, ``vertices`` ``(n, 4)`` (global vertex indices),
    ``min_dihedral_deg`` ``(n,)`` and ``tagged`` ``(n, 4)`` (face ``k`` of the cell,
    opposite its vertex ``k``, carries the tag).
    """
    topo = msh.topology
    if topo.cell_type.name != "tetrahedron":
        raise ValueError(f"gather_tetrahedra needs a tetrahedron mesh, got {topo.cell_type.name}")
    nco = topo.index_map(3).size_local
    topo.create_connectivity(3, 0)
    topo.create_connectivity(2, 3)
    topo.create_connectivity(3, 2)
    c2v = topo.connectivity(3, 0).array.reshape(-1, 4)[:nco]
    c2f = topo.connectivity(3, 2).array.reshape(-1, 4)[:nco]
    corners = msh.geometry.x[msh.geometry.dofmaps[0][:nco, :4]]
    x = corners.reshape(-1, 3)
    cells = np.arange(4 * nco, dtype=np.int64).reshape(-1, 4)
    with np.errstate(invalid="ignore"):
        angles = _tetrahedron.dihedral_angles(x, cells) if nco else np.zeros((0, 6))
        quality = np.degrees(np.nanmin(angles, axis=1)) if nco else np.zeros(0)
    imf = topo.index_map(2)
    marked = np.zeros(imf.size_local + imf.num_ghosts, dtype=bool)
    if facet_tags is None:
        marked[_exterior_facets(msh)] = True
    else:
        sel = np.ones(len(facet_tags.values), bool) if tag is None else facet_tags.values == tag
        marked[facet_tags.indices[sel]] = True
    local = {
        "corners": np.ascontiguousarray(corners),
        "vertices": topo.index_map(0).local_to_global(c2v.ravel()).reshape(-1, 4),
        "min_dihedral_deg": quality,
        "tagged": marked[c2f],
    }
    parts = msh.comm.gather(local, root=root)
    if msh.comm.rank != root:
        return None
    return {k: np.concatenate([p[k] for p in parts]) for k in local}


def _exterior_facets(msh: dmesh.Mesh) -> npt.NDArray[np.int32]:
    """Process-local exterior facets of a mesh (``dolfinx.mesh.exterior_facet_indices``)."""
    from dolfinx import mesh as dmesh

    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    return dmesh.exterior_facet_indices(msh.topology)


def _outward_faces(corners: npt.NDArray) -> npt.NDArray:
    """Faces ``(n, 4, 3, 3)`` of tetrahedra ``(n, 4, 3)``, oriented out of each cell."""
    faces = corners[:, _TET_FACES]
    d = corners[:, 1:] - corners[:, :1]
    negative = np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) < 0
    faces[negative] = faces[negative][:, :, [0, 2, 1]]
    return faces


def clipped_faces(
    data: dict[str, npt.NDArray],
    origin: npt.ArrayLike,
    normal: npt.ArrayLike,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """The visible faces of the tetrahedra behind a clipping plane.

    The cells whose centroid ``c`` has ``(c - origin) . normal <= 0`` are kept; their faces
    that no other kept cell shares (the cut through the mesh, and the mesh's own boundary
    on that side) are returned, oriented out of their cells.

    Parameters
    ----------
    data
        As returned by :func:`gather_tetrahedra` (on its root rank).
    origin, normal
        A point of the plane ``(3,)`` and its normal ``(3,)``, pointing to the removed half.

    Returns
    -------
    faces
        ``(m, 3, 3)`` corner coordinates.
    cells
        ``(m,)`` index of each face's cell in ``data``.
    """
    corners = data["corners"]
    centroid = corners.mean(axis=1)
    keep = np.flatnonzero((centroid - np.asarray(origin)) @ np.asarray(normal, float) <= 0)
    ids = np.sort(data["vertices"][keep][:, _TET_FACES].reshape(-1, 3), axis=1)
    _, inverse, counts = np.unique(ids, axis=0, return_inverse=True, return_counts=True)
    single = counts[inverse.reshape(-1)] == 1
    faces = _outward_faces(corners[keep]).reshape(-1, 3, 3)[single]
    cells = np.repeat(keep, 4)[single]
    return faces, cells


def _view_vector(elev: float, azim: float) -> npt.NDArray[np.float64]:
    """Unit vector from the scene towards the camera of mplot3d's ``view_init``."""
    e, a = np.radians(elev), np.radians(azim)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def plot_tetrahedra(
    mesh: ConformingMesh | dmesh.Mesh,
    ax: Any = None,
    *,
    view: str = "clipped",
    facet_tags: dmesh.MeshTags | None = None,
    tag: int | None = 1,
    origin: npt.ArrayLike | None = None,
    normal: npt.ArrayLike = (0.0, -1.0, 0.0),
    elev: float = 22.0,
    azim: float = -58.0,
    cmap: Any = "viridis",
    vmin: float | None = None,
    vmax: float | None = None,
    colorbar: bool = True,
    shade: bool = True,
    edgecolor: Any = "k",
    linewidth: float = 0.15,
    title: str | None = None,
    figsize: tuple[float, float] = (7.0, 6.0),
) -> tuple[Figure | None, Any]:
    """3D figure of a tetrahedron mesh: a clipped view, or its surface, coloured by quality.

    Every drawn face is coloured by the smallest dihedral angle of its tetrahedron (degrees).
    ``view="clipped"``: the tetrahedra with their centroid on the kept side of a plane
    (:func:`clipped_faces`: the cut through the mesh and the boundary behind it).
    ``view="surface"``: the faces tagged ``tag`` (for a conforming mesh, Gamma_h: its
    IMMERSED faces), or all exterior faces when the mesh has no tags. Drawn with mplot3d's
    ``Poly3DCollection`` (painter's algorithm: faces sorted by depth; colours shaded by a
    light from the camera's side unless ``shade=False``), with equal axis scales.

    Collective: call on every rank. Drawing happens on rank 0 only.

    Parameters
    ----------
    mesh
        A :class:`~dolfinx_universal.conforming.universal.ConformingMesh` (its mesh and facet tags)
        or a
        tetrahedron mesh (degree 1: cells drawn straight through their vertices).
    ax
        3D axes (``projection="3d"``) on rank 0, or ``None`` for a new figure there.
    view
        ``"clipped"`` or ``"surface"``.
    facet_tags
        Face tags of a plain mesh (a conforming mesh brings its own).
    tag
        The value of the faces drawn by ``view="surface"`` (``None``: all tagged faces).
    origin, normal
        Clipping plane: a point (default: the centre of the mesh's bounding box) and the
        normal pointing to the removed half (default ``-y``: the half nearest the default
        camera goes).
    elev, azim
        Camera angles (degrees), as in ``Axes3D.view_init``.
    cmap, vmin, vmax
        Colour map and range of the min dihedral angles (default: their range).
    colorbar
        Add a colour bar (new figures and given axes alike).
    shade
        Shade the face colours by their orientation to the light.
    edgecolor, linewidth
        Face outlines.
    title
        Axes title.
    figsize
        Size of a new figure.

    Returns
    -------
    ``(figure, axes)`` on rank 0, ``(None, None)`` elsewhere.
    """
    if view not in ("clipped", "surface"):
        raise ValueError(f"view must be 'clipped' or 'surface', got {view!r}")
    if hasattr(mesh, "facet_tags") and facet_tags is None:
        facet_tags = mesh.facet_tags
    msh = getattr(mesh, "mesh", mesh)
    data = gather_tetrahedra(msh, facet_tags, tag)
    if data is None:
        return None, None
    mpl = _mpl()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    quality = data["min_dihedral_deg"]
    if view == "clipped":
        x = data["corners"].reshape(-1, 3)
        centre = 0.5 * (x.min(axis=0) + x.max(axis=0)) if len(x) else np.zeros(3)
        o = centre if origin is None else np.asarray(origin, dtype=np.float64)
        faces, cells = clipped_faces(data, o, normal)
    else:
        faces = _outward_faces(data["corners"])[data["tagged"]]
        cells = np.nonzero(data["tagged"])[0]
    values = quality[cells]
    if ax is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=figsize, layout="constrained")
        ax = fig.add_subplot(projection="3d")
    else:
        fig = _figure(ax)
    lo = vmin if vmin is not None else (float(values.min()) if len(values) else 0.0)
    hi = vmax if vmax is not None else (float(values.max()) if len(values) else 90.0)
    norm = mpl.colors.Normalize(vmin=lo, vmax=max(hi, lo + 1e-9))
    colours = mpl.colormaps[cmap](norm(values)) if isinstance(cmap, str) else cmap(norm(values))
    if shade and len(faces):
        n = np.cross(faces[:, 1] - faces[:, 0], faces[:, 2] - faces[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        light = _view_vector(elev + 25.0, azim - 30.0)
        intensity = 0.55 + 0.45 * np.abs(n @ light)
        colours[:, :3] *= intensity[:, None]
    collection = Poly3DCollection(
        faces, facecolors=colours, edgecolors=edgecolor, linewidths=linewidth
    )
    ax.add_collection3d(collection)
    pts = data["corners"].reshape(-1, 3)
    if len(pts):
        lo3, hi3 = pts.min(axis=0), pts.max(axis=0)
        ax.set_xlim(lo3[0], hi3[0]), ax.set_ylim(lo3[1], hi3[1]), ax.set_zlim(lo3[2], hi3[2])
        ax.set_box_aspect(np.maximum(hi3 - lo3, 1e-12))
    ax.view_init(elev=elev, azim=azim)
    ax.set_xlabel("x"), ax.set_ylabel("y"), ax.set_zlabel("z")
    if colorbar:
        mappable = mpl.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(mappable, ax=ax, label="min dihedral angle of the cell (deg)", shrink=0.7)
    if title is not None:
        ax.set_title(title)
    return fig, ax
