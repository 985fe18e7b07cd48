"""Curved universal meshes: the maps G_h, G~_h and their degree-k interpolants I_h, I~_h.

The driver :func:`curved_mesh` serves both dimensions; the triangle blend is in
:mod:`.maps_tri`, the tetrahedron blend in :mod:`.maps_tet`, picked by the cell type
(:data:`CELL_MAPS`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from types import ModuleType

from mpi4py import MPI

import basix
import numpy as np
import numpy.typing as npt
from dolfinx import fem
from dolfinx import mesh as dmesh

from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.conforming.classify import positively_cut
from dolfinx_universal.conforming.universal import IMMERSED, ConformingMesh
from dolfinx_universal.core.arrays import Float, write_cell_nodes
from dolfinx_universal.core.collective import Problem, collective_call, raise_collective
from dolfinx_universal.curved import maps_tet, maps_tri
from dolfinx_universal.curved.bounds import check_degree, jacobian_bounds

__all__ = [
    "CELL_MAPS",
    "MAPS",
    "CurvedMesh",
    "boundary_dof_data",
    "curved_mesh",
    "jacobian_ratio",
]


MAPS = ("I", "I~", "G", "G~")
"""Map names. ``"I"``/``"G"`` interpolate the exactly conforming blend ``G_h``; ``"I~"``/``"G~"``
interpolate ``G~_h`` (through the straight mesh). DOLFINx geometry is polynomial, so ``G`` is
realised as its degree-q interpolant: ``"G"`` with a geometry degree above the space degree is
the superparametric approximation of ``G_h``; with equal degrees it is ``I_h``. Triangles and
tetrahedra alike (the tetrahedron blend: :mod:`dolfinx_universal.curved.maps_tet`)."""

CELL_MAPS: dict[int, ModuleType] = {2: maps_tri, 3: maps_tet}
"""The curved maps per topological dimension: :mod:`.maps_tri` (triangles) and
:mod:`.maps_tet` (tetrahedra), with the same names (``reference_nodes``, ``curved_cells``,
``coordinate_geometry``, ``tangents``)."""


def _curved_cells(
    cm: ConformingMesh, degree: int, kind: str
) -> tuple[npt.NDArray[np.intp], Callable[[npt.NDArray, Float], Float]]:
    """The local cells a curved map changes and the map of their nodes
    (``curved_cells`` of :mod:`.maps_tri` or :mod:`.maps_tet`; collective).

    Returns
    -------
    cells
        Indices of the cells to curve ``(k,)``.
    map
        ``(cells (k, tdim + 1), y (num_vertices, gdim)) -> nodes (k, ndofs, gdim)``.
    """
    return CELL_MAPS[cm.mesh.topology.dim].curved_cells(
        cm.mesh,
        cm.cells,
        np.flatnonzero(positively_cut(cm.sign, cm.cells)),
        cm.facet_tags.find(IMMERSED),
        cm.on_gamma,
        cm.sign,
        cm.background_x,
        degree,
        kind,
        cm.boundary.closest_point,
    )


def jacobian_ratio(
    nodes: Float, degree: int, resolution: int | None = None, *, threshold: float = 0.0
) -> Float:
    """Proven lower bound of the ratio ``det J / det J_affine`` over each curved cell.

    ``det J`` of a degree-k triangle (tetrahedron) is a polynomial of degree ``2(k-1)``
    (``3(k-1)``) in the reference coordinates;
    :func:`~dolfinx_universal.curved.bounds.jacobian_bounds`
    writes it in the Bernstein basis and subdivides until the bound decides ``threshold`` and
    lies within 5 % (5e-4 near 0) of an attained value (``det J_affine``: the cell through the
    vertex nodes). ``ratio <= threshold`` is therefore a safe failure test: a cell above it
    is proven valid; an undecided cell (after 8 subdivision levels, 6 for tetrahedra) stays
    at or below it.

    Parameters
    ----------
    nodes
        Node coordinates of each cell, ``(m, ndofs, 2)`` (triangles) or ``(m, ndofs, 3)``
        (tetrahedra).
    degree
        Geometry degree.
    resolution
        Deprecated and ignored (the former sampling lattice's subdivisions per edge).
    threshold
        The ratio to decide exactly (default 0: inversion).

    Returns
    -------
    The lower bound for each cell, ``(m,)`` (1 for an affine cell).
    """
    if resolution is not None:
        warnings.warn(
            "jacobian_ratio(resolution=...) is ignored: the bound is proven, not sampled",
            DeprecationWarning,
            stacklevel=2,
        )
    return jacobian_bounds(nodes, degree, threshold=threshold)[0]


@lru_cache(maxsize=16)
def _coordinate_element(cell_type: dmesh.CellType, degree: int) -> fem.CoordinateElement:
    """DOLFINx's GLL-warped Lagrange coordinate element, built once per cell type and degree
    (the build costs about as much as the curved map of 1e4 triangles)."""
    return fem.coordinate_element(cell_type, degree, basix.LagrangeVariant.gll_warped)


@dataclass
class CurvedMesh:
    """A degree-k conforming mesh on the topology of a straight conforming mesh."""

    mesh: dmesh.Mesh
    """The curved mesh (Lagrange coordinate element of degree ``degree``, GLL-warped nodes)."""
    facet_tags: dmesh.MeshTags
    """:data:`~dolfinx_universal.conforming.universal.IMMERSED` /
    :data:`~dolfinx_universal.conforming.universal.OUTER`."""
    conforming: ConformingMesh
    degree: int
    map: str
    min_jacobian_ratio: float
    """Global minimum of ``det J / det J_straight`` over the curved cells: a proven lower
    bound, within 5 % of the minimum (:func:`jacobian_ratio`)."""


def curved_mesh(
    cm: ConformingMesh, degree: int, map: str = "I", *, min_ratio: float = 0.0
) -> CurvedMesh:
    """Degree-k DOLFINx mesh whose nodes are the images of the Lagrange nodes under a curved map.

    Triangles: only positively cut cells are curved (their positive edge follows Gamma
    through the closest-point projection). Tetrahedra: the cells with a positive face (it
    follows Gamma) and those touching Gamma_h by an edge (it follows the curved edge), see
    :mod:`dolfinx_universal.curved.maps_tet`. Every other cell is the affine image of its ``M_h``
    vertices. Nodes on Gamma lie exactly on Gamma. Collective.

    Parameters
    ----------
    cm
        Straight conforming mesh from :func:`~dolfinx_universal.conforming.universal.conform`.
    degree
        Geometry degree ``q >= 1``, at most :data:`~dolfinx_universal.curved.bounds.MAX_DEGREE`
        (7 for triangles, 5 for tetrahedra). ``degree = 1`` returns a copy of the straight
        mesh.
    map
        One of :data:`MAPS`.
    min_ratio
        Smallest allowed ``det J / det J_straight`` in a curved cell (0: only inversion is
        an error).

    Raises
    ------
    MeshingError
        If a curved cell is inverted (its Jacobian determinant changes sign).
    ValueError
        If the degree is not an integer from 1 to the limit above, or the map is unknown.
    """
    if not isinstance(cm, ConformingMesh):
        raise TypeError(
            "curved_mesh needs the ConformingMesh returned by conform (it carries the "
            f"background positions, signs and the boundary), got {type(cm).__name__}: use "
            "curved_mesh(conform(background, boundary), degree)"
        )
    if map not in MAPS:
        raise ValueError(f"unknown map {map!r}: choose one of {MAPS}")
    tdim = cm.mesh.topology.dim
    degree = check_degree(degree, tdim)
    kernels = cell_kernels(tdim)
    kind = "G" if map in ("I", "G") else "G~"
    ce = _coordinate_element(kernels.cell_type, degree)
    # The degree-q geometry is the affine image of every cell: only the curved cells change
    # (affine on their straight entities, so shared nodes agree).
    msh = CELL_MAPS[tdim].coordinate_geometry(cm.mesh, ce)
    cells = cm.cells
    pc, cell_map = _curved_cells(cm, degree, kind)
    dofmap = msh.geometry.dofmaps[0]
    # Vertex positions of the curved cells only (a node shared by a curved cell and an
    # affine one agrees up to rounding: the curved map is affine on the straight entities).
    corners = cm.mesh.geometry.x[cm.mesh.geometry.dofmaps[0][pc], :tdim]  # (k, tdim + 1, tdim)
    y = np.zeros((len(cm.sign), tdim))
    y[cells[pc]] = corners
    nodes = collective_call(msh.comm, "the curved map", cell_map, cells[pc], y)
    write_cell_nodes(msh.geometry.x, dofmap, pc, nodes)

    ratio = (
        jacobian_ratio(nodes, degree, threshold=min_ratio) if degree > 1 and len(pc) else np.ones(0)
    )
    bad = ratio <= min_ratio
    problems = []
    if bad.any():
        problems.append(
            Problem(
                f"{{count}} curved {kernels.plural} are not proven valid (det J / "
                f"det J_straight >= {min_ratio:g} fails) near " + "{where}: the background is "
                "too coarse for the "
                "boundary's curvature there; refine near those points",
                nodes[bad].mean(axis=1),
                int(bad.sum()),
            )
        )
    raise_collective(msh.comm, problems)
    local_min = float(ratio.min()) if len(ratio) else 1.0
    tags = dmesh.meshtags(msh, tdim - 1, cm.facet_tags.indices, cm.facet_tags.values)
    return CurvedMesh(
        mesh=msh,
        facet_tags=tags,
        conforming=cm,
        degree=int(degree),
        map=map,
        min_jacobian_ratio=msh.comm.allreduce(local_min, op=MPI.MIN),
    )


def boundary_dof_data(
    V: fem.FunctionSpace, curved: CurvedMesh, tag: int = IMMERSED
) -> tuple[npt.NDArray[np.int32], Float, Float, Float]:
    """Boundary degrees of freedom of ``V`` on a tagged boundary, with the true geometry there.

    Parameters
    ----------
    V
        A (scalar, or blocked vector) Lagrange space on ``curved.mesh``.
    curved
        The curved mesh.
    tag
        Facet tag (default the immersed boundary).

    Returns
    -------
    dofs
        Process-local dof (block) indices on the tagged facets, owned and ghost, ``(n,)``.
    closest
        Closest points of Gamma to the dof coordinates, ``(n, gdim)`` (the dofs lie on Gamma
        when the space and geometry degrees agree).
    normal
        Unit outward normal of Gamma there, ``(n, gdim)``.
    tangent
        Unit tangent of a curve ``(n, 2)``; orthonormal tangent bases of a surface
        ``(n, 2, 3)`` (:meth:`~dolfinx_universal.boundaries.surfaces.Surface.tangent_basis`).
    """
    tdim = curved.mesh.topology.dim
    facets = curved.facet_tags.find(tag)
    dofs = fem.locate_dofs_topological(V, tdim - 1, facets)
    xd = V.tabulate_dof_coordinates()[dofs, :tdim]
    boundary = curved.conforming.boundary

    def frames() -> tuple[Float, Float, Float]:
        y = boundary.closest_point(xd) if len(dofs) else np.zeros((0, tdim))
        return y, boundary.normal(y), CELL_MAPS[tdim].tangents(boundary, y)

    # Collective: the projection runs on each rank's own nodes, and fails on all if on one.
    y, normal, tangent = collective_call(V.mesh.comm, "closest-point projection", frames)
    return dofs, y, normal, tangent
