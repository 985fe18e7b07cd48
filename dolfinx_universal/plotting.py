"""Matplotlib figures of background, conforming and curved meshes (gathered to rank 0)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from dolfinx import mesh as dmesh
    from matplotlib.axes import Axes
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    from .conform import ConformingMesh
    from .curved import CurvedMesh

__all__ = [
    "boundary_polyline",
    "cell_outlines",
    "gather_cells",
    "plot_conforming",
    "plot_mesh",
    "save",
]

#: Default colours of :func:`plot_conforming`.
BACKGROUND_EDGE = "0.78"
KEPT_FACE = "#dbe7f3"
CUT_FACE = "#8fb4d9"
BOUNDARY_COLOR = "tab:red"


def _degree_of(ndofs: int) -> int:
    """Lagrange degree ``k`` of a triangle with ``(k + 1)(k + 2)/2`` nodes."""
    k = int(round((np.sqrt(8 * ndofs + 1) - 3) / 2))
    if k < 1 or (k + 1) * (k + 2) // 2 != ndofs:
        raise ValueError(f"{ndofs} nodes per cell is not a Lagrange triangle")
    return k


@overload
def gather_cells(
    msh: dmesh.Mesh, values: None = None, root: int = 0
) -> npt.NDArray[np.float64] | None: ...


@overload
def gather_cells(
    msh: dmesh.Mesh, values: npt.ArrayLike, root: int = 0
) -> tuple[npt.NDArray[np.float64] | None, npt.NDArray | None]: ...


def gather_cells(msh, values=None, root=0):
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
    dofmap = msh.geometry.dofmaps[0][:nco]
    local = msh.geometry.x[dofmap][:, :, :2]
    parts = comm.gather(np.ascontiguousarray(local), root=root)
    nodes = np.concatenate(parts, axis=0) if comm.rank == root else None
    if values is None:
        return nodes
    vals = np.asarray(values)[:nco]
    vparts = comm.gather(np.ascontiguousarray(vals), root=root)
    gathered = np.concatenate(vparts, axis=0) if comm.rank == root else None
    return nodes, gathered


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
    nodes = np.asarray(nodes, dtype=np.float64)
    if nodes.ndim != 3 or nodes.shape[2] < 2:
        raise ValueError(f"nodes must have shape (num_cells, num_nodes, 2), got {nodes.shape}")
    nodes = nodes[:, :, :2]
    k = _degree_of(nodes.shape[1]) if degree is None else int(degree)
    if (k + 1) * (k + 2) // 2 != nodes.shape[1]:
        raise ValueError(f"degree {k} needs {(k + 1) * (k + 2) // 2} nodes per cell, "
                         f"got {nodes.shape[1]}")
    if k == 1:
        return nodes[:, :3].copy()
    import basix

    if variant is None:
        variant = basix.LagrangeVariant.gll_warped
    elif not isinstance(variant, basix.LagrangeVariant):
        variant = basix.LagrangeVariant(int(variant))
    if k >= 3 and variant == basix.LagrangeVariant.unset:
        variant = basix.LagrangeVariant.gll_warped
    element = basix.create_element(basix.ElementFamily.P, basix.CellType.triangle, k, variant)
    t = np.arange(points_per_edge) / points_per_edge
    zero = np.zeros_like(t)
    ref = np.concatenate(
        [
            np.column_stack([t, zero]),  # vertex 0 -> vertex 1
            np.column_stack([1.0 - t, t]),  # vertex 1 -> vertex 2
            np.column_stack([zero, 1.0 - t]),  # vertex 2 -> vertex 0
        ]
    )
    phi = element.tabulate(0, ref)[0, :, :, 0]  # (num_points, num_nodes)
    return np.einsum("pn,cnd->cpd", phi, nodes)


def plot_mesh(
    ax: Axes | None,
    nodes: npt.ArrayLike | None,
    degree: int | None = None,
    facecolors: Any = None,
    edgecolor: Any = "k",
    linewidth: float = 0.3,
    *,
    values: npt.ArrayLike | None = None,
    cmap: Any = None,
    points_per_edge: int = 8,
    variant: Any = None,
    autoscale: bool = True,
    **kwargs: Any,
) -> PolyCollection | None:
    """Draw triangles (straight or curved) as one :class:`~matplotlib.collections.PolyCollection`.

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
        with curved edges (see :func:`cell_outlines`).
    facecolors
        A colour, one colour per cell, or ``None`` (no fill; ``"none"`` also works).
    edgecolor, linewidth
        Edges; ``edgecolor="none"`` hides them.
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
    **kwargs
        Passed to :class:`~matplotlib.collections.PolyCollection` (``zorder``, ``alpha``...).

    Returns
    -------
    The collection of the cells' faces (it carries ``values`` for a colorbar), or of their
    edges when unfilled; ``None`` when ``nodes`` is ``None``. Filled cells with edges are
    drawn as two collections, faces then edges, so that no face hides a neighbour's edge.
    """
    if nodes is None or ax is None:
        return None
    from matplotlib.collections import PolyCollection

    outlines = cell_outlines(nodes, degree, points_per_edge, variant)
    filled = values is not None or not (
        facecolors is None or (isinstance(facecolors, str) and facecolors == "none")
    )
    edged = not (edgecolor is None or (isinstance(edgecolor, str) and edgecolor == "none"))
    zorder = kwargs.pop("zorder", 1.0)
    faces = None
    if filled:  # faces first, edges in a second collection so no fill hides an edge
        faces = PolyCollection(
            outlines,
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
        edges = PolyCollection(
            outlines,
            facecolors="none",
            edgecolors=edgecolor,
            linewidths=linewidth,
            zorder=zorder + 0.01,
            **kwargs,
        )
        ax.add_collection(edges, autolim=autoscale and faces is None)
    coll = faces if faces is not None else edges
    if autoscale and len(outlines):
        ax.set_aspect("equal")
        ax.autoscale_view()
    return coll


def _geometry_degree(msh: dmesh.Mesh) -> tuple[int, Any]:
    """Degree and Lagrange variant of a mesh's coordinate element."""
    cmap = msh.geometry.cmaps[0]
    return int(cmap.degree), cmap.variant


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
    linewidth: float = 0.3,
    boundary_color: Any = BOUNDARY_COLOR,
    boundary_linewidth: float = 0.8,
    boundary_samples: int = 2000,
    points_per_edge: int = 8,
    title: str | None = None,
    figsize: tuple[float, float] = (7.0, 7.0),
) -> tuple[Figure | None, Axes | None]:
    """Figure of a conforming mesh over its background, as in the universal-mesh papers.

    With ``show_background=True`` the background triangulation is drawn with light grey
    edges, the triangles of ``T_h^sub`` (kept) lightly shaded and the positively cut ones
    darker (in their background positions); the conforming mesh edges are drawn on top and
    the exact boundary as a thin coloured line. With ``show_background=False`` only the
    conforming mesh is drawn (its kept / positively cut cells shaded, when ``shade``) with
    the exact boundary. Zoom afterwards with ``ax.set_xlim`` / ``ax.set_ylim``.

    Collective: call on every rank. Drawing happens on rank 0 only.

    Parameters
    ----------
    ax
        Axes to draw into on rank 0, or ``None`` to create a new figure there.
    cm
        The conforming mesh.
    show_background
        Draw the background mesh and ``T_h^sub`` underneath.
    mesh
        Mesh drawn as the conforming mesh instead of ``cm.mesh``, e.g. the curved mesh of
        :func:`dolfinx_universal.curved.curved_mesh` (a ``CurvedMesh`` or its ``.mesh``;
        drawn with curved edges). The per-cell shading of the conforming-only variant needs
        the same local cells as ``cm.mesh`` (true for curved meshes, which share its
        topology); otherwise cells are shaded uniformly.
    show_boundary
        Draw ``cm.boundary`` sampled at ``boundary_samples`` points.
    shade
        Shade kept and positively cut cells.
    background_edgecolor, kept_color, cut_color
        Colours of the background edges, kept and positively cut cells.
    edgecolor, linewidth
        Edges of the conforming mesh.
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

    Returns
    -------
    ``(figure, axes)`` on rank 0, ``(None, None)`` on the other ranks.
    """
    comm = cm.mesh.comm
    msh = cm.mesh if mesh is None else getattr(mesh, "mesh", mesh)  # Mesh or CurvedMesh
    sub = cm.mesh
    nco_sub = sub.topology.index_map(2).size_local
    kind = 1 + cm.positively_cut.astype(np.int8)  # 1 kept, 2 positively cut
    if show_background:
        bg = cm.background
        nbg = bg.topology.index_map(2).size_local
        nbg_all = nbg + bg.topology.index_map(2).num_ghosts
        bg_kind = np.zeros(nbg_all, dtype=np.int8)
        bg_kind[cm.cell_map[:nco_sub]] = kind[:nco_sub]
        bg_nodes, bg_kind = gather_cells(bg, bg_kind)
    degree, variant = _geometry_degree(msh)
    local_ok = int(msh is sub or msh.topology.index_map(2).size_local == nco_sub)
    same_order = comm.allreduce(local_ok, op=MPI.MIN) == 1
    if same_order:
        nodes, cell_kind = gather_cells(msh, kind)
    else:
        nodes, cell_kind = gather_cells(msh), None
    if comm.rank != 0:
        return None, None

    if ax is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=figsize)
        ax = fig.add_subplot()
    else:
        fig = ax.figure
    if show_background:
        faces = np.array(["none", kept_color, cut_color], dtype=object)[bg_kind]
        if not shade:
            faces = "none"
        plot_mesh(ax, bg_nodes, 1, facecolors=faces, edgecolor=background_edgecolor,
                  linewidth=linewidth, zorder=1)
        plot_mesh(ax, nodes, degree, facecolors="none", edgecolor=edgecolor,
                  linewidth=linewidth, points_per_edge=points_per_edge, variant=variant,
                  zorder=2)
    else:
        if shade and cell_kind is not None:
            faces = np.array(["none", kept_color, cut_color], dtype=object)[cell_kind]
        elif shade:
            faces = kept_color
        else:
            faces = "none"
        plot_mesh(ax, nodes, degree, facecolors=faces, edgecolor=edgecolor,
                  linewidth=linewidth, points_per_edge=points_per_edge, variant=variant,
                  zorder=2)
    if show_boundary and getattr(cm, "boundary", None) is not None:
        pts = boundary_polyline(cm.boundary, boundary_samples)
        ax.plot(pts[:, 0], pts[:, 1], color=boundary_color, linewidth=boundary_linewidth,
                zorder=3)
    ax.set_aspect("equal")
    ax.autoscale_view()
    if title is not None:
        ax.set_title(title)
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
