"""Vertex relaxation after M_h: move the band's vertices to improve the worst cells.

After ``M_h`` the cells at Gamma are the worst of a universal mesh (Rangarajan & Lew 2014:
minimum angles of about 21-23 degrees on equilateral backgrounds). Connectivity is fixed, so
quality can only be gained by moving vertices: each inside vertex of the band moves freely,
each vertex on Gamma slides along Gamma, to maximise the worst quality of the kept cells
around it: the max-min (nonsmooth) vertex optimisation of optimisation-based smoothing
(Freitag & Ollivier-Gooch 1997; Amenta, Bern & Eppstein 1999). A move is accepted only if
it raises the vertex's worst incident quality (by more than a tolerance) and keeps every
incident kept cell positively oriented, so validity and the global minimum of the quality
never get worse.

:func:`relax_vertices` picks the method of the cell type through the per-dimension kit
(:func:`~dolfinx_universal.conforming.kit.conforming_kit`): a compass search on triangles
(:mod:`~dolfinx_universal.conforming.relax_tri`), exact line searches along an ascent
direction on tetrahedra (:mod:`~dolfinx_universal.conforming.relax_tet`, a directional
vertex relaxation). Both share the movable vertices, their colouring and the frames of
:mod:`~dolfinx_universal.conforming.relax_common`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from mpi4py import MPI

from dolfinx_universal.conforming.kit import conforming_kit
from dolfinx_universal.conforming.relax_common import (
    FRAME_GRID,
    Relaxation,
    RelaxFrame,
    coordinate_priority,
    movable_vertices,
    vertex_colours,
)
from dolfinx_universal.conforming.relax_tri import shape_quality
from dolfinx_universal.core.arrays import Bool, Float, Int

if TYPE_CHECKING:
    from dolfinx.common import IndexMap

__all__ = [
    "FRAME_GRID",
    "Relaxation",
    "RelaxFrame",
    "coordinate_priority",
    "movable_vertices",
    "relax_vertices",
    "shape_quality",
    "vertex_colours",
]


def relax_vertices(
    comm: MPI.Comm,
    imv: IndexMap,
    onto_gamma: Callable[[Float], tuple[Float, Float]],
    x0: Float,
    xp: Float,
    y: Float,
    cells: Int,
    movable: Bool,
    on_gamma: Bool,
    normal: Float,
    phi: Float,
    h: Float,
    *,
    sweeps: int | None = None,
    frame: RelaxFrame | None = None,
) -> Relaxation:
    """Relax the images of vertices to raise the worst quality of their cells (collective).

    Triangles (points ``(n, 2)``): the compass search of
    :func:`~dolfinx_universal.conforming.relax_tri.relax_triangles`; tetrahedra (points
    ``(n, 3)``): the directional relaxation of
    :func:`~dolfinx_universal.conforming.relax_tet.relax_tetrahedra`. Both sweep over the
    colours of :func:`~dolfinx_universal.conforming.relax_common.vertex_colours` and move a
    vertex only where that raises the worst quality of its star by more than
    :data:`~dolfinx_universal.conforming.relax_common.TIE`.

    Parameters
    ----------
    comm
        Communicator of the mesh.
    imv
        Vertex index map.
    onto_gamma
        Points of Gamma near the sliding candidates of the vertices on Gamma, with the unit
        outward normals there, ``(n, gdim) -> ((n, gdim), (n, gdim))``
        (:meth:`~dolfinx_universal.boundaries.base.Boundary.onto_gamma`).
    x0
        Original background positions ``(num_vertices, gdim)`` (priorities, moved flags).
    xp
        Background positions used by the curved maps ``(num_vertices, gdim)``.
    y
        Vertex images after ``M_h`` ``(num_vertices, gdim)``.
    cells
        The owned kept cells whose quality counts ``(k, gdim + 1)``; every cell of a movable
        vertex must be among the owned ``cells`` of some rank.
    movable
        Vertices that may move, the same on every rank ``(num_vertices,)``.
    on_gamma
        Vertices on Gamma: they slide along it ``(num_vertices,)``.
    normal
        Unit normals of Gamma at the vertices on Gamma ``(num_vertices, gdim)`` (other rows are
        not read): the directions of their slides are tangent to Gamma there.
    phi
        Signed distances of the background positions ``xp`` ``(num_vertices,)`` (rows of
        the vertices on Gamma are read): a vertex that slides to ``y`` gets the background
        position ``y + phi N(y)`` (``N(y)`` from the projection that found ``y``), which
        projects onto ``y`` and lies as far from Gamma as before (so the exactly conforming
        map ``G_h`` still projects a background edge).
    h
        Mesh size at each vertex ``(num_vertices,)`` (scales the steps).
    sweeps
        Sweeps over all colours (fewer when two sweeps in a row move nothing).
    frame
        The frame of the colour priorities and the search directions (default: the world's
        axes, priorities from the background positions ``x0``).

    Returns
    -------
    The relaxed images and background positions, and the moved flags.
    """
    relax = conforming_kit(y.shape[1]).relax
    return relax(
        comm, imv, onto_gamma, x0, xp, y, cells, movable, on_gamma, normal, phi, h,
        sweeps=sweeps, frame=frame,
    )  # fmt: skip
