"""Quality of conforming meshes: angles, radius ratios, edge ratios, what was altered.

One report for both dimensions (:func:`quality_report`): the counts of cells kept, cut and
unaltered are common; the shape figures are those of the cell type, picked through the
per-dimension kit (:func:`~dolfinx_universal.conforming.kit.conforming_kit`): interior
angles, radius ratios and edge ratios of triangles
(:func:`~dolfinx_universal.conforming.quality_tri.shape_figures`); dihedral angles, radius
and mean ratios of tetrahedra (:func:`~dolfinx_universal.conforming.quality_tet.shape_figures`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.conforming.classify import positively_cut
from dolfinx_universal.conforming.kit import conforming_kit
from dolfinx_universal.conforming.quality_tri import edge_ratio, radius_ratio
from dolfinx_universal.core.arrays import any_rows

if TYPE_CHECKING:
    from dolfinx_universal.conforming.universal import ConformingMesh

__all__ = ["background_positions", "cell_quality", "edge_ratio", "quality_report", "radius_ratio"]

QualityReport = dict[str, Any]
"""The figures of :func:`quality_report`: ints and floats (and, for tetrahedra, the
dihedral angle histogram as a list of ints)."""


def quality_report(cm: ConformingMesh) -> QualityReport:
    """Global quality figures of a conforming mesh (collective).

    Returns
    -------
    A dict with, in both dimensions: ``n_cells`` (cells kept), ``n_positively_cut``,
    ``n_unaltered`` (no vertex moved), ``percent_unaltered``, ``theta_min_deg`` and
    ``theta_max_deg`` (smallest and largest angle: interior angles of triangles, dihedral
    angles of tetrahedra) and ``n_inverted`` (cells whose orientation differs from that of
    the cell in the original background: the relaxation may move ``background_x`` of the
    vertices on Gamma, the orientation is checked against the background itself).

    Triangles add ``q_max`` (max circumradius/inradius), ``Q3_max``, ``Q2_max``, ``Q1_max``
    (max longest/shortest edge over triangles with 3, 2 and 1 vertices inside the domain; 0
    when there are none) and ``min_area_ratio`` (conforming area over the area of the
    triangle in the background).

    Tetrahedra add ``dihedral_histogram`` (counts of the dihedral angles in the 18 bins of
    10 degrees over [0, 180], a list of ints), ``radius_ratio_min`` (``3 r_in / R_circ``, 1
    for the regular tetrahedron), ``mean_ratio_min`` (signed by the background's orientation)
    and ``min_volume_ratio`` (conforming volume over the background tetrahedron's volume).
    """
    nco = cm.mesh.topology.index_map(cm.mesh.topology.dim).size_local
    return cell_quality(
        cm.mesh.comm, cm.x, background_positions(cm), cm.cells[:nco], cm.sign, cm.moved
    )


def background_positions(cm: ConformingMesh) -> npt.NDArray[np.float64]:
    """Original background positions of the vertices of ``cm``, ``(num_vertices, tdim)``."""
    bg = cm.background
    topo = bg.topology
    tdim = topo.dim
    topo.create_connectivity(tdim, 0)
    c2v = topo.connectivity(tdim, 0).array.reshape(-1, tdim + 1)
    imv = topo.index_map(0)
    v2n = np.empty(imv.size_local + imv.num_ghosts, dtype=np.int32)
    v2n[c2v] = bg.geometry.dofmaps[0][:, : tdim + 1]
    return bg.geometry.x[v2n[cm.vertex_map], :tdim]


def cell_quality(
    comm: MPI.Comm,
    x: npt.NDArray[np.float64],
    background_x: npt.NDArray[np.float64],
    cells: npt.NDArray,
    sign: npt.NDArray[np.float64],
    moved: npt.NDArray[np.bool_],
) -> QualityReport:
    """The figures of :func:`quality_report` for given (owned) cells (collective).

    Parameters
    ----------
    comm
        Communicator to reduce over.
    x, background_x
        Conforming and background vertex positions ``(num_vertices, tdim)``.
    cells
        Owned triangles ``(m, 3)`` or tetrahedra ``(m, 4)`` to report on (every rank
        passes cells of one kind, possibly none).
    sign, moved
        Vertex signs and moved flags ``(num_vertices,)``.
    """
    cells = np.asarray(cells)
    shape_figures = conforming_kit(cells.shape[1] - 1).shape_figures
    report = {
        "n_cells": comm.allreduce(len(cells), op=MPI.SUM),
        "n_positively_cut": comm.allreduce(int(positively_cut(sign, cells).sum()), op=MPI.SUM),
        "n_unaltered": comm.allreduce(int((~any_rows(moved[cells])).sum()), op=MPI.SUM),
    }
    report.update(shape_figures(comm, x, background_x, cells, sign))
    report["percent_unaltered"] = 100.0 * report["n_unaltered"] / max(report["n_cells"], 1)
    return report
